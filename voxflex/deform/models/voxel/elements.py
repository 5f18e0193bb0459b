"""The voxel model's constant stiffness as element matrices (what multigrid's fast path reads)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class ElementMatrices:
    """A voxel stiffness as element matrices: ``K = sum_e scale[e] * units[kind[e]]`` over the grid's voxels.

    Attributes
    ----------
    units : (k, 24, 24) float
        The distinct element matrices (node-major DOFs ``3 * corner + component``).
    kind : (m,) int
        Which one each voxel has (-1: none).
    scale : (m,) float
        Each voxel's factor (its volume).
    """

    units: np.ndarray
    kind: np.ndarray
    scale: np.ndarray
