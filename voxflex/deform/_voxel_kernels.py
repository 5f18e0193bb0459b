"""Compiled kernels of the voxel model (stiffness of trilinear voxels, CSR scatter).

Two kernels, each with a plain numpy twin used by the tests:

* :func:`element_stiffness` — ``K_e = sum_q vol_q B_q^T A_q B_q`` for a batch
  of voxels sharing the world gradient table ``G (Q, 8, 3)`` (the same in every
  voxel of a regular grid), where ``(B_q x)_ij = sum_a x_ai G_qaj``;
  DOF order inside the element: ``3 * corner + component``.
* :func:`scatter_blocks` — adds element matrices into the data array of a CSR
  matrix whose rows hold whole 3x3 node blocks (see :func:`block_csr_pattern`).
"""

from __future__ import annotations

import numpy as np

from .._jit import njit, prange


@njit(parallel=True)
def _element_stiffness_kernel(G, A, vol, out):
    k = out.shape[0]
    nq = G.shape[0]
    for e in prange(k):
        T = np.empty((8, 3, 3, 3))
        Ke = out[e]
        for r in range(24):
            for s in range(24):
                Ke[r, s] = 0.0
        for q in range(nq):
            row = e * nq + q
            v = vol[row]
            if v == 0.0:
                continue
            # T[a, i, k, l] = sum_j G[q, a, j] A[i, j, k, l]
            for a in range(8):
                for i in range(3):
                    for kk in range(3):
                        for ll in range(3):
                            acc = 0.0
                            for j in range(3):
                                acc += G[q, a, j] * A[row, i, j, kk, ll]
                            T[a, i, kk, ll] = acc * v
            # K[a i, b k] += sum_l T[a, i, k, l] G[q, b, l]
            for a in range(8):
                for i in range(3):
                    for b in range(8):
                        g0 = G[q, b, 0]
                        g1 = G[q, b, 1]
                        g2 = G[q, b, 2]
                        for kk in range(3):
                            Ke[3 * a + i, 3 * b + kk] += (
                                T[a, i, kk, 0] * g0 + T[a, i, kk, 1] * g1 + T[a, i, kk, 2] * g2
                            )


def element_stiffness(G, A, vol):
    """Element stiffness matrices of a batch of trilinear voxels.

    Parameters
    ----------
    G : (Q, 8, 3) float
        World gradients of the corner weights at the Q quadrature points (1/m).
    A : (k * Q, 3, 3, 3, 3) float
        Tangent dP/dF at each sample, element-major (Pa).
    vol : (k * Q,) float
        Volume weight of each sample (m^3).

    Returns
    -------
    (k, 24, 24) float, N/m; DOF ``3 * corner + component``.
    """
    G = np.ascontiguousarray(G, dtype=np.float64)
    A = np.ascontiguousarray(A, dtype=np.float64)
    vol = np.ascontiguousarray(vol, dtype=np.float64)
    k = len(vol) // G.shape[0]
    out = np.empty((k, 24, 24))
    _element_stiffness_kernel(G, A, vol, out)
    return out


def element_stiffness_numpy(G, A, vol):
    """Plain numpy twin of :func:`element_stiffness` (reference for tests)."""
    nq = G.shape[0]
    k = len(vol) // nq
    A = A.reshape(k, nq, 3, 3, 3, 3) * vol.reshape(k, nq)[:, :, None, None, None, None]
    K = np.einsum("qaj,eqijkl,qbl->eaibk", G, A, G)
    return K.reshape(k, 24, 24)


@njit
def _scatter_kernel(Ke, conn, blockmap, indptr_b, data):
    for e in range(Ke.shape[0]):
        for a in range(8):
            i = conn[e, a]
            start = indptr_b[i]
            deg = indptr_b[i + 1] - start
            for b in range(8):
                blk = blockmap[e, 8 * a + b]
                p = blk - start
                base = 9 * start + 3 * p
                for c in range(3):
                    off = base + c * 3 * deg
                    for d in range(3):
                        data[off + d] += Ke[e, 3 * a + c, 3 * b + d]


def scatter_blocks(Ke, conn, blockmap, indptr_b, data):
    """Add element matrices ``Ke (k, 24, 24)`` into CSR ``data`` in place.

    ``conn (k, 8)`` are the element nodes, ``blockmap (k, 64)`` the index of
    node block ``(conn[a], conn[b])`` (entry ``8 a + b``) in the block pattern
    whose row pointer is ``indptr_b (n + 1,)``.
    """
    _scatter_kernel(
        np.ascontiguousarray(Ke),
        np.ascontiguousarray(conn, dtype=np.int64),
        np.ascontiguousarray(blockmap),
        indptr_b,
        data,
    )


def block_csr_pattern(conn, n_nodes):
    """Sparsity of a 3-DOF-per-node matrix coupling the nodes of each element.

    Parameters
    ----------
    conn : (m, 8) int
        Element nodes.
    n_nodes : int

    Returns
    -------
    indptr : (3 n + 1,) int, indices : (nnz,) int
        Scalar CSR pattern, DOF ``3 * node + component``, columns sorted.
    indptr_b : (n + 1,) int64
        Node-block row pointer.
    blockmap : (m, 64) int32 or int64
        Index of block ``(conn[e, a], conn[e, b])`` at entry ``8 a + b``.

    Row ``3 i + c`` holds the blocks of node row ``i`` in column order; the
    entry for block ``k`` (position ``p = k - indptr_b[i]`` in its row of
    ``deg`` blocks), component ``(c, d)`` lies at ``9 indptr_b[i] + 3 c deg + 3 p + d``.
    """
    conn = np.asarray(conn, dtype=np.int64)
    n = int(n_nodes)
    rows = np.repeat(conn, 8, axis=1)  # (m, 64): a-major
    cols = np.tile(conn, (1, 8))
    keys = rows * n + cols
    ukeys = np.unique(keys)
    brow = ukeys // n
    bcol = ukeys % n
    nnzb = len(ukeys)
    index_dtype = np.int32 if 9 * nnzb < np.iinfo(np.int32).max else np.int64
    blockmap = np.searchsorted(ukeys, keys).astype(index_dtype)
    del keys
    indptr_b = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(brow, minlength=n), out=indptr_b[1:])
    deg = np.diff(indptr_b)
    # scalar pattern
    row_len = np.repeat(3 * deg, 3)
    indptr = np.zeros(3 * n + 1, dtype=np.int64)
    np.cumsum(row_len, out=indptr[1:])
    k = np.arange(nnzb)
    p = k - indptr_b[brow]
    base = 9 * indptr_b[brow] + 3 * p  # (nnzb,)
    dg = deg[brow]
    c = np.arange(3)
    pos = base[:, None, None] + (3 * c)[None, :, None] * dg[:, None, None] + c[None, None, :]  # (nnzb, c, d)
    indices = np.empty(9 * nnzb, dtype=index_dtype)
    indices[pos.ravel()] = np.broadcast_to((3 * bcol)[:, None, None] + c[None, None, :], pos.shape).ravel()
    return indptr.astype(index_dtype), indices, indptr_b, blockmap
