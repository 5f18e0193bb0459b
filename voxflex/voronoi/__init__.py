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
(:mod:`voxflex.image.grid`).
"""

from .geodesic import geodesic_distance
from .placement import place_frames
from .shape_function import ShapeFunction, shape_function
from .shape_functions import ShapeValues, shepard

__all__ = ["geodesic_distance", "place_frames", "shape_function", "ShapeFunction", "ShapeValues", "shepard"]
