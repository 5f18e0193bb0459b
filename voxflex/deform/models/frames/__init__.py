"""The affine frame model: a few 12-DOF frames skinned over the image (the reduced model)."""

from ...._lazy import lazy

__getattr__, __dir__, __all__ = lazy(__name__, {
    "FrameModel": "voxflex.deform.models.frames.model",
})
