"""Compiled moment fits of the elastons' sub-rules (:func:`voxflex.sampling.subrule.moment_fitted_rule`).

Per region: the (nm, k) system of its candidates' monomials, a non-negative least-squares fit by the
active-set method of Lawson and Hanson (a basic solution: at most nm points with positive weights), then the
weights on that support re-solved to round-off.  Exact ties between entering candidates (symmetric Gauss
points) go to the lowest of a fixed, scattered rank (:func:`voxflex.sampling.subrule.tie_ranks`).  Every small
least-squares problem (nm <= 20 rows) is solved by Householder QR.  The regions are independent: one thread
per slice of regions, each writing only its own candidates' slots, so the answer does not depend on the thread
count.

The plain twin is :func:`voxflex.sampling.subrule.fit_region` (scipy's NNLS and numpy's least squares, one region),
which the tests compare with this kernel.
"""

from __future__ import annotations

import numpy as np

from .._jit import njit, prange

__all__ = ["fit_regions"]


@njit
def _largest_column(A, cols, ncol):  # pragma: no cover - compiled
    """The largest Euclidean norm of the columns ``A[:, cols[:ncol]]``."""
    top = 0.0
    for c in range(ncol):
        s = 0.0
        for i in range(A.shape[0]):
            s += A[i, cols[c]] * A[i, cols[c]]
        top = max(top, np.sqrt(s))
    return top


@njit
def _qr_solve(A, cols, ncol, b, z):  # pragma: no cover - compiled
    """Least squares ``min |A[:, cols[:ncol]] z - b|`` by Householder QR; z (ncol,) written.  False where a
    column is numerically dependent on the others (|R_jj| <= 1e-13 of the largest column norm)."""
    m = A.shape[0]
    R = np.empty((m, ncol))
    for c in range(ncol):
        for i in range(m):
            R[i, c] = A[i, cols[c]]
    y = b.copy()
    top = _largest_column(A, cols, ncol)  # the columns R starts as
    if ncol > m:
        return False
    for c in range(ncol):
        norm = 0.0
        for i in range(c, m):
            norm += R[i, c] * R[i, c]
        norm = np.sqrt(norm)
        if not norm > 1e-13 * top:
            return False
        alpha = -norm if R[c, c] >= 0.0 else norm
        v0 = R[c, c] - alpha
        # reflector v = (v0, R[c+1:, c]); H = I - 2 v v^T / (v^T v)
        vv = v0 * v0
        for i in range(c + 1, m):
            vv += R[i, c] * R[i, c]
        if vv > 0.0:
            for j in range(c + 1, ncol):
                s = v0 * R[c, j]
                for i in range(c + 1, m):
                    s += R[i, c] * R[i, j]
                f = 2.0 * s / vv
                R[c, j] -= f * v0
                for i in range(c + 1, m):
                    R[i, j] -= f * R[i, c]
            s = v0 * y[c]
            for i in range(c + 1, m):
                s += R[i, c] * y[i]
            f = 2.0 * s / vv
            y[c] -= f * v0
            for i in range(c + 1, m):
                y[i] -= f * R[i, c]
        R[c, c] = alpha
    for c in range(ncol - 1, -1, -1):
        s = y[c]
        for j in range(c + 1, ncol):
            s -= R[c, j] * z[j]
        z[c] = s / R[c, c]
    return True


@njit
def _nnls(A, b, maxiter, x, rank):  # pragma: no cover - compiled
    """Lawson-Hanson active set for ``min |A x - b|, x >= 0``; x (k,) written.  Returns the support size, or
    -1 when ``maxiter`` inner steps did not finish (the caller keeps the full rule)."""
    m, k = A.shape
    inset = np.zeros(k, dtype=np.bool_)
    cols = np.empty(k, dtype=np.int64)
    z = np.empty(k)
    w = np.empty(k)
    r = b.copy()
    x[:] = 0.0
    anorm = _largest_column(A, np.arange(k), k)
    bnorm = 0.0
    for i in range(m):
        bnorm += b[i] * b[i]
    tol = 1e-12 * anorm * np.sqrt(bnorm)
    skip = np.zeros(k, dtype=np.bool_)  # columns whose entry failed this round (round-off): not tried again
    nset = 0
    it = 0
    while True:
        for j in range(k):
            s = 0.0
            for i in range(m):
                s += A[i, j] * r[i]
            w[j] = s
        best = tol
        for j in range(k):
            if not inset[j] and not skip[j] and w[j] > best:
                best = w[j]
        jmax = -1
        if best > tol:  # of the candidates tied with the largest to 1e-9, the lowest rank: ties between
            for j in range(k):  # symmetric points broken by a fixed hash of the points, not by round-off (any unit)
                if not inset[j] and not skip[j] and w[j] >= best - 1e-9 * best:
                    if jmax < 0 or rank[j] < rank[jmax]:
                        jmax = j
        if jmax < 0 or nset >= m:
            break
        inset[jmax] = True
        cols[nset] = jmax
        nset += 1
        entered = True
        while True:
            it += 1
            if it > maxiter:
                return -1
            ok = _qr_solve(A, cols, nset, b, z)
            if entered and (not ok or z[nset - 1] <= 0.0):
                # the entering column cannot carry weight (dependent, or its step points out): leave it out
                nset -= 1
                inset[jmax] = False
                skip[jmax] = True
                if nset > 0:
                    _qr_solve(A, cols, nset, b, z)
                break
            entered = False
            if not ok:
                return -1
            positive = True
            for c in range(nset):
                if z[c] <= 0.0:
                    positive = False
            if positive:
                break
            alpha = np.inf
            climit = -1
            for c in range(nset):
                if z[c] <= 0.0:
                    xc = x[cols[c]]
                    t = xc / (xc - z[c])
                    if t < alpha * (1.0 - 1e-12):  # ties: the first in the set
                        alpha = t
                        climit = c
            for c in range(nset):
                x[cols[c]] += alpha * (z[c] - x[cols[c]])
            keep = 0
            for c in range(nset):
                j = cols[c]
                if c != climit and x[j] > 0.0:
                    cols[keep] = j
                    keep += 1
                else:  # the point that reached zero first (and any round-off below it) leaves the set
                    x[j] = 0.0
                    inset[j] = False
            nset = keep
            if nset == 0:
                break
        for c in range(nset):
            x[cols[c]] = z[c]
        for j in range(k):
            if not inset[j]:
                x[j] = 0.0
        for i in range(m):
            s = b[i]
            for j in range(k):
                s -= A[i, j] * x[j]
            r[i] = s
        if not entered:  # the set changed: columns refused before may enter now
            skip[:] = False
    return nset


@njit
def _meets(A, cols, ncol, x, b, rtol, atol):  # pragma: no cover - compiled
    """Whether ``A[:, cols] x`` is within ``atol + rtol |b|`` of b, row by row (False where x is not finite)."""
    for i in range(A.shape[0]):
        s = 0.0
        for c in range(ncol):
            s += A[i, cols[c]] * x[c]
        if not abs(s - b[i]) <= atol + rtol * abs(b[i]):
            return False
    return True


@njit
def _fit_one(A, v, rank, xout):  # pragma: no cover - compiled
    """One region: A (nm, k) its monomials, v (k,) its candidates' weights; xout (k,) the fitted weights (0 off
    the support).  Returns False where no fit met the moments (the caller keeps the full rule)."""
    nm, k = A.shape
    b = np.zeros(nm)
    for i in range(nm):
        s = 0.0
        for j in range(k):
            s += A[i, j] * v[j]
        b[i] = s
    scale = np.empty(nm)
    As = np.empty((nm, k))
    bs = np.empty(nm)
    for i in range(nm):
        top = 0.0
        for j in range(k):
            top = max(top, abs(A[i, j]))
        scale[i] = 1.0 / max(top, 1e-300)
        for j in range(k):
            As[i, j] = A[i, j] * scale[i]
        bs[i] = b[i] * scale[i]
    x = np.empty(k)
    ns = _nnls(As, bs, 50 * k, x, rank)
    if ns <= 0:
        return False
    xmax = 0.0
    for j in range(k):
        xmax = max(xmax, x[j])
    cols = np.empty(k, dtype=np.int64)
    n = 0
    for j in range(k):
        if x[j] > 1e-12 * xmax:
            cols[n] = j
            n += 1
    xn = np.empty(n)
    for c in range(n):
        xn[c] = x[cols[c]]
    xs = np.empty(n)
    tol = abs(b[0])
    use = xn
    if _qr_solve(As, cols, n, bs, xs):
        positive = True
        for c in range(n):
            if not xs[c] > 0.0:
                positive = False
        if positive and _meets(A, cols, n, xs, b, 1e-10, 1e-13 * tol):
            use = xs  # re-solved to round-off (NNLS stops at its own tolerance)
    if not _meets(A, cols, n, use, b, 1e-8, 1e-11 * tol):
        return False
    xout[:] = 0.0
    for c in range(n):
        xout[cols[c]] = use[c]
    return True


@njit(parallel=True)
def fit_regions(offsets, volume, order, bounds, exps, rank, chosen, weight):  # pragma: no cover - compiled
    """Fit every region's sub-rule (see the module).

    offsets (K, 3) the candidates from their region's centroid, in the fit's unit; volume (K,) their weights;
    order (K,) the candidates grouped by region (region r: ``order[bounds[r]:bounds[r + 1]]``); exps (nm, 3)
    the monomials' exponents; rank (K,) uint64, the order in which exact ties are broken
    (:func:`voxflex.sampling.subrule.tie_ranks`).  Written: chosen (K,) whether each candidate is in its region's
    rule, weight (K,) its weight there.  Regions with at most nm candidates, or no fit within tolerance, keep
    every candidate with its own weight.
    """
    nm = exps.shape[0]
    nreg = len(bounds) - 1
    for r in prange(nreg):
        a, e = bounds[r], bounds[r + 1]
        k = e - a
        done = False
        if k > nm:
            A = np.empty((nm, k))
            v = np.empty(k)
            rk = np.empty(k, dtype=np.uint64)
            for j in range(k):
                p = order[a + j]
                v[j] = volume[p]
                rk[j] = rank[p]
                d0 = offsets[p, 0]
                d1 = offsets[p, 1]
                d2 = offsets[p, 2]
                for i in range(nm):
                    A[i, j] = d0 ** exps[i, 0] * d1 ** exps[i, 1] * d2 ** exps[i, 2]
            x = np.empty(k)
            if _fit_one(A, v, rk, x):
                for j in range(k):
                    p = order[a + j]
                    chosen[p] = x[j] > 0.0
                    weight[p] = x[j]
                done = True
        if not done:
            for j in range(k):
                p = order[a + j]
                chosen[p] = True
                weight[p] = volume[p]
