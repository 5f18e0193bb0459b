"""Boundary conditions and loads on box regions of the rest configuration, for any model.

* :class:`FixedRegion`: the nodes whose *rest* position lies in the box
  ``[min, max]`` are held (all components, or only those in ``components`` —
  a sliding support), optionally moved by an affine map ``transform`` (3x4)
  reached at the end of the run: a rigid map along its screw motion (every
  intermediate map rigid), any other map linearly from the identity,
  ``x(s) = X + s (A X + t - X)``, in the load factor (static) or in time
  (dynamics); see :func:`~voxflex.deform.models.motion.transform_at`.  Which DOFs a box holds is the model's
  answer (:meth:`~voxflex.deform.models.protocol.Model.held_dofs`): voxel-corner
  points in the box, or frames in the box (their translation and matrix rows).
* :class:`ForceRegion`: a total force on the material in the box, or a
  traction (force per unit area) on the boundary faces whose centre lies in
  the box.  Forces act on material points and reach the nodes through the
  transposed Jacobian of the model's point mapping (see :func:`region_forces`).

The functions here turn regions into arrays for any :class:`~voxflex.deform.models.protocol.Model`:
:func:`fixed_dofs`, :func:`prescribed_positions`, :func:`region_forces`, :func:`load_vector`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import InputError, check_choice
from ..models.motion import moved_rest, transform_at

FORCE_KINDS = ("force", "traction")
"""Kinds of region loads (the scene's ``[[load]] kind`` besides ``gravity`` and ``pressure``)."""

PRESSURE_KIND = "pressure"
"""``[[load]] kind`` of a follower pressure on a membrane.  It is a potential of the membrane
model (:mod:`voxflex.deform.models.membrane.model`), not a dead load, so it never becomes a :class:`ForceRegion`."""


def _vec3(name, value):
    try:
        v = np.broadcast_to(np.asarray(value, dtype=float), (3,)).copy()
    except (ValueError, TypeError):
        raise InputError(f"{name} must be 3 numbers, got {value!r}") from None
    if np.any(np.isnan(v)):
        raise InputError(f"{name} must not contain NaN, got {v.tolist()}")
    v.setflags(write=False)
    return v


@dataclass(frozen=True, eq=False)
class FixedRegion:
    """Hold (or move) the nodes whose rest position lies in the box [min, max].

    Parameters
    ----------
    min, max : (3,) float (m)
        Box corners (inclusive; +-inf allowed).
    components : str
        Held components, a non-empty subset of "xyz" ("x" = sliding support normal to x).
    transform : (3, 4) float, optional
        Affine map ``[A | t]`` reached at the end of the run (load factor 1);
        ``None`` holds the nodes at their rest positions.
    """

    min: np.ndarray
    max: np.ndarray
    components: str = "xyz"
    transform: np.ndarray | None = None

    def __post_init__(self):
        lo, hi = _vec3("fixed region min", self.min), _vec3("fixed region max", self.max)
        if np.any(lo > hi):
            raise InputError(f"fixed region min {lo.tolist()} exceeds max {hi.tolist()}; swap them")
        comps = str(self.components).lower()
        if not comps or any(c not in "xyz" for c in comps) or len(set(comps)) != len(comps):
            raise InputError(f"fixed components must be a non-empty subset of 'xyz', got {self.components!r}")
        object.__setattr__(self, "min", lo)
        object.__setattr__(self, "max", hi)
        object.__setattr__(self, "components", "".join(sorted(comps)))
        if self.transform is not None:
            T = np.asarray(self.transform, dtype=float)
            if T.shape != (3, 4) or not np.all(np.isfinite(T)):
                raise InputError(f"fixed region transform must be a finite 3x4 affine matrix [A | t], got shape {T.shape}")
            T = T.copy()
            T.setflags(write=False)
            object.__setattr__(self, "transform", T)

    @property
    def component_indices(self) -> np.ndarray:
        return np.array(["xyz".index(c) for c in self.components], dtype=np.int64)

    def position(self, X, factor: float) -> np.ndarray:
        """Prescribed positions (k, 3) of rest points ``X`` (k, 3) at load factor / time fraction ``factor``."""
        X = np.asarray(X, dtype=float)
        if self.transform is None:
            return X.copy()
        T = transform_at(self.transform, factor)
        return X @ T[:, :3].T + T[:, 3]

    @staticmethod
    def rotation(min, max, axis_point, axis, angle, components: str = "xyz") -> "FixedRegion":
        """Region rotated by ``angle`` (radians) about the line through ``axis_point`` along ``axis``.

        The intermediate load steps turn the region by the same fraction of
        ``angle`` about the same axis (a screw motion, rigid throughout).
        """
        p = _vec3("axis point", axis_point)
        a = _vec3("axis", axis)
        na = np.linalg.norm(a)
        if na == 0:
            raise InputError("rotation axis must be non-zero")
        a = a / na
        K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
        R = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * (K @ K)
        T = np.hstack([R, (p - R @ p)[:, None]])
        return FixedRegion(min, max, components, T)


@dataclass(frozen=True, eq=False)
class ForceRegion:
    """A force on the material in the box [min, max].

    Parameters
    ----------
    min, max : (3,) float (m)
    vector : (3,) float
        ``kind="force"``: the total force (N), spread over the material in
        the box (see :func:`region_forces`); ``kind="traction"``: force per
        unit area (Pa) on the boundary faces whose centre lies in the box.
    kind : {"force", "traction"}
    """

    min: np.ndarray
    max: np.ndarray
    vector: np.ndarray
    kind: str = "force"

    def __post_init__(self):
        lo, hi = _vec3("force region min", self.min), _vec3("force region max", self.max)
        if np.any(lo > hi):
            raise InputError(f"force region min {lo.tolist()} exceeds max {hi.tolist()}; swap them")
        vec = _vec3("force vector", self.vector)
        if not np.all(np.isfinite(vec)):
            raise InputError(f"force vector must be finite, got {vec.tolist()}")
        check_choice("force kind", self.kind, FORCE_KINDS)
        object.__setattr__(self, "min", lo)
        object.__setattr__(self, "max", hi)
        object.__setattr__(self, "vector", vec)


def _in_box(points, lo, hi):
    return np.all((points >= lo) & (points <= hi), axis=1)


def _box_text(region) -> str:
    return f"[{region.min.tolist()}, {region.max.tolist()}]"


def fixed_dofs(model, regions) -> tuple[np.ndarray, np.ndarray]:
    """Fixed DOFs of the regions and the region that fixes each (the last listed wins).

    Parameters
    ----------
    model : Model
        Asked which flat DOFs each box holds (:meth:`Model.held_dofs`).
    regions : sequence of FixedRegion

    Returns
    -------
    dofs : (k,) int64, sorted flat DOFs (``d * node + j``)
    owner : (k,) int64, index of the region fixing each DOF

    Raises
    ------
    InputError
        When a region holds nothing (names the region).
    """
    owner = np.full(np.asarray(model.rest).size, -1, dtype=np.int64)
    for r, region in enumerate(regions):
        dofs = np.asarray(model.held_dofs(region.min, region.max, region.components), dtype=np.int64)
        if len(dofs) == 0:
            raise InputError(
                f"fixed region #{r} {_box_text(region)} contains no {model.kind.noun}; "
                "enlarge the box to reach the object's rest position"
            )
        owner[dofs] = r
    dofs = np.flatnonzero(owner >= 0)
    return dofs, owner[dofs]


def prescribed_positions(model, regions, dofs, owner, factor: float) -> np.ndarray:
    """Values (k,) of the fixed DOFs at load factor / time fraction ``factor``.

    Held DOFs keep their rest values; the DOFs of a region with a transform
    take the model's state moved by the interpolated map (:func:`moved_rest`).
    """
    values = np.asarray(model.rest, dtype=float).ravel()[dofs].copy()
    for r, region in enumerate(regions):
        sel = owner == r
        if region.transform is None or not np.any(sel):
            continue
        values[sel] = moved_rest(model, region.transform, factor)[dofs[sel]]
    return values


def load_vector(model, forces=(), gravity=None, densities=None) -> np.ndarray:
    """The full external load (N,) flat at load factor 1: the force regions' forces
    (:func:`region_forces`) plus gravity on the materials' densities (N)."""
    N = np.asarray(model.rest).size
    f = region_forces(model, forces).ravel() if forces else np.zeros(N)
    if gravity is not None:
        f = f + model.gravity_force(densities, gravity).ravel()
    return f


def region_forces(model, regions) -> np.ndarray:
    """Generalised node forces (n, d) of the force regions on ``model`` (N for point nodes).

    A region's force acts on material points and reaches the nodes through
    ``J^T`` of the model's point mapping:

    * ``kind="force"``: the total force is spread over the volume points
      (:meth:`Model.volume_points`) inside the box in proportion to their
      volume; a box holding no volume point (a thin box around a face) spreads
      it over the boundary-face Gauss points inside it in proportion to area;
    * ``kind="traction"``: force per unit area on the boundary faces whose
      centre lies in the box, integrated with 2x2 Gauss points per face
      (on voxel faces: a quarter of each face's force to each corner).

    Raises
    ------
    InputError
        When a region touches no material ("force") or no boundary face ("traction").
    """
    rest = np.asarray(model.rest, dtype=float)
    f = np.zeros(rest.shape)
    surface = None
    for r, region in enumerate(regions):
        pts = sel = None
        if region.kind == "force":
            pts, vol = model.volume_points()
            sel = _in_box(pts, region.min, region.max)
        if surface is None and not (region.kind == "force" and np.any(sel)):
            surface = model.load_surface()  # only when a surface is needed (membranes have none)
        if region.kind == "force":
            if np.any(sel):
                pts, share = pts[sel], vol[sel]
            else:
                sel = _in_box(surface.points, region.min, region.max)
                if not np.any(sel):
                    raise InputError(
                        f"force region #{r} {_box_text(region)} contains no material; enlarge the box to cover part of the object"
                    )
                pts, share = surface.points[sel], surface.weight[sel]
            forces = (share / share.sum())[:, None] * region.vector[None, :]
        else:
            sel = _in_box(surface.centre, region.min, region.max)[surface.patch]
            if not np.any(sel):
                raise InputError(
                    f"traction region #{r} {_box_text(region)} contains no boundary face centre; "
                    "enlarge the box to cover part of the surface"
                )
            pts = surface.points[sel]
            forces = surface.weight[sel][:, None] * region.vector[None, :]
        f += model.point_mapping(pts).vjp(rest, forces)
    return f
