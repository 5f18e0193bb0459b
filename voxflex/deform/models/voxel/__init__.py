"""The full-resolution voxel model: trilinear nodes at the corners of occupied voxels (the reference)."""

from ...._lazy import lazy

__getattr__, __dir__, __all__ = lazy(__name__, {
    "VoxelModel": "voxflex.deform.models.voxel.model",
})
