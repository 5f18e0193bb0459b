"""Batched kernels of the node -> child mappings, each with a plain numpy twin.

Every mapping of :mod:`voxflex.deform.chain.mappings` is linear in the per-node
"homogeneous frame" ``Â_a = [A_a | t_a]`` (3×4): points are frames with
``A = 0, t = x_a``, rigid frames are affine frames with ``A = R``.  For a child
c with parents a the output is

    y_c[i, α] = Σ_a Σ_l Â_a[i, l] B_a(c)[α, l]

where the coefficient matrix ``B`` (nα × 4) depends only on the shape
functions and the rest geometry (``r = X_c - X_a``):

* order 0 (points, nα = 1):   ``B = [w r, w]``;
* order 1 (F, nα = 3, α = j):  ``B[j, l] = w δ_jl + r_l ∂_j w``, ``B[j, 3] = ∂_j w``;
* order 2 (F and ∇F, nα = 12): the 3 rows of order 1, then for α = (j, k):
  ``B[l] = ∂_k w δ_jl + ∂_j w δ_kl + r_l ∂_jk w``, ``B[3] = ∂_jk w``.

So one forward kernel (``y = Σ Â Bᵀ``), one transpose kernel
(``gÂ_a += Σ_c f_c B``) and one CSR assembly kernel serve every node type and
every mapping.  Node parameters are passed as an ``(n, 12)`` array in the
affine state layout (A row-major, then t) when ``affine`` is true, or as an
``(n, 3)`` array of translations only (points) when it is false; gradients
come back in the same layout.  Output rows of a child are permuted by
``rowmap`` (internal row ``i * nα + α`` -> position in the child's block).

The forward and Jacobian kernels are serial over a range of children
``[c0, c1)`` and release the GIL; the caller splits large problems over
threads (numba's ``prange`` made the loop body 3-5 times slower per thread
here, measured with numba 0.68).  The transpose (a scatter) is serial.
"""

from __future__ import annotations

import numpy as np

from ..._jit import njit

N_ALPHA = (1, 3, 12)


@njit
def _coeffs(order, c, p, w, dw, ddw, r0, r1, r2, B):
    """Fill B (nα, 4) for child c, parent slot p (see the module notes)."""
    wv = w[c, p]
    if order == 0:
        B[0, 0] = wv * r0
        B[0, 1] = wv * r1
        B[0, 2] = wv * r2
        B[0, 3] = wv
        return
    for j in range(3):
        dj = dw[c, p, j]
        B[j, 0] = r0 * dj
        B[j, 1] = r1 * dj
        B[j, 2] = r2 * dj
        B[j, j] += wv
        B[j, 3] = dj
    if order == 2:
        for j in range(3):
            dj = dw[c, p, j]
            for k in range(3):
                dk = dw[c, p, k]
                h = ddw[c, p, j, k]
                q = 3 + 3 * j + k
                B[q, 0] = r0 * h
                B[q, 1] = r1 * h
                B[q, 2] = r2 * h
                B[q, j] += dk
                B[q, k] += dj
                B[q, 3] = h


@njit
def forward_kernel(c0, c1, index, w, dw, ddw, xc, xn, S, order, affine, rowmap, out):
    """out[c, rowmap[i*nα+α]] = Σ_a Σ_l Â_a[i,l] B_a(c)[α,l] for children c0 <= c < c1; out (m, 3 nα)."""
    P = index.shape[1]
    na = 1 if order == 0 else (3 if order == 1 else 12)
    toff = 9 if affine else 0
    B = np.empty((12, 4))
    acc = np.empty((3, 12))
    for c in range(c0, c1):
        for i in range(3):
            for al in range(na):
                acc[i, al] = 0.0
        for p in range(P):
            a = index[c, p]
            if a < 0:
                continue
            r0 = xc[c, 0] - xn[a, 0]
            r1 = xc[c, 1] - xn[a, 1]
            r2 = xc[c, 2] - xn[a, 2]
            _coeffs(order, c, p, w, dw, ddw, r0, r1, r2, B)
            for i in range(3):
                ti = S[a, toff + i]
                if affine:
                    a0 = S[a, 3 * i]
                    a1 = S[a, 3 * i + 1]
                    a2 = S[a, 3 * i + 2]
                    for al in range(na):
                        acc[i, al] += a0 * B[al, 0] + a1 * B[al, 1] + a2 * B[al, 2] + ti * B[al, 3]
                else:
                    for al in range(na):
                        acc[i, al] += ti * B[al, 3]
        for i in range(3):
            for al in range(na):
                out[c, rowmap[i * na + al]] = acc[i, al]


@njit
def transpose_kernel(index, w, dw, ddw, xc, xn, f, order, affine, rowmap, g):
    """g[a] += Σ_c f_c B_a(c) (in the node layout); f (m, 3 nα), g (n, 12 or 3), accumulated."""
    m, P = index.shape
    na = 1 if order == 0 else (3 if order == 1 else 12)
    toff = 9 if affine else 0
    B = np.empty((12, 4))
    fc = np.empty((3, 12))
    for c in range(m):
        for i in range(3):
            for al in range(na):
                fc[i, al] = f[c, rowmap[i * na + al]]
        for p in range(P):
            a = index[c, p]
            if a < 0:
                continue
            r0 = xc[c, 0] - xn[a, 0]
            r1 = xc[c, 1] - xn[a, 1]
            r2 = xc[c, 2] - xn[a, 2]
            _coeffs(order, c, p, w, dw, ddw, r0, r1, r2, B)
            for i in range(3):
                s0 = 0.0
                s1 = 0.0
                s2 = 0.0
                s3 = 0.0
                for al in range(na):
                    fv = fc[i, al]
                    s0 += fv * B[al, 0]
                    s1 += fv * B[al, 1]
                    s2 += fv * B[al, 2]
                    s3 += fv * B[al, 3]
                if affine:
                    g[a, 3 * i] += s0
                    g[a, 3 * i + 1] += s1
                    g[a, 3 * i + 2] += s2
                g[a, toff + i] += s3


@njit
def jacobian_kernel(c0, c1, index, w, dw, ddw, xc, xn, order, affine, rowmap, child_ptr, indices, data):
    """Fill the CSR Jacobian rows of children c0 <= c < c1; those of child c start at ``child_ptr[c]``.

    Each row of child c holds ``nv_c * ncol`` entries (nv_c valid parents,
    ncol = 4 for affine, 1 for points) with the parents in increasing index
    order, so the columns of every row come out sorted.
    """
    P = index.shape[1]
    na = 1 if order == 0 else (3 if order == 1 else 12)
    ncol = 4 if affine else 1
    width = 12 if affine else 3
    B = np.empty((12, 4))
    perm = np.empty(P, dtype=np.int64)
    for c in range(c0, c1):
        # parents sorted by node index (insertion sort on P entries)
        nv = 0
        for p in range(P):
            a = index[c, p]
            if a < 0:
                continue
            q = nv
            while q > 0 and index[c, perm[q - 1]] > a:
                perm[q] = perm[q - 1]
                q -= 1
            perm[q] = p
            nv += 1
        rowlen = nv * ncol
        base = child_ptr[c]
        for s in range(nv):
            p = perm[s]
            a = index[c, p]
            r0 = xc[c, 0] - xn[a, 0]
            r1 = xc[c, 1] - xn[a, 1]
            r2 = xc[c, 2] - xn[a, 2]
            _coeffs(order, c, p, w, dw, ddw, r0, r1, r2, B)
            for i in range(3):
                for al in range(na):
                    pos = base + rowmap[i * na + al] * rowlen + s * ncol
                    if affine:
                        col = a * width + 3 * i
                        indices[pos] = col
                        indices[pos + 1] = col + 1
                        indices[pos + 2] = col + 2
                        indices[pos + 3] = a * width + 9 + i
                        data[pos] = B[al, 0]
                        data[pos + 1] = B[al, 1]
                        data[pos + 2] = B[al, 2]
                        data[pos + 3] = B[al, 3]
                    else:
                        indices[pos] = a * width + i
                        data[pos] = B[al, 3]


# ---------------------------------------------------------------------------
# numpy twins (reference implementations used by the tests)
# ---------------------------------------------------------------------------


def coeffs_numpy(order, index, w, dw, ddw, xc, xn):
    """B for every (child, parent slot): (m, P, nα, 4); zero on padded slots."""
    valid = index >= 0
    r = np.where(valid[..., None], xc[:, None, :] - xn[np.maximum(index, 0)], 0.0)
    m, P = index.shape
    na = N_ALPHA[order]
    B = np.zeros((m, P, na, 4))
    if order == 0:
        B[..., 0, :3] = w[..., None] * r
        B[..., 0, 3] = w
        return B
    eye = np.eye(3)
    B[..., :3, :3] = dw[..., :, None] * r[..., None, :] + w[..., None, None] * eye
    B[..., :3, 3] = dw
    if order == 2:
        H = ddw  # (m, P, 3, 3)
        # [j, k, l]
        T = (
            dw[..., None, :, None] * eye[:, None, :]  # ∂_k w δ_jl
            + dw[..., :, None, None] * eye[None, :, :]  # ∂_j w δ_kl
            + H[..., :, :, None] * r[..., None, None, :]
        )
        B[..., 3:, :3] = T.reshape(m, P, 9, 3)
        B[..., 3:, 3] = H.reshape(m, P, 9)
    return B


def _hat_numpy(S, affine):
    n = S.shape[0]
    Ah = np.zeros((n, 3, 4))
    if affine:
        Ah[:, :, :3] = S[:, :9].reshape(n, 3, 3)
        Ah[:, :, 3] = S[:, 9:12]
    else:
        Ah[:, :, 3] = S[:, :3]
    return Ah


def forward_numpy(index, w, dw, ddw, xc, xn, S, order, affine, rowmap):
    B = coeffs_numpy(order, index, w, dw, ddw, xc, xn)
    Ah = _hat_numpy(S, affine)[np.maximum(index, 0)]  # (m, P, 3, 4); B is 0 on padding
    y = np.einsum("mpil,mpal->mia", Ah, B).reshape(len(index), -1)
    out = np.empty_like(y)
    out[:, rowmap] = y
    return out


def transpose_numpy(index, w, dw, ddw, xc, xn, f, order, affine, rowmap, n):
    B = coeffs_numpy(order, index, w, dw, ddw, xc, xn)
    na = N_ALPHA[order]
    fc = f[:, rowmap].reshape(len(index), 3, na)
    G = np.einsum("mia,mpal->mpil", fc, B)  # (m, P, 3, 4)
    valid = index >= 0
    gh = np.zeros((n, 3, 4))
    np.add.at(gh, index[valid], G[valid])
    if affine:
        return np.concatenate([gh[:, :, :3].reshape(n, 9), gh[:, :, 3]], axis=1)
    return gh[:, :, 3].copy()


def jacobian_numpy(index, w, dw, ddw, xc, xn, order, affine, rowmap, n):
    """COO triplets (rows, cols, vals) of the Jacobian; the caller assembles."""
    B = coeffs_numpy(order, index, w, dw, ddw, xc, xn)  # (m, P, na, 4)
    m, P = index.shape
    na = N_ALPHA[order]
    nr = 3 * na
    width = 12 if affine else 3
    c_idx, p_idx = np.nonzero(index >= 0)
    a = index[c_idx, p_idx]
    Bv = B[c_idx, p_idx]  # (k, na, 4)
    i = np.arange(3)
    al = np.arange(na)
    rows = c_idx[:, None, None] * nr + rowmap[(i[:, None] * na + al[None, :])][None]  # (k, 3, na)
    if affine:
        cols_A = a[:, None, None] * width + 3 * i[None, :, None] + np.arange(3)[None, None, :]  # (k, 3, 3) [i, l]
        cols_t = a[:, None] * width + 9 + i[None, :]  # (k, 3)
        cols = np.concatenate([cols_A, cols_t[..., None]], axis=2)  # (k, 3, 4) [i, l]
        R = np.broadcast_to(rows[..., None], rows.shape + (4,))
        C = np.broadcast_to(cols[:, :, None, :], rows.shape + (4,))
        V = np.broadcast_to(Bv[:, None, :, :], rows.shape + (4,))
    else:
        R = rows
        C = np.broadcast_to((a[:, None] * width + i[None, :])[:, :, None], rows.shape)
        V = np.broadcast_to(Bv[:, None, :, 3], rows.shape)
    return R.ravel(), C.ravel(), V.ravel()
