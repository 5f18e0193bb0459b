"""The natural-neighbour weights' per-node quadratic fits (:func:`fit_nodes`): each node's own weights interpolated
and its neighbours' fitted by least squares, as quadratics in ``(x - x_node) / h``; compiled (:func:`_fit_kernel`)
with its numpy twin (:func:`_fit_nodes`).  Used by :func:`voxflex.voronoi.weights.shape_function`, which
evaluates the quadratics (:func:`_basis`) at points.
"""

from __future__ import annotations

import numpy as np

from .._jit import njit

_RIDGE = 1e-8
"""The ridge on the non-constant terms of every node's normal equations (a flat layer of nodes cannot see some
monomials)."""


def _basis(x):
    """Quadratic monomials (m, 9) at local coords x (m, 3), their gradients (m, 9, 3) and Hessians (9, 3, 3)."""
    X, Y, Z = x[:, 0], x[:, 1], x[:, 2]
    one, zero = np.ones_like(X), np.zeros_like(X)
    phi = np.stack([X, Y, Z, X * X, X * Y, X * Z, Y * Y, Y * Z, Z * Z], axis=1)
    dphi = np.stack([
        np.stack([one, zero, zero], 1), np.stack([zero, one, zero], 1), np.stack([zero, zero, one], 1),
        np.stack([2 * X, zero, zero], 1), np.stack([Y, X, zero], 1), np.stack([Z, zero, X], 1),
        np.stack([zero, 2 * Y, zero], 1), np.stack([zero, Z, Y], 1), np.stack([zero, zero, 2 * Z], 1),
    ], axis=1)
    H = np.zeros((9, 3, 3))
    H[3, 0, 0] = 2
    H[4, 0, 1] = H[4, 1, 0] = 1
    H[5, 0, 2] = H[5, 2, 0] = 1
    H[6, 1, 1] = 2
    H[7, 1, 2] = H[7, 2, 1] = 1
    H[8, 2, 2] = 2
    return phi, dphi, H


def _adjacency(pa, pb, Q):
    """CSR (indptr, indices) of the symmetric node adjacency from the pairs (pa < pb), neighbours in
    increasing order."""
    a = np.concatenate([pa, pb]).astype(np.int64)
    b = np.concatenate([pb, pa]).astype(np.int64)
    order = np.lexsort((b, a))
    indptr = np.zeros(Q + 1, dtype=np.int64)
    np.add.at(indptr, a + 1, 1)
    return np.cumsum(indptr), b[order]


def fit_nodes(node_pos, nf, nw, pa, pb, h, n, *, backend="numba"):
    """Per node, the frames it or its sample nodes see (Q, K) (-1 padded, increasing) and the
    coefficients (Q, K, 10) (value, then the 9 monomials of :func:`_basis`) of the quadratics that
    interpolate the node's own weights and fit its neighbours' by least squares (a ridge of 1e-8 on the
    non-constant terms).  The samples are the node and its neighbours, and the neighbours' neighbours
    when that gives fewer than 10.

    ``backend="numba"``: :func:`_fit_kernel`, one pass to size, one to fit (the bunny at 2 mm with
    40 frames, 1515 nodes: 0.6-1.5 s in the Python loop); ``"numpy"``: :func:`_fit_nodes`, the twin.
    """
    Q = len(node_pos)
    indptr, indices = _adjacency(pa, pb, Q)
    if backend == "numpy":
        nbr = [indices[indptr[q]:indptr[q + 1]].tolist() for q in range(Q)]
        coefs, frs = _fit_nodes(node_pos, nf, nw, nbr, h, n)
        K = max(len(f) for f in frs)
        node_frames = np.full((Q, K), -1, dtype=np.int64)
        node_coef = np.zeros((Q, K, 10))
        for q in range(Q):
            node_frames[q, :len(frs[q])] = frs[q]
            node_coef[q, :len(frs[q])] = coefs[q]
        return node_frames, node_coef
    args = (np.ascontiguousarray(node_pos, dtype=np.float64), np.ascontiguousarray(nf, dtype=np.int64),
            np.ascontiguousarray(nw, dtype=np.float64), indptr, indices, float(h), int(n))
    sizes = np.zeros(Q, dtype=np.int64)
    _fit_kernel(*args, sizes, np.zeros((Q, 1), np.int64), np.zeros((Q, 1, 10)), False)
    K = max(1, int(sizes.max()))
    node_frames = np.full((Q, K), -1, dtype=np.int64)
    node_coef = np.zeros((Q, K, 10))
    _fit_kernel(*args, sizes, node_frames, node_coef, True)
    return node_frames, node_coef


@njit
def _fit_kernel(node_pos, nf, nw, indptr, indices, h, n, sizes, node_frames, node_coef, fill):  # pragma: no cover
    """Compiled :func:`_fit_nodes`: with ``fill`` False only the frame counts into ``sizes``."""
    Q = node_pos.shape[0]
    kmax = nf.shape[1]
    stamp = np.full(Q, -1, dtype=np.int64)
    fstamp = np.full(n, -1, dtype=np.int64)
    slot = np.zeros(n, dtype=np.int64)
    samples = np.empty(Q, dtype=np.int64)
    frames = np.empty(n, dtype=np.int64)
    A = np.empty((9, 9))
    for q in range(Q):
        # samples: q, its neighbours (in order), or q and the sorted union of two rings
        ns = 1
        samples[0] = q
        for e in range(indptr[q], indptr[q + 1]):
            samples[ns] = indices[e]
            ns += 1
        if ns < 10:
            stamp[q] = q
            cnt = 0
            for e in range(indptr[q], indptr[q + 1]):
                r = indices[e]
                if stamp[r] != q:
                    stamp[r] = q
                    samples[1 + cnt] = r
                    cnt += 1
                for e2 in range(indptr[r], indptr[r + 1]):
                    t = indices[e2]
                    if stamp[t] != q:
                        stamp[t] = q
                        samples[1 + cnt] = t
                        cnt += 1
            ns = 1 + cnt
            samples[1:ns] = np.sort(samples[1:ns])
        # the frames seen, increasing
        k = 0
        for i in range(ns):
            smp = samples[i]
            for j in range(kmax):
                f = nf[smp, j]
                if f >= 0 and fstamp[f] != q:
                    fstamp[f] = q
                    frames[k] = f
                    k += 1
        if not fill:
            sizes[q] = k
            continue
        fr = np.sort(frames[:k])
        for j in range(k):
            slot[fr[j]] = j
            node_frames[q, j] = fr[j]
        Y = np.zeros((ns, k))
        for i in range(ns):
            smp = samples[i]
            for j in range(kmax):
                f = nf[smp, j]
                if f >= 0:
                    Y[i, slot[f]] = nw[smp, j]
        m = ns - 1
        phi = np.empty((m, 9))
        for i in range(m):
            x = (node_pos[samples[i + 1], 0] - node_pos[q, 0]) / h
            y = (node_pos[samples[i + 1], 1] - node_pos[q, 1]) / h
            z = (node_pos[samples[i + 1], 2] - node_pos[q, 2]) / h
            phi[i, 0] = x
            phi[i, 1] = y
            phi[i, 2] = z
            phi[i, 3] = x * x
            phi[i, 4] = x * y
            phi[i, 5] = x * z
            phi[i, 6] = y * y
            phi[i, 7] = y * z
            phi[i, 8] = z * z
        for a in range(9):
            for b in range(9):
                acc = 0.0
                for i in range(m):
                    acc += phi[i, a] * phi[i, b]
                A[a, b] = acc + (_RIDGE if a == b else 0.0)
        rhs = np.zeros((9, k))
        for i in range(m):
            for j in range(k):
                d = Y[i + 1, j] - Y[0, j]
                if d != 0.0:
                    for a in range(9):
                        rhs[a, j] += phi[i, a] * d
        beta = np.linalg.solve(A, rhs)
        for j in range(k):
            node_coef[q, j, 0] = Y[0, j]
            for a in range(9):
                node_coef[q, j, 1 + a] = beta[a, j]


def _fit_nodes(node_pos, nf, nw, nbr, h, n):
    """Per node: frames seen and coefficients (k, 10) of the interpolating least-squares quadratics
    (the numpy twin of :func:`_fit_kernel`)."""
    Q = len(node_pos)
    coefs, frs = [], []
    dense = np.zeros(n)
    for q in range(Q):
        samples = [q] + nbr[q]
        if len(samples) < 10:
            ring2 = set(samples)
            for r in nbr[q]:
                ring2.update(nbr[r])
            samples = [q] + sorted(ring2 - {q})
        fr = np.unique(nf[samples][nf[samples] >= 0])
        Y = np.zeros((len(samples), len(fr)))
        for i, smp in enumerate(samples):
            row = nf[smp] >= 0
            dense[nf[smp][row]] = nw[smp][row]
            Y[i] = dense[fr]
            dense[nf[smp][row]] = 0.0
        x = (node_pos[samples[1:]] - node_pos[q]) / h
        phi, _, _ = _basis(x)
        A = phi.T @ phi + _RIDGE * np.eye(9)
        beta = np.linalg.solve(A, phi.T @ (Y[1:] - Y[0]))  # (9, k)
        c = np.concatenate([Y[0][None], beta], axis=0).T  # (k, 10)
        coefs.append(c)
        frs.append(fr)
    return coefs, frs
