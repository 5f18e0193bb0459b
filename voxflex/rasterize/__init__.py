"""Rasterization: primitives and surface meshes -> label images.

>>> import voxflex as vf
>>> image = vf.voxelize("box:4,1,1", voxel_size=0.125)
>>> image.shape
(32, 8, 8)
"""

from .._lazy import lazy

__getattr__, __dir__, __all__ = lazy(__name__, {
    "voxelize": "voxflex.rasterize.voxelizer",
    "estimate_bytes": "voxflex.rasterize.voxelizer",
    "Box": "voxflex.rasterize.primitives",
    "Cylinder": "voxflex.rasterize.primitives",
    "Sphere": "voxflex.rasterize.primitives",
    "parse_spec": "voxflex.rasterize.primitives",
    "SurfaceMesh": "voxflex.rasterize.mesh",
    "load_mesh": "voxflex.rasterize.mesh",
    "winding_number": "voxflex.rasterize.winding",
    "winding_number_brute": "voxflex.rasterize.winding",
    "build_tree": "voxflex.rasterize.winding",
    "turn_up": "voxflex.rasterize.orient",
    "up_rotation": "voxflex.rasterize.orient",
    "UP_AXES": "voxflex.rasterize.orient",
})
