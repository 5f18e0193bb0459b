"""Infinitesimal rigid motions of a point set (the near-null space of elasticity)."""

from __future__ import annotations

import numpy as np


def rigid_body_modes(positions) -> np.ndarray:
    """Rigid-body modes (3n, 6) of points (n, 3): 3 translations, 3 rotations about the centroid.

    DOF order ``3 * node + component``; columns are not normalised.
    """
    X = np.asarray(positions, dtype=float)
    X = X - X.mean(axis=0)
    n = len(X)
    B = np.zeros((n, 3, 6))
    for c in range(3):
        B[:, c, c] = 1.0
    # rotation about axis e_k: e_k x X
    B[:, 1, 3], B[:, 2, 3] = -X[:, 2], X[:, 1]
    B[:, 0, 4], B[:, 2, 4] = X[:, 2], -X[:, 0]
    B[:, 0, 5], B[:, 1, 5] = -X[:, 1], X[:, 0]
    return B.reshape(3 * n, 6)
