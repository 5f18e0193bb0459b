"""Rasterization: primitives and surface meshes -> label images.

>>> import voxflex as vf
>>> image = vf.voxelize("box:4,1,1", voxel_size=0.125)
>>> image.shape
(32, 8, 8)
"""

from .mesh import SurfaceMesh, load_mesh
from .orient import UP_AXES, turn_up, up_rotation
from .primitives import Box, Cylinder, Sphere, parse_spec
from .voxelize import estimate_bytes, voxelize
from .winding import build_tree, winding_number, winding_number_brute

__all__ = [
    "voxelize",
    "Box",
    "Cylinder",
    "Sphere",
    "parse_spec",
    "SurfaceMesh",
    "load_mesh",
    "winding_number",
    "winding_number_brute",
    "build_tree",
    "estimate_bytes",
    "turn_up",
    "up_rotation",
    "UP_AXES",
]
