"""The frames' mass: lumped per frame, or consistent ``J^T diag(m) J`` (:meth:`FrameModel.mass_matrix`).

The mass points are the voxel centres (:meth:`FrameModel._mass_points`), each with its voxel's volume
times its label's density; the consistent mass integrates the 2x2x2 Gauss points of every voxel instead
(one point per voxel can leave it singular on thin parts).  Lumped: every voxel centre's mass goes to its
frames in proportion to their weights, each frame carrying its share as its own affine body
(block-diagonal 12 x 12 blocks, exact total mass and momentum), unless some weight is negative
(reproducing kernels): then the point masses through the weights themselves (:func:`point_mass`).
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import scipy.sparse as sp

from ....sampling.voxel import voxel_samples
from . import _kernels as K

__all__ = ["mass_matrix", "point_mass"]


def mass_matrix(model, densities: Mapping[int, float], *, lumped: bool = True) -> sp.csr_matrix:
    """Mass matrix (12n, 12n): consistent ``J^T diag(m) J`` or lumped per frame (see the module docstring)."""
    mp = model._point_masses(densities)
    if not lumped:
        # one point per voxel can leave the consistent mass singular on thin parts (few voxels
        # across a frame's support): the 2x2x2 Gauss points of every voxel integrate it
        s = voxel_samples(model.image, model.shape_function, rule="gauss-legendre", use_occupancy=model.use_occupancy)
        m8 = np.repeat(mp / model._mass_points()[1], 8) * s.volume  # density of each voxel x Gauss volumes
        return point_mass(model, s.values, m8)
    _, _, pmap = model._mass_layer()
    v = pmap.shape
    if np.any(v.w < 0):
        # weights negative somewhere (reproducing kernels): per-frame blocks would be indefinite (35 of 40
        # frames on the cantilever) and, made positive, would not accelerate the material by g under its
        # own weight where a held frame's weight is negative (1.8 g at a beam's tip): the mass of the
        # voxel centres, the points gravity acts on, through the weights themselves
        return point_mass(model, v, mp)
    n = model.n_nodes
    blocks = np.zeros((n, 4, 4))  # per frame: sum m w [r; 1][r; 1]^T with r = X - X_a
    K.mass_blocks(np.ascontiguousarray(v.index), np.ascontiguousarray(v.w, dtype=np.float64),
                  np.ascontiguousarray(v.rest, dtype=np.float64), np.ascontiguousarray(model.frames, dtype=np.float64),
                  np.ascontiguousarray(mp, dtype=np.float64), blocks)
    # DOF layout: A row i (3 entries) then t_i; x_i = sum_j A_ij r_j + t_i couples A_i. with t_i
    full = np.zeros((n, 12, 12))
    for i in range(3):
        dofs = [3 * i, 3 * i + 1, 3 * i + 2, 9 + i]
        full[:, np.ix_(dofs, dofs)[0], np.ix_(dofs, dofs)[1]] = blocks
    return sp.block_diag(list(full), format="csr")


def point_mass(model, values, masses, chunk: int = 4096) -> sp.csr_matrix:
    """``J^T diag(m) J`` of point masses ``masses`` (k,) at the points of ``values``, with the gauge
    motions of linearly precise weights (:func:`~voxflex.deform.models.frames.modes.gauge_modes`,
    along which it is singular: they move no point) given the frames' mean matrix-entry mass, which
    no force excites (every force is ``J^T f``, and ``J`` vanishes on them).

    Each spatial component of a point moves by ``sum_a w_a [r_a; 1] . [A_a row; t_a]``: the (4n, 4n)
    matrix ``sum_p m_p b_p b_p^T`` (``b_p`` the point's ``w_a [r_a; 1]`` in the frames' slots, dense
    by chunks of points) is the same for the three components (the sparse J of the bunny's 94k
    voxel centres with 35 parents would hold 10 million entries)."""
    from .modes import motion_gram, weights_gauge_modes

    n = model.n_nodes
    G4 = motion_gram(model.frames, values, masses=masses, chunk=chunk)
    # DOF layout: A row i (3 entries) then t_i; component i of x moves with [A row i, t_i]
    M = np.zeros((n, 12, n, 12))
    G4 = G4.reshape(n, 4, n, 4)
    for i in range(3):
        d = np.array([3 * i, 3 * i + 1, 3 * i + 2, 9 + i])
        M[:, d[:, None], :, d[None, :]] = G4.transpose(1, 3, 0, 2)
    M = M.reshape(12 * n, 12 * n)
    G = weights_gauge_modes(model.shape_function, model.frames, values)
    if G.shape[1]:
        a_ = (np.arange(12 * n) % 12) < 9
        M += float(np.diagonal(M)[a_].mean()) * (G @ G.T)
    return sp.csr_matrix(0.5 * (M + M.T))
