"""Moment-fitted sub-rules: a few points per region that integrate its polynomials exactly.

An elaston region (a union of voxels, :func:`voxflex.sampling.sample`) is
integrated by a handful of points chosen among its voxels' 2x2x2 Gauss points,
with non-negative weights that reproduce the region's volume moments up to a
degree ``p`` (:func:`moment_fitted_rule`):

    sum_k v_k (x_k - c)^alpha = int_region (x - c)^alpha dV,   |alpha| <= p,

(c the region's centroid).  The Gauss points with their own weights (a
voxel's volume / 8, occupancy included) already satisfy these equations (the
2x2x2 rule is exact to degree 3 per voxel), so a non-negative solution exists;
a non-negative least-squares fit (scipy's active-set NNLS) returns a basic one,
at most ``binom(p + 3, 3)`` points (10 at p = 2), and the weights on those
points are then re-solved to round-off.  Any energy density evaluated at the
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
    """The first ``nm`` monomials of :data:`~voxflex.sampling.volume_moments.EXPONENTS` at offsets d (K, 3).

    Column by column from contiguous powers (the same products in the same order as gathering the
    exponents of a (K, degree, 3) table, a quarter of its time: 0.35 s of the bunny's 754k Gauss points)."""
    e = EXPONENTS[:nm]
    top = int(e.max()) + 1
    dt = np.ascontiguousarray(np.asarray(d, dtype=np.float64).T)  # (3, K)
    powers = np.empty((top, 3, dt.shape[1]))
    powers[0] = 1.0
    for k in range(1, top):
        powers[k] = powers[k - 1] * dt
    out = np.empty((dt.shape[1], nm))
    for j, (a, b, c) in enumerate(e):
        out[:, j] = powers[a, 0] * powers[b, 1] * powers[c, 2]
    return out


def moment_fitted_rule(points, volume, region, n_regions: int, *, h: float, degree: int = SUBRULE_DEGREE):
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
    from scipy.optimize import nnls

    points = np.asarray(points, dtype=np.float64)
    volume = np.asarray(volume, dtype=np.float64)
    region = np.asarray(region, dtype=np.int64)
    if points.ndim != 2 or points.shape[1] != 3 or volume.shape != (len(points),) or region.shape != (len(points),):
        raise InputError("points must be (K, 3) with one volume and one region per point")
    if int(degree) not in (0, 1, 2, 3):
        raise InputError(f"sub-rule degree must be 0, 1, 2 or 3, got {degree}")
    if not (np.isfinite(h) and h > 0):
        raise InputError(f"h must be a positive length, got {h}")
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
    selected = [None] * n_regions
    weights = [None] * n_regions
    fits = {}  # support size -> [(region, ids, A, b, scale, keep, x)]: re-solved in batches below
    for r in range(n_regions):
        ids = order[bounds[r]:bounds[r + 1]]
        if len(ids) <= nm:  # no fewer points possible in general: keep the full rule
            selected[r], weights[r] = ids, volume[ids]
            continue
        A = mono[ids].T  # (nm, k)
        b = A @ (volume[ids] / h**3)  # weights in voxel volumes: NNLS's tolerances are absolute, the fit scale-free
        scale = 1.0 / np.maximum(np.abs(A).max(axis=1), 1e-300)
        x, _ = nnls(A * scale[:, None], b * scale, maxiter=50 * len(ids))
        keep = np.flatnonzero(x > 1e-12 * x.max())
        fits.setdefault(len(keep), []).append((r, ids, A, b, scale, keep, x))
    for group in fits.values():
        _resolve(group, selected, weights, volume, h)
    return np.concatenate(selected).astype(np.int64), np.concatenate(weights)


def _resolve(group, selected, weights, volume, h) -> None:
    """The weights on each NNLS support re-solved to round-off (NNLS stops at its own tolerance), for regions
    with supports of one size at once: least squares by batched QR of the row-scaled (nm, k) systems (full
    column rank: NNLS's supports are independent columns), kept where every weight is positive and the moments
    are met to 1e-10, else NNLS's own weights; a support that misses them beyond 1e-8 keeps the full rule."""
    Ak = np.stack([A[:, keep] for _, _, A, _, _, keep, _ in group])  # (G, nm, k)
    b = np.stack([g[3] for g in group])  # (G, nm)
    scale = np.stack([g[4] for g in group])
    k = Ak.shape[2]
    xs = np.full((len(group), k), np.nan)
    if k:
        Q, R = np.linalg.qr(Ak * scale[:, :, None])
        rhs = np.einsum("gik,gi->gk", Q, b * scale)
        d = np.abs(np.diagonal(R, axis1=1, axis2=2))
        ok = d.min(axis=1) > 1e-14 * d.max(axis=1)  # numerically independent columns (else NNLS's weights)
        if ok.any():
            xs[ok] = np.linalg.solve(R[ok], rhs[ok][..., None])[..., 0]
    xn = np.stack([x[keep] for *_, keep, x in group])  # NNLS's own weights on the supports
    tol = np.abs(b[:, :1])
    with np.errstate(invalid="ignore"):
        resolved = np.all(xs > 0, axis=1) & _close_rows(Ak, xs, b, 1e-10, 1e-13 * tol)
    x_keep = np.where(resolved[:, None], xs, xn)
    met = _close_rows(Ak, x_keep, b, 1e-8, 1e-11 * tol)
    for (r, ids, *_, keep, _), xk, ok in zip(group, x_keep, met):
        if ok:
            selected[r], weights[r] = ids[keep], xk * h**3
        else:  # pragma: no cover - cannot happen for Gauss candidates (the full rule is a solution); be safe
            selected[r], weights[r] = ids, volume[ids]


def _close_rows(A, x, b, rtol, atol) -> np.ndarray:
    """Per system g, whether ``A[g] @ x[g]`` is within ``atol[g] + rtol |b[g]|`` of ``b[g]`` (``np.allclose`` per
    system, without its overhead; False where x is not finite)."""
    Ax = np.matmul(A, x[..., None])[..., 0]
    return np.all(np.abs(Ax - b) <= atol + rtol * np.abs(b), axis=1)
