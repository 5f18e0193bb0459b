"""Distances, geodesic voxel Voronoi partitions, node seeding and shape functions.

The stage takes a label image and returns shape functions:

* :func:`geodesic_distance`: multi-source distances inside the material
  (fast marching of second order, or Dijkstra), optionally compliance-weighted,
  and the Voronoi partition;
* :func:`place_frames`: farthest-point sampling and Lloyd relaxation of frames
  in that metric;
* :func:`shape_function`: natural-neighbour (Sibson, Laplace), distance-ratio
  and Shepard weights at any material point, as :class:`ShapeValues`.

The full-resolution voxel model uses trilinear shape functions
(:mod:`voxflex.voronoi.trilinear`); the family names are in
:mod:`voxflex.voronoi.families`.  Public names are imported lazily.
"""

from .._lazy import lazy

__getattr__, __dir__, __all__ = lazy(__name__, {
    "geodesic_distance": "voxflex.voronoi.geodesic",
    "place_frames": "voxflex.voronoi.placement",
    "shape_function": "voxflex.voronoi.weights",
    "ShapeFunction": "voxflex.voronoi.weights",
    "ShapeValues": "voxflex.voronoi.shape_functions",
    "shepard": "voxflex.voronoi.shape_functions",
})
