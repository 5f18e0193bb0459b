"""Vector and sparse-matrix helpers shared by every layer.

``vdot`` / ``vnorm`` are BLAS dot products and norms of flat float vectors
(numpy's ``np.dot`` of 1-D arrays, without the temporaries of ``(a * b).sum()``);
:func:`free_block` gathers the rows and columns of the free DOFs of a CSR
matrix (the Newton systems of every model); :func:`diagonal` reads a sparse diagonal without a scan.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .errors import InputError

DIRECT_FALLBACK_MAX = 20000
"""Unknowns up to which an iterative solve that stops short falls back to the sparse LU (``fallback="auto"``).

Beyond it the factorisation costs far more than the multigrid solves it replaces, and its fill
grows faster than the unknowns (``benchmarks/bench_direct_limit.py``: on clamped Hooke beams, 2
loaded cores, LU / multigrid-CG at rtol 1e-8: 7776 unknowns 0.50 / 0.047 s, factor 52 MB;
24336: 3.9 / 0.23 s, 288 MB; the 26k-DOF cow tangent took 25-47 s, the 315k-DOF bunny sat over
30 minutes at 8.7 GB).  Up to this size an LU costs about as much as one failed multigrid-CG run of
:data:`~voxflex.deform.solve.linear.MULTIGRID_MAXITER` iterations; there it is kept because it is immune to ill-conditioning and
indefiniteness.  Above it a solve that stops short raises (or, with ``partial=True``, returns CG's
last iterate for the Newton solver's own remedies, see :mod:`voxflex.deform.solve.newton`)."""


def vdot(a, b) -> float:
    """Dot product of two float vectors without BLAS.

    OpenBLAS threads its ``ddot`` on long vectors; on a shared 2-core machine
    the threads spin against other processes' work and a 55k-entry dot product
    took 7 ms instead of 6 us (scipy's CG on the 55k-DOF beam: 7.8 s instead of
    0.96 s at load average 2).  ``einsum`` sums in one thread, with SIMD.
    """
    return float(np.einsum("i,i->", a, b))


def vnorm(a) -> float:
    """Euclidean norm of a float vector without BLAS (see :func:`vdot`)."""
    return float(np.sqrt(np.einsum("i,i->", a, a)))


FREE_BLOCK_ROWS = 4096
"""Rows per pass of the numpy twin of :func:`free_block` (its scratch: ~13 bytes per stored entry
of that many rows; at 56k DOF 65536 rows put the peak at 3702 bytes/DOF above the model, 4096 at 1973)."""


def diagonal(A) -> np.ndarray:
    """The diagonal of a square matrix: of a CSR matrix with sorted indices by a compiled binary search per
    row (:func:`~voxflex._linalg_kernels.csr_diagonal_kernel`), of anything else by its own ``diagonal()``."""
    if not (sp.isspmatrix_csr(A) and A.shape[0] == A.shape[1] and A.has_sorted_indices and A.nnz):
        return A.diagonal()
    from ._linalg_kernels import csr_diagonal_kernel

    out = np.zeros(A.shape[0], dtype=A.dtype)
    csr_diagonal_kernel(A.indptr, A.indices, A.data, out)
    return out


def free_block(A, free, *, overwrite: bool = False) -> sp.csr_matrix:
    """``A[free][:, free]`` of a CSR matrix, gathered row by row, optionally in A's own arrays.

    scipy's two-step fancy indexing peaks at about twice the matrix (3.2 kB
    per DOF at 0.8 million voxel DOFs); here a compiled gather
    (:func:`~voxflex._linalg_kernels.free_block_kernel`) needs only a
    column map (8 bytes per row) besides the block.  With ``overwrite=True`` the kept entries
    are moved to the front of ``A.data`` and ``A.indices`` (a stable
    compaction: an entry only moves towards the start), so the block costs no
    second matrix; A is then invalid and the block's arrays are views of A's
    buffers (the dropped entries stay allocated behind them; scipy copies the
    arrays instead when the block keeps less than half of A's entries).

    Parameters
    ----------
    A : (N, N) csr_matrix with sorted indices
    free : (F,) int, sorted unique indices in [0, N)
    overwrite : bool
        Compact A's arrays in place (A must own writable arrays and not be needed again).

    Returns
    -------
    (F, F) csr_matrix, sorted indices, the index dtype of A.

    Raises
    ------
    InputError
        A not square CSR, ``free`` not sorted unique indices, or overwrite of read-only arrays.
    """
    if not sp.isspmatrix_csr(A) or A.shape[0] != A.shape[1]:
        raise InputError("free_block needs a square CSR matrix (scipy.sparse.csr_matrix)")
    N = A.shape[0]
    free = np.asarray(free)
    if free.ndim != 1 or free.dtype.kind not in "iu" or (len(free) and (free[0] < 0 or free[-1] >= N)) or \
            np.any(np.diff(free) <= 0):
        raise InputError(f"free must be sorted unique indices in [0, {N})")
    if overwrite and not (A.data.flags.writeable and A.indices.flags.writeable):
        raise InputError("free_block(overwrite=True) needs writable arrays; pass overwrite=False to copy")
    if not A.has_sorted_indices:
        A = A.copy() if not overwrite else A
        A.sort_indices()
    from ._linalg_kernels import free_block_kernel

    indptr, indices, data = A.indptr, A.indices, A.data
    free = free.astype(np.int64)
    F = len(free)
    newcol = np.full(N, -1, dtype=np.int64)
    newcol[free] = np.arange(F)
    idx = indices.dtype if max(int(A.nnz), F) < np.iinfo(np.int32).max or indices.dtype == np.int64 else np.int64
    new_indptr = np.zeros(F + 1, dtype=np.int64)
    if overwrite and indices.dtype == idx:
        nnz = free_block_kernel(indptr, indices, data, newcol, free, new_indptr, indices, data)
        out_idx, out_data = indices, data
    else:  # count, then gather into new arrays (6-10 ms at 55k DOF; the row-blocked numpy twin took 50 ms)
        nnz = free_block_kernel(indptr, indices, data, newcol, free, new_indptr, np.empty(0, dtype=idx),
                                np.empty(0, dtype=data.dtype))
        out_idx, out_data = np.empty(nnz, dtype=idx), (data if overwrite else np.empty(nnz, dtype=data.dtype))
        free_block_kernel(indptr, indices, data, newcol, free, new_indptr, out_idx, out_data)
    return sp.csr_matrix((out_data[:nnz], out_idx[:nnz], new_indptr.astype(idx)), shape=(F, F))


def _free_block_impl(indptr, indices, data, free, N, overwrite):
    """Plain numpy twin of the compiled gather (:func:`~voxflex._linalg_kernels.free_block_kernel`),
    by row blocks of :data:`FREE_BLOCK_ROWS` rows; the tests compare the two."""
    keep = np.zeros(N, dtype=bool)
    keep[free] = True
    F = len(free)
    newcol = np.full(N, -1, dtype=indices.dtype)
    newcol[free] = np.arange(F, dtype=indices.dtype)

    def kept(r0, r1):
        """Positions (relative to the block start) of the kept entries of rows r0..r1-1."""
        a, b = int(indptr[r0]), int(indptr[r1])
        m = keep[indices[a:b]]
        m &= np.repeat(keep[r0:r1], np.diff(indptr[r0 : r1 + 1]))
        return a, m

    # pass 1: entries kept per free row
    counts = np.zeros(N, dtype=np.int64)
    for r0 in range(0, N, FREE_BLOCK_ROWS):
        r1 = min(N, r0 + FREE_BLOCK_ROWS)
        a, m = kept(r0, r1)
        cm = np.concatenate([[0], np.cumsum(m, dtype=np.int64)])
        counts[r0:r1] = cm[indptr[r0 + 1 : r1 + 1] - a] - cm[indptr[r0:r1] - a]
    nnz = int(counts[free].sum())
    idx = indices.dtype if max(nnz, F) < np.iinfo(np.int32).max or indices.dtype == np.int64 else np.int64
    new_indptr = np.zeros(F + 1, dtype=idx)
    np.cumsum(counts[free], out=new_indptr[1:])
    del counts
    out_data = data if overwrite else np.empty(nnz, dtype=data.dtype)
    out_idx = indices if overwrite and indices.dtype == idx else np.empty(nnz, dtype=idx)
    # pass 2: gather (the gathered block is a copy taken before it is written, at or before its source)
    w = 0
    for r0 in range(0, N, FREE_BLOCK_ROWS):
        r1 = min(N, r0 + FREE_BLOCK_ROWS)
        a, m = kept(r0, r1)
        sel = np.flatnonzero(m) + a
        c = len(sel)
        out_data[w : w + c] = data[sel]
        out_idx[w : w + c] = newcol[indices[sel]]
        w += c
    return sp.csr_matrix((out_data[:nnz], out_idx[:nnz], new_indptr), shape=(F, F))
