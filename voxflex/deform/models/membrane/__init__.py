"""The membrane model: the vertices of a triangle mesh, a plane-stress membrane and a follower pressure."""

from ...._lazy import lazy

__getattr__, __dir__, __all__ = lazy(__name__, {
    "MembraneModel": "voxflex.deform.models.membrane.model",
})
