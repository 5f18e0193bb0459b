"""Per-voxel quadrature samples (2x2x2 Gauss or the voxel centre) over every material voxel."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..voronoi.shape_functions import ShapeValues
from .quadrature import voxel_rule_points

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
    index, fraction, voxel = voxel_rule_points(image, rule, use_occupancy=use_occupancy)
    pts = image.index_to_world(index)
    vol = fraction * float(image.voxel_volume)
    ijk = np.argwhere(image.labels > 0)[voxel]
    label = image.labels[ijk[:, 0], ijk[:, 1], ijk[:, 2]].astype(np.int64)
    return VoxelSamples(rule, pts, vol, label, shape_function(pts))
