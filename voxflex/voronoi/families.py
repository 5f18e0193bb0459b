"""The shape-function families by name (a light vocabulary: scenes read it without loading the stage).

``[nodes] shape_function`` takes one of :data:`FRAME_SHAPE_FUNCTIONS` for frames
(the first is the default) and :data:`VOXEL_SHAPE_FUNCTIONS` for voxel nodes.
Each node kind (:mod:`voxflex.deform.models.kinds`) names the families it takes.
"""

from __future__ import annotations

__all__ = ["FRAME_SHAPE_FUNCTIONS", "VOXEL_SHAPE_FUNCTIONS", "SHAPE_FUNCTIONS", "ALIASES"]

FRAME_SHAPE_FUNCTIONS = ("reproducing-kernel", "natural-neighbour", "sibson", "laplace", "distance-ratio", "shepard")
"""Weights of frames over the image (:func:`voxflex.voronoi.shape_function`).  Reproducing-kernel weights,
the default, are linearly precise (:mod:`voxflex.voronoi.reproducing_kernel`): blended affine frames then
bend without parasitic strain and converge to the voxel model from the stiff side; natural-neighbour
(Sibson's) weights are interpolating and lock in bending (see docs/frames.md)."""

VOXEL_SHAPE_FUNCTIONS = ("trilinear",)
"""Weights of the voxel model's corner nodes (:mod:`voxflex.voronoi.trilinear`)."""

SHAPE_FUNCTIONS = FRAME_SHAPE_FUNCTIONS + VOXEL_SHAPE_FUNCTIONS
"""Every family name."""

ALIASES = {"natural-neighbour": "sibson"}
"""Names that are another family's name (what the implementation computes)."""
