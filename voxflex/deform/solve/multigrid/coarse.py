"""The coarse levels' operators: Galerkin products ``P^T A P`` and the solve on the coarsest level.

:func:`_galerkin_impl` forms a coarse matrix from the finer one by row blocks of A (cut from its arrays,
:func:`_row_block`) summed pairwise, so that a large fine level needs little scratch; :class:`_CoarseSolver`
factorises the coarsest matrix once by sparse LU (a pseudo-inverse where it is singular) and solves on it
at every cycle.  :mod:`voxflex.deform.solve.multigrid.hierarchy` builds the levels with them.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

GALERKIN_CHUNK = 1 << 16
"""Rows of A per block of the Galerkin product: ``A @ P`` has ~2x the entries of A, so the fine
level's product is done by row blocks (scratch ~2 % of A at 6 million DOF instead of 1.5 A)."""


def _row_block(A, r0, r1):
    """Rows [r0, r1) of the CSR matrix A, from slices of its arrays (scipy keeps copies of such small
    views: a memcpy), not by scipy's row slicing (``get_csr_submatrix``: 2.6 s of the voxel bunny's 11
    Galerkin products; a first-level product on 287k unknowns 0.54 -> 0.44 s, the same bits)."""
    a, b = int(A.indptr[r0]), int(A.indptr[r1])
    return sp.csr_matrix((A.data[a:b], A.indices[a:b], A.indptr[r0:r1 + 1] - a), shape=(r1 - r0, A.shape[1]),
                         copy=False)


def _galerkin_impl(A, P, R):
    """``P^T A P`` (CSR), by row blocks of A when A is large.

    The block products are summed pairwise (a binary-counter merge), so the
    work is O(nnz log blocks) instead of one running sum that touches the
    whole coarse matrix per block (O(nnz blocks): ~100 blocks at 6 million DOF).
    The row blocks of A are cut from its arrays directly (:func:`_row_block`).
    """
    n = A.shape[0]
    if n <= GALERKIN_CHUNK:
        return sp.csr_matrix(R @ (A @ P))
    A = sp.csr_matrix(A)
    stack = []  # (blocks summed, partial sum); sizes strictly decrease down the stack
    for s in range(0, n, GALERKIN_CHUNK):
        e = min(n, s + GALERKIN_CHUNK)
        part, count = sp.csr_matrix(P[s:e].T @ (_row_block(A, s, e) @ P)), 1
        while stack and stack[-1][0] == count:
            count += stack[-1][0]
            part = stack.pop()[1] + part
        stack.append((count, part))
    out = stack.pop()[1]
    while stack:
        out = stack.pop()[1] + out
    return sp.csr_matrix(out)


class _CoarseSolver:
    """Sparse LU of the coarsest matrix (SuperLU, minimum-degree ordering), factorised at once.

    A Newton run factors the coarsest level whenever it rebuilds its coarse
    levels (at least every :data:`MAX_STALE_SOLVES` + 1 iterations; every
    iteration before the stale reuse): on the neo-Hooke beam
    32x8x8 (7776 unknowns, coarsest level 1275 DOFs) a dense Cholesky took 25
    ms of each iteration, a quarter of it; the sparse LU of the same matrix
    11 ms (the 31-iteration run: 4.1 against 2.8 CPU s in one process), and
    the 243-DOF level that :data:`MAX_COARSE_CUBIC` now gives that beam 1 ms.
    Falls back to a pseudo-inverse when the coarse matrix is singular
    (a coarse space that is not full rank on a few voxels).  With ``single``
    (a single-precision cycle) the factorisation stays in double precision;
    the right-hand side and the answer are cast.
    """

    def __init__(self, Ac, single: bool = False):
        import scipy.sparse.linalg as spla

        self.single = single

        Ac = sp.csc_matrix(0.5 * (Ac + Ac.T))
        self.lu = self.pinv = None
        try:
            lu = spla.splu(Ac, permc_spec="MMD_AT_PLUS_A")
            pivots = np.abs(lu.U.diagonal())
            # a pivot at round-off of the largest: singular in exact arithmetic (LU does not fail there)
            if pivots.min() > 1e-12 * pivots.max():
                self.lu = lu
        except RuntimeError:  # SuperLU: "Factor is exactly singular"
            pass
        if self.lu is None:
            self.pinv = sla.pinvh(Ac.toarray())

    def __call__(self, A, b):
        if self.single:
            b = b.astype(np.float64)
        x = self.lu.solve(b) if self.lu is not None else self.pinv @ b
        return x.astype(np.float32) if self.single else x
