"""The voxel stencil: the finest multigrid level of a constant-tangent voxel model, applied from per-pattern rows.

A node whose 8 voxels share one material and volume and whose coupled
neighbours are free has its 3 rows given by a 3x81 stencil per pattern of
voxels around it, gathered from its 27 neighbours; the other rows come from
the stored matrix.  Sweeps keep the row order of the assembled matrix.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from ...._jit import njit
from ....image.grid import CORNER_OFFSETS


class VoxelStencil:
    """The finest-level matrix of a constant-tangent voxel model applied without reading it.

    A node whose 8 voxels all exist with the same material and volume, and
    whose 27 neighbours (itself included) have all 3 DOFs free, has the same 3
    rows as every such node: ``scale * S[a]`` over its neighbours' DOFs, with
    ``S`` the 3 x 81 stencil of that material's unit element matrix.  Those
    rows are applied from the stencil (81 products on 81 gathered values per
    row, no stored entries read); the other rows (the surface, the fixed DOFs'
    neighbours, material interfaces) are kept from A.  :meth:`sweep` is
    pointwise Gauss-Seidel in the same row order as on the assembled matrix,
    so the cycle is the same; ``A @ x`` (:meth:`__matmul__`) serves the
    residuals and CG.  Built by :meth:`VoxelHierarchy.stencil`.
    """

    def __init__(self, A, node_of_row, nbr, kind, scale, S, rows, stored=None):
        self.shape = A.shape
        self.dtype = np.dtype(np.float64)
        self.node_of_row, self.nbr, self.kind, self.scale, self.S = node_of_row, nbr, kind, scale, S
        self.interior_rows = int((node_of_row >= 0).sum())
        self.b_row = np.full(A.shape[0], -1, dtype=node_of_row.dtype)
        self.b_row[rows] = np.arange(len(rows))
        # the stored rows (columns stay A's): read from A, or given (assembled from the element matrices)
        sub = A[rows] if stored is None else stored
        self.b_ptr, self.b_idx, self.b_val = sub.indptr.astype(np.int64), sub.indices, sub.data

    def _args(self):
        return (self.node_of_row, self.nbr, self.kind, self.scale, self.S, self.b_row, self.b_ptr, self.b_idx,
                self.b_val)

    def __matmul__(self, x):
        from ._kernels import stencil_matvec

        return stencil_matvec(x, *self._args(), np.empty_like(x))

    def sweep(self, x, b, forward: bool = True) -> None:
        """One Gauss-Seidel sweep on ``A x = b``, in place on x (forward or backward row order)."""
        from ._kernels import stencil_sweep

        stencil_sweep(x, b, *self._args(), bool(forward))


def _unit_stencil(unit, pattern: int = 255) -> np.ndarray:
    """(3, 81): a node's rows in the sum of ``unit`` (24 x 24) over the voxels of ``pattern`` around it
    (bit v: the voxel at the node minus corner v), over the neighbours
    ``o = (ox + 1) * 9 + (oy + 1) * 3 + (oz + 1)`` and their components."""
    S = np.zeros((3, 27, 3))
    for v in range(8):  # the voxel at offset -(corner of the node in it)
        if not (pattern >> v) & 1:
            continue
        ci = CORNER_OFFSETS[v]
        for cj in range(8):
            o = CORNER_OFFSETS[cj] - ci + 1
            S[:, o[0] * 9 + o[1] * 3 + o[2], :] += unit[3 * v : 3 * v + 3, 3 * cj : 3 * cj + 3]
    return S.reshape(3, 81)


@lru_cache(maxsize=1)
def _coupled_offsets() -> np.ndarray:
    """(256, 27) bool: the neighbour offsets that share a voxel with the node, per pattern of voxels."""
    bits = ((np.arange(256)[:, None] >> np.arange(8)) & 1).astype(bool)
    out = np.zeros((256, 27), dtype=bool)
    for v in range(8):
        for cj in range(8):
            o = CORNER_OFFSETS[cj] - CORNER_OFFSETS[v] + 1
            out[:, o[0] * 9 + o[1] * 3 + o[2]] |= bits[:, v]
    out.setflags(write=False)
    return out


@njit
def _gather_forward(data, sel):
    """``data[k] = data[sel[k]]`` for k in order, in place (valid when ``sel[k] >= k``, as a compaction's)."""
    for k in range(len(sel)):
        data[k] = data[sel[k]]


def _voxel_keys(ijk, shape):
    return (ijk[:, 0] * shape[1] + ijk[:, 1]) * shape[2] + ijk[:, 2]
