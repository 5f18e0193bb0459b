"""A stand-in for ``voxflex.voronoi.weights`` used by the sampling tests.

It satisfies the interface the sampler codes against (``frames``, ``parents``,
``__call__(points) -> ShapeValues``, ``voxel_values()`` at the material voxel
centres in ``np.flatnonzero(labels > 0)`` order) with renormalized Shepard
weights, so the tests run before the Voronoi stage lands.  ``QuadraticSF`` is
an oracle: two "frames" whose weights are a known quadratic q(x) and 1 - q(x).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from voxflex.image import LabelImage
from voxflex.voronoi.shape_functions import ShapeValues, shepard


@dataclass(frozen=True, eq=False)
class ShepardSF:
    image: LabelImage
    frames: np.ndarray
    parents: int = 4

    def __call__(self, points):
        return shepard(points, self.frames, n_parents=min(self.parents, len(self.frames)))

    def voxel_values(self):
        return self(self.image.voxel_centers())


@dataclass(frozen=True, eq=False)
class QuadraticSF:
    """w0 = q(x) = c + g.x + 1/2 x.H.x, w1 = 1 - q: an exact quadratic field."""

    image: LabelImage
    c: float
    g: np.ndarray
    H: np.ndarray
    parents: int = 2

    @property
    def frames(self):
        return np.zeros((2, 3))

    def __call__(self, points):
        X = np.asarray(points, dtype=float)
        q = self.c + X @ self.g + 0.5 * np.einsum("ni,ij,nj->n", X, self.H, X)
        dq = self.g + X @ self.H
        m = len(X)
        w = np.stack([q, 1.0 - q], 1)
        dw = np.stack([dq, -dq], 1)
        ddw = np.stack([np.broadcast_to(self.H, (m, 3, 3)), -np.broadcast_to(self.H, (m, 3, 3))], 1)
        index = np.broadcast_to(np.arange(2), (m, 2))
        return ShapeValues(index=index, w=w, dw=dw, ddw=ddw, rest=X, n_nodes=2)

    def voxel_values(self):
        return self(self.image.voxel_centers())


def rotation(angle_z=0.3, angle_x=0.2):
    cz, sz, cx, sx = np.cos(angle_z), np.sin(angle_z), np.cos(angle_x), np.sin(angle_x)
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    return Rz @ Rx


def two_label_block(n=16, occupancy=False, rotated=True, seed=0):
    """A block with two labels and a notch, anisotropic spacing, optionally rotated and with occupancy."""
    lab = np.zeros((n, n - 2, n - 4), np.uint8)
    lab[1:-1, 1:-1, 1:-1] = 1
    lab[1 : n // 3, 1:-1, 1:-1] = 2
    lab[n // 2 :, n // 2 :, : (n - 4) // 2] = 0  # a notch: non-convex
    occ = None
    if occupancy:
        occ = np.random.default_rng(seed).uniform(0.2, 1.0, lab.shape).astype(np.float32)
    return LabelImage(
        lab,
        spacing=[0.01, 0.012, 0.009],
        origin=[0.1, -0.2, 0.3],
        direction=rotation() if rotated else np.eye(3),
        occupancy=occ,
    )


def frames_in(image, k, seed=1):
    centres = image.voxel_centers()
    rng = np.random.default_rng(seed)
    return centres[np.sort(rng.choice(len(centres), k, replace=False))]
