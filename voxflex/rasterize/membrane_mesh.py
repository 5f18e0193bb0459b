"""Triangle meshes of membranes: disks, rectangles, mesh files, and the voxels they pass through."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["disk_mesh", "rectangle_mesh", "load_membrane_mesh", "footprint_image", "open_rim", "MEMBRANE_SHAPES"]

MEMBRANE_SHAPES = {"disk": 1, "rectangle": 2}
"""Flat sheets voxflex makes for ``[object] shape`` (membranes only): name -> number of ``size`` values
(disk: radius; rectangle: lx, ly), in the plane z = origin_z, normal +z."""


FLAT_TOL = 1e-10
"""|n_t x n_0| below which every triangle normal counts as parallel (a flat membrane)."""


# ----------------------------------------------------------------------------------------------
# geometry
# ----------------------------------------------------------------------------------------------
def _edge(edge) -> float:
    e = float(edge)
    if not (np.isfinite(e) and e > 0):
        raise InputError(f"edge length must be > 0 (m), got {edge!r}")
    return e


def disk_mesh(radius: float, edge: float, *, center=(0.0, 0.0, 0.0)):
    """A flat disk of triangles in the plane z = center_z, normal +z.

    Rings at radii ``radius k / N`` (``N = max(1, round(radius / edge))``) of
    ``6 k`` vertices each around the centre vertex, joined ring to ring by strips:
    ``1 + 3 N (N + 1)`` vertices, ``6 N²`` nearly equilateral triangles; the rim
    (ring N) lies on the circle.

    Parameters
    ----------
    radius : float (m)
    edge : float (m), the target edge length
    center : (3,) float (m)

    Returns
    -------
    points : (n, 3) float (m); the centre is point 0
    triangles : (m, 3) int, counter-clockwise seen from +z
    """
    r = float(radius)
    if not (np.isfinite(r) and r > 0):
        raise InputError(f"disk radius must be > 0 (m), got {radius!r}")
    n = max(1, int(round(r / _edge(edge))))
    c = np.asarray(center, dtype=float)
    points = [np.zeros(3)]
    start = [0]
    for k in range(1, n + 1):
        start.append(len(points))
        a = 2 * np.pi * np.arange(6 * k) / (6 * k)
        points.extend(np.stack([r * k / n * np.cos(a), r * k / n * np.sin(a), np.zeros(6 * k)], axis=1))
    tris = []
    for j in range(6):
        tris.append([0, 1 + j, 1 + (j + 1) % 6])
    for k in range(1, n):
        m1, m2 = 6 * k, 6 * (k + 1)
        A = lambda i: start[k] + i % m1  # noqa: E731
        B = lambda j: start[k + 1] + j % m2  # noqa: E731
        i = j = 0
        while i < m1 or j < m2:
            if j < m2 and (i == m1 or (j + 1) / m2 <= (i + 1) / m1):
                tris.append([A(i), B(j), B(j + 1)])
                j += 1
            else:
                tris.append([A(i), B(j), A(i + 1)])
                i += 1
    P = np.asarray(points) + c
    T = np.asarray(tris, dtype=np.int64)
    return P, _orient_up(P, T)


def rectangle_mesh(size, edge: float, *, origin=(0.0, 0.0, 0.0)):
    """A flat rectangle ``[ox, ox + lx] x [oy, oy + ly]`` at z = oz of right triangles, normal +z.

    ``max(1, round(l / edge))`` cells along each side, each split in two along
    alternating diagonals (a symmetric pattern).  Returns points (n, 3) and triangles (m, 3).
    """
    lx, ly = (float(v) for v in size)
    if not (lx > 0 and ly > 0 and np.isfinite(lx) and np.isfinite(ly)):
        raise InputError(f"rectangle size must be two lengths > 0 (m), got {size!r}")
    e = _edge(edge)
    nx, ny = max(1, int(round(lx / e))), max(1, int(round(ly / e)))
    gx, gy = np.linspace(0.0, lx, nx + 1), np.linspace(0.0, ly, ny + 1)
    P = np.array([[x, y, 0.0] for y in gy for x in gx]) + np.asarray(origin, dtype=float)
    tris = []
    for j in range(ny):
        for i in range(nx):
            a = j * (nx + 1) + i
            b, c, d = a + 1, a + nx + 2, a + nx + 1
            tris += [[a, b, c], [a, c, d]] if (i + j) % 2 == 0 else [[a, b, d], [b, c, d]]
    T = np.asarray(tris, dtype=np.int64)
    return P, _orient_up(P, T)


def _orient_up(P, T):
    n = np.cross(P[T[:, 1]] - P[T[:, 0]], P[T[:, 2]] - P[T[:, 0]])
    flip = n[:, 2] < 0
    T = T.copy()
    T[flip] = T[flip][:, ::-1]
    return T


def load_membrane_mesh(path, *, up: str = "z"):
    """Read a surface mesh file (.stl .obj .ply .vtk .vtp; open or closed, flat allowed) as a membrane.

    Coincident points are merged (STL repeats them per triangle) and unused
    points dropped; ``up`` turns the mesh about the origin so that this axis
    becomes +z (as ``[object] up`` does for solids).

    Returns
    -------
    points : (n, 3) float (m)
    triangles : (m, 3) int
    """
    from .mesh import MESH_EXTENSIONS
    from .orient import up_rotation

    path = Path(path)
    if path.is_dir():  # named as a folder, not as a bad extension
        from ..errors import missing_file

        raise missing_file(path, "mesh file")
    if path.suffix.lower() not in MESH_EXTENSIONS:
        raise InputError(f"'{path}' is not a surface mesh file; use one of {' '.join(MESH_EXTENSIONS)}")
    if not path.is_file():
        raise InputError(f"mesh file '{path}' not found; check the path")
    import pyvista as pv

    try:
        data = pv.read(str(path))
        if isinstance(data, pv.MultiBlock):
            data = data.combine()
        if not isinstance(data, pv.PolyData):
            data = data.extract_surface()
        data = data.triangulate().clean()
    except Exception as exc:  # the VTK readers raise many types
        raise InputError(f"could not read '{path}' as a membrane mesh ({type(exc).__name__}); check the file") from None
    faces = np.asarray(data.faces).reshape(-1, 4) if data.n_cells else np.zeros((0, 4), dtype=np.int64)
    if len(faces) == 0 or np.any(faces[:, 0] != 3):
        raise InputError(f"'{path}' holds no triangles; give a triangulated surface mesh")
    T = faces[:, 1:].astype(np.int64)
    P = np.asarray(data.points, dtype=float)
    used, T = np.unique(T, return_inverse=True)
    P, T = P[used], T.reshape(-1, 3)
    if not np.all(np.isfinite(P)):
        raise InputError(f"'{path}': vertex coordinates contain NaN or inf; repair the mesh")
    return P @ up_rotation(up).T, T


def open_rim(triangles) -> np.ndarray:
    """Sorted indices of the vertices on the open rim: the ends of the edges only one triangle uses."""
    T = np.asarray(triangles, dtype=np.int64)
    e = np.sort(np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]]), axis=1)
    uniq, count = np.unique(e, axis=0, return_counts=True)
    return np.unique(uniq[count == 1])


def _consistently_oriented(triangles) -> bool:
    """Every edge shared by two triangles is traversed once in each direction."""
    T = np.asarray(triangles, dtype=np.int64)
    d = np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]])
    _, n_dir = np.unique(d, axis=0, return_counts=True)
    if np.any(n_dir > 1):  # the same directed edge twice: two neighbours disagree
        return False
    return True


def footprint_image(points, triangles, voxel_size: float):
    """The voxels of size ``voxel_size`` the triangles pass through, label 1 (a :class:`LabelImage`).

    Each triangle is sampled on a barycentric grid finer than half a voxel; the
    grid spans the mesh's bounding box (at least one voxel thick, centred).
    """
    from ..image.label_image import LabelImage

    h = _edge(voxel_size)
    P = np.asarray(points, dtype=float)
    T = np.asarray(triangles, dtype=np.int64)
    lo, hi = P.min(axis=0), P.max(axis=0)
    shape = np.maximum(np.ceil((hi - lo) / h - 1e-9).astype(np.int64) + 1, 1)
    origin = lo - 0.5 * (shape * h - (hi - lo))
    idx = _sample_triangles(P, T, h) - origin
    ijk = np.clip(np.floor(idx / h).astype(np.int64), 0, shape - 1)
    labels = np.zeros(tuple(shape), dtype=np.uint8)
    labels[ijk[:, 0], ijk[:, 1], ijk[:, 2]] = 1
    return LabelImage(labels, spacing=np.full(3, h), origin=origin)


def _sample_triangles(P, T, h, *, which=False):
    """Points on every triangle, spaced below h / 2 (and the triangle of each when ``which``)."""
    a, b, c = P[T[:, 0]], P[T[:, 1]], P[T[:, 2]]
    longest = np.max([np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1), np.linalg.norm(a - c, axis=1)],
                     axis=0)
    k = int(max(1, np.ceil(longest.max() / (0.5 * h))))
    u, v = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
    keep = u + v <= k
    u, v = u[keep] / k, v[keep] / k
    pts = a[:, None] + u[None, :, None] * (b - a)[:, None] + v[None, :, None] * (c - a)[:, None]
    if which:
        return pts.reshape(-1, 3), np.repeat(np.arange(len(T)), len(u))
    return pts.reshape(-1, 3)
