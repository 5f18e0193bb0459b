"""Quadrature rules on the unit cube [0, 1]^3.

Each rule is a pair ``(points (Q, 3), weights (Q,))`` with the weights summing
to one, so that the integral of f over a voxel of volume V is approximately
``V * sum(weights * f(points))`` (points in local voxel coordinates).

* ``"gauss-legendre"``: the 2x2x2 tensor Gauss-Legendre rule, points at
  ``1/2 +- 1/(2 sqrt 3)``, weights 1/8; exact for polynomials of degree <= 3
  in each variable (so the stiffness and the consistent mass of trilinear
  voxels are integrated exactly for linear elasticity).
* ``"midpoint"``: one point at the centre, weight 1; exact for degree <= 1.
  On trilinear voxels it under-integrates the stiffness: every voxel has
  hourglass (zero-energy) modes that are not rigid motions.

>>> points, weights = unit_cube_rule("gauss-legendre")
>>> points.shape, float(weights.sum())
((8, 3), 1.0)
"""

from __future__ import annotations

import numpy as np

from ..errors import check_choice

QUADRATURES = ("midpoint", "gauss-legendre", "elaston")
"""``[elasticity] quadrature`` values: one sample per region, 2x2x2 Gauss per voxel, elastons (regions with moments)."""

REGION_RULES = ("midpoint", "elaston")
"""The quadratures of a reduced model that integrate over regions (``[elasticity] samples`` of them)."""

RULES = ("gauss-legendre", "midpoint")
"""The rules on one voxel (the voxel model's quadratures)."""


def gauss_legendre_cube(order: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Tensor Gauss-Legendre rule with ``order`` points per axis on [0, 1]^3.

    Parameters
    ----------
    order : int >= 1
        Points per axis; the rule is exact for degree ``2 * order - 1`` per axis.

    Returns
    -------
    points : (order**3, 3) float
        Local coordinates in [0, 1]^3, C order (the last axis fastest).
    weights : (order**3,) float
        Summing to 1.
    """
    order = int(order)
    if order < 1:
        from ..errors import InputError

        raise InputError(f"Gauss-Legendre order must be >= 1, got {order}")
    x, w = np.polynomial.legendre.leggauss(order)
    x = 0.5 * (x + 1.0)
    w = 0.5 * w
    grid = np.stack(np.meshgrid(x, x, x, indexing="ij"), axis=-1).reshape(-1, 3)
    weights = (w[:, None, None] * w[None, :, None] * w[None, None, :]).reshape(-1)
    return grid, weights


def midpoint_cube() -> tuple[np.ndarray, np.ndarray]:
    """One-point rule at the cube centre: points (1, 3) = 0.5, weights (1,) = 1."""
    return np.full((1, 3), 0.5), np.ones(1)


def unit_cube_rule(name: str) -> tuple[np.ndarray, np.ndarray]:
    """The named rule on [0, 1]^3: ``"gauss-legendre"`` (2x2x2) or ``"midpoint"``.

    Returns
    -------
    points : (Q, 3) float, local coordinates
    weights : (Q,) float, summing to 1
    """
    check_choice("quadrature", name, RULES)
    if name == "gauss-legendre":
        return gauss_legendre_cube(2)
    return midpoint_cube()


def voxel_rule_points(image, rule: str = "gauss-legendre", *, use_occupancy: bool = True):
    """The points of a per-voxel rule over every material voxel of ``image``, in voxel units.

    Returns
    -------
    index : (K, 3) float, continuous index coordinates, voxel by voxel in
        ``np.argwhere(image.labels > 0)`` order, Q points each (the rule's order)
    fraction : (K,) float, each point's weight as a fraction of a voxel's volume
        (times the voxel's occupancy when ``use_occupancy`` and the image has one)
    voxel : (K,) int64, the point's voxel in that order

    The one producer of per-voxel Gauss-Legendre (and centre) points: the voxel
    samples of frame models, the elastons' candidates and the Gauss-Legendre
    sampler read it.  In voxel units the bits do not depend on the unit of length.
    """
    local, weights = unit_cube_rule(rule)
    ijk = np.argwhere(np.asarray(image.labels) > 0)
    index = (ijk[:, None, :] + local[None, :, :]).reshape(-1, 3)
    frac = np.ones(len(ijk))
    if use_occupancy and image.occupancy is not None:
        frac = np.asarray(image.occupancy, dtype=float)[ijk[:, 0], ijk[:, 1], ijk[:, 2]]
    fraction = (frac[:, None] * weights[None, :]).reshape(-1)
    return index, fraction, np.repeat(np.arange(len(ijk), dtype=np.int64), len(weights))
