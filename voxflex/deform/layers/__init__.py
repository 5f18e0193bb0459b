"""Layers: energies added on top of a model (contact with obstacles, cables, plasticity).

Each layer wraps a model and satisfies the same protocol; a scene builds only
the layers it needs.
"""

from ..._lazy import lazy

__getattr__, __dir__, __all__ = lazy(__name__, {
    "ContactModel": "voxflex.deform.layers.contact",
    "with_contact": "voxflex.deform.layers.contact",
    "obstacle": "voxflex.deform.layers.obstacles",
    "CableModel": "voxflex.deform.layers.cables",
    "with_cables": "voxflex.deform.layers.cables",
    "PlasticMaterial": "voxflex.deform.layers.plasticity",
    "PlasticModel": "voxflex.deform.layers.plasticity",
    "with_plasticity": "voxflex.deform.layers.plasticity",
    "ModelLayer": "voxflex.deform.layers.base",
})
