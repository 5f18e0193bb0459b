"""The scene's tables: one frozen, validated dataclass per TOML table, and the vocabularies they take.

Each table (``[object]``, ``[[material]]``, ``[nodes]``, ``[elasticity]``, ``[[fixed]]``, ``[[load]]``,
``[solver]``, ``[[probe]]``, ``[output]``, ``[[obstacle]]``, ``[contact]``, ``[[cable]]``; a node kind's own
tables come from its kind) checks its own keys, types and ranges on construction, naming the table and the
key.  What concerns several tables at once, reading and writing TOML, and the scene itself live in
:mod:`voxflex.scene`, which re-exports every name here (docs/scene.md is the reference).  Light: no numba,
no scipy.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

from ._checks import boolean as _boolean
from ._checks import number as _number
from ._checks import string as _string
from ._checks import vector as _vector
from .deform.layers.cable import Cable
from .deform.layers.obstacles import OBSTACLE_KEYS as _OBSTACLE_KEYS
from .deform.layers.obstacles import OBSTACLE_KINDS
from .deform.layers.obstacles import POINT_RULES as CONTACT_POINT_RULES
from .deform.materials.catalogue import (
    MATERIAL_NAMES,
    POISSON_RANGE,
    STRAIN_NAMES,
    check_constants,
)
from .deform.materials.fbar import VOLUMETRIC
from .deform.models.fields import check_field_names
from .deform.models.kinds import default_kind, node_kind, node_kinds
from .deform.models.membrane.kind import MembraneSpec  # noqa: F401  (the [membrane] table, defined by its kind)
from .deform.models.voxel.kind import HOURGLASS
from .deform.solve.boundary import FORCE_KINDS, PRESSURE_KIND
from .deform.solve.options import SolverOptions
from .errors import InputError, check_choice
from .rasterize.primitives import PRIMITIVES
from .sampling.quadrature import QUADRATURES
from .voronoi.families import PLACEMENTS, SHAPE_FUNCTIONS

# every vocabulary is defined once, in the stage that owns it (node kinds add their own shapes and loads)
SHAPES = {**{name: entry[1] for name, entry in PRIMITIVES.items()},
          **{name: n for kind in node_kinds().values() for name, n in kind.shapes.items()}}
NODE_KINDS = tuple(node_kinds())
LOAD_KINDS = ("gravity", *FORCE_KINDS, *(k for kind in node_kinds().values() for k in kind.load_kinds))
DISTANCES = ("geodesic", "compliance")
MIN_PARENTS = 4
"""Fewest ``[nodes] parents`` a frame model takes: cut (conformingly) to fewer frames per point, the weights leave
the frames far stiffer than the same weights uncut (the 16x4x4 linear cantilever with 20 natural-neighbour frames
and Gauss points sags 0.114 / 0.182 / 0.236 / 0.259 m with 2 / 3 / 4 / 6 parents against 0.262 m uncut and a
converged 0.393 m).  The cut used to renormalise the kept weights as they were, which jumped between frames:
0.536 m with 2 parents and 0.439 m with 3, softer than converged."""
FRICTION_MAX = 100.0
"""The largest Coulomb coefficient a scene takes (dimensionless).  Dry rubber on rough surfaces stays below
about 2; far beyond, the friction spring below the slip threshold (stiffness ~ mu N / eps) outgrows
the material by so much that Newton's residual cannot fall below its round-off (friction 1e12 on a
sliding ball: steps stopped at relative residual 1.0)."""
KEEP = ("all", "largest")
_INF = math.inf


# ---------------------------------------------------------------------------
# the tables
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class ObjectSpec:
    """``[object]``: exactly one of ``shape`` / ``mesh`` / ``image``.

    Parameters
    ----------
    shape : {"box", "cylinder", "sphere"}, optional
        A primitive; ``size`` gives box lengths (3), cylinder ``[radius, length]``
        or sphere ``[radius]``, in metres.
    mesh, image : str, optional
        Paths (absolute once read from a file: relative paths are resolved
        against the scene file's folder).  A mesh is voxelized at ``voxel_size``;
        an image is used as is (its own spacing and origin).
    voxel_size : float, metres
        Required for shape and mesh.
    origin : (3,) float, metres
        Lower corner of the shape's bounding box (shape only).
    axis : {"x", "y", "z"}
        Cylinder axis (extension; default "z").
    occupancy : bool
        Partial volume (extension; default false): shapes and meshes are
        voxelized with occupancy fractions, and every voxel's volume and mass
        are weighted by its fraction; an image uses the fractions it carries.
    keep : {"all", "largest"}
        Keep every material component (face connectivity) or only the largest.
    min_component_voxels : int
        Drop components with fewer voxels (islands of a voxelized mesh), with a warning.
    up : {"x", "y", "z"}
        The object's axis that should point up: the object is turned about the
        world origin so that this axis becomes +z (``"y"`` for y-up meshes);
        every other key of the scene is in the turned frame.  Default "z".
    """

    shape: str | None = None
    size: tuple[float, ...] | None = None
    mesh: str | None = None
    image: str | None = None
    voxel_size: float | None = None
    origin: tuple[float, float, float] | None = None
    axis: str | None = None
    occupancy: bool | None = None
    keep: str = "all"
    min_component_voxels: int = 1
    up: str = "z"

    def __post_init__(self):
        t = "object"
        _string(t, "up", self.up, ("x", "y", "z"))
        if self.occupancy is not None:
            _boolean(t, "occupancy", self.occupancy)
        _string(t, "keep", self.keep, KEEP)
        object.__setattr__(self, "min_component_voxels",
                           _number(t, "min_component_voxels", self.min_component_voxels, integer=True, minimum=1))
        given = [k for k in ("shape", "mesh", "image") if getattr(self, k) is not None]
        if len(given) != 1:
            raise InputError(
                f"[object] needs exactly one of shape, mesh, image (got {', '.join(given) or 'none'}); "
                "e.g. shape = \"box\" with size = [4.0, 1.0, 1.0]"
            )
        if self.shape is not None:
            _string(t, "shape", self.shape, tuple(SHAPES))
            if self.size is None:
                raise InputError(f"[object] shape = \"{self.shape}\" needs size ({_size_help(self.shape)})")
            n = SHAPES[self.shape]
            if isinstance(self.size, (int, float)) and not isinstance(self.size, bool) and n == 1:
                object.__setattr__(self, "size", (self.size,))
            try:
                size = _vector(t, "size", self.size, n, positive=True)
            except InputError:
                raise InputError(
                    f"[object] size for shape \"{self.shape}\" must be {_size_help(self.shape)}, got {self.size!r}"
                ) from None
            object.__setattr__(self, "size", size)
            if self.axis is not None:
                _string(t, "axis", self.axis, ("x", "y", "z"))
                if self.shape != "cylinder":
                    raise InputError("[object] axis applies to shape = \"cylinder\" only; remove it")
        else:
            if self.size is not None:
                raise InputError("[object] size applies to shape only; remove it for a mesh or an image")
            if self.axis is not None:
                raise InputError("[object] axis applies to shape = \"cylinder\" only; remove it")
            if self.origin is not None:
                raise InputError(
                    "[object] origin applies to shape only (a mesh or an image keeps its own coordinates); remove it"
                )
            key = "mesh" if self.mesh is not None else "image"
            _string(t, key, getattr(self, key))
        if self.image is not None:
            if self.voxel_size is not None:
                raise InputError(
                    "[object] voxel_size applies to shape and mesh only (an image keeps its own spacing); remove it"
                )
        else:
            if self.voxel_size is None:
                raise InputError("[object] needs voxel_size (metres) for a shape or a mesh, e.g. voxel_size = 0.1")
            object.__setattr__(self, "voxel_size", _number(t, "voxel_size", self.voxel_size, positive=True))
        if self.origin is not None:
            object.__setattr__(self, "origin", _vector(t, "origin", self.origin))

    @property
    def source_kind(self) -> str:
        """``"shape"``, ``"mesh"`` or ``"image"``."""
        return "shape" if self.shape else ("mesh" if self.mesh else "image")


def _size_help(shape: str) -> str:
    return {
        "box": "[lx, ly, lz]",
        "cylinder": "[radius, length]",
        "sphere": "[radius]",
        "disk": "[radius]",
        "rectangle": "[lx, ly]",
    }.get(shape, "a list of positive numbers")


@dataclass(frozen=True)
class MaterialSpec:
    """``[[material]]``: the material of one label.

    ``young`` (Pa) and ``poisson`` in (-1, 0.5) for every isotropic model, or the
    model's own constants (``constants``, written as plain keys in TOML);
    ``density`` in kg/m^3; ``strain`` overrides ``[elasticity] strain`` for this
    label.  ``yield_strain`` makes the label plastic (von Mises on the strain,
    :class:`~voxflex.deform.layers.plasticity.PlasticMaterial`) with the linear
    ``hardening`` modulus (dimensionless, default 0: perfectly plastic).
    """

    label: int = 1
    model: str = "neo-hookean"
    young: float | None = None
    poisson: float | None = None
    density: float = 1000.0
    strain: str | None = None
    yield_strain: float | None = None
    hardening: float | None = None
    constants: tuple[tuple[str, float], ...] = ()

    def __post_init__(self):
        t = "material"
        label = _number(t, "label", self.label, integer=True)
        if not 1 <= label <= 65535:
            raise InputError(f"[material] label must be in 1..65535 (0 is empty space), got {label}")
        object.__setattr__(self, "label", label)
        _string(t, "model", self.model, MATERIAL_NAMES)
        if self.young is not None:
            object.__setattr__(self, "young", _number(t, "young", self.young, positive=True))
        if self.poisson is not None:
            nu = _number(t, "poisson", self.poisson)
            lo, hi = POISSON_RANGE
            if not lo < nu < hi:
                raise InputError(f"[material] poisson must be in ({lo:g}, {hi:g}), got {nu!r}")
            object.__setattr__(self, "poisson", nu)
        object.__setattr__(self, "density", _number(t, "density", self.density, positive=True))
        if self.strain is not None:
            _string(t, "strain", self.strain, STRAIN_NAMES)
        if self.yield_strain is not None:
            object.__setattr__(self, "yield_strain", _number(t, "yield_strain", self.yield_strain, positive=True))
        if self.hardening is not None:
            if self.yield_strain is None:
                raise InputError("[material] hardening needs yield_strain (the label is elastic without it); "
                                 "add yield_strain or remove hardening")
            object.__setattr__(self, "hardening", _number(t, "hardening", self.hardening, nonnegative=True))
        constants = dict(self.constants)
        check_constants(self.model, sorted(constants))
        for name, value in constants.items():
            if isinstance(value, (list, tuple)):
                constants[name] = tuple(_number(t, name, v) for v in value)
            else:
                constants[name] = _number(t, name, value)
        object.__setattr__(self, "constants", tuple(sorted(constants.items())))

    def material_kwargs(self, default_strain: str | None = None) -> dict:
        """Keyword arguments for :func:`voxflex.deform.materials.constitutive.material` (besides the name)."""
        kwargs = dict(self.constants)
        if self.young is not None:
            kwargs["young"] = self.young
        if self.poisson is not None:
            kwargs["poisson"] = self.poisson
        strain = self.strain or default_strain
        if strain is not None:
            kwargs["strain"] = strain
        return kwargs


@dataclass(frozen=True)
class NodesSpec:
    """``[nodes]``: what carries the degrees of freedom.

    ``kind``: ``"affine"`` (12-DOF frames, the reduced model: the default),
    ``"voxel"`` (trilinear nodes at the voxel corners, the full-resolution
    reference) or ``"rigid"`` (6-DOF frames: static scenes only).  The frame keys: ``count`` frames in all
    (default 20, or the number of material voxels when the object has fewer),
    ``positions`` (frames given by the user, world, placed first),
    ``shape_function`` (default: the kind's own, ``"reproducing-kernel"`` for affine
    frames, which the builder swaps for natural neighbours on a body where they would leave
    spurious modes; :attr:`weights` names the default), ``parents`` (at most this
    many frames influence a material point; not applied to
    ``"reproducing-kernel"``, whose weights are never truncated), ``support``
    (``"reproducing-kernel"`` only: kernel radius in local frame spacings,
    default 2.5), ``distance`` (``geodesic`` or ``compliance``), ``seed``
    (placement is deterministic for a seed) and ``placement`` (``"volume"``, the
    default: farthest point and Lloyd over the material; ``"strain"``: the same in
    the metric of a first cheap solve's strain energy, see
    :func:`voxflex.build.strain_indicator`; not with ``"eigenmode"`` weights, whose
    frames are chosen from the modes).
    Each kind takes the shape functions its :class:`~voxflex.deform.models.kinds.NodeKind` names
    (voxel nodes: ``"trilinear"`` only; membranes: none).
    """

    kind: str = field(default_factory=lambda: default_kind().name)
    count: int | None = None
    positions: tuple[tuple[float, float, float], ...] | None = None
    shape_function: str | None = None
    parents: int = 6
    distance: str = "geodesic"
    seed: int = 0
    support: float | None = None
    placement: str | None = None

    def __post_init__(self):
        t = "nodes"
        _string(t, "kind", self.kind, NODE_KINDS)
        if self.count is not None:
            object.__setattr__(self, "count", _number(t, "count", self.count, integer=True, minimum=1))
        if self.shape_function is not None:
            valid = node_kind(self.kind).shape_functions
            if self.shape_function in SHAPE_FUNCTIONS and self.shape_function not in valid:
                raise InputError(
                    f'[nodes] shape_function = "{self.shape_function}" does not apply to kind = "{self.kind}"; '
                    + (f"valid for it: {', '.join(valid)}" if valid else "that kind takes none (remove the key)")
                )
            _string(t, "shape_function", self.shape_function, valid or SHAPE_FUNCTIONS)
        if self.positions is not None:
            rows = self.positions
            if isinstance(rows, (str, bytes)) or not hasattr(rows, "__len__") or len(rows) == 0:
                raise InputError(f"[nodes] positions must be a list of [x, y, z] points, got {rows!r}")
            object.__setattr__(self, "positions", tuple(_vector(t, "positions", r) for r in rows))
        object.__setattr__(self, "parents", _number(t, "parents", self.parents, integer=True, minimum=1))
        _string(t, "distance", self.distance, DISTANCES)
        object.__setattr__(self, "seed", _number(t, "seed", self.seed, integer=True, minimum=0))
        if self.support is not None:
            if self.weights != "reproducing-kernel":
                raise InputError('[nodes] support is the kernel radius of shape_function = "reproducing-kernel"; '
                                 'remove it or set that shape function')
            object.__setattr__(self, "support", _number(t, "support", self.support, positive=True))
        if self.placement is not None:
            _string(t, "placement", self.placement, PLACEMENTS)
            if self.placement != "volume" and "strain-placement" not in node_kind(self.kind).takes:
                raise InputError(f'[nodes] placement = "{self.placement}" places frames; kind = "{self.kind}" '
                                 "does not take it (remove the key)")
            if self.placement == "strain" and self.weights == "eigenmode":
                raise InputError('[nodes] placement = "strain" does not apply to shape_function = "eigenmode": its '
                                 "frames are chosen from the modes (the weights' span does not depend on where "
                                 "they sit); remove placement")

    @property
    def weights(self) -> str | None:
        """The shape-function family the nodes use: ``shape_function``, or the kind's default (None for
        a kind that takes none).  Read this, not ``shape_function``, wherever the family matters."""
        return self.shape_function or node_kind(self.kind).default_shape_function


@dataclass(frozen=True)
class ElasticitySpec:
    """``[elasticity]``: quadrature, samples, strain, volumetric (``"auto"``: F-bar where nu >= 0.4)
    and hourglass (mid-point stabilisation of voxels and of frames' regions).

    ``quadrature`` defaults to the node kind's own (resolved by :class:`Scene`):
    ``"gauss-legendre"`` (2x2x2 per voxel) for voxel nodes, ``"midpoint"``
    (``samples`` regions) for frames, ``"elaston"`` for frames with weights never cut to their parents
    (``"reproducing-kernel"``, ``"eigenmode"``: :data:`voxflex.voronoi.families.UNTRUNCATED`).  ``samples`` (frames' regions) defaults to a count
    the frame builder chooses from the frames and checks for soft modes
    (``voxflex.deform.models.frames.build.REGIONS_PER_FRAME``, resolved where the frame count is known)."""

    quadrature: str | None = None
    samples: int | None = None
    strain: str | None = None
    volumetric: str = "auto"
    hourglass: str = "stiffness"

    def __post_init__(self):
        if self.quadrature is not None:
            _string("elasticity", "quadrature", self.quadrature, QUADRATURES)
        _string("elasticity", "volumetric", self.volumetric, VOLUMETRIC)
        _string("elasticity", "hourglass", self.hourglass, HOURGLASS)
        if self.samples is not None:
            object.__setattr__(self, "samples", _number("elasticity", "samples", self.samples, integer=True,
                                                        minimum=1))
        if self.strain is not None:
            _string("elasticity", "strain", self.strain, STRAIN_NAMES)


@dataclass(frozen=True)
class FixedSpec:
    """``[[fixed]]``: nodes whose rest position lies in the box [min, max] are held.

    ``components`` holds only some (e.g. ``"x"`` for a sliding support);
    ``transform`` (3x4 affine map, reached at the end of the run) moves the
    region instead of holding it in place.
    """

    min: tuple[float, float, float] = (-_INF, -_INF, -_INF)
    max: tuple[float, float, float] = (_INF, _INF, _INF)
    components: str = "xyz"
    transform: tuple[tuple[float, ...], ...] | None = None

    def __post_init__(self):
        t = "fixed"
        lo = _vector(t, "min", self.min, finite=False)
        hi = _vector(t, "max", self.max, finite=False)
        if any(a > b for a, b in zip(lo, hi)):
            raise InputError(f"[fixed] min must be <= max along every axis, got min={list(lo)} max={list(hi)}")
        object.__setattr__(self, "min", lo)
        object.__setattr__(self, "max", hi)
        comp = _string(t, "components", self.components)
        if not comp or any(c not in "xyz" for c in comp) or len(set(comp)) != len(comp):
            raise InputError(f"[fixed] components must be a non-empty subset of \"xyz\" (e.g. \"x\"), got {comp!r}")
        object.__setattr__(self, "components", "".join(c for c in "xyz" if c in comp))
        if self.transform is not None:
            rows = self.transform
            if isinstance(rows, (str, bytes)) or not hasattr(rows, "__len__") or len(rows) != 3:
                raise InputError(f"[fixed] transform must be a 3x4 matrix [[a,b,c,tx],[..],[..]], got {rows!r}")
            object.__setattr__(self, "transform", tuple(_vector(t, "transform", r, 4) for r in rows))
            _check_reachable(self.transform)


def _check_reachable(transform) -> None:
    """InputError for a ``[[fixed]] transform`` that collapses the region: a real eigenvalue of its 3x3 part at 0
    (the zero matrix crushed the clamp to a point and ran, exit 0).  Negative eigenvalues are kept: a region
    pushed through zero volume is how inversion is tested, and inverted samples are counted and warned about."""
    import numpy as np

    A = np.asarray(transform, dtype=float)[:, :3]
    lam = np.linalg.eigvals(A)
    size = max(float(np.abs(lam).max()), 1.0)
    real = lam.real[np.abs(lam.imag) <= 1e-9 * size]
    if np.any(np.abs(real) <= 1e-12 * size):
        raise InputError(
            f"[fixed] transform's 3x3 part is singular (determinant {np.linalg.det(A):.3g}): it collapses the "
            "region to zero volume at the end of the run, where no material is defined; give a map with a "
            "non-zero determinant (a rotation, a stretch, a shear)")


@dataclass(frozen=True)
class LoadSpec:
    """``[[load]]``: ``gravity`` (acceleration, m/s^2, on every label's density),
    ``traction`` (Pa on the boundary faces inside [min, max]), ``force``
    (a total force in N spread over the nodes inside [min, max]) or ``pressure``
    (``pressure`` Pa along the normals of a membrane's triangles, a follower load;
    membranes only, on the whole membrane: no vector, min or max)."""

    kind: str = "gravity"
    vector: tuple[float, float, float] | None = None
    min: tuple[float, float, float] | None = None
    max: tuple[float, float, float] | None = None
    pressure: float | None = None

    def __post_init__(self):
        t = "load"
        _string(t, "kind", self.kind, LOAD_KINDS)
        if self.kind == PRESSURE_KIND:
            if self.pressure is None:
                raise InputError('[load] kind = "pressure" needs pressure (Pa), e.g. pressure = 1000.0')
            object.__setattr__(self, "pressure", _number(t, "pressure", self.pressure))
            if math.isinf(self.pressure):
                raise InputError(f"[load] pressure must be finite, got {self.pressure!r}")
            if self.vector is not None and any(v != 0 for v in _vector(t, "vector", self.vector)):
                raise InputError('[load] vector does not apply to kind = "pressure" (it pushes along the '
                                 "membrane's normals); remove it")
            bounds = [_vector(t, k, getattr(self, k), finite=False) for k in ("min", "max") if getattr(self, k) is not None]
            if any(not math.isinf(v) for box in bounds for v in box):  # (to_toml writes the unbounded box)
                raise InputError('[load] kind = "pressure" acts on the whole membrane (a conservative pressure '
                                 "needs all of it); remove min/max")
            object.__setattr__(self, "vector", (0.0, 0.0, 0.0))  # simulate() reads a vector from every load
            object.__setattr__(self, "min", (-_INF,) * 3)
            object.__setattr__(self, "max", (_INF,) * 3)
            return
        if self.pressure is not None:
            raise InputError(f'[load] pressure applies to kind = "pressure" only; remove it (kind = "{self.kind}")')
        vector = (0.0, 0.0, -9.81) if self.vector is None else self.vector
        object.__setattr__(self, "vector", _vector(t, "vector", vector))
        if self.kind == "gravity":
            if self.min is not None or self.max is not None:
                raise InputError("[load] min/max apply to traction and force loads; gravity acts everywhere")
        else:
            lo = (-_INF,) * 3 if self.min is None else _vector(t, "min", self.min, finite=False)
            hi = (_INF,) * 3 if self.max is None else _vector(t, "max", self.max, finite=False)
            if self.min is None and self.max is None:
                raise InputError(f"[load] kind = \"{self.kind}\" needs a region: give min and/or max")
            if any(a > b for a, b in zip(lo, hi)):
                raise InputError(f"[load] min must be <= max along every axis, got min={list(lo)} max={list(hi)}")
            object.__setattr__(self, "min", lo)
            object.__setattr__(self, "max", hi)


SolverSpec = SolverOptions
"""``[solver]``: the solver's options themselves (:class:`voxflex.deform.solve.options.SolverOptions`)."""


@dataclass(frozen=True)
class ProbeSpec:
    """``[[probe]]``: a material point (world rest position, metres) recorded at every step."""

    name: str
    point: tuple[float, float, float]

    def __post_init__(self):
        name = _string("probe", "name", self.name)
        if not name or "/" in name or name in {".", ".."}:
            raise InputError(f"[probe] name must be a non-empty name without '/', got {name!r}")
        object.__setattr__(self, "point", _vector("probe", "point", self.point))


KEEP_CHOICES = ("auto", "all", "last")
"""Named values of ``keep`` (which recorded states a run holds in memory); an integer N >= 1 also works."""

def check_keep(keep, where: str = "keep"):
    """Validate ``keep``: ``"auto"``, ``"all"``, ``"last"`` or an integer N >= 1; returns it.

    Raises
    ------
    InputError
        Anything else (the message lists the valid values).
    """
    if isinstance(keep, str):
        return check_choice(where, keep, KEEP_CHOICES)
    if isinstance(keep, numbers.Integral) and not isinstance(keep, bool) and keep >= 1:
        return int(keep)
    raise InputError(f"{where} must be \"auto\", \"all\", \"last\" or a number of states >= 1, got {keep!r}")


def check_every(every, where: str = "every") -> int:
    """Validate ``every`` (record every k-th step): an integer >= 1; returns it."""
    if isinstance(every, numbers.Integral) and not isinstance(every, bool) and every >= 1:
        return int(every)
    raise InputError(f"{where} must be an integer >= 1 (record every k-th step), got {every!r}")


@dataclass(frozen=True)
class OutputSpec:
    """``[output]``: ``file`` — the result file (.h5) written after the run (resolved like mesh paths);
    ``fields`` — the result fields computed at every state (names of :data:`voxflex.deform.models.fields.FIELD_NAMES`);
    ``every`` — record every k-th step (and the rest state and the last step); ``keep`` — which recorded
    states the returned result holds in memory (``"auto"``, ``"all"``, ``"last"`` or a number N; the file
    has every recorded state).  The command line's ``--every`` / ``--keep`` override the last two."""

    file: str | None = None
    fields: tuple[str, ...] = ()
    every: int = 1
    keep: str | int = "auto"

    def __post_init__(self):
        if self.file is not None:
            _string("output", "file", self.file)
        object.__setattr__(self, "fields", check_field_names(self.fields, where="[output] fields"))
        object.__setattr__(self, "every", check_every(self.every, where="[output] every"))
        object.__setattr__(self, "keep", check_keep(self.keep, where="[output] keep"))




@dataclass(frozen=True)
class ObstacleSpec:
    """``[[obstacle]]``: a rigid obstacle the body collides with (the collision layer).

    ``kind`` ``"plane"`` (``point``, ``normal``: the side the body lies on),
    ``"sphere"`` (``center``, ``radius``), ``"box"`` (``min``, ``max``) or ``"sdf"``
    (``file``: a label image, or an ``.npz`` signed-distance image with
    ``distance``, ``spacing``, ``origin``; resolved like mesh paths); metres.
    ``friction`` is the Coulomb coefficient (lagged, smoothed friction: :mod:`voxflex.deform.layers.contact`);
    ``motion`` a rigid 3x4 map ``[R | t]`` the obstacle reaches at the end of the
    run (interpolated over the steps).
    """

    kind: str = "plane"
    point: tuple[float, float, float] | None = None
    normal: tuple[float, float, float] | None = None
    center: tuple[float, float, float] | None = None
    radius: float | None = None
    min: tuple[float, float, float] | None = None
    max: tuple[float, float, float] | None = None
    file: str | None = None
    friction: float = 0.0
    motion: tuple[tuple[float, ...], ...] | None = None

    def __post_init__(self):
        t = "obstacle"
        _string(t, "kind", self.kind, OBSTACLE_KINDS)
        needed = _OBSTACLE_KEYS[self.kind]
        every = sorted({k for keys in _OBSTACLE_KEYS.values() for k in keys})
        for key in every:
            value = getattr(self, key)
            if key in needed and value is None:
                raise InputError(f"[obstacle] kind = \"{self.kind}\" needs {' and '.join(needed)}")
            if key not in needed and value is not None:
                raise InputError(f"[obstacle] {key} does not apply to kind = \"{self.kind}\" "
                                 f"(it takes {', '.join(needed)}); remove it")
        for key in ("point", "normal", "center", "min", "max"):
            if getattr(self, key) is not None:
                object.__setattr__(self, key, _vector(t, key, getattr(self, key)))
        if self.radius is not None:
            object.__setattr__(self, "radius", _number(t, "radius", self.radius, positive=True))
        if self.file is not None:
            _string(t, "file", self.file)
        object.__setattr__(self, "friction", _number(t, "friction", self.friction, nonnegative=True))
        if self.friction > FRICTION_MAX:
            raise InputError(f"[obstacle] friction = {self.friction:g} is no Coulomb coefficient: give one in "
                             f"[0, {FRICTION_MAX:g}] (friction = 10 already holds a body under tangential loads ten "
                             "times its normal force)")
        if self.motion is not None:
            rows = self.motion
            if isinstance(rows, (str, bytes)) or not hasattr(rows, "__len__") or len(rows) != 3:
                raise InputError(f"[obstacle] motion must be a 3x4 matrix [[a,b,c,tx],[..],[..]], got {rows!r}")
            object.__setattr__(self, "motion", tuple(_vector(t, "motion", r, 4) for r in rows))

    def parameters(self) -> dict:
        """Keyword arguments of :func:`voxflex.deform.layers.obstacles.obstacle` (besides the kind)."""
        out = {k: getattr(self, k) for k in _OBSTACLE_KEYS[self.kind]}
        out["friction"] = self.friction
        if self.motion is not None:
            out["motion"] = self.motion
        return out


@dataclass(frozen=True)
class ContactSpec:
    """``[contact]``: the collision layer's settings (used only with ``[[obstacle]]`` tables).

    ``distance``: the barrier's activation distance (m; default 1 % of the
    smallest voxel spacing); ``stiffness``: the barrier stiffness (Pa; default
    the largest Young's modulus); ``points``: ``"surface"`` (2x2 Gauss points on
    every exposed voxel face, the default), ``"vertices"`` or a count k (k x k
    points per face).
    """

    distance: float | None = None
    stiffness: float | None = None
    points: str | int = "surface"

    def __post_init__(self):
        t = "contact"
        if self.distance is not None:
            object.__setattr__(self, "distance", _number(t, "distance", self.distance, positive=True))
        if self.stiffness is not None:
            object.__setattr__(self, "stiffness", _number(t, "stiffness", self.stiffness, positive=True))
        if isinstance(self.points, str):
            _string(t, "points", self.points, CONTACT_POINT_RULES)
        else:
            k = _number(t, "points", self.points, integer=True, minimum=1)
            if k > 8:
                raise InputError(f"[contact] points (per face edge) must be in 1..8, got {k}")
            object.__setattr__(self, "points", k)


@dataclass(frozen=True)
class CableSpec:
    """``[[cable]]``: a tension-only cable through material points (:mod:`voxflex.deform.layers.cables`).

    ``points`` the rest positions (m) of the material points it runs through, in
    order (it slides through them without friction: one tension along the whole
    cable); ``anchor`` an optional fixed world point, the cable's first end;
    ``stiffness`` the whole cable's axial stiffness EA / L (N/m); ``rest_length``
    (m, default the rest polyline length); ``shorten`` the length reduction (m)
    reached at the end of the run; or ``pull`` a tension (N) reached at the end of
    the run instead of stiffness / rest_length / shorten; ``tension_only = false``
    makes it a two-sided spring.
    """

    points: tuple[tuple[float, float, float], ...] = ()
    anchor: tuple[float, float, float] | None = None
    stiffness: float | None = None
    rest_length: float | None = None
    shorten: float = 0.0
    pull: float | None = None
    tension_only: bool = True

    def __post_init__(self):
        t = "cable"
        pts = self.points
        if isinstance(pts, (str, bytes)) or not hasattr(pts, "__len__") or len(pts) == 0:
            raise InputError("[cable] needs points, a list of [x, y, z] rest positions (m), "
                             "e.g. points = [[0.1, 0.5, 1.0], [3.9, 0.5, 1.0]]")
        object.__setattr__(self, "points", tuple(_vector(t, "points", p) for p in pts))
        if self.anchor is not None:
            object.__setattr__(self, "anchor", _vector(t, "anchor", self.anchor))
        for key in ("stiffness", "rest_length", "pull"):
            if getattr(self, key) is not None:
                object.__setattr__(self, key, _number(t, key, getattr(self, key), positive=True))
        shorten = _number(t, "shorten", self.shorten)
        if math.isinf(shorten):
            raise InputError(f"[cable] shorten must be finite, got {self.shorten!r}")
        object.__setattr__(self, "shorten", shorten)
        _boolean(t, "tension_only", self.tension_only)
        try:  # the checks across keys (zero-length segments, pull against stiffness, shortening)
            Cable(points=self.points, anchor=self.anchor, stiffness=self.stiffness, rest_length=self.rest_length,
                  shorten=self.shorten, pull=self.pull, tension_only=self.tension_only)
        except InputError as exc:
            raise InputError(f"[cable] {exc}") from None
