"""Checks at the edge of a run, before and while it solves: garbage is refused or named, never returned.

Before building (:func:`check_magnitudes`, on the scene and its image):

* every modulus, density, load, voxel size and time step is a number double
  precision can multiply and square: its magnitude lies in
  :data:`REPRESENTABLE` (Young 5e-324 or 1e-300, gravity 1e200 are refused);
* the loads do not strain the body by more than :data:`MAX_LOAD_STRAIN`
  (gravity ``rho |g| L / E``, traction ``|t| / E``, force ``|F| / (E A)``,
  with ``L`` the body's size and ``A`` its cross-section), a bound no solid
  reaches, so gravity -1e30 m/s^2 on a 1e4 Pa body is refused instead of
  giving displacements of 1e28 m;
* the quadrature can see the body: mid-point samples on a body one voxel
  thick all sit on its mid-plane (:func:`check_thin_body`).

These thresholds are dimensionless (a strain, a ratio of sizes) or bounds of
double precision; the same scene at 1 um and 1 km gets the same verdict.

Before solving (:func:`check_held`, on the :class:`~voxflex.deform.solve.problem.Problem`): the held DOFs
leave something free that moves material (one held frame freezing the whole body is refused).

Every accepted state (:class:`StateCheck`, called by the recorder of :mod:`voxflex.simulation`):
finite; accepted at a relative residual below :data:`RESIDUAL_REFUSE`; its
deformed size within :data:`GROWTH_WARN` (a warning) and
:data:`GROWTH_REFUSE` (an error) times the rest size.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from .errors import ConvergenceError, InputError

__all__ = ["check_magnitudes", "check_thin_body", "check_unreached_components", "check_held", "warn_locking",
           "StateCheck", "ImplausibleStateWarning", "LockingWarning", "LOCKING_POISSON",
           "REPRESENTABLE", "MAX_LOAD_STRAIN", "FAR_VOXELS", "GROWTH_WARN", "GROWTH_REFUSE", "RESIDUAL_REFUSE",
           "THIN_FRACTION"]

REPRESENTABLE = (1e-100, 1e100)
"""Magnitudes an input may have (moduli, densities, loads, voxel sizes, time steps; 0 where a load may be 0).
A bound of double precision, not of physics: energies multiply a modulus by a squared strain and a
volume, forces a density by an acceleration and a volume (1e-100 to 1e100 keeps those products away from
the 1e-308 / 1e308 ends).  Changing units from micrometres to kilometres moves a value by at most 1e18."""

MAX_LOAD_STRAIN = 1e3
"""Largest strain a load may impose by the estimate ``rho |g| L / E`` (gravity), ``|t| / E`` (traction),
``|F| / (E A)`` (force): a solid strained a thousandfold by its load is not a solid (the stiffest rubber
breaks below 10); beyond this the answer is meaningless, so the scene is refused naming the units."""

GROWTH_WARN = 10.0
"""An accepted state whose deformed body is this many times larger than at rest (bounding-box diagonal of
the drawn surface) gets an :class:`ImplausibleStateWarning`."""

GROWTH_REFUSE = 1e3
"""An accepted state this many times larger than at rest stops the run: no elastic answer is that."""

RESIDUAL_REFUSE = 1e-2
"""A step accepted at a relative residual (out-of-balance force over the largest force) above this is not an
equilibrium: the run stops with an error (the round-off floor of a stiff layer, e.g. friction 1e12, once
accepted steps at 1.0)."""

ROUNDOFF_MOTION = 1e-11
"""A step refused out of balance whose largest displacement is at most this fraction of the body's size is
named as a motion below the forces' round-off, not blamed on a stiff layer: models that form F from the
positions (known to eps |x|; the layers) see a strain of ~eps |x| / h as noise, those that form it from the
displacement (:class:`~voxflex.deform.models.protocol.FromDisplacement`: the voxel and frame models) a
strain of ~eps.  A neo-Hookean voxel cantilever under 1e-11 of its gravity stops at relative residual 0.98
(a linear model, whose forces are K u, solves any load)."""

THIN_FRACTION = 0.5
"""A body is one voxel thick along an axis when at least this fraction of its voxels have no material
neighbour on either side along that axis."""

_MODULI = ("mu", "lmbda", "c1", "c2", "bulk", "E1", "E2", "E3", "G12", "G23", "G13", "mu_p")
"""Material constants that are moduli (Pa): the stiffness a load is compared with."""


class ImplausibleStateWarning(UserWarning):
    """An accepted state is far larger than the body at rest (a load far beyond what the model is for)."""


# ---------------------------------------------------------------------------
# inputs
# ---------------------------------------------------------------------------
def _representable(where: str, value: float, *, zero_ok: bool = True) -> None:
    lo, hi = REPRESENTABLE
    a = abs(float(value))
    if a == 0.0 and zero_ok:
        return
    if not math.isfinite(a) or not lo <= a <= hi:
        raise InputError(
            f"{where} = {float(value)!r} is outside {lo:g} .. {hi:g} in magnitude, beyond what double precision can "
            "multiply and square in an energy; check the units (m, Pa, kg/m^3, s)")


def _stiffness(spec) -> float | None:
    """The modulus (Pa) a load strains a material against: its Young's modulus, else its largest modulus."""
    if spec.young is not None:
        return float(spec.young)
    values = []
    for name, value in spec.constants:
        if name in _MODULI:
            values += [abs(float(v)) for v in (value if isinstance(value, tuple) else (value,))]
    values = [v for v in values if v > 0]
    return max(values) if values else None


def _body(image):
    """(size L: the largest extent of the material, m; volume V, m^3) of an image."""
    mask = np.asarray(image.labels) > 0
    spacing = np.asarray(image.spacing, dtype=float)
    if not np.any(mask):
        return 0.0, 0.0
    idx = [np.flatnonzero(np.any(mask, axis=tuple(a for a in range(3) if a != ax))) for ax in range(3)]
    extent = np.array([(i[-1] - i[0] + 1) for i in idx], dtype=float) * spacing
    return float(extent.max()), float(np.count_nonzero(mask) * np.prod(spacing))


FAR_VOXELS = 2.0 ** 36
"""The farthest a body's voxels may lie from the origin, in voxel sizes (about 6.9e10: 140,000 km at 2 mm).  World
coordinates there carry 16 eps |x| / h = 2.4e-4 of a voxel of round-off, which moved frame models' answers (a 4 cm
beam 1e9 m out, 5e11 voxels: 1 % off; 1e12 m: its end-face probe 'outside the material'); a dimensionless bound,
so the same scene is refused at every unit."""


def _check_far(image) -> None:
    """InputError for a body so far from the origin that its coordinates lose a voxel's digits
    (:data:`FAR_VOXELS`)."""
    h = float(np.min(image.spacing))
    far = max(float(np.abs(np.concatenate(box)).max()) for box in image.world_bounding_boxes().values())
    if far > FAR_VOXELS * h:
        raise InputError(f"the object lies {far:.3g} m from the origin, {far / h:.3g} voxel sizes: its coordinates "
                         f"carry {16 * np.finfo(float).eps * far / h:.2g} of a voxel of round-off (the limit is "
                         f"{FAR_VOXELS:.3g} voxel sizes); move it near the origin ([object] origin, or the mesh's "
                         "coordinates)")


def check_magnitudes(scene, image) -> None:
    """InputError for an input double precision cannot carry or a load no solid carries (module docstring).

    Parameters
    ----------
    scene : Scene
    image : LabelImage
        The scene's image (its size and volume scale the loads).
    """
    for i, s in enumerate(np.asarray(image.spacing, dtype=float)):
        _representable(f"the voxel size along {'xyz'[i]}", s, zero_ok=False)
    for m in scene.materials:
        where = f"[[material]] label {m.label}"
        if m.young is not None:
            _representable(f"{where} young", m.young, zero_ok=False)
        _representable(f"{where} density", m.density, zero_ok=False)
        for name, value in m.constants:
            for v in value if isinstance(value, tuple) else (value,):
                _representable(f"{where} {name}", v)
    for ld in scene.loads:
        if ld.pressure is not None:
            _representable(f'[[load]] kind = "{ld.kind}" pressure', ld.pressure)
        else:
            _representable(f'[[load]] kind = "{ld.kind}" vector magnitude', _norm(ld.vector))
    solver = scene.solver
    if solver.kind == "implicit-euler":
        _representable("[solver] dt", solver.dt, zero_ok=False)
        _representable("[solver] rayleigh_mass", solver.rayleigh_mass)
        _representable("[solver] rayleigh_stiffness", solver.rayleigh_stiffness)
    size, volume = _body(image)
    if size <= 0:
        return
    _check_far(image)
    labels = set(int(x) for x in np.unique(np.asarray(image.labels))) - {0}
    specs = [m for m in scene.materials if m.label in labels] or list(scene.materials)
    soft = [(s, _stiffness(s)) for s in specs]
    soft = [(s, E) for s, E in soft if E is not None and E > 0]
    if not soft:
        return
    spec, E = min(soft, key=lambda p: p[1])
    area = volume ** (2.0 / 3.0)
    g = scene.gravity
    worst = []
    if g is not None:
        heavy = max(specs, key=lambda s: s.density / (_stiffness(s) or E))
        Eh = _stiffness(heavy) or E
        strain = heavy.density * _norm(g) * size / Eh
        worst.append((strain, f"gravity {_fmt_vec(g)} m/s^2 on label {heavy.label} (density {heavy.density:g} "
                               f"kg/m^3, modulus {Eh:g} Pa) over the body's {size:.4g} m: rho |g| L / E"))
    for ld in scene.loads:
        if ld.kind == "traction":
            worst.append((_norm(ld.vector) / E,
                          f"the traction {_fmt_vec(ld.vector)} Pa on label {spec.label} (modulus {E:g} Pa): |t| / E"))
        elif ld.kind == "force":
            worst.append((_norm(ld.vector) / (E * area),
                          f"the force {_fmt_vec(ld.vector)} N on a body of cross-section about {area:.4g} m^2 "
                          f"(modulus {E:g} Pa): |F| / (E A)"))
    if not worst:
        return
    strain, what = max(worst, key=lambda p: p[0])
    if strain > MAX_LOAD_STRAIN:
        raise InputError(
            f"{what} = {strain:.3g}: the load would strain the body {strain:.3g} times over, beyond any solid "
            f"(the limit is {MAX_LOAD_STRAIN:g}); check the units (m, Pa, kg/m^3, m/s^2, N)")


def _norm(v) -> float:
    """Euclidean length without overflow (math.hypot scales: a 1e200 component gives 1e200, not inf)."""
    return math.hypot(*(float(x) for x in v))


def _fmt_vec(v) -> str:
    return "[" + ", ".join(f"{float(x):g}" for x in v) + "]"


def thin_axes(image) -> list[tuple[int, float]]:
    """(axis, fraction) of each axis along which at least :data:`THIN_FRACTION` of the material voxels
    have no material neighbour on either side (the body is one voxel thick there)."""
    mask = np.asarray(image.labels) > 0
    n = int(np.count_nonzero(mask))
    out = []
    if n == 0:
        return out
    for ax in range(3):
        padded = np.pad(mask, [(1, 1) if a == ax else (0, 0) for a in range(3)])
        sl = [slice(None)] * 3
        lo, mid, hi = list(sl), list(sl), list(sl)
        lo[ax], mid[ax], hi[ax] = slice(0, -2), slice(1, -1), slice(2, None)
        alone = padded[tuple(mid)] & ~padded[tuple(lo)] & ~padded[tuple(hi)]
        frac = float(np.count_nonzero(alone)) / n
        if frac >= THIN_FRACTION:
            out.append((ax, frac))
    return out


def check_thin_body(scene, image) -> None:
    """InputError for bare one-point-per-region samples (``"midpoint"``, ``hourglass = "none"``) on a body one
    voxel thick (stabilised regions add their Gauss points' fluctuation, which sees the bending).

    Every mid-point sample of such a body lies on its mid-plane, where bending strains vanish: measured
    (``benchmarks/bench_robustness.py --thin``), 20 frames on a 4 x 1 x 0.2 m cantilever plate one voxel thick
    sag 18.9 m against 3.9 m with Gauss-Legendre samples on the same voxels and 3.4-3.8 m on images 2 and 4
    voxels thick, and the answer does not change with the plate's thickness.  Gauss-Legendre points (two
    through the thickness) and elastons (the regions' moments) see it.
    """
    from .deform.models.kinds import node_kind

    kind = node_kind(scene.nodes.kind)
    if not kind.reduced or scene.elasticity.quadrature != "midpoint" or scene.elasticity.hourglass != "none":
        return
    thin = thin_axes(image)
    if not thin:
        return
    ax, frac = thin[0]
    shape = " x ".join(map(str, np.asarray(image.labels).shape))
    spacing = " x ".join(f"{s:.4g}" for s in np.asarray(image.spacing, dtype=float))
    raise InputError(
        f"the object is one voxel thick along {'xyz'[ax]} ({frac:.0%} of its voxels; image {shape} voxels of "
        f"{spacing} m): mid-point samples all lie on its mid-plane and miss bending through the thickness "
        f"(a one-voxel-thick plate came out 4.8x too soft); use {_thickness_fix(kind)}, or a voxel "
        "size that puts at least two voxels through the thickness")


def _thickness_fix(kind) -> str:
    """The settings of ``kind`` that see a thin body: stabilised mid-point regions (their Gauss points),
    Gauss-Legendre points and elastons (every material takes them)."""
    options = " or ".join(f'"{q}"' for q in ("gauss-legendre", "elaston") if q in kind.quadratures)
    return f'[elasticity] hourglass = "stiffness" (the default), quadrature = {options}'


def check_unreached_components(scene, image) -> None:
    """InputError naming a material component that no ``[[fixed]]`` region reaches, in a static scene
    without obstacles or cables (which could hold it), before any model is built.

    Components are taken by vertex connectivity (voxels touching at all) and a region reaches a component
    when it touches one of its voxels: no model can hold such a part, whatever its nodes (the frame
    model blamed its samples' "zero-energy modes" for a floating part, after the whole precompute).
    Parts held partly, or only through an edge or a corner, are judged later by the model's own support
    check (:func:`voxflex.deform.solve.supports.check_supports`).
    """
    if scene.solver.kind != "static" or scene.obstacles or getattr(scene, "cables", ()) or not scene.fixed:
        return
    from scipy import ndimage

    from .deform.models.kinds import node_kind
    from .voronoi.placement import voxels_touching_box

    if node_kind(scene.nodes.kind).image_builder is not None:  # a membrane's mesh pieces are its parts
        return
    labels = np.asarray(image.labels)
    material = labels > 0
    comps, n = ndimage.label(material, structure=np.ones((3, 3, 3), dtype=bool))
    if n == 0:
        return
    reached = np.zeros(n + 1, dtype=bool)
    for f in scene.fixed:
        touch = voxels_touching_box(image, np.asarray(f.min, dtype=float), np.asarray(f.max, dtype=float))
        if not np.any(touch & material):
            return  # a region that holds nothing: the boundary check names that region, the real mistake
        reached[np.unique(comps[touch & material])] = True
    missing = [c for c in range(1, n + 1) if not reached[c]]
    if not missing:
        return
    c = missing[0]
    ijk = np.argwhere(comps == c)
    corners = np.array([ijk.min(axis=0), ijk.max(axis=0) + 1], dtype=float)
    world = np.asarray(image.index_to_world(corners))
    lo, hi = world.min(axis=0), world.max(axis=0)
    which = ", ".join(str(int(v)) for v in np.unique(labels[comps == c]))
    more = f" ({len(missing) - 1} more)" if len(missing) > 1 else ""
    raise InputError(
        f"static scene is ill-posed: material component {c} of {n} (label {which}, {len(ijk)} voxels, box "
        f"[{', '.join(f'{v:.4g}' for v in lo)}] .. [{', '.join(f'{v:.4g}' for v in hi)}] m) is not held: no "
        f"[[fixed]] region reaches it, 6 free rigid motion(s){more}; fix it with a [[fixed]] region covering it, "
        'drop islands with [object] keep = "largest" or min_component_voxels, or simulate dynamics (implicit-euler)')


class LockingWarning(UserWarning):
    """A frame model integrates a nearly incompressible material's volumetric term in full: it locks."""


LOCKING_POISSON = 0.49
"""Poisson's ratio from which a frame model with the full volumetric term warns that it locks.  Measured on
the linear 16x4x4 cantilever, 20 frames, mid-point samples, against the voxel model with F-bar (each
column: the frames' tip over the voxels'): nu = 0.3: 0.82 (the reduced model's own stiffness),
0.45: 0.66, 0.49: 0.46, 0.4999: 0.070 (93 % too stiff)."""


def warn_locking(model, scene) -> None:
    """:class:`LockingWarning` when a frame model keeps the full volumetric term (``model.describe()``'s
    ``volumetric`` is ``"full"``) of a material with Poisson's ratio >= :data:`LOCKING_POISSON`."""
    if not getattr(model.kind, "reduced", False) or model.describe().get("volumetric") != "full":
        return
    nus = [m.poisson for m in scene.materials if m.poisson is not None]
    if not nus or max(nus) < LOCKING_POISSON:
        return
    nu = max(nus)
    if getattr(getattr(model, "shape_function", None), "linearly_precise", False):
        # linearly precise weights with the full term: an explicit "full", or stabilised mid-point regions (which
        # have no capped remainder, frames/volumetric.py); they lock less than natural neighbours
        expected = "up to about 10 %" if nu >= 0.4999 else "a few per cent"
        measured = ("linear cantilevers against the voxel model with B-bar: 32x8x8, 20 / 40 / 80 frames, "
                    "8.3 / 3.7 / 6.2 % at 0.4999; 16x4x4, 20 frames, 10.5 % at 0.4999")
        fix = ('[elasticity] volumetric = "auto" with point samples (quadrature = "elaston" or "gauss-legendre"), '
               "which projects the volume change and caps the rest")
    else:
        expected = "about 93 %" if nu >= 0.4999 else "about 54 %" if nu >= 0.49 else "tens of per cent"
        measured = "the cantilever: 54 % at 0.49, 93 % at 0.4999, against the voxel model with F-bar"
        fix = '[elasticity] volumetric = "auto", more frames, or [nodes] kind = "voxel"'
    warnings.warn(
        f"poisson = {nu:g} with {model.kind.plural} and the full volumetric term: the model locks, and its "
        f"displacements come out {expected} too small ({measured}); use {fix}", LockingWarning, stacklevel=3)


# ---------------------------------------------------------------------------
# the problem
# ---------------------------------------------------------------------------
def check_held(problem) -> None:
    """InputError when the held DOFs leave no free DOF that moves material (nothing could move).

    A fixed region with a ``transform`` prescribes a motion: such a problem is not refused.
    """
    if not problem.fixed or any(f.transform is not None for f in problem.fixed):
        return
    model = problem.model
    dofs, _ = problem.held
    N = int(np.asarray(model.rest).size)
    d = model.dofs_per_node
    free = np.ones(N, dtype=bool)
    free[dofs] = False  # (a mask: np.setdiff1d took 1.2 s for 810k DOFs)
    free = np.flatnonzero(free)
    if 2 * len(free) > N:
        return  # most DOFs free: every kind's nodes move material (voxel corners, frames' cells, mesh vertices)
    if len(free):
        # the nodes that move material are those of the model's parts (about 0.7 s for 270k voxel nodes,
        # so only when the held set is most of the model; the volume points' mapping took 17 s and 1.4 GB)
        moving = np.unique(np.concatenate([np.asarray(p.nodes, dtype=np.int64) for p in model.parts()] or [[]]))
        moves = np.zeros(N, dtype=bool)
        moves[(d * moving[:, None] + np.arange(d)).ravel()] = True
        if np.any(moves[free]):
            return
    nodes = N // d
    held_nodes = len(np.unique(dofs // d))
    kind = model.kind
    raise InputError(
        f"the [[fixed]] regions hold every DOF that moves the material ({held_nodes} of {nodes} "
        f"{kind.plural if nodes != 1 else kind.noun} held), so nothing can move and every displacement would be "
        "exactly 0; make the fixed regions cover only the supports"
        + (f", or use more {kind.plural} ([nodes] count)" if kind.reduced else ""))


# ---------------------------------------------------------------------------
# every accepted state
# ---------------------------------------------------------------------------
class StateCheck:
    """Checks each accepted state of a run (module docstring): call it with the step number, the state's
    drawn surface positions and the relative residual the step was accepted at.

    Parameters
    ----------
    surface_rest : (V, 3) float
        The drawn surface at rest (its bounding-box diagonal is the body's size).
    """

    def __init__(self, surface_rest):
        rest = np.asarray(surface_rest, dtype=float)
        self.rest_size = float(np.linalg.norm(rest.max(axis=0) - rest.min(axis=0))) if len(rest) else 0.0
        self.worst_growth = (1.0, 0)
        self.warned = False

    def __call__(self, step: int, q, surface, residual: float) -> None:
        """Both checks: :meth:`state` then :meth:`size`."""
        self.state(step, q, residual)
        self.size(step, surface)

    def state(self, step: int, q, residual: float, displacement=None) -> None:
        """ConvergenceError for a node state that is not finite, or accepted out of balance (``displacement``:
        the solver's ``q - X``, which tells a motion below the positions' round-off from a stiff layer)."""
        if not np.all(np.isfinite(q)):
            raise ConvergenceError(
                f"step {step} was accepted with a state that is not finite (NaN or inf): the loads or the material "
                "constants are beyond what double precision solves; check the units")
        if step > 0 and residual > RESIDUAL_REFUSE:
            moved = float(np.max(np.abs(displacement))) if displacement is not None and np.size(displacement) else None
            if moved is not None and self.rest_size > 0 and moved <= ROUNDOFF_MOTION * self.rest_size:
                raise ConvergenceError(
                    f"step {step} stopped at relative residual {residual:.2e} (the limit is {RESIDUAL_REFUSE:g}): the "
                    f"motion ({moved:.3g} m, {moved / self.rest_size:.2g} of the body's size) is below what the elastic "
                    "forces resolve (their strains carry round-off of about 1e-16, or 1e-16 of the size where a "
                    "model forms them from positions); raise the loads (a linear answer scales with them) or "
                    "simulate in dynamics, whose steps keep their digits")
            raise ConvergenceError(
                f"step {step} stopped at relative residual {residual:.2e} (its forces are out of balance by that "
                f"fraction; the limit is {RESIDUAL_REFUSE:g}), which is not an equilibrium: a layer far stiffer "
                "than the body (friction, contact stiffness) or a load far beyond the model; soften it or use more "
                "steps")

    def size(self, step: int, surface) -> None:
        """ConvergenceError for a drawn surface that is not finite or grown beyond :data:`GROWTH_REFUSE`."""
        surface = np.asarray(surface, dtype=float)
        if len(surface) == 0:
            return
        # NaN and inf anywhere reach the bounds; column by column (numpy's axis-0 reduction of an (n, 3) array
        # is ~20x slower: 1 ms of a 60-frame implicit-Euler step at 20k vertices)
        lo = np.array([surface[:, k].min() for k in range(surface.shape[1])])
        hi = np.array([surface[:, k].max() for k in range(surface.shape[1])])
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise ConvergenceError(f"step {step}: the drawn surface is not finite (NaN or inf); check the units")
        if self.rest_size <= 0:
            return
        size = float(np.linalg.norm(hi - lo))
        growth = size / self.rest_size
        if growth > self.worst_growth[0]:
            self.worst_growth = (growth, step)
        if growth > GROWTH_REFUSE:
            raise ConvergenceError(
                f"step {step}: the deformed body is {growth:.3g} times its rest size ({size:.3g} m against "
                f"{self.rest_size:.3g} m; the limit is {GROWTH_REFUSE:g}): not an elastic answer; check the units and "
                "the loads")

    def warn(self) -> None:
        """After the run: an :class:`ImplausibleStateWarning` when a state grew beyond :data:`GROWTH_WARN`."""
        growth, step = self.worst_growth
        if growth > GROWTH_WARN:
            warnings.warn(
                f"at step {step} the deformed body is {growth:.3g} times its rest size (more than {GROWTH_WARN:g}): "
                "far beyond what the model is for (linear strain above a few per cent, a load beyond the "
                "material); check the loads and the units",
                ImplausibleStateWarning, stacklevel=3)
