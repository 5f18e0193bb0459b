"""Build the full-resolution voxel model from a scene."""

from __future__ import annotations

from ....errors import InputError
from ....scene import Scene


def _voxel_model(scene: Scene, image, materials):
    from .model import VoxelModel

    quadrature = scene.elasticity.quadrature
    if quadrature == "elaston":
        raise InputError(
            'elaston quadrature needs regions of several voxels (frame models); with [nodes] kind = "voxel" '
            'use quadrature = "gauss-legendre" or "midpoint"'
        )
    sf = scene.nodes.shape_function
    if sf not in (None, "trilinear"):
        raise InputError(
            f'[nodes] shape_function = "{sf}" applies to frames; voxel nodes are trilinear '
            '(remove the key or use "trilinear")'
        )
    el = scene.elasticity
    return VoxelModel.from_image(image, materials, quadrature=quadrature, use_occupancy=bool(scene.object.occupancy),
                                 volumetric=el.volumetric, hourglass=el.hourglass)
