"""The frame model's quadratures over sampling regions: elastons' sub-rules and mid-point regions' tables.

* Elastons (:func:`elaston_samples`): each region of the sampler is integrated
  by a moment-fitted sub-rule (:func:`voxflex.sampling.subrule.moment_fitted_rule`):
  at most 10 of its voxels' Gauss points, with non-negative weights that
  reproduce the region's volume moments to degree 2.  The points are ordinary
  point samples (the shape functions evaluated there), so every material
  integrates with its own stress and tangent; the region's energy is exact for
  integrands quadratic over the region, with an error O(h^3) per unit volume
  for smooth ones (h the region's size; measured in ``tests/test_subrule.py``).
* Mid-point regions with the stabilisation (:func:`midpoint_tables`): the mean
  F over each region's Gauss points and the fluctuation moments
  (:mod:`voxflex.deform.models.frames.stabilise`).

Both read the Gauss points of the regions' voxels; values are those of the
Gauss-Legendre model of the same frames (the shape function at the points,
pruned to ``parents``), so the rules converge to it as regions shrink.
"""

from __future__ import annotations

import numpy as np

from ....errors import InputError
from ....sampling.subrule import SUBRULE_DEGREE, gauss_points, gauss_points_in_voxels, moment_fitted_rule
from ....sampling.voxel import VoxelSamples
from ....voronoi.shape_functions import keep_largest

__all__ = ["region_of_gauss_points", "elaston_samples", "midpoint_tables"]


def region_of_gauss_points(image, samples, voxel) -> np.ndarray:
    """Region (sample) index of each Gauss point from the samples' region image (or one region per
    voxel for per-voxel samples)."""
    region = getattr(samples, "region", None)
    ijk = np.argwhere(image.labels > 0)
    if region is not None and np.ndim(region) == 3:
        reg = np.asarray(region)[ijk[:, 0], ijk[:, 1], ijk[:, 2]]
    elif len(samples.volume) == len(ijk):  # one sample per voxel, in the same order
        reg = np.arange(len(ijk), dtype=np.int64)
    else:
        raise InputError("the samples carry no region image; build them with vf.sample or per voxel")
    if np.any(reg < 0):
        raise InputError("every material voxel must belong to a sample's region")
    return reg[voxel].astype(np.int64)


def point_values(sf, points, parents):
    """Values and gradients of ``sf`` at points: the sub-rules' and Gauss points read no Hessians, so the package's
    weight families skip them (230 MB for the bunny's 93k elaston points with 34 reproducing-kernel parents, 1 GB
    for its 754k Gauss points with natural neighbours; other callables are asked as they are)."""
    from ....voronoi.corner_weights import CornerWeights
    from ....voronoi.weights import ShapeFunction

    values = sf(points, hessians=False) if isinstance(sf, (CornerWeights, ShapeFunction)) else sf(points)
    return values if parents is None else keep_largest(values, int(parents))


def elaston_samples(image, sf, regions, *, parents=None, use_occupancy=True, degree=SUBRULE_DEGREE) -> VoxelSamples:
    """Point samples of the elastons' sub-rules over the sampler's ``regions``.

    Parameters
    ----------
    image : LabelImage
    sf : shape function (callable on points)
    regions : Samples
        The regions (their region image, volumes and labels).
    parents : int, optional
        Prune the points' shape values to this many parents (default: as ``sf`` gives them).
    use_occupancy : bool
    degree : int
        Moment degree of the sub-rules (:func:`voxflex.sampling.subrule.moment_fitted_rule`).

    Returns
    -------
    VoxelSamples of kind ``"elaston"``; ``region`` gives each point's region.
    """
    index, fraction, voxel = gauss_points_in_voxels(image, use_occupancy=use_occupancy)
    reg = region_of_gauss_points(image, regions, voxel)
    m = len(regions.volume)
    # fitted in voxel units (an affine map of the world: the same polynomial space, the same bits at any unit)
    sel, frac = moment_fitted_rule(index, fraction, reg, m, h=1.0, degree=degree)
    points, wts = image.index_to_world(index[sel]), frac * float(image.voxel_volume)
    label = np.asarray(regions.label, dtype=np.int64)[reg[sel]]
    return VoxelSamples("elaston", points, wts, label, point_values(sf, points, parents), region=reg[sel])


def midpoint_tables(image, sf, regions, frames, *, parents=None, use_occupancy=True, values=None):
    """:class:`~voxflex.deform.models.frames.stabilise.RegionTables` of mid-point ``regions``.

    ``values``: the shape values at the Gauss points when the caller has them (from a cache).
    Returns ``(tables, gauss)`` with ``gauss = (values, volume, region)`` of the Gauss points.
    """
    from .stabilise import region_tables

    points, volume, voxel = gauss_points(image, use_occupancy=use_occupancy)
    reg = region_of_gauss_points(image, regions, voxel)
    if values is None:
        values = point_values(sf, points, parents)
    return region_tables(values, volume, reg, len(regions.volume), frames), (values, volume, reg)
