"""Build a rigid frame model from a scene (the affine frame model restricted to rotations)."""

from __future__ import annotations

from ..frames.build import build as build_frames


def build(scene, image, materials, *, cache: bool = True):
    """Rigid frames: the affine frame model of the scene (same placement, weights, samples and
    cache) restricted to rotations (:class:`~voxflex.deform.models.rigid.model.RigidFrameModel`).
    The scenes rigid frames refuse are refused when the scene is made (:func:`check_scene`).
    """
    from .model import RigidFrameModel

    inner = build_frames(scene, image, materials, cache=cache)
    densities = {int(label): float(scene.material_for(int(label)).density) for label in materials}
    return RigidFrameModel(inner, densities=densities)
