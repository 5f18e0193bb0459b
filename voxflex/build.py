"""Build what a scene asks for: its label image, its materials and its model.

:func:`model` looks the scene's ``[nodes] kind`` up in :data:`MODEL_BUILDERS`
and returns a model of the protocol in :mod:`voxflex.deform.model`; the
solvers, loads, results and renders only ever talk to that protocol.

Example
-------
>>> import voxflex as vf
>>> scene = vf.Scene.from_toml("examples/cantilever.toml")   # doctest: +SKIP
>>> m = vf.model(scene)                                      # doctest: +SKIP
>>> m.node_kind, m.rest.shape                                # doctest: +SKIP
('voxel', (..., 3))
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from .errors import InputError, check_choice
from .scene import Scene

__all__ = ["model", "build_image", "build_materials", "MODEL_BUILDERS"]


def build_image(scene: Scene):
    """The label image of ``scene.object`` (shape or mesh voxelized, image loaded)."""
    obj = scene.object
    if obj.image is not None:
        from .image import LabelImage

        return LabelImage.load(obj.image)
    from .rasterize.voxelize import voxelize

    occupancy = bool(obj.occupancy)
    if obj.mesh is not None:
        return voxelize(obj.mesh, obj.voxel_size, occupancy=occupancy, progress=False)
    from .rasterize.primitives import Box, Cylinder, Sphere

    origin = obj.origin if obj.origin is not None else (0.0, 0.0, 0.0)
    if obj.shape == "box":
        prim = Box(obj.size, origin=origin)
    elif obj.shape == "cylinder":
        prim = Cylinder(obj.size[0], obj.size[1], origin=origin, axis=obj.axis or "z")
    else:
        prim = Sphere(obj.size[0], origin=origin)
    return voxelize(prim, obj.voxel_size, occupancy=occupancy, progress=False)


def build_materials(scene: Scene, labels_present) -> dict:
    """{label: Material} for the labels present in the image (InputError on a label without material)."""
    from .deform.materials import material

    present = sorted(int(x) for x in labels_present)
    if not present:
        raise InputError("the image has no material (every label is 0); voxelize a non-empty object")
    given = {m.label for m in scene.materials}
    unused = sorted(given - set(present))
    if unused:
        raise InputError(
            f"[[material]] label {unused[0]} does not occur in the image (labels present: "
            f"{', '.join(map(str, present))}); fix the label or remove that material"
        )
    out = {}
    for label in present:
        spec = scene.material_for(label)
        out[label] = material(spec.model, **spec.material_kwargs(scene.elasticity.strain))
    return out


def _voxel_model(scene: Scene, image, materials):
    from .deform.voxel_model import VoxelModel

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
    return VoxelModel.from_image(image, materials, quadrature=quadrature, use_occupancy=bool(scene.object.occupancy))


def _not_implemented(kind: str):
    def builder(scene, image, materials):
        built = [k for k, b in MODEL_BUILDERS.items() if not getattr(b, "not_implemented", False)]
        raise NotImplementedError(
            f'[nodes] kind = "{kind}" is not implemented yet; use {" or ".join(repr(k) for k in built)}'
        )

    builder.not_implemented = True

    return builder


MODEL_BUILDERS: dict[str, Callable] = {
    "voxel": _voxel_model,
    "affine": _not_implemented("affine"),
    "rigid": _not_implemented("rigid"),
}
"""Registry: ``[nodes] kind`` -> builder ``(scene, image, materials) -> Model``."""


def model(scene, *, image=None):
    """The model ``scene`` asks for (``[nodes] kind``), built on its image.

    Parameters
    ----------
    scene : Scene or path to a scene file
    image : LabelImage, optional
        The scene's image when already built (default: :func:`build_image`).

    Returns
    -------
    Model
        A :class:`~voxflex.deform.voxel_model.VoxelModel` or a frame model.

    Raises
    ------
    InputError
        A label without material, a setting the node kind does not take.
    NotImplementedError
        A node kind that is registered but not built yet (named in the message).
    """
    if not isinstance(scene, Scene):
        scene = Scene.from_toml(scene)
    check_choice("node kind", scene.nodes.kind, MODEL_BUILDERS)
    if image is None:
        image = build_image(scene)
    labels_present = np.unique(image.labels[image.labels > 0])
    materials = build_materials(scene, labels_present)
    return MODEL_BUILDERS[scene.nodes.kind](scene, image, materials)
