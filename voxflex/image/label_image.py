"""The label image: integer labels on a regular grid placed in the world.

Conventions (see SPEC): ``labels[i, j, k]`` with i along x; ``spacing`` is the
voxel size along the array axes; ``origin`` is the world position of the
*corner* of voxel (0, 0, 0); ``direction`` is an orthonormal 3x3 matrix whose
columns are the world directions of the array axes.  Voxel (i, j, k) covers
``origin + direction @ (spacing * ([i, i+1] x [j, j+1] x [k, k+1]))``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError

LABEL_DTYPES = (np.uint8, np.uint16)


def _as_labels(labels) -> np.ndarray:
    arr = np.asarray(labels)
    if arr.ndim != 3:
        raise InputError(f"label image must be 3-D, got shape {arr.shape}; pass a (nx, ny, nz) array")
    if arr.size == 0:
        raise InputError(f"label image is empty (shape {arr.shape}); give at least one voxel along each axis")
    if arr.dtype == bool:
        arr = arr.astype(np.uint8)
    elif not np.issubdtype(arr.dtype, np.integer):
        if not np.issubdtype(arr.dtype, np.floating):
            raise InputError(f"label data must be integer, got dtype {arr.dtype}; convert the image to integer labels")
        if not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)):
            raise InputError(
                "label data is not integer (fractional or NaN values); segment the image into integer labels first"
            )
    if arr.size and arr.min() < 0:
        raise InputError(f"labels must be >= 0 (0 = empty), found {arr.min()}; relabel the image")
    top = int(arr.max()) if arr.size else 0
    dtype = np.uint8 if top <= 255 else np.uint16
    if top > 65535:
        raise InputError(f"labels must be <= 65535, found {top}; relabel the image")
    return np.ascontiguousarray(arr, dtype=dtype)


def _as_vector(name, value, positive=False) -> np.ndarray:
    try:
        vec = np.broadcast_to(np.asarray(value, dtype=float), (3,)).copy()
    except (ValueError, TypeError):
        raise InputError(f"{name} must be 3 numbers, got {value!r}") from None
    if not np.all(np.isfinite(vec)):
        raise InputError(f"{name} must be finite, got {vec.tolist()}")
    if positive and np.any(vec <= 0):
        raise InputError(f"{name} must be > 0 along every axis, got {vec.tolist()}; give a positive voxel size")
    return vec


@dataclass(frozen=True, eq=False)
class LabelImage:
    """Integer labels on a regular grid placed in the world.

    Parameters
    ----------
    labels : (nx, ny, nz) integer array
        0 is empty, 1..255 (up to 65535) are materials.  Stored as uint8 or uint16.
    spacing : (3,) float, metres
        Voxel size along the array axes, > 0.
    origin : (3,) float, metres
        World position of the corner of voxel (0, 0, 0).
    direction : (3, 3) float, optional
        Orthonormal; column a is the world direction of array axis a.  Identity by default.
    occupancy : (nx, ny, nz) float array in [0, 1], optional
        Fraction of each voxel's volume occupied by material (partial volume).
    """

    labels: np.ndarray
    spacing: np.ndarray = field(default_factory=lambda: np.ones(3))
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    direction: np.ndarray = field(default_factory=lambda: np.eye(3))
    occupancy: np.ndarray | None = None

    def __post_init__(self):
        labels = _as_labels(self.labels)
        spacing = _as_vector("spacing", self.spacing, positive=True)
        origin = _as_vector("origin", self.origin)
        direction = np.asarray(self.direction, dtype=float)
        if direction.shape != (3, 3) or not np.all(np.isfinite(direction)):
            raise InputError(f"direction must be a finite 3x3 matrix, got shape {direction.shape}")
        if not np.allclose(direction.T @ direction, np.eye(3), atol=1e-6):
            raise InputError("direction must be orthonormal (columns are unit axis directions); fix the image header")
        occupancy = self.occupancy
        if occupancy is not None:
            occupancy = np.asarray(occupancy, dtype=np.float32)
            if occupancy.shape != labels.shape:
                raise InputError(f"occupancy shape {occupancy.shape} differs from labels shape {labels.shape}")
            if not np.all(np.isfinite(occupancy)) or occupancy.min() < 0 or occupancy.max() > 1 + 1e-6:
                raise InputError("occupancy fractions must lie in [0, 1]")
            occupancy = np.clip(occupancy, 0.0, 1.0)
            occupancy.setflags(write=False)
        for arr in (labels, spacing, origin, direction):
            arr.setflags(write=False)
        object.__setattr__(self, "labels", labels)
        object.__setattr__(self, "spacing", spacing)
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "direction", direction)
        object.__setattr__(self, "occupancy", occupancy)

    # -- geometry ---------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(int(s) for s in self.labels.shape)

    @property
    def voxel_volume(self) -> float:
        return float(np.prod(self.spacing))

    def index_to_world(self, index) -> np.ndarray:
        """World positions (n, 3) of continuous voxel coordinates ``index`` (n, 3).

        Integer coordinates are voxel corners; ``ijk + 0.5`` is the centre of voxel ijk.
        """
        index = np.asarray(index, dtype=float)
        return self.origin + (index * self.spacing) @ self.direction.T

    def world_to_index(self, points) -> np.ndarray:
        """Continuous voxel coordinates (n, 3) of world ``points`` (n, 3); inverse of :meth:`index_to_world`."""
        points = np.asarray(points, dtype=float)
        return ((points - self.origin) @ self.direction) / self.spacing

    def voxel_centers(self, mask=None) -> np.ndarray:
        """World centres (n, 3) of the voxels where ``mask`` is true (default: labels > 0), in C order."""
        if mask is None:
            mask = self.labels > 0
        ijk = np.argwhere(mask)
        return self.index_to_world(ijk + 0.5)
