"""The rigid frame model: affine frames restricted to rotations (6 DOF per frame, static scenes)."""

from ...._lazy import lazy

__getattr__, __dir__, __all__ = lazy(__name__, {
    "RigidFrameModel": "voxflex.deform.models.rigid.model",
})
