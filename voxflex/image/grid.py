"""Trilinear shape functions on the corners of occupied voxels.

The full-resolution voxel model places one node at every corner of an
occupied voxel (label > 0).  Nodes are numbered by their sorted linear corner
index ``(i * (ny + 1) + j) * (nz + 1) + k`` on the ``(nx+1, ny+1, nz+1)``
corner grid; elements are the occupied voxels in C order.  Corner ``c`` of a
voxel (0..7) sits at offset ``((c >> 2) & 1, (c >> 1) & 1, c & 1)``.

Inside voxel ``ijk`` with local coordinates ``xi`` in [0, 1]^3 the weight of
corner ``c`` with offset ``d`` is ``prod_a (xi_a if d_a else 1 - xi_a)``: the
weights are non-negative, sum to one and reproduce affine fields exactly.
World gradients follow from ``x = origin + direction @ (spacing * (ijk + xi))``.

>>> import numpy as np
>>> from voxflex.image.label_image import LabelImage
>>> grid = TrilinearGrid.from_image(LabelImage(np.ones((2, 1, 1))))
>>> grid.n_nodes, grid.n_elements
(12, 2)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError

CORNER_OFFSETS = np.array([[(c >> 2) & 1, (c >> 1) & 1, c & 1] for c in range(8)], dtype=np.int64)
"""(8, 3) int: offset of voxel corner c from the voxel's lower corner."""


def trilinear_weights(local, *, hessian: bool = False):
    """Trilinear weights of the 8 voxel corners at local coordinates.

    Parameters
    ----------
    local : (m, 3) float
        Local coordinates in the voxel, [0, 1]^3 (not checked; outside it the
        polynomials extrapolate).
    hessian : bool
        Also return the second derivatives.

    Returns
    -------
    w : (m, 8) float
    dw : (m, 8, 3) float, derivatives with respect to the local coordinates
    ddw : (m, 8, 3, 3) float or None
    """
    local = np.asarray(local, dtype=float)
    d = CORNER_OFFSETS.astype(float)  # (8, 3)
    t = local[:, None, :]  # (m, 1, 3)
    f = np.where(d > 0, t, 1.0 - t)  # (m, 8, 3) one-dimensional factors
    df = np.where(d > 0, 1.0, -1.0) * np.ones_like(f)  # derivative of each factor
    w = f[..., 0] * f[..., 1] * f[..., 2]
    dw = np.empty(f.shape)
    dw[..., 0] = df[..., 0] * f[..., 1] * f[..., 2]
    dw[..., 1] = f[..., 0] * df[..., 1] * f[..., 2]
    dw[..., 2] = f[..., 0] * f[..., 1] * df[..., 2]
    ddw = None
    if hessian:
        ddw = np.zeros(f.shape + (3,))
        for a, b, c in ((0, 1, 2), (0, 2, 1), (1, 2, 0)):
            ddw[..., a, b] = ddw[..., b, a] = df[..., a] * df[..., b] * f[..., c]
    return w, dw, ddw


def _local_to_world_gradient(dw_local, spacing, direction):
    """(…, 3) local derivatives -> world derivatives (the chain rule through x(xi))."""
    return (dw_local / spacing) @ direction.T


@dataclass(frozen=True, eq=False)
class TrilinearGrid:
    """Nodes at the corners of the occupied voxels of a label image.

    Attributes
    ----------
    shape : (3,) int
        Image shape (nx, ny, nz).
    spacing, origin : (3,) float, metres
    direction : (3, 3) float, orthonormal
    element_ijk : (m, 3) int64
        Index of each occupied voxel (element), C order.
    element_nodes : (m, 8) int64
        Node of each voxel corner (corner order of :data:`CORNER_OFFSETS`).
    node_ijk : (n, 3) int64
        Corner-grid index of each node.
    node_key : (n,) int64
        Sorted linear corner index of each node.
    """

    shape: tuple
    spacing: np.ndarray
    origin: np.ndarray
    direction: np.ndarray
    element_ijk: np.ndarray
    element_nodes: np.ndarray
    node_ijk: np.ndarray
    node_key: np.ndarray

    @classmethod
    def from_image(cls, image, mask=None) -> "TrilinearGrid":
        """Grid of the voxels where ``mask`` is true (default: ``image.labels > 0``)."""
        if mask is None:
            mask = image.labels > 0
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != image.shape:
            raise InputError(f"mask shape {mask.shape} differs from image shape {image.shape}")
        element_ijk = np.argwhere(mask).astype(np.int64)
        if len(element_ijk) == 0:
            raise InputError("the image has no occupied voxel (all labels are 0); give at least one labelled voxel")
        nx, ny, nz = image.shape
        corners = element_ijk[:, None, :] + CORNER_OFFSETS[None, :, :]  # (m, 8, 3)
        keys = (corners[..., 0] * (ny + 1) + corners[..., 1]) * (nz + 1) + corners[..., 2]
        node_key = np.unique(keys)
        element_nodes = np.searchsorted(node_key, keys).astype(np.int64)
        k = node_key
        node_ijk = np.stack([k // ((ny + 1) * (nz + 1)), (k // (nz + 1)) % (ny + 1), k % (nz + 1)], axis=1)
        return cls(
            shape=(int(nx), int(ny), int(nz)),
            spacing=np.asarray(image.spacing, dtype=float),
            origin=np.asarray(image.origin, dtype=float),
            direction=np.asarray(image.direction, dtype=float),
            element_ijk=element_ijk,
            element_nodes=element_nodes,
            node_ijk=node_ijk.astype(np.int64),
            node_key=node_key.astype(np.int64),
        )

    # -- sizes and positions ------------------------------------------------
    @property
    def n_nodes(self) -> int:
        return int(len(self.node_key))

    @property
    def n_elements(self) -> int:
        return int(len(self.element_ijk))

    def index_to_world(self, index) -> np.ndarray:
        """World positions (m, 3) of continuous voxel coordinates (m, 3)."""
        return self.origin + (np.asarray(index, dtype=float) * self.spacing) @ self.direction.T

    def world_to_index(self, points) -> np.ndarray:
        """Continuous voxel coordinates (m, 3) of world points (m, 3)."""
        return ((np.asarray(points, dtype=float) - self.origin) @ self.direction) / self.spacing

    @property
    def node_positions(self) -> np.ndarray:
        """(n, 3) world rest positions of the nodes."""
        return self.index_to_world(self.node_ijk)

    def reference_gradients(self, local) -> np.ndarray:
        """World gradients (Q, 8, 3) of the corner weights at local points (Q, 3).

        They are the same in every voxel of a regular grid.
        """
        _, dw, _ = trilinear_weights(local)
        return _local_to_world_gradient(dw, self.spacing, self.direction)

    # -- point location -----------------------------------------------------
    def index_roundoff(self, points) -> float:
        """Round-off (voxels) of the continuous voxel coordinates of world ``points``: 16 eps |x| / h.

        A point given on a face of a body far from the origin (1000 km, 2 mm voxels) is ~5e-8 voxel off
        it after ``world_to_index``; a tolerance below this would put it in or out by its units' round-off.
        """
        far = max(float(np.max(np.abs(self.origin), initial=0.0)), float(np.max(np.abs(points), initial=0.0)))
        return 16.0 * np.finfo(float).eps * far / float(np.min(self.spacing))

    def locate(self, points, *, tolerance: float = 1e-9):
        """The occupied voxel holding each world point, and its local coordinates.

        A point on a face, edge or corner shared by several voxels goes to an
        occupied one.  Points within ``tolerance`` (in voxel units) of the
        material count as inside.

        Returns
        -------
        element : (m,) int64, index into the elements; -1 where the point is outside the material
        local : (m, 3) float in [0, 1]^3
        """
        c = np.atleast_2d(self.world_to_index(points))
        tolerance = max(tolerance, self.index_roundoff(points))
        m = len(c)
        base = np.floor(c).astype(np.int64)
        frac = c - base
        # a coordinate within tolerance of an integer may belong to either neighbour voxel
        near_low = frac < tolerance
        near_high = frac > 1.0 - tolerance
        occupied_key = (
            (self.element_ijk[:, 0] * self.shape[1] + self.element_ijk[:, 1]) * self.shape[2] + self.element_ijk[:, 2]
        )  # sorted: element_ijk is in C order
        element = np.full(m, -1, dtype=np.int64)
        for shift in range(8):
            s = CORNER_OFFSETS[shift]
            # candidate voxel: base, or base-1 along axes near their lower face, or base+1 near the upper face
            todo = element < 0
            if not np.any(todo):
                break
            cand = base.copy()
            valid = todo.copy()
            for a in range(3):
                if s[a]:
                    low = near_low[:, a]
                    high = near_high[:, a]
                    cand[:, a] = np.where(low, base[:, a] - 1, np.where(high, base[:, a] + 1, base[:, a]))
                    valid &= low | high
            inside = valid & np.all((cand >= 0) & (cand < np.asarray(self.shape)), axis=1)
            key = (cand[:, 0] * self.shape[1] + cand[:, 1]) * self.shape[2] + cand[:, 2]
            pos = np.searchsorted(occupied_key, key)
            pos = np.minimum(pos, len(occupied_key) - 1)
            hit = inside & (occupied_key[pos] == key)
            element[hit] = pos[hit]
        local = np.zeros((m, 3))
        ok = element >= 0
        local[ok] = np.clip(c[ok] - self.element_ijk[element[ok]], 0.0, 1.0)
        return element, local
