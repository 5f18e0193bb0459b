"""Trilinear shape functions: the voxel model's weights at the corners of occupied voxels.

The grid and the corner weight polynomials live with the image
(:mod:`voxflex.image.grid`); this module turns them into
:class:`~voxflex.voronoi.shape_functions.ShapeValues` at world points or at the
same local points of every voxel, the form every mapping reads.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..image.grid import _local_to_world_gradient, trilinear_weights
from .shape_functions import ShapeValues

__all__ = ["trilinear_values", "trilinear_quadrature_values"]


def trilinear_values(grid, points, *, hessian: bool = False):
    """Trilinear :class:`~voxflex.voronoi.shape_functions.ShapeValues` of ``grid`` (a TrilinearGrid) at world points (m, 3).

    ``index`` (m, 8) holds the nodes of the voxel holding each point,
    ``w`` their weights, ``dw`` (m, 8, 3) world gradients (1/m), ``ddw``
    (m, 8, 3, 3) second derivatives (1/m^2) when ``hessian``.

    Raises
    ------
    InputError
        When a point lies outside the material, naming the first such point.
    """
    points = np.atleast_2d(np.asarray(points, dtype=float))
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(f"points must be an (m, 3) array, got shape {points.shape}")
    element, local = grid.locate(points)
    if np.any(element < 0):
        bad = int(np.flatnonzero(element < 0)[0])
        raise InputError(
            f"point {points[bad].tolist()} (#{bad}) lies outside the material; move it into an occupied voxel"
        )
    return _values(grid, element, local, points, hessian=hessian)

def trilinear_quadrature_values(grid, local, *, hessian: bool = False):
    """ShapeValues at the same local points (Q, 3) of every element, element-major (m * Q rows).

    ``local`` are coordinates in the unit cube, e.g. the points of
    :func:`voxflex.sampling.quadrature.unit_cube_rule` (shape functions come
    before quadrature in the pipeline, so the rule is the caller's).
    """
    local = np.asarray(local, dtype=float).reshape(-1, 3)
    q = len(local)
    element = np.repeat(np.arange(grid.n_elements), q)
    loc = np.tile(local, (grid.n_elements, 1))
    rest = grid.index_to_world(grid.element_ijk[element] + loc)
    return _values(grid, element, loc, rest, hessian=hessian)

def _values(grid, element, local, rest, *, hessian=False):
    w, dw, ddw = trilinear_weights(local, hessian=hessian)
    dw = _local_to_world_gradient(dw, grid.spacing, grid.direction)
    if ddw is not None:
        scale = grid.direction / grid.spacing  # columns: world direction / spacing
        ddw = np.einsum("ka,mcab,lb->mckl", scale, ddw, scale)
    return ShapeValues(index=grid.element_nodes[element], w=w, dw=dw, ddw=ddw, rest=np.asarray(rest, dtype=float))
