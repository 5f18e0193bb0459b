"""The drawn triangles against curved obstacles: the deepest point of each triangle.

The collision points keep the drawn surface's *vertices* out of every
obstacle, which keeps every drawn triangle out of a plane (a linear distance
is smallest at a vertex).  A sphere, or a box's edge or corner, can still
poke between the vertices: a flat triangle pressed against a sphere of radius
R with its vertices outside it sags into it by up to about ``l^2 / (8 R)``
along an edge of length l, and a box's edge can cross a triangle at any depth
(measured with ``benchmarks/bench_contact_drawn.py``: 8 % of a voxel on a
sphere of two voxels' radius, 24 % of a voxel across a box's edge).

So against a sphere the contact layer collides each drawn triangle
``(x_a, x_b, x_c)`` at its *deepest point*: the point
``p = l_a x_a + l_b x_b + l_c x_c`` (barycentric ``l`` >= 0, summing to 1)
of the triangle closest to the sphere's centre (:func:`closest_on_triangles`,
the seven Voronoi regions of a triangle).  The barrier then holds
``d(p) > 0``, i.e. the whole triangle out of the sphere.  The closest point
of a triangle to a point is unique, so the distance is smooth enough for
Newton (C1, piecewise C2).

A box is not done so: its distance is flat in front of a face and along an
edge, so the deepest point of a triangle lying parallel to a face or an edge
(every voxel face on an axis-aligned box) is not unique, and the minimum over
the triangle has a kink there (a Newton solve of a box resting on a box
obstacle cycled without converging).  IPC's answer (a barrier per pair of
primitives, box corner against triangle and box edge against triangle edge,
with a mollifier for parallel edges) is left for later; the contact layer
warns instead (:class:`~voxflex.deform.layers.contact.DrawnSurfaceWarning`).

By the envelope theorem the distance's gradient with respect to the vertices
is ``l_i n`` (``n`` the obstacle's gradient at p) with ``l`` held.  Its
Hessian (:func:`distance_hessians`) must not hold ``l``: tilting a triangle
about its deepest point moves that point over it, and the distance to a
sphere of radius r falls by ``r theta^2 / 2`` (held, it would not change: a
Newton solve with that Hessian overshot along the tilts and cycled at a
relative residual of 1e-5).

Example
-------
>>> import numpy as np
>>> tri = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
>>> closest_on_triangles(np.array([[0.25, 0.25, 3.0]]), tri).round(6).tolist()
[[0.5, 0.25, 0.25]]
"""

from __future__ import annotations

import numpy as np

__all__ = ["CURVED_KINDS", "closest_on_triangles", "deepest_points", "distance_hessians"]

CURVED_KINDS = ("sphere",)
"""Obstacle kinds against which the drawn triangles collide at their deepest point (a plane's deepest point
is always a vertex; a box's and a distance field's are left to the collision points, see the module
docstring)."""


def _dot(a, b):
    return np.einsum("...i,...i->...", a, b)


def closest_on_triangles(p, tri) -> np.ndarray:
    """Barycentric coordinates (k, 3) of the point of each triangle closest to a point.

    Parameters
    ----------
    p : (k, 3) float, metres
    tri : (k, 3, 3) float, metres (vertices a, b, c of each triangle)

    Returns
    -------
    (k, 3) float: ``l`` >= 0 summing to 1, the closest point ``l @ tri``.
    """
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac = b - a, c - a
    ap, bp, cp = p - a, p - b, p - c
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    d3, d4 = _dot(ab, bp), _dot(ac, bp)
    d5, d6 = _dot(ab, cp), _dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    k = len(p)
    out = np.zeros((k, 3))
    done = np.zeros(k, dtype=bool)

    def put(mask, la, lb, lc):
        m = mask & ~done
        out[m, 0], out[m, 1], out[m, 2] = la[m], lb[m], lc[m]
        done[m] = True

    one, zero = np.ones(k), np.zeros(k)
    put((d1 <= 0) & (d2 <= 0), one, zero, zero)  # vertex a
    put((d3 >= 0) & (d4 <= d3), zero, one, zero)  # vertex b
    put((d6 >= 0) & (d5 <= d6), zero, zero, one)  # vertex c
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.clip(d1 / (d1 - d3), 0.0, 1.0)
        put((vc <= 0) & (d1 >= 0) & (d3 <= 0), 1.0 - v, v, zero)  # edge ab
        w = np.clip(d2 / (d2 - d6), 0.0, 1.0)
        put((vb <= 0) & (d2 >= 0) & (d6 <= 0), 1.0 - w, zero, w)  # edge ac
        u = np.clip((d4 - d3) / ((d4 - d3) + (d5 - d6)), 0.0, 1.0)
        put((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), zero, 1.0 - u, u)  # edge bc
        s = va + vb + vc
        s = np.where(s > 0, s, 1.0)
        lb, lc = vb / s, vc / s
    put(np.ones(k, dtype=bool), 1.0 - lb - lc, lb, lc)  # the face
    return out


def deepest_points(tri, ob, fraction: float = 0.0):
    """Barycentric coordinates of each triangle's deepest point in a sphere, and whether it crosses it.

    Parameters
    ----------
    tri : (k, 3, 3) float, metres: world vertices of the triangles
    ob : Sphere (:mod:`voxflex.deform.layers.obstacles`)
    fraction : float
        Where the obstacle's motion stands.

    Returns
    -------
    lam : (k, 3) float: ``lam @ tri`` is the triangle's point of smallest signed distance to the obstacle
    crosses : (k,) bool: the triangle meets the obstacle (its distance is <= 0)
    """
    tri = np.asarray(tri, dtype=float)
    R, t = ob.pose(fraction)
    if ob.kind == "sphere":
        centre = R @ ob.center + t
        lam = closest_on_triangles(np.broadcast_to(centre, (len(tri), 3)), tri)
        p = np.einsum("kv,kvc->kc", lam, tri)
        return lam, np.linalg.norm(p - centre, axis=1) <= ob.radius
    raise ValueError(f"deepest points are computed for {', '.join(CURVED_KINDS)}, not {ob.kind!r}")

def distance_hessians(lam, tri, g, H) -> np.ndarray:
    """Hessian (p, 9, 9) (1/m) of each triangle's smallest signed distance with respect to its 9 vertex
    coordinates (vertex-major: ``3 i + c``), the deepest point free to slide over the triangle.

    Parameters
    ----------
    lam : (p, 3) float: the deepest points' barycentric coordinates (:func:`deepest_points`)
    tri : (p, 3, 3) float, metres: the triangles' vertices
    g : (p, 3) float: the obstacle's distance gradient at the deepest points
    H : (p, 3, 3) float (1/m): its Hessian there

    Notes
    -----
    With ``mu`` the free barycentric coordinates of the feature the deepest point lies on (the face: two;
    an edge: one; a vertex: none) and ``f(mu, x)`` the distance at ``p(mu, x)``, the minimum's Hessian is
    ``f_xx - f_xmu f_mumu^+ f_mux`` with ``f_xx = L^T H L`` (``L = [l_a I, l_b I, l_c I]``),
    ``f_mumu = T^T H T`` (``T`` the feature's edge vectors), ``f_mux = T^T H L + G``, ``G`` the
    derivative of ``T^T g`` with the point held (``+-g`` on the vertices spanning each edge vector).
    A pseudo-inverse leaves out a direction along which the deepest point would not be unique (a degenerate
    triangle).
    """
    lam = np.asarray(lam, dtype=float)
    p = len(lam)
    Hxx = np.einsum("pi,pj,pab->piajb", lam, lam, H).reshape(p, 9, 9)
    active = lam > 0
    count = active.sum(axis=1)
    C = np.zeros((p, 2, 3))  # coefficients of the feature's edge vectors over the vertices
    face = count == 3
    C[face, 0] = (1.0, 0.0, -1.0)
    C[face, 1] = (0.0, 1.0, -1.0)
    edge = np.flatnonzero(count == 2)
    if len(edge):
        a = np.argmax(active[edge], axis=1)  # first active vertex
        b = 2 - np.argmax(active[edge][:, ::-1], axis=1)  # last active vertex
        C[edge, 0, a] = -1.0
        C[edge, 0, b] = 1.0
    T = np.einsum("pkv,pvc->pkc", C, tri)  # (p, 2, 3) edge vectors as rows
    TH = np.einsum("pkb,pba->pka", T, H)
    Fmm = np.einsum("pka,pla->pkl", TH, T)
    Fmx = np.einsum("pka,pi->pkia", TH, lam).reshape(p, 2, 9) + np.einsum("pki,pa->pkia", C, g).reshape(p, 2, 9)
    scale = np.abs(Fmm).max(axis=(1, 2))
    pinv = np.zeros_like(Fmm)
    ok = scale > 0
    if np.any(ok):
        pinv[ok] = np.linalg.pinv(Fmm[ok], rcond=1e-10)
    return Hxx - np.einsum("pki,pkl,plj->pij", Fmx, pinv, Fmx)
