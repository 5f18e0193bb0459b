"""Checks of a contact scene before solving: obstacles the collision points cannot see.

The collision layer (:mod:`voxflex.deform.layers.contact`) sees an obstacle
only through its collision points (and, against spheres, the drawn triangles'
deepest points, :mod:`voxflex.deform.layers.drawn`).  Three ways that can
miss an obstacle are checked when the layer is built:

* an obstacle inside the material at rest (every collision point is on the
  surface, so it never acts): refused (:func:`check_overlap`);
* an obstacle smaller than the gaps between the collision points, which can
  pass between them: a :class:`ContactWarning` naming the obstacle, its size,
  the gap and a voxel size that closes it (:func:`warn_small_obstacles`);
* what the collision points do not keep out of the drawn surface (a box's or
  a distance field's edges and corners between the vertices; any obstacle
  with other point rules) is measured at every accepted step instead
  (:func:`drawn_depth`, :func:`kept_out`), and a run whose drawn triangles
  went deeper than :data:`DRAWN_TOLERANCE` of a voxel into an obstacle ends
  with a :class:`ContactWarning` naming the depth
  (:mod:`voxflex.simulation`);
* an obstacle that passed wholly into the body within one step (tunnelling:
  the barrier judges the states a step reaches, not the path between them) is
  found at every accepted step by the winding number of the drawn surface at
  the obstacle's centre (:func:`tunnelled`) and named after the run.

Every threshold is a ratio of lengths (the obstacle's size to the gap), so
the same scene gets the same verdict in any unit.
"""

from __future__ import annotations

import warnings

import numpy as np

from ...errors import InputError
from .drawn import CURVED_KINDS

__all__ = ["ContactWarning", "check_overlap", "collision_gap", "obstacle_size", "warn_small_obstacles",
           "drawn_depth", "kept_out", "DRAWN_TOLERANCE", "tunnelled"]

DRAWN_TOLERANCE = 1e-3
"""Depth of the drawn surface in an obstacle, as a fraction of the voxel size, above which a run ends with a
:class:`ContactWarning` (the issue's drop test allows 0.1 % of a voxel).  Measured where the collision points do
not keep the triangles out: a box's edge entered them by 24-25 % of a voxel where a slab drapes over it
(``benchmarks/bench_contact_drawn.py``, scene ``edge``), while the points stayed 0.6 % out."""


class ContactWarning(UserWarning):
    """A contact scene whose obstacles the collision points may not see (see the module docstring)."""


def check_overlap(inner, obstacles, chunk: int = 1 << 16) -> None:
    """InputError when an obstacle lies in the material at rest.  The collision points are on the surface,
    so an obstacle wholly inside the body (a sphere in a beam) touched none of them: it was accepted and never
    acted (contact force 0, exit 0).  Judged on the material voxels' centres, where the model has an image."""
    image = getattr(inner, "image", None)
    if image is None or not hasattr(image, "voxel_centers"):
        return
    X = image.voxel_centers()
    for o, ob in enumerate(obstacles):
        inside = 0
        first = None
        for a in range(0, len(X), chunk):
            d = ob.signed_distance(X[a:a + chunk], 0.0)[0]
            hit = np.flatnonzero(d <= 0)
            inside += len(hit)
            if first is None and len(hit):
                first = X[a + hit[0]]
        if inside:
            raise InputError(f"obstacle {o} ({ob.kind}) lies in the material at rest: {inside} of {len(X)} voxel "
                             f"centres are inside it (the first at {np.round(first, 6).tolist()}); an obstacle "
                             "must start outside the object: move it or the object apart")


def collision_gap(inner, points, *, triangles: int = 400, subdivisions: int = 8) -> float:
    """The largest distance (m) from a point of the drawn rest surface to its nearest collision point.

    Parameters
    ----------
    inner : Model
        The model (its :meth:`boundary_surface`).
    points : (m, 3) float, metres
        The collision points at rest.
    triangles : int
        At most this many drawn triangles, evenly spread over the surface, are sampled (the voxel
        surface repeats the same few faces).
    subdivisions : int
        Each sampled triangle is sampled on a barycentric grid of this many subdivisions per edge.

    Returns
    -------
    float, metres: the radius of the widest disc of the surface with no collision point (0 without a surface)
    """
    from scipy.spatial import cKDTree

    V, faces, _ = inner.boundary_surface()
    V = np.asarray(V, dtype=float)
    faces = np.asarray(faces)
    if len(faces) == 0 or len(points) == 0:
        return 0.0
    pick = faces[np.unique(np.linspace(0, len(faces) - 1, min(triangles, len(faces))).astype(np.int64))]
    n = subdivisions
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = i + j <= n
    lam = np.stack([i[keep], j[keep], n - i[keep] - j[keep]], axis=1) / n
    samples = np.einsum("sv,fvc->fsc", lam, V[pick]).reshape(-1, 3)
    return float(cKDTree(points).query(samples)[0].max())


def obstacle_size(ob):
    """(what, size in metres) of an obstacle that could pass through a round gap of that radius, or None:
    a sphere's radius; a box's smallest cross-section's half diagonal (planes and distance fields: None)."""
    if ob.kind == "sphere":
        return "radius", float(ob.radius)
    if ob.kind == "box":
        lo, mid = np.sort(ob.max - ob.min)[:2]
        return "smallest cross-section's half diagonal", float(0.5 * np.hypot(lo, mid))
    return None


def warn_small_obstacles(inner, obstacles, points, drawn: bool) -> None:
    """:class:`ContactWarning` for each sphere or box obstacle that fits through the gaps between the collision
    points at rest (its size at most :func:`collision_gap`).  ``drawn``: the drawn triangles collide with
    spheres (the default points), which then cannot pass between the points."""
    sized = [(o, ob, obstacle_size(ob)) for o, ob in enumerate(obstacles)]
    sized = [(o, ob, s) for o, ob, s in sized if s is not None and not (drawn and ob.kind in CURVED_KINDS)]
    if not sized:
        return
    gap = collision_gap(inner, points)
    image = getattr(inner, "image", None)
    h = float(np.min(image.spacing)) if image is not None else None
    for o, ob, (what, size) in sized:
        if size > gap:
            continue
        across = f" ({gap / h:.2f} voxel)" if h else ""
        fix = f"voxel_size below {h * size / gap:.3g} m" if h else "finer collision points"
        warnings.warn(f"obstacle {o} ({ob.kind}, {what} {size:.3g} m) fits through the gaps between the collision "
                      f"points (up to {gap:.3g} m{across} from the nearest): it can pass between them undetected; "
                      f"use {fix}, or a larger obstacle", ContactWarning, stacklevel=4)


def kept_out(rule) -> tuple[str, ...]:
    """The obstacle kinds the collision points of ``rule`` keep out of every drawn triangle: planes (the
    triangles' vertices are collision points with ``"surface"`` and ``"vertices"``) and spheres (the triangles'
    deepest points collide with ``"surface"``, :mod:`voxflex.deform.layers.drawn`); none for Gauss points only
    (an integer) or explicit points."""
    if isinstance(rule, str) and rule == "surface":
        return ("plane", "sphere")
    if isinstance(rule, str) and rule == "vertices":
        return ("plane",)
    return ()


def _box_distance(ob, x, fraction):
    """Signed distance (m,) of world points to a box obstacle, without its gradient and Hessian."""
    R, t = ob.pose(fraction)
    y = (np.asarray(x, dtype=float) - t) @ R
    q = np.abs(y - 0.5 * (ob.min + ob.max)) - 0.5 * (ob.max - ob.min)
    return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)


def _box_separated(ob, V, faces, fraction):
    """(F,) bool: triangles with all three vertices beyond one face plane of a box obstacle, which therefore
    cannot meet it (the box is convex: that plane separates them)."""
    R, t = ob.pose(fraction)
    y = (V - t) @ R  # the vertices in the box's frame
    # one bit per face plane a vertex lies beyond (Cohen-Sutherland outcodes): a triangle whose three codes
    # share a bit lies beyond that plane
    code = np.zeros(len(y), dtype=np.uint8)
    for a in range(3):
        code |= (y[:, a] < ob.min[a]).astype(np.uint8) << np.uint8(2 * a)
        code |= (y[:, a] > ob.max[a]).astype(np.uint8) << np.uint8(2 * a + 1)
    return (code[faces[:, 0]] & code[faces[:, 1]] & code[faces[:, 2]]) != 0


def drawn_depth(obstacles, V, faces, fraction: float, skip=(), *, subdivisions: int = 8):
    """How deep the drawn triangles reach into the obstacles whose kind is not in ``skip``.

    Parameters
    ----------
    obstacles : sequence of Obstacle
    V : (nv, 3) float, metres
        The drawn surface's vertices in the state measured.
    faces : (F, 3) int
        Its triangles.
    fraction : float
        The load fraction of the state (where moving obstacles are).
    skip : iterable of str
        Obstacle kinds not measured (:func:`kept_out`: the barrier keeps them out).
    subdivisions : int
        Each triangle that may reach an obstacle is sampled on a barycentric grid of this many subdivisions per
        edge (45 points at 8): the depth found is the deepest of those points, a lower bound of the triangle's
        own, within an eighth of its size.  May reach: against a box, no face plane has all three vertices
        beyond it (else that plane separates them: a body resting on a box's face samples nothing); against a
        distance field, a vertex within the triangle's longest edge of it (the distance is 1-Lipschitz).

    Returns
    -------
    (depth, obstacle) : depth in metres (>= 0; 0 when nothing drawn is inside) and the obstacle's index (-1)
    """
    worst, which = 0.0, -1
    measured = [(o, ob) for o, ob in enumerate(obstacles) if ob.kind not in skip]
    faces = np.asarray(faces, dtype=np.int64)
    if not measured or len(faces) == 0:
        return worst, which
    V = np.asarray(V, dtype=float)
    tri = None
    n = int(subdivisions)
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = i + j <= n
    lam = np.stack([i[keep], j[keep], n - i[keep] - j[keep]], axis=1) / n
    longest = None
    for o, ob in measured:
        if ob.kind == "box":
            near = np.flatnonzero(~_box_separated(ob, V, faces, fraction))
            distance = (lambda x, ob=ob: _box_distance(ob, x, fraction))
        else:
            if longest is None:
                tri = V[faces]
                longest = np.max(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2), axis=1)
            dv = ob.signed_distance(V, fraction)[0]
            near = np.flatnonzero(dv[faces].min(axis=1) < longest)
            distance = (lambda x, ob=ob: ob.signed_distance(x, fraction)[0])
        if len(near) == 0:
            continue
        pts = np.einsum("sv,fvc->fsc", lam, V[faces[near]]).reshape(-1, 3)
        depth = -float(distance(pts).min())
        if depth > worst:
            worst, which = depth, o
    return worst, which


def tunnelled(obstacles, V, faces, fraction: float) -> list[int]:
    """The spheres and boxes whose centre lies inside the drawn surface (V, faces) at ``fraction``.

    The barrier keeps every collision point (and, against spheres, every drawn triangle) out of the obstacles
    in the states a step reaches, not on the path between them: a sphere or box reached, or moving, by more
    than its size in one step can end wholly inside the body, touching nothing, and act no more.  Its centre is
    then inside the body's surface: the generalized winding number there is about 1 (0 outside; judged at
    0.5, a ratio, the same at any unit).  Planes cannot pass (a body wholly behind one has every point inside
    it); distance fields are not judged (no centre).

    Returns
    -------
    list of obstacle indices (empty when none tunnelled)
    """
    from ...rasterize.winding import winding_number_brute

    which, centres = [], []
    for o, ob in enumerate(obstacles):
        if ob.kind == "sphere":
            c = np.asarray(ob.center, dtype=float)
        elif ob.kind == "box":
            c = 0.5 * (np.asarray(ob.min, dtype=float) + np.asarray(ob.max, dtype=float))
        else:
            continue
        R, t = ob.pose(fraction)
        which.append(o)
        centres.append(R @ c + t)
    if not which or len(faces) == 0:
        return []
    V = np.asarray(V, dtype=float)
    centres = np.array(centres)
    # only a centre within the surface's bounding box can be inside (the winding number costs a pass over every
    # triangle: a few ms on a large surface, which a dynamic run pays at every step)
    box = np.all((centres >= V.min(axis=0)) & (centres <= V.max(axis=0)), axis=1)
    if not box.any():
        return []
    w = winding_number_brute(V, np.asarray(faces, dtype=np.int64), centres[box])
    return [o for o, wi in zip(np.asarray(which)[box].tolist(), w) if wi > 0.5]
