"""Moment-fitted sub-rules: a few points per region that integrate its polynomials exactly.

An elaston region (a union of voxels, :func:`voxflex.sampling.sample`) is
integrated by a handful of points chosen among its voxels' 2x2x2 Gauss points,
with non-negative weights that reproduce the region's volume moments up to a
degree ``p`` (:func:`moment_fitted_rule`):

    sum_k v_k (x_k - c)^alpha = int_region (x - c)^alpha dV,   |alpha| <= p,

(c the region's centroid).  The Gauss points with their own weights (a
voxel's volume / 8, occupancy included) already satisfy these equations (the
2x2x2 rule is exact to degree 3 per voxel), so a non-negative solution exists;
a non-negative least-squares fit (an active-set Lawson-Hanson NNLS, compiled,
every region in one call; its twin is a loop over scipy's) returns a basic one,
at most ``binom(p + 3, 3)`` points (10 at p = 2), and the weights on those
points are then re-solved to round-off.  Dual values that tie to 1e-9 go to the
first candidate, so a region gets the same rule at any unit.  Any energy density evaluated at the
points -- every material, with the ordinary point gradient ``J^T P`` and
Hessian ``J^T A J`` -- is integrated exactly when it is a polynomial of degree
<= p over the region, with an error of order ``h^(p+1)`` per unit volume for a
smooth integrand over a region of diameter h (measured:
``tests/test_subrule.py``, ``benchmarks/bench_elastons.py``).

The points lie inside the region (they are Gauss points of its voxels), so
the shape functions are evaluated where they are defined; values are not
extrapolated from a polynomial fit.

>>> import numpy as np
>>> from voxflex.image import LabelImage
>>> img = LabelImage(np.ones((3, 2, 2)))
>>> pts, vol, vox = gauss_points(img)
>>> sel, wts = moment_fitted_rule(pts, vol, np.zeros(len(pts), dtype=np.int64), 1, h=1.0)
>>> len(sel) <= 10, bool(np.isclose(wts.sum(), 12.0))
(True, True)
"""

from __future__ import annotations

from math import comb

import numpy as np

from .._jit import njit
from ..errors import InputError
from .quadrature import voxel_rule_points
from .volume_moments import EXPONENTS

__all__ = ["gauss_points", "gauss_points_in_voxels", "moment_fitted_rule", "SUBRULE_DEGREE"]

SUBRULE_DEGREE = 2
"""Degree of the polynomials the elastons' sub-rules integrate exactly (10 moments, at most 10 points)."""


def gauss_points(image, *, use_occupancy: bool = True):
    """The 2x2x2 Gauss-Legendre points of every material voxel.

    Parameters
    ----------
    image : LabelImage
    use_occupancy : bool
        Weight the volumes by the image's occupancy fractions.

    Returns
    -------
    points : (8N, 3) float, world positions [m], voxel by voxel in
        ``np.argwhere(image.labels > 0)`` order, 8 per voxel (the order of
        :func:`voxflex.sampling.voxel.voxel_samples` with ``rule="gauss-legendre"``)
    volume : (8N,) float, each point's weight [m^3] (its voxel's volume / 8)
    voxel : (8N,) int64, the voxel's position in that order
    """
    index, fraction, voxel = gauss_points_in_voxels(image, use_occupancy=use_occupancy)
    return image.index_to_world(index), fraction * float(image.voxel_volume), voxel


def gauss_points_in_voxels(image, *, use_occupancy: bool = True):
    """:func:`gauss_points` in voxel units: ``(index, fraction, voxel)`` with the points' continuous index
    coordinates and their weights as fractions of a voxel's volume
    (:func:`~voxflex.sampling.quadrature.voxel_rule_points`).  The same bits at any unit and spacing,
    so that a fit on them (:func:`moment_fitted_rule`) picks the same points for a scene in any unit."""
    return voxel_rule_points(image, "gauss-legendre", use_occupancy=use_occupancy)


def _n_moments(degree: int) -> int:
    return comb(degree + 3, 3)


def _monomials(d, nm) -> np.ndarray:
    """The first ``nm`` monomials of :data:`~voxflex.sampling.volume_moments.EXPONENTS` at offsets d (K, 3)."""
    e = EXPONENTS[:nm]
    top = int(e.max()) + 1
    d = np.ascontiguousarray(d, dtype=np.float64)
    powers = [[np.ones(len(d))] * 3]
    for k in range(1, top):
        powers.append([powers[-1][a] * d[:, a] for a in range(3)])
    out = np.empty((len(d), nm))
    for i, (a, b, c) in enumerate(e.tolist()):
        out[:, i] = powers[a][0] * powers[b][1] * powers[c][2]
    return out


@njit
def _close(a, b, rtol, atol) -> bool:
    """``np.allclose(a, b, rtol, atol)`` for finite vectors without its overhead (called twice per region:
    0.95 s of the bunny's 9,430 regions went to np.isclose's checks)."""
    return np.all(np.abs(a - b) <= atol + rtol * np.abs(b))


def moment_fitted_rule(points, volume, region, n_regions: int, *, h: float, degree: int = SUBRULE_DEGREE,
                       backend: str = "numba"):
    """Per region, a subset of ``points`` with non-negative weights reproducing its moments to ``degree``.

    Parameters
    ----------
    points : (K, 3) float
        Candidate points [m] (the regions' Gauss points).
    volume : (K,) float
        Their weights in the full rule [m^3]; the moments to reproduce are
        ``sum v (x - c)^alpha`` over each region's candidates (exact moments of
        the region for Gauss points of degree >= ``degree``).
    region : (K,) int
        Region of each candidate in ``[0, n_regions)``; every region needs one.
    n_regions : int
    h : float
        Length scale of the monomials [m] (the voxel edge): the fit is done on
        ``(x - c) / h``, so it is the same at any unit.
    degree : int in {0, 1, 2, 3}
        Monomial degree reproduced exactly (at most ``binom(degree + 3, 3)``
        points per region).
    backend : {"numba", "numpy"}
        The compiled fit of every region in one call (:func:`_fit_regions`, its own Lawson-Hanson NNLS), or
        its plain twin, a Python loop over scipy's NNLS (the bunny at 2 mm, 9,430 regions: 2.2 s, of a
        5.4 s natural-neighbour precompute at 40 frames).

    Returns
    -------
    selected : (k,) int64
        Indices into ``points``, grouped by region in increasing region order.
    weights : (k,) float
        The points' weights [m^3], > 0; per region they sum to its volume.

    Raises
    ------
    InputError
        Bad shapes, a region without candidates, a degree out of range, h <= 0.
    """
    points = np.asarray(points, dtype=np.float64)
    volume = np.asarray(volume, dtype=np.float64)
    region = np.asarray(region, dtype=np.int64)
    if points.ndim != 2 or points.shape[1] != 3 or volume.shape != (len(points),) or region.shape != (len(points),):
        raise InputError("points must be (K, 3) with one volume and one region per point")
    if int(degree) not in (0, 1, 2, 3):
        raise InputError(f"sub-rule degree must be 0, 1, 2 or 3, got {degree}")
    if not (np.isfinite(h) and h > 0):
        raise InputError(f"h must be a positive length, got {h}")
    if backend not in ("numba", "numpy"):
        raise InputError(f'backend must be "numba" or "numpy", got {backend!r}')
    n_regions = int(n_regions)
    if len(region) and (region.min() < 0 or region.max() >= n_regions):
        raise InputError("region indices must lie in [0, n_regions)")
    counts = np.bincount(region, minlength=n_regions)
    if np.any(counts == 0):
        raise InputError(f"region {int(np.flatnonzero(counts == 0)[0])} has no candidate point")
    nm = _n_moments(int(degree))
    order = np.argsort(region, kind="stable")
    bounds = np.concatenate([[0], np.cumsum(counts)])
    vol_r = np.bincount(region, weights=volume, minlength=n_regions)
    centre = np.stack([np.bincount(region, weights=volume * points[:, a], minlength=n_regions)
                       for a in range(3)], axis=1) / vol_r[:, None]
    mono = _monomials((points - centre[region]) / h, nm)
    if backend == "numba":
        keep = np.zeros(len(points), dtype=np.bool_)
        wts = np.zeros(len(points))
        _fit_regions(mono, volume, order, bounds, float(h), keep, wts)
        sel = order[keep[order]]  # grouped by region, in increasing region order
        return sel.astype(np.int64), wts[sel]
    from scipy.optimize import nnls

    selected, weights = [], []
    for r in range(n_regions):
        ids = order[bounds[r]:bounds[r + 1]]
        v = volume[ids]
        if len(ids) <= nm:  # no fewer points possible in general: keep the full rule
            selected.append(ids)
            weights.append(v)
            continue
        A = mono[ids].T  # (nm, k)
        b = A @ (v / h**3)  # weights in voxel volumes: NNLS's tolerances are absolute, the fit scale-free
        scale = 1.0 / np.maximum(np.abs(A).max(axis=1), 1e-300)
        x, _ = nnls(A * scale[:, None], b * scale, maxiter=50 * len(ids))
        keep = np.flatnonzero(x > 1e-12 * x.max())
        # the support's weights re-solved to round-off (NNLS stops at its own tolerance)
        Ak = A[:, keep]
        xs, *_ = np.linalg.lstsq(Ak * scale[:, None], b * scale, rcond=None)
        if np.all(xs > 0) and _close(Ak @ xs, b, 1e-10, 1e-13 * abs(b[0])):
            x_keep = xs
        else:
            x_keep = x[keep]
        if not _close(Ak @ x_keep, b, 1e-8, 1e-11 * abs(b[0])):  # pragma: no cover
            selected.append(ids)  # cannot happen for Gauss candidates (the full rule is a solution); be safe
            weights.append(v)
            continue
        selected.append(ids[keep])
        weights.append(x_keep * h**3)
    return np.concatenate(selected).astype(np.int64), np.concatenate(weights)


NNLS_TOL = 1e-12
"""Relative threshold of the compiled NNLS: a weight below it times the largest is dropped from the support, and
the optimality test stops when no dual variable exceeds it times |A| |b| (the twin's scipy NNLS uses its own)."""


@njit
def _least_squares(M, b):  # pragma: no cover - compiled
    """min |M z - b| for a small full-column-rank M (m, p), p <= m, by Householder QR (no LAPACK call: the
    NNLS below solves ~10 of these per region, where np.linalg.lstsq's setup cost dominated)."""
    m, p = M.shape
    R = M.copy()
    y = b.copy()
    for k in range(p):
        norm = 0.0
        for i in range(k, m):
            norm += R[i, k] * R[i, k]
        norm = np.sqrt(norm)
        if norm == 0.0:
            continue
        alpha = -norm if R[k, k] >= 0.0 else norm
        v = R[k:, k].copy()
        v[0] -= alpha
        vv = 0.0
        for i in range(m - k):
            vv += v[i] * v[i]
        if vv == 0.0:
            continue
        for j in range(k, p):
            d = 0.0
            for i in range(m - k):
                d += v[i] * R[k + i, j]
            f = 2.0 * d / vv
            for i in range(m - k):
                R[k + i, j] -= f * v[i]
        d = 0.0
        for i in range(m - k):
            d += v[i] * y[k + i]
        f = 2.0 * d / vv
        for i in range(m - k):
            y[k + i] -= f * v[i]
    z = np.zeros(p)
    for k in range(p - 1, -1, -1):
        acc = y[k]
        for j in range(k + 1, p):
            acc -= R[k, j] * z[j]
        z[k] = acc / R[k, k] if R[k, k] != 0.0 else 0.0
    return z


NNLS_TIE = 1e-9
"""Dual values within this fraction of the largest tie in the compiled NNLS (the first column wins)."""


@njit
def _nnls(A, b, maxiter):  # pragma: no cover - compiled
    """Lawson-Hanson active-set non-negative least squares: x >= 0 minimising |A x - b| (A small, dense).
    Returns (x, converged)."""
    m, n = A.shape
    x = np.zeros(n)
    passive = np.zeros(n, dtype=np.bool_)
    blocked = np.zeros(n, dtype=np.bool_)  # entered and left at once (a degenerate column): not again until x moves
    scale = 0.0
    for j in range(n):
        c = 0.0
        for i in range(m):
            c += abs(A[i, j])
        scale = max(scale, c)
    bn = 0.0
    for i in range(m):
        bn += abs(b[i])
    tol = NNLS_TOL * max(scale, 1e-300) * max(bn, 1e-300)
    its = 0
    while True:
        w = A.T @ (b - A @ x)
        best = tol
        for i in range(n):
            if not passive[i] and not blocked[i] and w[i] > best:
                best = w[i]
        if best <= tol:
            return x, True
        j = -1  # the first column within NNLS_TIE of the largest: symmetric candidates tie, and round-off must
        for i in range(n):  # not pick among them (the same region at another unit would get another rule)
            if not passive[i] and not blocked[i] and w[i] >= best * (1.0 - NNLS_TIE):
                j = i
                break
        passive[j] = True
        first = True
        while True:
            its += 1
            if its > maxiter:
                return x, False
            idx = np.flatnonzero(passive)
            if len(idx) > m:  # more columns than equations: no basic solution grows this way
                passive[j] = False
                blocked[j] = True
                break
            z = _least_squares(A[:, idx], b)
            if np.all(z > 0.0):
                x[:] = 0.0
                x[idx] = z
                blocked[:] = False
                break
            if first and z[np.searchsorted(idx, j)] <= 0.0:
                passive[j] = False  # the entering column cannot take a positive weight here
                blocked[j] = True
                break
            first = False
            alpha = np.inf
            for t in range(len(idx)):
                if z[t] <= 0.0:
                    xi = x[idx[t]]
                    alpha = min(alpha, xi / (xi - z[t]))
            top = 0.0
            for t in range(len(idx)):
                i = idx[t]
                x[i] += alpha * (z[t] - x[i])
                top = max(top, x[i])
            for t in range(len(idx)):  # the variables the step took to zero leave the support
                i = idx[t]
                if x[i] <= NNLS_TOL * top:
                    x[i] = 0.0
                    passive[i] = False
            blocked[:] = False


@njit
def _fit_regions(mono, volume, order, bounds, h, keep, weights):  # pragma: no cover - compiled
    """Every region's sub-rule (the loop of :func:`moment_fitted_rule`'s numpy twin): ``keep`` and ``weights``
    (K,) are set at the chosen points, by non-negative least squares on the scaled moment equations, the
    support's weights re-solved to round-off; the full rule where the fit does not reproduce the moments."""
    nm = mono.shape[1]
    h3 = h**3
    for r in range(len(bounds) - 1):
        ids = order[bounds[r]:bounds[r + 1]]
        k = len(ids)
        if k <= nm:
            for t in range(k):
                keep[ids[t]] = True
                weights[ids[t]] = volume[ids[t]]
            continue
        A = np.empty((nm, k))
        for t in range(k):
            for i in range(nm):
                A[i, t] = mono[ids[t], i]
        b = np.zeros(nm)
        for t in range(k):
            v = volume[ids[t]] / h3
            for i in range(nm):
                b[i] += A[i, t] * v
        sc = np.empty(nm)
        for i in range(nm):
            mx = 0.0
            for t in range(k):
                mx = max(mx, abs(A[i, t]))
            sc[i] = 1.0 / max(mx, 1e-300)
        As = A * sc.reshape(-1, 1)
        bs = b * sc
        x, ok = _nnls(As, bs, 50 * k)
        xmax = x.max()
        sel = np.flatnonzero(x > 1e-12 * xmax) if ok and xmax > 0 else np.arange(0)
        good = False
        xk = np.zeros(len(sel))
        if len(sel):
            xs = _least_squares(As[:, sel], bs)
            Ak = A[:, sel]
            if np.all(xs > 0) and _close(Ak @ xs, b, 1e-10, 1e-13 * abs(b[0])):
                xk = xs
            else:
                xk = x[sel]
            good = _close(Ak @ xk, b, 1e-8, 1e-11 * abs(b[0]))
        if not good:  # cannot happen for Gauss candidates (the full rule is a solution); be safe
            for t in range(k):
                keep[ids[t]] = True
                weights[ids[t]] = volume[ids[t]]
            continue
        for t in range(len(sel)):
            keep[ids[sel[t]]] = True
            weights[ids[sel[t]]] = xk[t] * h3
