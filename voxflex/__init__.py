"""voxflex: image-based voxel elastic simulation.

Objects (surface meshes, segmented scans, primitives) are rasterized into a
:class:`LabelImage`; nodes carry the degrees of freedom; shape functions spread
their motion over the material; quadrature samples integrate the energy of a
chain of mappings  nodes -> F -> strain -> material energy.

The public names are imported lazily so that ``import voxflex`` and the
command line start fast.

>>> import voxflex as vf
>>> image = vf.voxelize("sphere:1.0", voxel_size=0.25)   # doctest: +SKIP
"""

from __future__ import annotations

import importlib

from ._version import __version__
from .errors import ConvergenceError, InputError, VoxflexError

_LAZY = {
    "LabelImage": "voxflex.image",
    "voxelize": "voxflex.rasterize",
    "material": "voxflex.deform",
    "strain": "voxflex.deform",
    "Scene": "voxflex.scene",
    "simulate": "voxflex.simulation",
    "model": "voxflex.build",
    "tradeoff": "voxflex.sweep",
    "Result": "voxflex.result",
    "render": "voxflex.rendering",
    "sample": "voxflex.sampling",
    "Samples": "voxflex.sampling",
    "geodesic_distance": "voxflex.voronoi",
    "place_frames": "voxflex.voronoi",
    "shape_function": "voxflex.voronoi",
}

__all__ = ["__version__", "VoxflexError", "InputError", "ConvergenceError", *_LAZY]


def __getattr__(name: str):
    if name in _LAZY:
        module = importlib.import_module(_LAZY[name])
        value = getattr(module, name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'voxflex' has no attribute '{name}'")


def __dir__():
    return sorted(__all__)
