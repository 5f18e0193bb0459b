"""The :class:`Samples` container: integration samples of a label image.

Produced by :func:`voxflex.sampling.sample`; consumed by the frame model (energy
and mass integration) and by :func:`voxflex.deform.models.frames.modes.zero_energy_modes`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..voronoi.shape_functions import ShapeValues
from .quadrature import QUADRATURES
from .volume_moments import EXPONENT_INDEX, N_MOMENTS

__all__ = ["Samples", "KINDS"]

KINDS = QUADRATURES
"""Sampling kinds accepted by :func:`voxflex.sampling.sample`."""

_M2 = np.array([[EXPONENT_INDEX[tuple(int(i == a) + int(i == b) for i in range(3))] for b in range(3)] for a in range(3)])


@dataclass(frozen=True, eq=False)
class Samples:
    """Integration samples: points, volume moments, regions and shape values.

    Parameters
    ----------
    kind : str
        ``"midpoint"``, ``"gauss-legendre"`` or ``"elaston"``.
    points : (m, 3) float
        World positions of the samples [m].
    volume : (m,) float
        Volume of each sample's region [m^3], occupancy-weighted when the image has occupancy.
    moments : (m, 35) float
        Exact volume moments of each region about its point up to order 4
        (:data:`voxflex.sampling.volume_moments.EXPONENTS` order: 1, x, y, z, xx,
        xy, ...); ``moments[:, 0] == volume``; entry alpha in m^(3 + |alpha|).
    label : (m,) int
        Material label of each sample (a region never spans two labels).
    region : (nx, ny, nz) int64
        Sample index of each voxel, -1 outside the material.  For
        ``"gauss-legendre"`` each voxel holds 8 samples (one per octant, indices
        ``8 v .. 8 v + 7`` for the v-th material voxel in C order) and the image
        holds the first, ``8 v``.
    values : ShapeValues
        Shape functions of the samples (m children): ``w``, ``dw`` [1/m],
        ``ddw`` [1/m^2] at the sample points.

    Notes
    -----
    Arrays are validated and stored read-only.
    """

    kind: str
    points: np.ndarray
    volume: np.ndarray
    moments: np.ndarray
    label: np.ndarray
    region: np.ndarray
    values: ShapeValues

    def __post_init__(self):
        points = np.ascontiguousarray(self.points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3:
            raise InputError(f"Samples.points must be (m, 3), got {points.shape}")
        m = len(points)
        volume = np.ascontiguousarray(self.volume, dtype=np.float64)
        moments = np.ascontiguousarray(self.moments, dtype=np.float64)
        label = np.ascontiguousarray(self.label, dtype=np.int64)
        region = np.ascontiguousarray(self.region, dtype=np.int64)
        if volume.shape != (m,) or label.shape != (m,):
            raise InputError(f"Samples.volume and Samples.label must have shape ({m},)")
        if moments.shape != (m, N_MOMENTS):
            raise InputError(f"Samples.moments must have shape ({m}, {N_MOMENTS}), got {moments.shape}")
        if region.ndim != 3:
            raise InputError(f"Samples.region must be a 3-D image, got shape {region.shape}")
        if not isinstance(self.values, ShapeValues) or self.values.m != m:
            raise InputError(f"Samples.values must be a ShapeValues with {m} children")
        if not (np.all(np.isfinite(points)) and np.all(np.isfinite(moments))):
            raise InputError("Samples.points and Samples.moments must be finite")
        if np.any(volume <= 0):
            raise InputError("every sample needs a positive volume; drop empty regions")
        for a in (points, volume, moments, label, region):
            a.setflags(write=False)
        object.__setattr__(self, "points", points)
        object.__setattr__(self, "volume", volume)
        object.__setattr__(self, "moments", moments)
        object.__setattr__(self, "label", label)
        object.__setattr__(self, "region", region)

    @property
    def m(self) -> int:
        """Number of samples."""
        return len(self.points)

    @property
    def n_frames(self) -> int:
        """Number of frames the shape values refer to."""
        n = self.values.n_nodes
        return int(n) if n is not None else int(self.values.index.max()) + 1

    @property
    def M1(self) -> np.ndarray:
        """First moments about the points ``int (x - p) dV`` (m, 3) [m^4]."""
        return self.moments[:, 1:4]

    @property
    def M2(self) -> np.ndarray:
        """Second moments about the points ``int (x - p)(x - p)^T dV`` (m, 3, 3) [m^5]."""
        return self.moments[:, _M2]

    def __repr__(self) -> str:
        return f"Samples(kind={self.kind!r}, m={self.m}, volume={float(self.volume.sum()):.6g} m^3)"
