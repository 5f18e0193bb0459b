"""Prescribed motions of a whole model: the map at a fraction of the run, the moved rest state."""

from __future__ import annotations

import numpy as np

__all__ = ["moved_rest", "transform_at"]

RIGID_TRANSFORM_TOL = 1e-9
"""|AᵀA - I| and |det A - 1| below which a transform's matrix counts as a rotation (a rigid transform)."""


def transform_at(transform, factor: float) -> np.ndarray:
    """The map ``[A_s | t_s]`` (3, 4) at fraction ``s = factor`` of the way from the identity to ``transform``.

    A rigid transform (its matrix a rotation, see :data:`RIGID_TRANSFORM_TOL`)
    moves along its screw motion: a rotation by ``s θ`` about its axis (through
    the point ``c`` the transform turns about) and a slide ``s d`` along it, so
    every intermediate map is rigid too (a prescribed turn of a bone does not
    squeeze it half-way).  Any other map is interpolated linearly,
    ``A_s = I + s (A - I)``, ``t_s = s t``.  Both are exact at ``s = 0`` and 1.
    """
    T = np.asarray(transform, dtype=float)
    A, t = T[:, :3], T[:, 3]
    s = float(factor)
    rigid = (np.abs(A.T @ A - np.eye(3)).max() <= RIGID_TRANSFORM_TOL
             and abs(np.linalg.det(A) - 1.0) <= RIGID_TRANSFORM_TOL)
    if not rigid:
        return np.hstack([np.eye(3) + s * (A - np.eye(3)), (s * t)[:, None]])
    from ..chain.nodes import rotation_exp
    from ..chain.rigid import rotation_log

    w = rotation_log(A[None])[0]
    angle = float(np.linalg.norm(w))
    if angle < 1e-12:
        return np.hstack([np.eye(3), (s * t)[:, None]])
    axis = w / angle
    slide = float(t @ axis) * axis
    # the axis point c with (I - A) c = t - slide (I - A is singular only along the axis)
    c = np.linalg.lstsq(np.eye(3) - A, t - slide, rcond=None)[0]
    c -= float(c @ axis) * axis
    Rs = rotation_exp((s * w)[None])[0]
    return np.hstack([Rs, (c - Rs @ c + s * slide)[:, None]])


def moved_rest(model, transform, factor: float) -> np.ndarray:
    """Flat state of ``model`` at fraction ``factor`` of the way from rest to ``moved_state(transform)``.

    A rigid transform moves the body along its screw motion (:func:`transform_at`);
    for any other map, point nodes go ``X + s (A X + t - X)`` and affine frames'
    matrices ``I + s (A - I)`` with their origins ``X + s (A X + t - X)``, so the
    material points of a region whose frames are all moved follow the same
    interpolated affine map exactly.
    """
    return np.asarray(model.moved_state(transform_at(transform, factor)), dtype=float).ravel()
