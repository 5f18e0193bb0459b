"""The drawn triangles against curved obstacles, and obstacles the collision points cannot see (issue 27).

Oracles: brute-force sampling of triangles (the closest point to a sphere's
centre), central differences of the barrier energy with the triangles' terms
active (the exact Hessian lets the deepest point slide), and the gap between
the collision points of a voxel face computed by hand (the default rule's
widest empty disc is centred on the face: 0.289 sqrt(2) = 0.408 of a voxel
from its Gauss points).
"""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest

from voxflex.deform.layers.contact import ContactModel
from voxflex.deform.layers.contact_checks import ContactWarning, collision_gap
from voxflex.deform.layers.drawn import closest_on_triangles
from voxflex.deform.layers.obstacles import Box, Plane, Sphere
from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.errors import InputError
from voxflex.image.label_image import LabelImage


def _slab(h=0.25, shape=(4, 4, 2)):
    return VoxelModel.from_image(LabelImage(np.ones(shape), spacing=(h,) * 3),
                                 {1: material("neo-hookean", young=1e5, poisson=0.3)})


def _sampled_min(tri, centre, n=60):
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = i + j <= n
    lam = np.stack([i[keep], j[keep], n - i[keep] - j[keep]], axis=1) / n
    return np.linalg.norm(np.einsum("sv,kvc->ksc", lam, tri) - centre[:, None, :], axis=2).min(axis=1)



def _central_differences(model, q, rng, *, h, rel_gradient, rel_hessian):
    """The model's gradient and exact Hessian at q against central differences of its energy and gradient
    along a random direction (truncation O(h^2), round-off O(eps / h) of the energy's size)."""
    E, g, H = model.energy_gradient_hessian(q, exact=True)
    v = rng.standard_normal(q.shape)
    Ep, gp, _ = model.energy_gradient_hessian(q + h * v, hessian=False)
    Em, gm, _ = model.energy_gradient_hessian(q - h * v, hessian=False)
    assert (Ep - Em) / (2 * h) == pytest.approx(np.sum(g * v), rel=rel_gradient)
    Hv = H @ v.ravel()
    assert np.linalg.norm((gp - gm).ravel() / (2 * h) - Hv) < rel_hessian * np.linalg.norm(Hv)

def test_closest_point_on_triangles_against_sampling():
    """Every Voronoi region of a triangle (3 vertices, 3 edges, the face) is hit by 2000 random pairs; the
    closest point is never farther than the best of 1891 samples, and within their spacing of it."""
    rng = np.random.default_rng(7)
    tri = rng.uniform(-1, 1, (2000, 3, 3))
    p = rng.uniform(-2, 2, (2000, 3))
    lam = closest_on_triangles(p, tri)
    assert np.all(lam >= 0) and np.allclose(lam.sum(axis=1), 1.0)
    d = np.linalg.norm(np.einsum("kv,kvc->kc", lam, tri) - p, axis=1)
    sampled = _sampled_min(tri, p)
    assert np.all(d <= sampled + 1e-12)
    assert np.all(sampled - d < 0.1)
    regions = {tuple(row) for row in (lam > 0).astype(int)}
    assert len(regions) == 7  # 3 vertices, 3 edges, the face


def test_triangle_terms_derivatives_by_central_differences():
    """A slab just above a sphere of two voxels' radius, perturbed: the barrier's gradient is the derivative
    of its energy, and its exact Hessian (the deepest points sliding) that of the gradient.  Holding the deepest
    points in the Hessian was 2.6 % off here, and Newton cycled along the triangles' tilts."""
    inner = _slab()
    model = ContactModel(inner, [Sphere(center=(0.5, 0.5, -0.502), radius=0.5)], distance=0.01)
    rng = np.random.default_rng(1)
    q = inner.rest + 0.0005 * rng.standard_normal(inner.rest.shape)
    assert len(model._triangle_pairs(model.mapping.apply(q))[0]) >= 4
    _central_differences(model, q, rng, h=1e-7, rel_gradient=1e-7, rel_hessian=1e-6)


def test_a_sphere_between_the_vertices_is_seen_by_the_drawn_triangles():
    """A sphere of 0.3 voxel's radius touching the middle of a voxel face from below, 0.4 % of a voxel away:
    every collision point (the face's Gauss points are 0.41 voxel from its centre, its corners 0.71) is
    beyond the barrier's range, so the points alone felt nothing; the drawn triangles' deepest point is
    within it (0.001 m from the sphere) and pushes back.  Moved up into the face, the state is not admissible."""
    inner = _slab()
    h = 0.25
    ob = Sphere(center=(0.375, 0.375, -0.3 * h - 0.001), radius=0.3 * h)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model = ContactModel(inner, [ob])  # no warning: the drawn triangles see it
    with pytest.warns(ContactWarning, match="fits through the gaps between the collision points"):
        points_only = ContactModel(inner, [ob], points=2)
    assert np.all(points_only.contact_forces(inner.rest) == 0.0)
    pairs = model._triangle_pairs(model.mapping.apply(inner.rest))
    assert len(pairs[0]) >= 1 and pairs[3].min() == pytest.approx(0.001, rel=1e-9)
    assert model.contact_forces(inner.rest)[0, 2] > 0.0  # the sphere below pushes the body up
    up = inner.rest.copy()
    up[:, 2] -= 0.002
    assert points_only.admissible(up) and not model.admissible(up)


def test_a_sphere_crossing_the_drawn_surface_at_rest_is_refused():
    inner = _slab()
    ob = Sphere(center=(0.375, 0.375, -0.05), radius=0.06)  # pokes 0.01 m into the face, between its points
    with pytest.raises(InputError, match=r"the drawn surface at rest crosses obstacle 0 \(sphere\) between its "
                                         r"vertices .* move the obstacle or the object apart"):
        ContactModel(inner, [ob])


def test_the_default_gap_is_the_face_centre_to_its_gauss_points():
    inner = _slab()
    model = ContactModel(inner, [Plane(point=(0, 0, -0.01))])
    assert collision_gap(inner, model.points) == pytest.approx(0.25 * np.sqrt(2) / (2 * np.sqrt(3)), rel=1e-12)
    vertices = ContactModel(inner, [Plane(point=(0, 0, -0.01))], points="vertices")
    assert collision_gap(inner, vertices.points) == pytest.approx(0.25 / np.sqrt(2), rel=1e-12)


SMALL = [
    (Box, dict(min=(0.30, 0.30, -0.11), max=(0.42, 0.42, -0.01)), "surface",
     r"obstacle 0 \(box, smallest cross-section's half diagonal 0\.0781 m\) fits through the gaps between the "
     r"collision points \(up to 0\.102 m \(0\.41 voxel\) from the nearest\): it can pass between them undetected; "
     r"use voxel_size below 0\.191 m, or a larger obstacle"),
    (Sphere, dict(center=(0.375, 0.375, -0.16), radius=0.15), "vertices",
     r"obstacle 0 \(sphere, radius 0\.15 m\) fits through the gaps .* \(0\.71 voxel\) .* voxel_size below 0\.212 m"),
]


@pytest.mark.parametrize("kind, params, points, message", SMALL, ids=["box", "sphere-vertices"])
@pytest.mark.parametrize("unit", [1e-6, 1e-2, 1.0, 1e3], ids=["1um", "1cm", "1m", "1km"])
def test_an_obstacle_smaller_than_the_gaps_is_named_at_every_scale(kind, params, points, message, unit):
    """The same scene in µm, cm, m and km gets the same warning (the threshold is the obstacle's size over
    the gap); the message's lengths are the scene's own, so they are checked in metres only."""
    inner = _slab(h=0.25 * unit)
    scaled = {k: tuple(unit * np.asarray(v)) if isinstance(v, tuple) else unit * v for k, v in params.items()}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ContactModel(inner, [kind(**scaled)], points=points)
    small = [str(w.message) for w in caught if "fits through the gaps" in str(w.message)]
    assert len(small) == 1, [str(w.message) for w in caught]
    if unit == 1.0:
        assert re.search(message, small[0]), small[0]


@pytest.mark.parametrize("unit", [1e-6, 1e-2, 1.0, 1e3], ids=["1um", "1cm", "1m", "1km"])
def test_an_obstacle_larger_than_the_gaps_is_not_named_at_any_scale(unit):
    """A box whose smallest cross-section is 1.2 times the default gap, and a sphere of 0.1 voxel's radius
    (the drawn triangles see it): no warning about gaps in any unit."""
    inner = _slab(h=0.25 * unit)
    gap = 0.25 * np.sqrt(2) / (2 * np.sqrt(3))
    side = 1.2 * gap * np.sqrt(2)
    box = Box(min=(0.3 * unit, 0.3 * unit, -(0.01 + side) * unit), max=((0.3 + side) * unit, (0.3 + side) * unit,
                                                                        -0.01 * unit))
    sphere = Sphere(center=(0.375 * unit, 0.375 * unit, -0.04 * unit), radius=0.025 * unit)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ContactModel(inner, [box, sphere])
    assert not [w for w in caught if "fits through the gaps" in str(w.message)]
    assert not [w for w in caught if "drawn" in str(w.message)]  # a box's edges are measured at run time


def test_friction_of_the_drawn_triangles_by_central_differences():
    """Friction against a sphere acts at the triangles' deepest points too (their barycentric coordinates
    frozen over the step, like the lag's normal force): the energy, gradient and Hessian of barrier plus
    friction agree with central differences after a slide, and the friction force is tangential to the sphere."""
    inner = _slab()
    sphere = Sphere(center=(0.5, 0.5, -0.502), radius=0.5, friction=0.5)
    model = ContactModel(inner, [sphere], distance=0.01)
    rng = np.random.default_rng(4)
    q_lag = inner.rest + 0.0005 * rng.standard_normal(inner.rest.shape)
    model.begin_step(0.0, q_lag.ravel(), q_lag.ravel().copy())
    assert model._tri_lag is not None and len(model._tri_lag[1]) >= 4
    model.slip = 1e-4
    q = q_lag + 2e-4 * rng.standard_normal(q_lag.shape)
    _central_differences(model, q, rng, h=1e-8, rel_gradient=1e-6, rel_hessian=1e-5)
    friction = model.friction_forces(q)[0]
    assert np.linalg.norm(friction) > 0 and abs(friction[2]) < 0.05 * np.linalg.norm(friction)


def test_drawn_depth_of_a_box_edge_through_a_tilted_quad():
    """A quad on the plane z = -x - 0.25 straddles the edge x = z = 0 of the box x <= 0, z <= 0: its vertices are
    outside, the strip -0.25 < x < 0 inside, deepest 0.125 m at x = -0.125 (min(-x, -z)), a point of the
    8-subdivision grid.  Kinds the barrier keeps out are skipped; a plane above the quad reports nothing."""
    from voxflex.deform.layers.contact_checks import drawn_depth, kept_out
    from voxflex.deform.layers.obstacles import Plane

    V = np.array([[-0.5, -1.0, 0.25], [0.5, -1.0, -0.75], [0.5, 1.0, -0.75], [-0.5, 1.0, 0.25]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    box = Box(min=(-1.0, -2.0, -1.0), max=(0.0, 2.0, 0.0))
    assert np.all(box.signed_distance(V, 0.0)[0] > 0)
    depth, which = drawn_depth([Plane(point=(0, 0, -5), normal=(0, 0, 1)), box], V, faces, 0.0)
    assert which == 1 and depth == pytest.approx(0.125, rel=1e-12)
    assert drawn_depth([box], V, faces, 0.0, skip=("box",)) == (0.0, -1)
    assert kept_out("surface") == ("plane", "sphere") and kept_out("vertices") == ("plane",) and kept_out(2) == ()


def test_box_culling_never_skips_a_triangle_that_meets_the_box():
    """drawn_depth samples only the triangles no face plane of a box separates (outcodes sharing a bit): on 3,000
    random triangles around a moved box, every skipped triangle is outside it at every one of 231 barycentric
    points (a plane that has all three vertices beyond it has the whole triangle beyond it), and the depth found
    equals the brute-force sampling's on the kept ones."""
    from voxflex.deform.layers.contact_checks import _box_distance, _box_separated, drawn_depth

    rng = np.random.default_rng(7)
    box = Box(min=(-0.5, -0.3, -0.2), max=(0.5, 0.3, 0.2), motion=[[0.0, -1.0, 0.0, 0.1], [1.0, 0.0, 0.0, 0.0],
                                                                   [0.0, 0.0, 1.0, -0.05]])
    V = rng.uniform(-1.0, 1.0, size=(9000, 3))
    faces = np.arange(9000).reshape(-1, 3)
    skipped = _box_separated(box, V, faces, 0.7)
    assert 0 < skipped.sum() < len(faces)
    n = 20
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = i + j <= n
    lam = np.stack([i[keep], j[keep], n - i[keep] - j[keep]], axis=1) / n
    pts = np.einsum("sv,fvc->fsc", lam, V[faces])
    d = _box_distance(box, pts.reshape(-1, 3), 0.7).reshape(len(faces), -1)
    assert np.all(d[skipped] > 0)
    assert np.allclose(d, box.signed_distance(pts.reshape(-1, 3), 0.7)[0].reshape(d.shape), atol=1e-14)
    depth, which = drawn_depth([box], V, faces, 0.7, subdivisions=n)
    assert which == 0 and depth == pytest.approx(-d.min(), rel=1e-12)
