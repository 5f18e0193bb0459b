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
* a box or distance-field obstacle with the default points: its edges and
  corners can cross the drawn triangles between their vertices, which the
  points keep out (:func:`warn_drawn_surface`).

Every threshold is a ratio of lengths (the obstacle's size to the gap), so
the same scene gets the same verdict in any unit.
"""

from __future__ import annotations

import warnings

import numpy as np

from ...errors import InputError
from .drawn import CURVED_KINDS

__all__ = ["ContactWarning", "check_overlap", "collision_gap", "obstacle_size", "warn_small_obstacles",
           "warn_drawn_surface", "BOX_EDGE_DEPTH"]

BOX_EDGE_DEPTH = 0.25
"""How deep a box obstacle's edge went into the drawn triangles, as a fraction of the voxel size, with the
default points (``benchmarks/bench_contact_drawn.py``, scene ``edge``: a 4 x 4 x 2-voxel slab draped over a
box's edge, 0.24 with voxels and 0.25 with 10 affine frames); the collision points stayed 0.6 % of a voxel out."""


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


def warn_drawn_surface(obstacles) -> None:
    """:class:`ContactWarning` for each box or distance-field obstacle: with the default points the drawn
    surface's vertices stay out of it, but its edges and corners can cross the triangles between them."""
    for o, ob in enumerate(obstacles):
        if ob.kind not in ("box", "sdf"):
            continue
        warnings.warn(f"obstacle {o} ({ob.kind}): its edges and corners can cross the drawn triangles between their "
                      f"vertices (measured: {BOX_EDGE_DEPTH:.0%} of a voxel deep where the surface drapes over a "
                      "box's edge; the collision points stay out); the drawn surface is kept out of planes and "
                      "spheres only: use those where they fit, or a finer voxel_size (the depth scales with it)",
                      ContactWarning, stacklevel=4)
