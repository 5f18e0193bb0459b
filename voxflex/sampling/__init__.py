"""Quadrature samples (mid-point, Gauss-Legendre, elastons) and their volume moments.

``sample(image, sf, kind=..., count=...)`` turns a label image and a shape
function into :class:`Samples` (points, volumes, moments up to order 4,
regions, shape values); see :mod:`voxflex.sampling.sampler`.  The per-voxel
rules of the voxel model live in :mod:`voxflex.sampling.quadrature`.
Public names are imported lazily.
"""

from __future__ import annotations

from .._lazy import lazy

__getattr__, __dir__, __all__ = lazy(__name__, {
    "sample": "voxflex.sampling.sampler",
    "SamplingCountWarning": "voxflex.sampling.sampler",
    "Samples": "voxflex.sampling.samples",
    "KINDS": "voxflex.sampling.samples",
})
