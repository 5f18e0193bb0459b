"""Boundary conditions and loads on box regions of the rest configuration.

* :class:`FixedRegion`: the nodes whose *rest* position lies in the box
  ``[min, max]`` are held (all components, or only those in ``components`` —
  a sliding support), optionally moved by an affine map ``transform`` (3x4)
  reached at the end of the run and interpolated linearly from the identity
  in the load factor (static) or in time (dynamics):
  ``x(s) = X + s (A X + t - X)``.
* :class:`ForceRegion`: a total force spread over the nodes in the box in
  proportion to their lumped volume (on a flat face of a regular grid this is
  the same split as by lumped area), or a traction (force per unit area)
  on the boundary faces whose centre lies in the box, integrated exactly for
  bilinear faces (a quarter of each face's force to each of its corners).

The functions here turn regions into arrays for a model with ``rest (n, 3)``:
:func:`fixed_dofs` and :func:`prescribed_positions`, :func:`region_forces`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError, check_choice

FORCE_KINDS = ("total", "traction")


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
        A, t = self.transform[:, :3], self.transform[:, 3]
        return X + factor * (X @ A.T + t - X)

    @staticmethod
    def rotation(min, max, axis_point, axis, angle, components: str = "xyz") -> "FixedRegion":
        """Region rotated by ``angle`` (radians) about the line through ``axis_point`` along ``axis``.

        The final map is exact; intermediate load steps interpolate the matrix
        linearly (not a rotation in between; use enough steps for large angles).
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
        ``kind="total"``: the total force (N), spread over the nodes in the box
        in proportion to their lumped volume; ``kind="traction"``: force per
        unit area (Pa) on the boundary faces whose centre lies in the box.
    kind : {"total", "traction"}
    """

    min: np.ndarray
    max: np.ndarray
    vector: np.ndarray
    kind: str = "total"

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


def fixed_dofs(rest, regions) -> tuple[np.ndarray, np.ndarray]:
    """Fixed DOFs of the regions and the region that fixes each (the last listed wins).

    Returns
    -------
    dofs : (k,) int64, sorted, DOF ``3 * node + component``
    owner : (k,) int64, index of the region fixing each DOF

    Raises
    ------
    InputError
        When a region holds no node (names the region).
    """
    rest = np.asarray(rest, dtype=float)
    owner = np.full(3 * len(rest), -1, dtype=np.int64)
    for r, region in enumerate(regions):
        nodes = np.flatnonzero(_in_box(rest, region.min, region.max))
        if len(nodes) == 0:
            raise InputError(
                f"fixed region #{r} [{region.min.tolist()}, {region.max.tolist()}] contains no node; "
                "enlarge the box to reach the object's rest position"
            )
        dofs = (3 * nodes[:, None] + region.component_indices[None, :]).ravel()
        owner[dofs] = r
    dofs = np.flatnonzero(owner >= 0)
    return dofs, owner[dofs]


def prescribed_positions(rest, regions, dofs, owner, factor: float) -> np.ndarray:
    """Values (k,) of the fixed DOFs at load factor / time fraction ``factor``."""
    rest = np.asarray(rest, dtype=float)
    values = np.empty(len(dofs))
    for r, region in enumerate(regions):
        sel = owner == r
        if not np.any(sel):
            continue
        d = dofs[sel]
        nodes, comps = d // 3, d % 3
        values[sel] = region.position(rest[nodes], factor)[np.arange(len(d)), comps]
    return values


def region_forces(model, regions) -> np.ndarray:
    """Nodal forces (n, 3) in N of the force regions on ``model`` (a VoxelModel).

    Raises
    ------
    InputError
        When a region touches no node ("total") or no boundary face ("traction").
    """
    f = np.zeros((model.n_nodes, 3))
    quads = None
    for r, region in enumerate(regions):
        if region.kind == "total":
            nodes = np.flatnonzero(_in_box(model.rest, region.min, region.max))
            if len(nodes) == 0:
                raise InputError(
                    f"force region #{r} [{region.min.tolist()}, {region.max.tolist()}] contains no node; enlarge the box"
                )
            vol = model.nodal_volumes()[nodes]
            f[nodes] += (vol / vol.sum())[:, None] * region.vector[None, :]
        else:
            if quads is None:
                quads, area, centre, _ = model.boundary_quads()
            sel = _in_box(centre, region.min, region.max)
            if not np.any(sel):
                raise InputError(
                    f"traction region #{r} [{region.min.tolist()}, {region.max.tolist()}] contains no boundary face "
                    "centre; enlarge the box to cover part of the surface"
                )
            share = np.repeat(area[sel] / 4.0, 4)
            nodes = quads[sel].ravel()
            for c in range(3):
                f[:, c] += np.bincount(nodes, weights=share * region.vector[c], minlength=model.n_nodes)
    return f
