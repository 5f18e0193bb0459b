"""Generalized winding number of a triangle soup: a robust inside test.

The winding number of a closed, outward-oriented surface at a point p is the
signed solid angle it subtends, divided by 4 pi: 1 inside, 0 outside.  For
surfaces with holes, duplicated seam vertices or a few flipped triangles it
varies smoothly and still separates inside (w near 1) from outside (w near 0),
so ``w > 0.5`` is a sensible inside test (Jacobson et al. 2013).  A fully
inverted (inward-oriented) surface gives w = -1 inside; voxflex classifies
``|w| > 0.5`` as inside, so inverted meshes and inverted components voxelize
like correctly oriented ones.

Two evaluators:

* :func:`winding_number_brute` -- the exact sum over all triangles of the
  van Oosterom-Strackee solid angle, in plain numpy; O(points x triangles).
  The reference used by the tests.
* :func:`winding_number` with ``method="fast"`` -- the hierarchical fast
  winding number (Barill et al. 2018): a balanced binary tree over the
  triangles sorted along a Morton (Z-order) curve; a cluster whose bounding
  radius r is small compared with its distance d to the query point
  (d > beta r) is replaced by its expansion about its area-weighted centroid:
  the dipole term (area-weighted normal) plus the first-order term (the
  normal-position moment), truncation error O((r/d)^2) of the cluster's
  contribution; near clusters are opened down to exact leaf sums.

References
----------
A. Jacobson, L. Kavan, O. Sorkine-Hornung, "Robust inside-outside
segmentation using generalized winding numbers", ACM TOG 32(4), 2013.
G. Barill, N. Dickson, R. Schmidt, D. Levin, A. Jacobson, "Fast winding
numbers for soups and clouds", ACM TOG 37(4), 2018.
A. van Oosterom, J. Strackee, "The solid angle of a plane triangle",
IEEE Trans. Biomed. Eng. 30(2), 1983.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._jit import njit, prange
from ..errors import InputError, check_choice

FOUR_PI = 4.0 * math.pi
LEAF_SIZE = 8  # triangles per leaf (at most 2x this after balanced splitting)


# -- brute force (numpy twin) ------------------------------------------------
def winding_number_brute(vertices, faces, points, *, chunk: int = 2_000_000) -> np.ndarray:
    """Exact generalized winding number (n,) of ``points`` (n, 3), plain numpy.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
        Triangles, counter-clockwise seen from outside for w = +1 inside.
    points : (n, 3) float
    chunk : int
        Work-array budget (points x triangles per block).
    """
    tri = np.asarray(vertices, dtype=float)[np.asarray(faces, dtype=np.int64)]  # (F, 3, 3)
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    out = np.empty(len(points))
    step = max(1, chunk // max(1, len(tri)))
    for s in range(0, len(points), step):
        p = points[s : s + step, None, None, :]  # (m, 1, 1, 3)
        d = tri[None] - p  # (m, F, 3, 3)
        a, b, c = d[:, :, 0], d[:, :, 1], d[:, :, 2]
        la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
        det = np.einsum("mfi,mfi->mf", a, np.cross(b, c))
        den = (
            la * lb * lc
            + np.einsum("mfi,mfi->mf", a, b) * lc
            + np.einsum("mfi,mfi->mf", b, c) * la
            + np.einsum("mfi,mfi->mf", c, a) * lb
        )
        out[s : s + step] = (2.0 * np.arctan2(det, den)).sum(axis=1) / FOUR_PI
    return out


# -- tree ----------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class WindingTree:
    """Balanced binary tree over triangles (heap layout: children of k are 2k+1, 2k+2).

    Attributes
    ----------
    tri : (F, 3, 3) float
        Triangle corners, in tree order.
    start, stop : (K,) int
        Triangle range of each node.
    centre : (K, 3) float
        Area-weighted centroid of each node's triangles.
    normal : (K, 3) float
        Sum of area-weighted normals (half cross products), m^2.
    moment : (K, 3, 3) float
        sum_t a_t n_t (x_t - centre)^T, m^3 (first-order term).
    radius : (K,) float
        Largest distance from ``centre`` to a corner of the node's triangles.
    n_internal : int
        Nodes 0 .. n_internal-1 have children; the others are leaves.
    """

    tri: np.ndarray
    start: np.ndarray
    stop: np.ndarray
    centre: np.ndarray
    normal: np.ndarray
    moment: np.ndarray
    radius: np.ndarray
    n_internal: int


def _morton_order(points: np.ndarray) -> np.ndarray:
    lo, hi = points.min(axis=0), points.max(axis=0)
    q = ((points - lo) / np.maximum(hi - lo, 1e-300) * 1023.0).astype(np.uint64)
    code = np.zeros(len(points), dtype=np.uint64)
    for bit in range(10):
        for a in range(3):
            code |= ((q[:, a] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + a)
    return np.argsort(code, kind="stable")


def build_tree(vertices, faces, *, leaf_size: int = LEAF_SIZE) -> WindingTree:
    """Build the :class:`WindingTree` of a triangle soup (vectorized, level by level)."""
    tri = np.asarray(vertices, dtype=float)[np.asarray(faces, dtype=np.int64)]
    n_tri = len(tri)
    centroid = tri.mean(axis=1)
    order = _morton_order(centroid)
    tri, centroid = np.ascontiguousarray(tri[order]), centroid[order]
    an = 0.5 * np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # area-weighted normals
    area = np.linalg.norm(an, axis=1)
    depth = max(0, int(math.ceil(math.log2(max(n_tri / leaf_size, 1.0)))))
    while depth > 0 and (n_tri >> depth) < 1:
        depth -= 1
    n_nodes = 2 ** (depth + 1) - 1
    start = np.empty(n_nodes, dtype=np.int64)
    stop = np.empty(n_nodes, dtype=np.int64)
    centre = np.empty((n_nodes, 3))
    normal = np.empty((n_nodes, 3))
    moment = np.empty((n_nodes, 3, 3))
    radius = np.empty(n_nodes)
    tri_mom = np.einsum("ti,tj->tij", an, centroid)  # a n x^T per triangle
    weight = area + 1e-300  # degenerate clusters fall back to the plain mean
    for level in range(depth + 1):
        count = 2**level
        first = count - 1
        bounds = (np.arange(count + 1, dtype=np.int64) * n_tri) // count
        s, e = bounds[:-1], bounds[1:]
        w = np.add.reduceat(weight, s)
        c = np.add.reduceat(weight[:, None] * centroid, s) / w[:, None]
        n = np.add.reduceat(an, s)
        m = np.add.reduceat(tri_mom, s) - np.einsum("ki,kj->kij", n, c)
        owner = np.repeat(np.arange(count), e - s)
        far = np.linalg.norm(tri - c[owner][:, None, :], axis=2).max(axis=1)
        r = np.maximum.reduceat(far, s)
        sl = slice(first, first + count)
        start[sl], stop[sl], centre[sl], normal[sl], moment[sl], radius[sl] = s, e, c, n, m, r
    return WindingTree(tri, start, stop, centre, normal, moment, radius, 2**depth - 1)


# -- compiled evaluation ---------------------------------------------------------
@njit(parallel=True)
def _fast_winding_kernel(points, tri, start, stop, centre, normal, moment, radius, n_internal, beta, out):
    n = points.shape[0]
    block = 256
    n_blocks = (n + block - 1) // block
    four_pi = 4.0 * np.pi
    for b in prange(n_blocks):
        stack = np.empty(128, dtype=np.int64)
        for q in range(b * block, min(n, (b + 1) * block)):
            px, py, pz = points[q, 0], points[q, 1], points[q, 2]
            total = 0.0
            top = 1
            stack[0] = 0
            while top > 0:
                top -= 1
                k = stack[top]
                yx = centre[k, 0] - px
                yy = centre[k, 1] - py
                yz = centre[k, 2] - pz
                d2 = yx * yx + yy * yy + yz * yz
                rb = beta * radius[k]
                if d2 > rb * rb:
                    # far cluster: integrand n.K(y), K(y) = y/|y|^3, expanded about the centroid
                    inv = 1.0 / math.sqrt(d2)
                    inv3 = inv * inv * inv
                    val = (normal[k, 0] * yx + normal[k, 1] * yy + normal[k, 2] * yz) * inv3
                    m = moment[k]
                    tr = m[0, 0] + m[1, 1] + m[2, 2]
                    ymy = (
                        yx * (m[0, 0] * yx + m[0, 1] * yy + m[0, 2] * yz)
                        + yy * (m[1, 0] * yx + m[1, 1] * yy + m[1, 2] * yz)
                        + yz * (m[2, 0] * yx + m[2, 1] * yy + m[2, 2] * yz)
                    )
                    val += tr * inv3 - 3.0 * ymy * inv3 * inv * inv
                    total += val
                elif k >= n_internal:
                    for t in range(start[k], stop[k]):
                        ax = tri[t, 0, 0] - px
                        ay = tri[t, 0, 1] - py
                        az = tri[t, 0, 2] - pz
                        bx = tri[t, 1, 0] - px
                        by = tri[t, 1, 1] - py
                        bz = tri[t, 1, 2] - pz
                        cx = tri[t, 2, 0] - px
                        cy = tri[t, 2, 1] - py
                        cz = tri[t, 2, 2] - pz
                        la = math.sqrt(ax * ax + ay * ay + az * az)
                        lb = math.sqrt(bx * bx + by * by + bz * bz)
                        lc = math.sqrt(cx * cx + cy * cy + cz * cz)
                        det = ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)
                        den = (
                            la * lb * lc
                            + (ax * bx + ay * by + az * bz) * lc
                            + (bx * cx + by * cy + bz * cz) * la
                            + (cx * ax + cy * ay + cz * az) * lb
                        )
                        total += 2.0 * math.atan2(det, den)
                else:
                    stack[top] = 2 * k + 1
                    stack[top + 1] = 2 * k + 2
                    top += 2
            out[q] = total / four_pi


@njit(parallel=True)
def _crossing_fraction_kernel(centres, w_centre, ijk, offsets, keys, row_ptr, tri_ids, tri, dims, out):
    """Inside fraction of sub-points near each centre: w(sub) = w(centre) + signed crossings of [centre, sub].

    ``keys`` (sorted flat voxel ids) / ``row_ptr`` / ``tri_ids`` list the triangles
    sampled in each voxel; the triangles that can cross a segment inside voxel q
    are those listed in q's 27 neighbours.  Crossing an outward-oriented
    triangle against its normal raises w by one.
    """
    m = centres.shape[0]
    n_sub = offsets.shape[0]
    n_tri = tri.shape[0]
    block = 256
    n_blocks = (m + block - 1) // block
    for b in prange(n_blocks):
        stamp = np.full(n_tri, -1, dtype=np.int64)
        local = np.empty(n_tri, dtype=np.int64)
        for q in range(b * block, min(m, (b + 1) * block)):
            count = 0
            for di in range(-1, 2):
                i = ijk[q, 0] + di
                if i < 0 or i >= dims[0]:
                    continue
                for dj in range(-1, 2):
                    j = ijk[q, 1] + dj
                    if j < 0 or j >= dims[1]:
                        continue
                    for dk in range(-1, 2):
                        k = ijk[q, 2] + dk
                        if k < 0 or k >= dims[2]:
                            continue
                        key = (i * dims[1] + j) * dims[2] + k
                        row = np.searchsorted(keys, key)
                        if row >= keys.shape[0] or keys[row] != key:
                            continue
                        for r in range(row_ptr[row], row_ptr[row + 1]):
                            t = tri_ids[r]
                            if stamp[t] != q:
                                stamp[t] = q
                                local[count] = t
                                count += 1
            ax, ay, az = centres[q, 0], centres[q, 1], centres[q, 2]
            inside = 0
            for s in range(n_sub):
                dx, dy, dz = offsets[s, 0], offsets[s, 1], offsets[s, 2]
                w = w_centre[q]
                for c in range(count):
                    t = local[c]
                    e1x = tri[t, 1, 0] - tri[t, 0, 0]
                    e1y = tri[t, 1, 1] - tri[t, 0, 1]
                    e1z = tri[t, 1, 2] - tri[t, 0, 2]
                    e2x = tri[t, 2, 0] - tri[t, 0, 0]
                    e2y = tri[t, 2, 1] - tri[t, 0, 1]
                    e2z = tri[t, 2, 2] - tri[t, 0, 2]
                    px = dy * e2z - dz * e2y
                    py = dz * e2x - dx * e2z
                    pz = dx * e2y - dy * e2x
                    det = e1x * px + e1y * py + e1z * pz  # = -d . (e1 x e2)
                    if det == 0.0:
                        continue
                    inv = 1.0 / det
                    tx = ax - tri[t, 0, 0]
                    ty = ay - tri[t, 0, 1]
                    tz = az - tri[t, 0, 2]
                    u = (tx * px + ty * py + tz * pz) * inv
                    if u < 0.0 or u > 1.0:
                        continue
                    qx = ty * e1z - tz * e1y
                    qy = tz * e1x - tx * e1z
                    qz = tx * e1y - ty * e1x
                    v = (dx * qx + dy * qy + dz * qz) * inv
                    if v < 0.0 or u + v > 1.0:
                        continue
                    tt = (e2x * qx + e2y * qy + e2z * qz) * inv
                    if tt < 0.0 or tt > 1.0:
                        continue
                    w += 1.0 if det > 0.0 else -1.0
                if abs(w) > 0.5:
                    inside += 1
            out[q] = inside / n_sub


def _fast_impl(tree: WindingTree, points: np.ndarray, beta: float, out: np.ndarray | None = None) -> np.ndarray:
    if out is None:
        out = np.empty(len(points))
    if len(points):
        _fast_winding_kernel(
            np.ascontiguousarray(points, dtype=np.float64),
            tree.tri,
            tree.start,
            tree.stop,
            tree.centre,
            tree.normal,
            tree.moment,
            tree.radius,
            tree.n_internal,
            float(beta),
            out,
        )
    return out


def winding_number(vertices, faces, points, *, method: str = "fast", beta: float = 2.0, tree=None) -> np.ndarray:
    """Generalized winding number (n,) of ``points`` (n, 3) with respect to a triangle soup.

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int
    points : (n, 3) float, metres
    method : {"fast", "brute"}
        ``"fast"``: hierarchical evaluation (Barill et al. 2018), O(log F) per
        point; ``"brute"``: exact O(F) sum per point (numpy).
    beta : float
        Accuracy of the fast method: a cluster of radius r is approximated when
        farther than ``beta * r`` (>= 1; larger is more accurate and slower).
    tree : WindingTree, optional
        A tree from :func:`build_tree` to reuse over several calls.

    Returns
    -------
    (n,) float
        ~1 inside and ~0 outside an outward-oriented closed surface (-1 inside an inverted one).

    Examples
    --------
    >>> import numpy as np
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    >>> f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    >>> np.round(winding_number(v, f, [[0.1, 0.1, 0.1], [2, 2, 2]]), 6)
    array([1., 0.])
    """
    check_choice("winding method", method, ("fast", "brute"))
    vertices = np.asarray(vertices, dtype=float)
    faces = np.asarray(faces)
    points = np.asarray(points, dtype=float)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise InputError(f"vertices must have shape (V, 3), got {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
        raise InputError(f"faces must be an integer array of shape (F, 3), got {faces.shape} {faces.dtype}")
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(f"points must have shape (n, 3), got {points.shape}")
    if len(faces) and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise InputError("faces refer to vertices that do not exist; fix the mesh's face indices")
    if not (math.isfinite(beta) and beta >= 1.0):
        raise InputError(f"beta must be >= 1, got {beta}")
    if method == "brute":
        return winding_number_brute(vertices, faces, points)
    if len(faces) == 0:
        return np.zeros(len(points))
    if tree is None:
        tree = build_tree(vertices, faces)
    return _fast_impl(tree, points, beta)
