"""Models: the protocol every model satisfies, the registry of node kinds, and the models themselves.

``protocol`` (what solvers, loads, results and renders may ask of a model),
``voxel`` (trilinear nodes at voxel corners: the full-resolution reference),
``frames`` (affine frames skinned over the image: the reduced model), ``rigid``
(rigid frames) and ``membrane`` (a triangle mesh's vertices), plus the result
fields computed from any model.
"""

from ..._lazy import lazy

__getattr__, __dir__, __all__ = lazy(__name__, {
    "Model": "voxflex.deform.models.protocol",
    "PointMap": "voxflex.deform.models.protocol",
    "VoxelModel": "voxflex.deform.models.voxel.model",
    "FrameModel": "voxflex.deform.models.frames.model",
    "RigidFrameModel": "voxflex.deform.models.rigid.model",
    "MembraneModel": "voxflex.deform.models.membrane.model",
})
