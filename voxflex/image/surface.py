"""The boundary surface of a voxel set: exposed voxel faces as quads, and their triangles."""

from __future__ import annotations

import numpy as np

from .grid import TrilinearGrid

__all__ = ["boundary_quads", "triangulate", "face_points"]


def boundary_quads(grid: TrilinearGrid, mask):
    """Faces of the voxels of ``grid`` exposed to empty space (``mask`` false or outside the image).

    Returns
    -------
    quads : (F, 4) int64
        Grid nodes of each face, counter-clockwise seen from outside.
    area : (F,) float (m^2)
    normal : (F, 3) float, outward unit normal at rest
    """
    ijk = grid.element_ijk
    shape = np.asarray(grid.shape)
    nx, ny, nz = grid.shape
    quads, normals, areas = [], [], []
    flip = np.linalg.det(grid.direction) < 0
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3
        eb = np.eye(3, dtype=np.int64)[b]
        ec = np.eye(3, dtype=np.int64)[c]
        ea = np.eye(3, dtype=np.int64)[a]
        for side in (-1, 1):
            nb = ijk + side * ea
            outside = np.any((nb < 0) | (nb >= shape), axis=1)
            nbc = np.clip(nb, 0, shape - 1)
            empty = outside | ~mask[nbc[:, 0], nbc[:, 1], nbc[:, 2]]
            sel = ijk[empty]
            if len(sel) == 0:
                continue
            p0 = sel + (ea if side > 0 else 0)
            corners = np.stack([p0, p0 + eb, p0 + eb + ec, p0 + ec], axis=1)  # (f, 4, 3)
            if (side < 0) != flip:
                corners = corners[:, ::-1]
            keys = (corners[..., 0] * (ny + 1) + corners[..., 1]) * (nz + 1) + corners[..., 2]
            quads.append(np.searchsorted(grid.node_key, keys))
            normal = side * grid.direction[:, a]
            normals.append(np.broadcast_to(normal, (len(sel), 3)))
            areas.append(np.full(len(sel), grid.spacing[b] * grid.spacing[c]))
    return np.concatenate(quads).astype(np.int64), np.concatenate(areas), np.concatenate(normals).astype(float)


def triangulate(quads):
    """Triangles of quadrilaterals (two per quad) over the used nodes only.

    Returns
    -------
    vertex_node : (V,) int64, the node of each vertex (sorted)
    faces : (2F, 3) int64, vertex indices, orientation of the quads kept
    """
    tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]], axis=0)
    vertex_node, faces = np.unique(tris, return_inverse=True)
    return vertex_node.astype(np.int64), faces.reshape(-1, 3).astype(np.int64)


def face_points(corners, area, order: int = 2):
    """``order`` x ``order`` Gauss points on planar quadrilateral faces (parallelograms) and their area weights.

    Parameters
    ----------
    corners : (F, 4, 3) float, counter-clockwise corners (m); corner 0 at (0, 0), 1 at (1, 0), 3 at (0, 1)
    area : (F,) float (m^2), the faces' areas
    order : int >= 1, Gauss points per face edge (1: the face centres)

    Returns
    -------
    points : (F k^2, 3) float, face-major
    weights : (F k^2,) float (m^2): area times the product Gauss weights (exact for polynomials of
        degree 2k - 1 in each face coordinate)
    face : (F k^2,) int, the face each point lies on
    """
    corners = np.asarray(corners, dtype=float)
    x, w = np.polynomial.legendre.leggauss(int(order))
    x, w = 0.5 * (x + 1.0), 0.5 * w
    a, b = np.meshgrid(x, x, indexing="ij")
    wab = np.outer(w, w).ravel()
    c0 = corners[:, 0]
    e1 = corners[:, 1] - c0
    e3 = corners[:, 3] - c0
    pts = c0[:, None, :] + a.ravel()[None, :, None] * e1[:, None, :] + b.ravel()[None, :, None] * e3[:, None, :]
    k2 = len(wab)
    return pts.reshape(-1, 3), (np.asarray(area, dtype=float)[:, None] * wab[None, :]).ravel(), \
        np.repeat(np.arange(len(corners)), k2)
