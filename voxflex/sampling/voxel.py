"""Per-voxel quadrature samples (2x2x2 Gauss or the voxel centre) over every material voxel."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..voronoi.shape_functions import ShapeValues
from .quadrature import unit_cube_rule

__all__ = ["VoxelSamples", "voxel_samples"]


@dataclass(frozen=True, eq=False)
class VoxelSamples:
    """Quadrature samples as the frame model reads them.

    Attributes
    ----------
    kind : str
        ``"gauss-legendre"``, ``"midpoint"`` or ``"elaston"``.
    points : (m, 3) float, world (m)
    volume : (m,) float (m^3)
    label : (m,) int, the material label of each sample
    values : ShapeValues of the samples
    region : (m,) int or None, the sampling region of each point (elastons' sub-rules: several points
        per region), else None
    """

    kind: str
    points: np.ndarray
    volume: np.ndarray
    label: np.ndarray
    values: ShapeValues
    region: np.ndarray | None = None


def voxel_samples(image, shape_function: Callable, *, rule: str = "gauss-legendre", use_occupancy: bool = True) -> VoxelSamples:
    """Samples of a per-voxel rule (2x2x2 Gauss or the voxel centre) over every material voxel.

    The most accurate (and most expensive) quadrature of a frame model; the
    sampling stage's reduced samplers (mid-point regions, elastons) produce
    the same attributes.
    """
    local, weights = unit_cube_rule(rule)
    ijk = np.argwhere(image.labels > 0)
    pts = image.index_to_world((ijk[:, None, :] + local[None, :, :]).reshape(-1, 3))
    vol = np.full(len(ijk), float(image.voxel_volume))
    if use_occupancy and image.occupancy is not None:
        vol = vol * np.asarray(image.occupancy, dtype=float)[ijk[:, 0], ijk[:, 1], ijk[:, 2]]
    vol = (vol[:, None] * weights[None, :]).reshape(-1)
    label = np.repeat(image.labels[ijk[:, 0], ijk[:, 1], ijk[:, 2]].astype(np.int64), len(weights))
    return VoxelSamples(rule, pts, vol, label, shape_function(pts))
