"""Exact volume moments of unions of voxels about sample points, up to order 4.

A sample's region is a union of voxels (each a cube, or a box of the image's
spacing rotated by its direction), each with a uniform density equal to its
occupancy fraction (1 without occupancy).  Its moments about the sample point p
are the 35 integrals

    M_alpha(p) = int_region (x - p)^alpha dV,   |alpha| <= 4,

ordered by degree, then lexicographically in the axes: 1, x, y, z, xx, xy, xz,
yy, yz, zz, xxx, xxy, xxz, xyy, ... (:data:`EXPONENTS` lists them).

They are computed exactly (to round-off) by the binomial shift theorem: every
voxel is the same box, so its central moments ``C_beta`` are one table, and

    M_alpha(p) = sum_{beta <= alpha} binom(alpha, beta) C_beta S_{alpha - beta},
    S_gamma = sum_{voxels v} occupancy_v (c_v - p)^gamma,

with ``c_v`` the voxel centres; i.e. ``M = S @ T`` with a fixed 35 x 35 table T.

>>> import numpy as np
>>> m = box_moment_table([1.0, 2.0, 3.0], np.eye(3))
>>> float(m[0]), float(m[EXPONENT_INDEX[(2, 0, 0)]])    # V and int x^2 = V / 12
(6.0, 0.5)
"""

from __future__ import annotations

from itertools import combinations_with_replacement
from math import comb

import numpy as np

from ..errors import InputError
from .quadrature import gauss_legendre_cube

__all__ = ["EXPONENTS", "EXPONENT_INDEX", "N_MOMENTS", "monomials", "box_moment_table", "shift_table", "region_moments"]


def _exponents(order: int) -> np.ndarray:
    rows = []
    for degree in range(order + 1):
        for combo in combinations_with_replacement(range(3), degree):
            e = [0, 0, 0]
            for axis in combo:
                e[axis] += 1
            rows.append(e)
    return np.array(rows, dtype=np.int64)


EXPONENTS = _exponents(4)
"""(35, 3) int: the exponents alpha of the moments, by degree then lexicographic (1, x, y, z, xx, xy, ...)."""
EXPONENT_INDEX = {tuple(int(v) for v in e): i for i, e in enumerate(EXPONENTS)}
"""Position of each exponent tuple in :data:`EXPONENTS`."""
N_MOMENTS = len(EXPONENTS)


def monomials(d) -> np.ndarray:
    """The 35 monomials ``d^alpha`` of offsets ``d`` (n, 3) -> (n, 35), in :data:`EXPONENTS` order."""
    d = np.asarray(d, dtype=np.float64)
    powers = np.ones((d.shape[0], 5, 3))
    for k in range(1, 5):
        powers[:, k] = powers[:, k - 1] * d
    return powers[:, EXPONENTS[:, 0], 0] * powers[:, EXPONENTS[:, 1], 1] * powers[:, EXPONENTS[:, 2], 2]


def box_moment_table(size, direction) -> np.ndarray:
    """Central moments (35,) of a box of edge lengths ``size`` (3,) [m] whose axes are the columns of ``direction``.

    Exact: the 3-point tensor Gauss-Legendre rule integrates every monomial of
    degree <= 5 per axis exactly, and the monomials here have degree <= 4.
    Units: entry alpha is in m^(3 + |alpha|).
    """
    size = np.asarray(size, dtype=np.float64)
    direction = np.asarray(direction, dtype=np.float64)
    pts, wts = gauss_legendre_cube(3)
    offsets = ((pts - 0.5) * size) @ direction.T
    return float(np.prod(size)) * (wts @ monomials(offsets))


def shift_table(central) -> np.ndarray:
    """The (35, 35) table T with ``M = S @ T`` (see the module docstring) for a cell of central moments ``central`` (35,)."""
    central = np.asarray(central, dtype=np.float64)
    T = np.zeros((N_MOMENTS, N_MOMENTS))
    for a, alpha in enumerate(EXPONENTS):
        for g, gamma in enumerate(EXPONENTS):
            beta = alpha - gamma
            if np.all(beta >= 0):
                coef = comb(int(alpha[0]), int(beta[0])) * comb(int(alpha[1]), int(beta[1])) * comb(int(alpha[2]), int(beta[2]))
                T[g, a] = coef * central[EXPONENT_INDEX[tuple(int(v) for v in beta)]]
    return T


def region_moments(centres, weights, region, points, cell_size, direction) -> np.ndarray:
    """Exact moments (m, 35) of regions of identical cells about their sample points.

    Parameters
    ----------
    centres : (N, 3) float
        World centres of the cells (voxels) [m].
    weights : (N,) float
        Density of each cell (occupancy fraction, or 1).
    region : (N,) int
        Region (sample) index of each cell in ``[0, m)``; every sample needs at least one cell.
    points : (m, 3) float
        Sample points p [m].
    cell_size : (3,) float
        Edge lengths of each cell along its axes [m] (the image spacing).
    direction : (3, 3) float
        Columns: world directions of the cell axes.

    Returns
    -------
    (m, 35) float
        ``moments[:, 0]`` is the volume [m^3]; entry alpha is in m^(3 + |alpha|).
    """
    centres = np.asarray(centres, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64)
    region = np.asarray(region, dtype=np.int64)
    weights = np.asarray(weights, dtype=np.float64)
    m = len(points)
    if centres.ndim != 2 or centres.shape[1] != 3 or points.ndim != 2 or points.shape[1] != 3:
        raise InputError("centres and points must be (n, 3) arrays")
    if region.shape != (len(centres),) or weights.shape != (len(centres),):
        raise InputError("region and weights need one entry per cell")
    T = shift_table(box_moment_table(cell_size, direction))
    return _region_moments_impl(centres, weights, region, points, T, m)


def _region_moments_impl(centres, weights, region, points, T, m, chunk=1 << 18):
    S = np.zeros((m, N_MOMENTS))
    for start in range(0, len(centres), chunk):
        sl = slice(start, start + chunk)
        r = region[sl]
        mono = monomials(centres[sl] - points[r]) * weights[sl, None]
        for a in range(N_MOMENTS):
            S[:, a] += np.bincount(r, weights=mono[:, a], minlength=m)
    return S @ T
