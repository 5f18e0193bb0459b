"""Distances, geodesic voxel Voronoi partitions, node seeding and shape functions.

The reduced model (frame placement, natural-neighbour and Shepard weights) is
built here; the full-resolution voxel model uses trilinear shape functions
from :mod:`voxflex.deform`.  Nothing is implemented in this stage yet.
"""
