"""The shape-function families by name (a light vocabulary: scenes read it without loading the stage).

``[nodes] shape_function`` takes one of :data:`FRAME_SHAPE_FUNCTIONS` for frames
(the first is the default) and :data:`VOXEL_SHAPE_FUNCTIONS` for voxel nodes.
Each node kind (:mod:`voxflex.deform.models.kinds`) names the families it takes.
"""

from __future__ import annotations

__all__ = ["FRAME_SHAPE_FUNCTIONS", "VOXEL_SHAPE_FUNCTIONS", "SHAPE_FUNCTIONS", "ALIASES", "PLACEMENTS",
           "UNTRUNCATED", "FALLBACK"]

FRAME_SHAPE_FUNCTIONS = ("reproducing-kernel", "natural-neighbour", "sibson", "laplace", "distance-ratio", "shepard",
                         "eigenmode")
"""Weights of frames over the image (:func:`voxflex.voronoi.shape_function`); the first is the default.
Reproducing-kernel weights are linearly precise (:mod:`voxflex.voronoi.reproducing_kernel`: blended affine
frames bend without locking; they win every sweep in ``docs/tradeoff.md``), but on small or thin bodies, or
with frames nearly as dense as the voxels, their samples can leave spurious zero-energy modes: a scene that
names no weights then gets :data:`FALLBACK`.  Natural-neighbour (Sibson's) weights are interpolating and
reproduce a linear field only inside the frames' hull, so blended affine frames lock in bending; eigenmode
weights are global, from the lowest modes of the elastic energy (:mod:`voxflex.voronoi.eigenmode`)."""

FALLBACK = {"reproducing-kernel": "natural-neighbour"}
"""The weights a frame model gets instead of its default family when the scene names none and the default's
samples leave a spurious (near-)zero-energy mode on the body
(:func:`voxflex.deform.models.frames.build.build`)."""

UNTRUNCATED = ("reproducing-kernel", "eigenmode")
"""Frame families never cut to ``[nodes] parents`` (cutting breaks their linear precision and conformity): every
point keeps all the frames whose kernels reach it (34 of 40 on the bunny), so their default quadrature is the
elastons' (a stabilised mid-point region carries the union of its points' parents in its fluctuation term:
80 reproducing-kernel frames of the 32x8x8 cantilever solved in 15.8 s against 2.6 s with elastons)."""

VOXEL_SHAPE_FUNCTIONS = ("trilinear",)
"""Weights of the voxel model's corner nodes (:mod:`voxflex.voronoi.trilinear`)."""

SHAPE_FUNCTIONS = FRAME_SHAPE_FUNCTIONS + VOXEL_SHAPE_FUNCTIONS
"""Every family name."""

ALIASES = {"natural-neighbour": "sibson"}
"""Names that are another family's name (what the implementation computes)."""

PLACEMENTS = ("volume", "strain")
"""``[nodes] placement``: frames spread over the material's volume (farthest point and Lloyd, the default),
or in the metric of a first cheap solve's strain energy (:func:`voxflex.build.strain_indicator`)."""
