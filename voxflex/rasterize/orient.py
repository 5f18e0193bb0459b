"""Turning objects so that a chosen axis points up (world +z).

Many meshes come "y-up" (the cow, the bunny: the convention of OpenGL and most
modelling tools), while voxflex's world, its default scene and its renders
have z up.  :func:`turn_up` turns a surface mesh, a primitive or a label image
by a quarter turn about the world origin so that its ``up`` axis becomes +z:

======  ==========================  =========================
``up``  (x, y, z) becomes           rotation
======  ==========================  =========================
``z``   (x, y, z)                   none
``y``   (x, -z, y)                  +90 degrees about x
``x``   (-z, y, x)                  -90 degrees about y
======  ==========================  =========================

Both turns are proper rotations (no mirror image).  For ``up = "y"`` the
front of a y-up model (its +z side) ends up facing -y, that is, towards the
camera of voxflex's front view.

A label image is turned exactly, without resampling: when its direction
stays axis-aligned the voxel array is transposed and flipped (the direction
stays the identity, the spacing is permuted, the origin is the new lower
corner); otherwise the direction matrix is rotated.

>>> import numpy as np
>>> up_rotation("y") @ np.array([0.0, 1.0, 0.0])
array([0., 0., 1.])
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..errors import InputError, check_choice
from ..image.label_image import LabelImage
from .mesh import SurfaceMesh
from .primitives import Box, Cylinder, Sphere

__all__ = ["UP_AXES", "up_rotation", "turn_up"]

UP_AXES = ("x", "y", "z")
_ROTATIONS = {
    "z": np.eye(3),
    "y": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),
    "x": np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]),
}
_AXIS_NAMES = "xyz"


def up_rotation(up: str) -> np.ndarray:
    """The rotation R (3, 3) that takes the world axis ``up`` to +z (``R @ e_up = e_z``, det R = +1)."""
    check_choice("up axis", up, UP_AXES)
    return _ROTATIONS[up].copy()


def turn_up(obj, up: str = "z"):
    """Turn a mesh, a primitive or a label image so that its ``up`` axis points along world +z.

    Parameters
    ----------
    obj : SurfaceMesh, Box, Cylinder, Sphere or LabelImage
        What to turn (about the world origin).
    up : {"x", "y", "z"}
        The object's axis that should point up; ``"z"`` returns ``obj`` unchanged.

    Returns
    -------
    The same kind of object, turned.  A primitive keeps its kind (a box's sizes
    and a cylinder's axis are permuted; ``origin`` is the lower corner of the
    turned bounding box).  A label image keeps its voxels exactly.

    Examples
    --------
    >>> from voxflex.rasterize import Box
    >>> turn_up(Box((1.0, 2.0, 3.0)), "y")
    Box(size=(1.0, 3.0, 2.0), origin=(0.0, -3.0, 0.0))
    """
    R = up_rotation(up)
    if up == "z":
        return obj
    if isinstance(obj, SurfaceMesh):
        return SurfaceMesh(obj.vertices @ R.T, obj.faces, name=obj.name)
    if isinstance(obj, (Box, Cylinder, Sphere)):
        return _turn_primitive(obj, R)
    if isinstance(obj, LabelImage):
        return _turn_image(obj, R)
    raise InputError(
        f"cannot turn a {type(obj).__name__}; give a SurfaceMesh, a Box/Cylinder/Sphere or a LabelImage"
    )


def _turned_box(lo, hi, R) -> tuple[np.ndarray, np.ndarray]:
    corners = np.array([[a, b, c] for a in (lo[0], hi[0]) for b in (lo[1], hi[1]) for c in (lo[2], hi[2])])
    turned = corners @ R.T
    return turned.min(axis=0), turned.max(axis=0)


def _turn_primitive(prim, R):
    lo, _ = _turned_box(*prim.bounds(), R)
    origin = tuple(float(v) for v in lo)
    if isinstance(prim, Box):
        return Box(tuple(float(v) for v in np.abs(R) @ np.asarray(prim.size)), origin=origin)
    if isinstance(prim, Cylinder):
        axis = _AXIS_NAMES[int(np.argmax(np.abs(R[:, _AXIS_NAMES.index(prim.axis)])))]
        return replace(prim, origin=origin, axis=axis)
    return replace(prim, origin=origin)


def _turn_image(image: LabelImage, R) -> LabelImage:
    M = R @ image.direction  # columns: world directions of the array axes after the turn
    lo, _ = _turned_box(*_image_box(image), R)
    axis_of = np.argmax(np.abs(M), axis=1)  # array axis along each world axis
    signed_permutation = np.allclose(np.abs(M).max(axis=1), 1.0, atol=1e-9) and len(set(axis_of)) == 3
    if not signed_permutation:
        return replace(image, origin=image.origin @ R.T, direction=M)
    signs = np.sign(M[np.arange(3), axis_of])

    def arrange(a):
        if a is None:
            return None
        a = np.transpose(a, axis_of)
        flips = tuple(w for w in range(3) if signs[w] < 0)
        return np.ascontiguousarray(np.flip(a, axis=flips) if flips else a)

    # new array axis w is old axis axis_of[w], flipped where it ran against world axis w: it runs along +e_w
    return replace(
        image,
        labels=arrange(image.labels),
        occupancy=arrange(image.occupancy),
        spacing=np.asarray(image.spacing)[axis_of],
        origin=lo,
        direction=np.eye(3),
    )


def _image_box(image: LabelImage) -> tuple[np.ndarray, np.ndarray]:
    """World bounding box of the image's grid (all voxels, empty ones included)."""
    extent = np.asarray(image.shape) * np.asarray(image.spacing)
    corners = np.array([[a, b, c] for a in (0, extent[0]) for b in (0, extent[1]) for c in (0, extent[2])])
    world = image.origin + corners @ np.asarray(image.direction).T
    return world.min(axis=0), world.max(axis=0)
