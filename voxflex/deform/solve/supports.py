"""Supports and mechanisms, checked before a static solve.

A static problem has a unique equilibrium only when every part of the body
is held against all six rigid motions.  Parts are what the model says they are
(:meth:`Model.parts`: face-connected voxels for the voxel model, since voxels
that share only an edge or a corner form a hinge; the components the frames'
shape functions couple for the frame model; pieces of mesh for a membrane).  A
component is held when the rigid motions of its nodes are restrained to rank
6 by the fixed DOFs, or by nodes it shares with components already held (an
edge or a corner shared with a clamped part restrains only 5 or 3 of them:
a hinge).  Anything less is refused before solving, with a message naming
the component and the fixes, instead of letting Newton return garbage.
"""

from __future__ import annotations

import numpy as np

from ...errors import InputError

__all__ = ["check_supports", "unsupported_components", "free_rigid_motions", "FreeMotionWarning"]


class FreeMotionWarning(UserWarning):
    """A static answer held by obstacles only that some rigid motion leaves in equilibrium: its position along
    that motion is arbitrary (e.g. a ball on a frictionless plane can slide and spin)."""


FREE_MOTION_RATIO = 1e-8
"""A rigid motion of a static answer whose stiffness is below this fraction of the free DOFs' mean diagonal
stiffness (both per unit motion, dimensionless) is held by nothing."""

_RANK_TOL = 1e-10


def _rank(rows: np.ndarray) -> int:
    """Numerical rank of the (k, 6) rows, after scaling each row and then each column to unit length.

    The scaling changes no exact rank, and makes the relative threshold independent of units: a frame's
    DOFs mix a dimensionless matrix with a translation in metres, so a 1 um body's rows differed by 1e12
    and its translations fell under the threshold (a clamped 1 um beam was refused as unsupported)."""
    if rows.shape[0] == 0:
        return 0
    norms = np.linalg.norm(rows, axis=1)
    rows = rows[norms > 0] / norms[norms > 0, None]
    if rows.shape[0] == 0:
        return 0
    cols = np.linalg.norm(rows, axis=0)
    rows = rows / np.where(cols > 0, cols, 1.0)
    G = rows.T @ rows
    ev = np.linalg.eigvalsh(G)
    top = ev.max()
    return int(np.sum(ev > _RANK_TOL * top)) if top > 0 else 0


def unsupported_components(model, fixed_dofs) -> list[dict]:
    """Components of ``model`` not held against every rigid motion by ``fixed_dofs`` (flat DOFs).

    Returns
    -------
    list of dict, one per unsupported part: ``index`` (1-based), ``n`` (number of
    parts), ``voxels`` (its cells, ``cell`` says what they are), ``labels``, ``lo``/``hi`` (world bounding box, m),
    ``free`` (number of free rigid motions), ``hinge`` (True when it is held only
    through shared edges or corners).
    """
    parts = model.parts()
    n = len(parts)
    if n == 0:
        return []
    nodes_of = [p.nodes for p in parts]
    d = model.dofs_per_node
    N = np.asarray(model.rest).size
    B = np.asarray(model.rigid_modes(), dtype=float)  # read only: the rows a rank needs are scaled when taken
    held = np.zeros(N, dtype=bool)
    held[np.asarray(fixed_dofs, dtype=np.int64)] = True
    n_nodes = N // d
    supported = np.zeros(n, dtype=bool)
    owner_count = np.zeros(n_nodes, dtype=np.int64)
    for nodes in nodes_of:
        owner_count[nodes] += 1
    support_node = np.zeros(n_nodes, dtype=bool)
    lo = np.min([p.lo for p in parts], axis=0)
    hi = np.max([p.hi for p in parts], axis=0)
    extent = float(np.max(hi - lo)) or 1.0
    unit = np.array([1.0, 1.0, 1.0, 1.0 / extent, 1.0 / extent, 1.0 / extent])  # rotations comparable to translations
    ranks = np.zeros(n, dtype=np.int64)
    own = np.zeros(n, dtype=np.int64)
    changed = True
    while changed:
        changed = False
        for c in range(n):
            if supported[c]:
                continue
            nodes = nodes_of[c]
            dofs = (d * nodes[:, None] + np.arange(d)).ravel()
            by_fixed = held[dofs]
            own[c] = _rank(B[dofs[by_fixed]] * unit)
            shared = np.repeat(support_node[nodes] & (owner_count[nodes] > 1), d)
            ranks[c] = _rank(B[dofs[by_fixed | shared]] * unit)
            if ranks[c] == 6:
                supported[c] = True
                support_node[nodes] = True
                changed = True
    out = []
    for c in np.flatnonzero(~supported):
        p = parts[c]
        out.append({"index": int(c + 1), "n": int(n), "voxels": int(p.size), "cell": p.cell, "labels": list(p.labels),
                    "lo": p.lo, "hi": p.hi, "free": int(6 - ranks[c]), "hinge": bool(ranks[c] > own[c])})
    return out


def check_supports(model, fixed_dofs) -> None:
    """InputError naming the first component a static solve cannot hold (see the module docstring)."""
    bad = unsupported_components(model, fixed_dofs)
    if not bad:
        return
    b = bad[0]
    lo = ", ".join(f"{v:.4g}" for v in b["lo"])
    hi = ", ".join(f"{v:.4g}" for v in b["hi"])
    how = ("is held only through a shared edge or corner (a hinge)" if b["hinge"]
           else "is not held" if b["free"] == 6 else "is not held against every rigid motion")
    more = f" ({len(bad) - 1} more)" if len(bad) > 1 else ""
    raise InputError(
        f"static scene is ill-posed: material component {b['index']} of {b['n']} (label "
        f"{', '.join(map(str, b['labels']))}, {b['voxels']} {b['cell']}, box [{lo}] .. [{hi}] m) {how}: "
        f"{b['free']} free rigid motion(s){more}; fix it with a [[fixed]] region covering it, drop islands with "
        '[object] keep = "largest" or min_component_voxels, or simulate dynamics (implicit-euler)'
    )


def free_rigid_motions(model, q, free) -> int:
    """How many independent rigid motions (of the six about the shape at ``q``) the tangent there leaves
    without stiffness over the ``free`` DOFs: those an equilibrium held by frictionless obstacles alone can
    drift along.

    The six motions (rotations scaled by the body's extent, as :func:`unsupported_components` does) projected
    on the tangent, ``R = B^T H B``; a motion counts as free where R's eigenvalue is below
    :data:`FREE_MOTION_RATIO` of the mean diagonal stiffness times the motion's squared norm."""
    import scipy.sparse as sp

    from ..chain.rigid_modes import rigid_body_modes

    free = np.asarray(free, dtype=np.int64)
    if model.dofs_per_node != 3 or len(free) == 0:
        return 0  # the motions of the state are those of its points: only models whose DOFs are positions
    q = np.asarray(q, dtype=float).reshape(-1, 3)
    H = model.energy_gradient_hessian(q)[2]
    H = sp.csr_matrix(H) if sp.issparse(H) else np.asarray(H)
    # about the state, not the rest: a motion about the rest shape strains the deformed body (a spin of a
    # ball resting on a plane measured 3e-4 of the scale about the rest, round-off about the state)
    extent = float(np.max(np.ptp(q, axis=0))) or 1.0
    B = rigid_body_modes(q) * np.array([1.0, 1.0, 1.0, 1.0 / extent, 1.0 / extent, 1.0 / extent])
    held = np.ones(len(B), dtype=bool)
    held[free] = False
    B[held] = 0.0  # the motions over the free DOFs only (no copy of the free block)
    R = B.T @ (H @ B)
    R = 0.5 * (R + R.T)
    B = B[free]
    scale = float(np.abs(H.diagonal()[free]).mean()) * float((B * B).sum(axis=0).max())
    if not scale > 0:
        return 0
    tri = np.abs(np.diag(np.linalg.qr(B, mode="r")))  # the motions' span over the free DOFs: its rank
    rank = int(np.sum(tri > 1e-12 * tri.max()))
    ev = np.linalg.eigvalsh(R)
    return int(np.sum(ev < FREE_MOTION_RATIO * scale)) - (6 - rank)
