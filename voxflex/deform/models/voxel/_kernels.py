"""Compiled kernels of the voxel model (stiffness of trilinear voxels, CSR scatter).

Kernels, each with a plain numpy twin used by the tests:

* :func:`element_stiffness` — ``K_e = sum_q vol_q B_q^T A_q B_q`` for a batch
  of voxels sharing the world gradient table ``G (Q, 8, 3)`` (the same in every
  voxel of a regular grid), where ``(B_q x)_ij = sum_a x_ai G_qaj``;
  DOF order inside the element: ``3 * corner + component``;
  :func:`element_stiffness_i1j` the same for a neo-Hookean tangent, from F and
  three coefficients per sample instead of the (9, 9) tangent.
* :func:`scatter_blocks` — adds element matrices (or one shared matrix times a
  per-element factor) into the data array of a CSR matrix whose rows hold
  whole 3x3 node blocks (see :func:`block_csr_pattern`).
* :func:`free_block_kernel` — the free-DOF block ``A[free][:, free]`` of a
  CSR matrix, gathered row by row (in place or into new arrays).

The sparsity pattern: :func:`grid_block_pattern` reads it off the grid
structure in O(64 m + 27 n) (two compiled loops); :func:`block_csr_pattern`,
which sorts the 64 node pairs of every element, is its reference twin.
"""

from __future__ import annotations

import numpy as np

from ...._jit import njit, prange


@njit
def _zeroed(Ke):  # pragma: no cover - compiled
    for r in range(Ke.shape[0]):
        for c in range(Ke.shape[1]):
            Ke[r, c] = 0.0
    return Ke


@njit
def _mirror(Ke):  # pragma: no cover - compiled
    """Below the diagonal = above it (the kernels fill the node blocks b >= a: the tangents have major symmetry)."""
    for r in range(Ke.shape[0]):
        for c in range(r):
            Ke[r, c] = Ke[c, r]


@njit(parallel=True)
def _element_stiffness_kernel(G, A, vol, out):
    k = out.shape[0]
    nq = G.shape[0]
    for e in prange(k):
        T = np.empty((8, 3, 3, 3))
        Ke = _zeroed(out[e])
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
            # K[a i, b k] += sum_l T[a, i, k, l] G[q, b, l], node blocks b >= a (mirrored below)
            for a in range(8):
                for i in range(3):
                    for b in range(a, 8):
                        g0 = G[q, b, 0]
                        g1 = G[q, b, 1]
                        g2 = G[q, b, 2]
                        for kk in range(3):
                            Ke[3 * a + i, 3 * b + kk] += (
                                T[a, i, kk, 0] * g0 + T[a, i, kk, 1] * g1 + T[a, i, kk, 2] * g2
                            )
        _mirror(Ke)  # A has major symmetry (A_ijkl = A_klij), so K is symmetric


def element_stiffness(G, A, vol):
    """Element stiffness matrices of a batch of trilinear voxels.

    Parameters
    ----------
    G : (Q, 8, 3) float
        World gradients of the corner weights at the Q quadrature points (1/m).
    A : (k * Q, 3, 3, 3, 3) float
        Tangent dP/dF at each sample, element-major (Pa), with major symmetry
        ``A_ijkl = A_klij`` (every tangent voxflex builds: second derivatives of
        an energy, their PSD projection, the F-bar terms): the kernel computes
        the node blocks on and above the diagonal and mirrors them, so K is
        exactly symmetric (2048 voxels x 8 points, five processes alternated with
        the full kernel, min of 80 calls each: median 5.5 against 7.0 ms).
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


@njit(parallel=True)
def _element_stiffness_i1j_kernel(G, F, J, s1, s3, k33, vol, out):  # pragma: no cover - compiled
    k = out.shape[0]
    nq = G.shape[0]
    for e in prange(k):
        h = np.empty((8, 3))
        C = np.empty((3, 3))
        Ke = _zeroed(out[e])
        for q in range(nq):
            row = e * nq + q
            v = vol[row]
            if v == 0.0:
                continue
            f = F[row]
            # C = cof(F) = J F^-T
            C[0, 0] = f[1, 1] * f[2, 2] - f[1, 2] * f[2, 1]
            C[0, 1] = f[1, 2] * f[2, 0] - f[1, 0] * f[2, 2]
            C[0, 2] = f[1, 0] * f[2, 1] - f[1, 1] * f[2, 0]
            C[1, 0] = f[0, 2] * f[2, 1] - f[0, 1] * f[2, 2]
            C[1, 1] = f[0, 0] * f[2, 2] - f[0, 2] * f[2, 0]
            C[1, 2] = f[0, 1] * f[2, 0] - f[0, 0] * f[2, 1]
            C[2, 0] = f[0, 1] * f[1, 2] - f[0, 2] * f[1, 1]
            C[2, 1] = f[0, 2] * f[1, 0] - f[0, 0] * f[1, 2]
            C[2, 2] = f[0, 0] * f[1, 1] - f[0, 1] * f[1, 0]
            for a in range(8):
                for i in range(3):
                    h[a, i] = C[i, 0] * G[q, a, 0] + C[i, 1] * G[q, a, 1] + C[i, 2] * G[q, a, 2]
            sj = s3[row] / J[row]
            al = 2.0 * s1[row] * v
            be = (sj + k33[row]) * v
            ga = -sj * v
            for a in range(8):
                for b in range(a, 8):
                    gg = al * (G[q, a, 0] * G[q, b, 0] + G[q, a, 1] * G[q, b, 1] + G[q, a, 2] * G[q, b, 2])
                    for i in range(3):
                        for kk in range(3):
                            val = be * h[a, i] * h[b, kk] + ga * h[b, i] * h[a, kk]
                            if i == kk:
                                val += gg
                            Ke[3 * a + i, 3 * b + kk] += val
        _mirror(Ke)


def element_stiffness_i1j(G, F, J, s1, s3, k33, vol):
    """Element stiffness matrices of a material whose tangent is ``2 s1 I + s3 d2J/dF2 + K33 dJ/dF dJ/dF``
    (a law ``W = a I1 + f(J)`` over the invariant strain: neo-Hooke), from F and those three coefficients.

    With ``h_a = cof(F) G_a`` (the corner's gradient pushed forward, times J) the node block is
    ``v [2 s1 (G_a . G_b) I + (s3 / J + K33) h_a h_b^T - (s3 / J) h_b h_a^T]``: about a third of
    :func:`element_stiffness`'s work, and the (n, 9, 9) tangent is never formed (the bunny at 2 mm,
    754k samples: that tangent is 0.5 GB).  Equal to :func:`element_stiffness` of the material's full
    tangent to round-off (``tests/deform/models/test_voxel_kernels.py``).

    Parameters
    ----------
    G : (Q, 8, 3) float
    F : (k * Q, 3, 3) float
    J, s1, s3, k33 : (k * Q,) float
        det F and the law's dW/dI1, dW/dJ, d2W/dJ2 at each sample (NaN where J <= 0: NaN blocks).
    vol : (k * Q,) float

    Returns
    -------
    (k, 24, 24) float, N/m.
    """
    G = np.ascontiguousarray(G, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.float64)
    args = [np.ascontiguousarray(a, dtype=np.float64) for a in (J, s1, s3, k33, vol)]
    k = len(args[-1]) // G.shape[0]
    out = np.empty((k, 24, 24))
    _element_stiffness_i1j_kernel(G, F, *args, out)
    return out


def element_stiffness_i1j_numpy(G, F, J, s1, s3, k33, vol):
    """Plain numpy twin of :func:`element_stiffness_i1j`: the full tangent, then :func:`element_stiffness_numpy`."""
    F = np.asarray(F, dtype=np.float64)
    C = np.linalg.det(F)[:, None, None] * np.linalg.inv(F).transpose(0, 2, 1)  # cof(F) (NaN-free for J != 0)
    sj = np.asarray(s3) / np.asarray(J)
    A = (2.0 * np.asarray(s1)[:, None, None, None, None] * np.einsum("ik,jl->ijkl", np.eye(3), np.eye(3))
         + (sj + np.asarray(k33))[:, None, None, None, None] * np.einsum("nij,nkl->nijkl", C, C)
         - sj[:, None, None, None, None] * np.einsum("nil,nkj->nijkl", C, C))
    return element_stiffness_numpy(G, A, np.asarray(vol, dtype=np.float64))


def element_stiffness_numpy(G, A, vol):
    """Plain numpy twin of :func:`element_stiffness` (reference for tests)."""
    nq = G.shape[0]
    k = len(vol) // nq
    A = A.reshape(k, nq, 3, 3, 3, 3) * vol.reshape(k, nq)[:, :, None, None, None, None]
    K = np.einsum("qaj,eqijkl,qbl->eaibk", G, A, G)
    return K.reshape(k, 24, 24)


@njit
def _scatter_one(Ke, scale, conn, blockmap, indptr_b, data, e):  # pragma: no cover - compiled
    """Element e's ``scale[e] Ke[e]`` (or the shared ``Ke[0]``) into the CSR data: rows of its own nodes only."""
    ke = 0 if Ke.shape[0] == 1 else e
    s = scale[e]
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
                    data[off + d] += s * Ke[ke, 3 * a + c, 3 * b + d]


@njit
def _scatter_kernel(Ke, scale, conn, blockmap, indptr_b, data):  # pragma: no cover - compiled
    for e in range(conn.shape[0]):
        _scatter_one(Ke, scale, conn, blockmap, indptr_b, data, e)


@njit(parallel=True)
def _scatter_colored(Ke, scale, conn, blockmap, indptr_b, data, order, starts):  # pragma: no cover - compiled
    """The elements colour by colour (``order[starts[c]:starts[c + 1]]``), each colour's on numba's threads:
    two voxels of one parity colour share no node, so no two threads write one entry."""
    for c in range(starts.shape[0] - 1):
        for t in prange(starts[c], starts[c + 1]):
            _scatter_one(Ke, scale, conn, blockmap, indptr_b, data, order[t])


SCATTER_PARALLEL_MIN = 4096
"""Elements from which :func:`scatter_blocks` runs colour by colour on numba's threads (given ``ijk``)."""


def scatter_blocks(Ke, conn, blockmap, indptr_b, data, scale=None, ijk=None):
    """Add element matrices ``scale[e] * Ke[e]`` into CSR ``data`` in place.

    Parameters
    ----------
    Ke : (k, 24, 24) or (1, 24, 24) float
        Element matrices, or one matrix shared by every element (constant
        stiffness on a regular grid).
    conn : (k, 8) int
        Element nodes.
    blockmap : (k, 64) int
        Index of node block ``(conn[a], conn[b])`` (entry ``8 a + b``) in the
        block pattern whose row pointer is ``indptr_b (n + 1,)``.
    indptr_b : (n + 1,) int64
    data : (nnz,) float, updated in place
    scale : (k,) float, optional
        Factor of each element (default 1; multiplying by 1.0 is exact).
    ijk : (k, 3) int, optional
        The elements' voxel indices: from :data:`SCATTER_PARALLEL_MIN` elements on, the elements are
        added by parity colour (8 colours, each on numba's threads; an entry's terms are then summed in
        colour order: the same bits for any thread count).
    """
    conn = np.ascontiguousarray(conn, dtype=np.int64)
    if scale is None:
        scale = np.ones(len(conn))
    args = (np.ascontiguousarray(Ke, dtype=np.float64), np.ascontiguousarray(scale, dtype=np.float64), conn,
            np.ascontiguousarray(blockmap), indptr_b, data)
    if ijk is not None and len(conn) >= SCATTER_PARALLEL_MIN:
        ijk = np.asarray(ijk)
        colour = (ijk[:, 0] & 1) * 4 + (ijk[:, 1] & 1) * 2 + (ijk[:, 2] & 1)
        order = np.argsort(colour, kind="stable").astype(np.int64)
        starts = np.searchsorted(colour[order], np.arange(9)).astype(np.int64)
        _scatter_colored(*args, order, starts)
    else:
        _scatter_kernel(*args)


def scatter_blocks_numpy(Ke, conn, blockmap, indptr_b, data, scale=None):
    """Plain numpy twin of :func:`scatter_blocks` (reference for tests)."""
    k = len(conn)
    Ke = np.broadcast_to(Ke, (k, 24, 24)) if len(Ke) == 1 else Ke
    if scale is not None:
        Ke = Ke * np.asarray(scale, dtype=float)[:, None, None]
    rows = np.repeat(np.asarray(conn), 8, axis=1)  # (k, 64) node of corner a
    start = indptr_b[rows]
    deg = indptr_b[rows + 1] - start
    base = 9 * start + 3 * (blockmap - start)  # (k, 64)
    c = np.arange(3)
    pos = base[:, :, None, None] + (3 * c)[None, None, :, None] * deg[:, :, None, None] + c[None, None, None, :]
    vals = Ke.reshape(k, 8, 3, 8, 3).transpose(0, 1, 3, 2, 4).reshape(k, 64, 3, 3)
    np.add.at(data, pos.ravel(), vals.ravel())


def block_csr_pattern(conn, n_nodes):
    """Sparsity of a 3-DOF-per-node matrix coupling the nodes of each element (general, by sorting).

    The reference twin of :func:`grid_block_pattern` (any connectivity; sorts
    ``64 m`` keys, so ~10x slower and ~3x the memory on voxel grids).

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


def _pair_offsets():
    """For entry ``8 a + b`` of an element's node pairs: the rank (0..26) of the offset
    ``corner_b - corner_a`` in {-1, 0, 1}^3 in lexicographic order."""
    from ....image.grid import CORNER_OFFSETS

    a = np.repeat(np.arange(8), 8)
    b = np.tile(np.arange(8), 8)
    d = CORNER_OFFSETS[b] - CORNER_OFFSETS[a] + 1
    return a, b, (d[:, 0] * 9 + d[:, 1] * 3 + d[:, 2]).astype(np.int64)


def grid_block_pattern(conn, n_nodes):
    """Same result as :func:`block_csr_pattern` for voxel-grid connectivity, without sorting.

    On a voxel grid node ``p`` can only couple with the 27 nodes ``p + o``,
    ``o`` in {-1, 0, 1}^3.  A table ``(n, 27)`` of the coupled node (or -1)
    is filled from the elements (corner pair ``(a, b)`` of an element is the
    offset ``corner_b - corner_a``); since nodes are numbered by sorted C-order
    corner index, offsets in lexicographic order give increasing node ids, so
    each row's columns come out sorted and the block index of ``(p, p + o)`` is
    the row start plus the rank of ``o`` among the row's present offsets.
    O(64 m + 27 n), two compiled loops, no sort (64x16x16 voxels: 7 ms; 35 ms vectorised in numpy).

    Parameters
    ----------
    conn : (m, 8) int
        Element nodes in the corner order of
        :data:`~voxflex.image.grid.CORNER_OFFSETS`, nodes numbered by
        sorted linear corner index (as :class:`~voxflex.image.grid.TrilinearGrid` builds them).
    n_nodes : int

    Returns
    -------
    indptr, indices, indptr_b, blockmap
        As :func:`block_csr_pattern` (identical arrays).
    """
    conn = np.ascontiguousarray(conn, dtype=np.int64)
    n = int(n_nodes)
    m = len(conn)
    pa, pb, po = _pair_offsets()
    node_dtype = np.int32 if n < np.iinfo(np.int32).max else np.int64
    col = np.full((n, 27), -1, dtype=node_dtype)
    _pattern_table(conn, pa, pb, po, col)
    deg = (col >= 0).sum(axis=1)
    indptr_b = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(deg, out=indptr_b[1:])
    nnzb = int(indptr_b[-1])
    index_dtype = np.int32 if 9 * nnzb < np.iinfo(np.int32).max else np.int64
    blockmap = np.empty((m, 64), dtype=index_dtype)
    indices = np.empty(9 * nnzb, dtype=index_dtype)
    indptr = np.empty(3 * n + 1, dtype=index_dtype)
    _pattern_fill(conn, col, indptr_b, pa, po, blockmap, indices, indptr)
    return indptr, indices, indptr_b, blockmap


@njit
def _pattern_table(conn, pa, pb, po, col):
    """col[p, o] = the node at offset o of node p (left -1 where none), from every element's 64 corner pairs."""
    for e in range(conn.shape[0]):
        for k in range(64):
            col[conn[e, pa[k]], po[k]] = conn[e, pb[k]]


@njit
def _pattern_fill(conn, col, indptr_b, pa, po, blockmap, indices, indptr):
    """The block map (m, 64) and the scalar CSR pattern of :func:`grid_block_pattern` from the offset table."""
    n = col.shape[0]
    slot = np.full((n, 27), -1, dtype=blockmap.dtype)  # block index of (p, p + o): row start + rank of o
    for p in range(n):
        r = indptr_b[p]
        for o in range(27):
            if col[p, o] >= 0:
                slot[p, o] = r
                r += 1
    for e in range(conn.shape[0]):
        for k in range(64):
            blockmap[e, k] = slot[conn[e, pa[k]], po[k]]
    # rows 3p, 3p+1, 3p+2 all hold columns 3 col + d of the row's blocks in order
    w = 0
    for p in range(n):
        for d in range(3):
            indptr[3 * p + d] = w
            for o in range(27):
                c = col[p, o]
                if c >= 0:
                    for dd in range(3):
                        indices[w] = 3 * c + dd
                        w += 1
    indptr[3 * n] = w


@njit
def _element_matvec_kernel(units, kind, scale, conn, x, y, centred):
    energy = 0.0
    v = np.empty(24)
    for e in range(conn.shape[0]):
        k = kind[e]
        if k < 0:
            continue
        s = scale[e]
        for c in range(3):
            mean = 0.0
            if centred:
                for a in range(8):
                    mean += x[3 * conn[e, a] + c]
                mean *= 0.125
            for a in range(8):
                v[3 * a + c] = x[3 * conn[e, a] + c] - mean
        ee = 0.0
        for row in range(24):
            acc = 0.0
            for col in range(24):
                acc += units[k, row, col] * v[col]
            ee += v[row] * acc
            y[3 * conn[e, row // 3] + row % 3] += s * acc
        energy += 0.5 * s * ee
    return energy


def element_matvec(units, kind, scale, conn, x, y=None):
    """``y += K x`` with ``K = sum_e scale[e] * units[kind[e]]`` over the voxels, never assembled.

    Parameters
    ----------
    units : (k, 24, 24) float
        The distinct element matrices (DOF ``3 * corner + component``).
    kind : (m,) int
        Which one each voxel has (-1: none).
    scale : (m,) float
        Each voxel's factor.
    conn : (m, 8) int
        Voxel nodes.
    x : (3 n,) float
    y : (3 n,) float, optional
        Added to in place (default zeros).

    Returns
    -------
    y : (3 n,) float
    """
    return element_matvec_energy(units, kind, scale, conn, x, y, centred=False)[0]


def element_matvec_energy(units, kind, scale, conn, x, y=None, *, centred: bool = True):
    """:func:`element_matvec` and the quadratic energy ``x^T K x / 2`` in the same pass over the voxels.

    With ``centred`` each voxel's values are taken relative to their mean over its 8 corners
    first (the units must annihilate translations, as elastic stiffnesses do): the products are
    then free of the translation's round-off, so a rigidly moved, unstrained body has energy and
    forces at round-off of its strain, not of its position (a global ``x . K x`` shows
    ``eps |K| |x|^2``).  Returns ``(y, energy)``.
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    if y is None:
        y = np.zeros_like(x)
    energy = _element_matvec_kernel(np.ascontiguousarray(units, dtype=np.float64), np.ascontiguousarray(kind),
                                    np.ascontiguousarray(scale, dtype=np.float64), np.ascontiguousarray(conn), x, y,
                                    bool(centred))
    return y, float(energy)


@njit
def _element_diagonal_kernel(diag, kind, scale, conn, y):  # pragma: no cover - compiled
    for e in range(conn.shape[0]):
        k = kind[e]
        if k < 0:
            continue
        s = scale[e]
        for r in range(24):
            y[3 * conn[e, r // 3] + r % 3] += s * diag[k, r]


def element_diagonal(units, kind, scale, conn, n_dofs: int) -> np.ndarray:
    """The diagonal (n_dofs,) of ``K = sum_e scale[e] * units[kind[e]]`` in one pass over the voxels (24 adds each;
    the numpy twin with per-block ``bincount`` took 0.65 s at 6.4 million DOF, a full-length array per block)."""
    diag = np.ascontiguousarray(np.diagonal(np.asarray(units, dtype=np.float64), axis1=1, axis2=2))
    y = np.zeros(int(n_dofs))
    _element_diagonal_kernel(diag, np.ascontiguousarray(kind), np.ascontiguousarray(scale, dtype=np.float64),
                             np.ascontiguousarray(conn), y)
    return y


def element_matvec_numpy(units, kind, scale, conn, x, y=None):
    """Plain numpy twin of :func:`element_matvec` (reference for tests)."""
    x = np.asarray(x, dtype=float)
    y = np.zeros_like(x) if y is None else y
    used = np.asarray(kind) >= 0
    conn = np.asarray(conn)[used]
    dof = ((3 * conn)[:, :, None] + np.arange(3)).reshape(len(conn), 24)
    fe = np.einsum("eij,ej->ei", np.asarray(units)[np.asarray(kind)[used]], x[dof]) * np.asarray(scale)[used][:, None]
    np.add.at(y, dof.ravel(), fe.ravel())
    return y
