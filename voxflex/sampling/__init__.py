"""Quadrature samples (mid-point, Gauss-Legendre, elastons) and their volume moments.

``sample(image, sf, kind=..., count=...)`` turns a label image and a shape
function into :class:`Samples` (points, volumes, moments up to order 4,
regions, shape values); see :mod:`voxflex.sampling.sampler`.  The per-voxel
rules of the voxel model live in :mod:`voxflex.sampling.quadrature`.
Public names are imported lazily.
"""

from __future__ import annotations

import importlib

_LAZY = {
    "sample": "voxflex.sampling.sampler",
    "SamplingCountWarning": "voxflex.sampling.sampler",
    "Samples": "voxflex.sampling.samples",
    "KINDS": "voxflex.sampling.samples",
}

__all__ = list(_LAZY)


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'voxflex.sampling' has no attribute '{name}'")


def __dir__():
    return sorted(__all__)
