"""Generalized winding number: fast tree vs brute force, closed/open/inverted meshes."""

from __future__ import annotations

import numpy as np
import pytest

from voxflex.rasterize import build_tree, winding_number, winding_number_brute


def _tetra():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return v, f


def _sphere(res=40):
    import pyvista as pv

    m = pv.Sphere(radius=1.0, theta_resolution=res, phi_resolution=res).triangulate()
    return np.asarray(m.points, dtype=float), np.asarray(m.faces).reshape(-1, 4)[:, 1:]


def test_brute_force_closed_tetrahedron_is_exactly_one_or_zero():
    v, f = _tetra()
    rng = np.random.default_rng(0)
    p = rng.uniform(-0.5, 1.5, (400, 3))
    inside = (p > 0).all(axis=1) & (p.sum(axis=1) < 1)
    w = winding_number_brute(v, f, p)
    # closed surface: integer up to round-off (1e-12)
    np.testing.assert_allclose(w, inside.astype(float), atol=1e-12)


def test_fast_matches_brute_force_on_random_points():
    v, f = _sphere(40)
    rng = np.random.default_rng(1)
    p = rng.uniform(-1.6, 1.6, (1500, 3))
    wb = winding_number_brute(v, f, p)
    err = {beta: np.abs(winding_number(v, f, p, beta=beta) - wb).max() for beta in (2.0, 4.0)}
    # beta = 2: far clusters (radius r at distance > 2r) are truncated after the first-order term, relative
    # error (r/d)^2 <= 1/4 of a cluster's share; measured max 0.056 over the whole box; 0.1 keeps the
    # inside/outside decision (threshold 0.5, true values 0 or 1) safe with a 4x margin.
    assert err[2.0] < 0.1
    # the truncation error falls like (1/beta)^2 or faster: beta 2 -> 4 must gain at least a factor 3
    assert err[4.0] < err[2.0] / 3
    # a huge beta never approximates: the tree must then reproduce the exact sum to round-off
    np.testing.assert_allclose(winding_number(v, f, p, beta=1e6), wb, atol=1e-10)


def test_far_field_error_decays_like_distance_to_the_minus_four():
    # one cluster (leaf size larger than the soup): contribution ~ d^-2, first-order truncation ~ d^-4
    rng = np.random.default_rng(2)
    v = rng.normal(size=(30, 3))
    f = np.array([t for t in rng.integers(0, 30, (60, 3)) if len(set(t)) == 3][:40])
    tree = build_tree(v, f, leaf_size=1000)
    errs = []
    for d in (10.0, 20.0, 40.0):
        p = np.array([[d, 0.3 * d, 0.1]])
        errs.append(abs(winding_number(v, f, p, tree=tree, beta=1.0)[0] - winding_number_brute(v, f, p)[0]))
    rates = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(rates > 3.5), rates  # expected 4 (an error in the first-order term would give 3)


def test_open_mesh_still_separates_inside_from_outside():
    v, f = _sphere(40)
    rng = np.random.default_rng(3)
    keep = np.ones(len(f), bool)
    keep[rng.choice(len(f), len(f) // 20, replace=False)] = False  # 5 % of the faces missing, scattered
    p_in = rng.normal(size=(300, 3))
    p_in *= (rng.uniform(0, 0.8, 300) / np.linalg.norm(p_in, axis=1))[:, None]
    p_out = rng.normal(size=(300, 3))
    p_out *= (rng.uniform(1.25, 3, 300) / np.linalg.norm(p_out, axis=1))[:, None]
    w_in = winding_number(v, f[keep], p_in)
    w_out = winding_number(v, f[keep], p_out)
    # each missing face removes its solid angle (< 5 % of 4 pi in total): w stays within 0.2 of the truth
    assert w_in.min() > 0.8 and np.abs(w_out).max() < 0.2


def test_inverted_mesh_gives_minus_one_and_flipped_triangles_are_local():
    v, f = _sphere(30)
    p = np.array([[0.0, 0.0, 0.0], [0.3, -0.2, 0.1], [2.0, 0.0, 0.0]])
    np.testing.assert_allclose(winding_number(v, f[:, ::-1], p, method="brute"), [-1, -1, 0], atol=1e-9)
    # flipping one triangle changes w by twice its solid angle: small away from it
    g = f.copy()
    g[0] = g[0, ::-1]
    w = winding_number(v, g, p, method="brute")
    tri = v[f[0]]
    assert abs(w[0] - 1) < 0.01 and abs(w[2]) < 0.01
    assert np.linalg.norm(tri.mean(axis=0)) > 0.9  # the flipped face is on the surface, far from the test points


def test_validation():
    v, f = _tetra()
    with pytest.raises(ValueError, match="valid: brute, fast"):
        winding_number(v, f, [[0, 0, 0]], method="exact")
    with pytest.raises(ValueError, match="do not exist"):
        winding_number(v, f + 10, [[0, 0, 0]])


def _holey_sphere(res=40, seed=3):
    """Sphere with one big hole (the faces nearest a point) and 2 % scattered missing faces."""
    v, f = _sphere(res)
    rng = np.random.default_rng(seed)
    centroids = v[f].mean(axis=1)
    keep = np.ones(len(f), bool)
    keep[np.argsort(np.linalg.norm(centroids - [0.3, 0.3, 0.9], axis=1))[: len(f) // 40]] = False
    keep[rng.choice(len(f), len(f) // 50, replace=False)] = False
    return v, f[keep]


def test_tree_is_a_median_split_with_exact_radii_and_moments():
    v, f = _sphere(40)
    tree = build_tree(v, f)
    tri = tree.tri
    cen = tri.mean(axis=1)
    sizes = tree.stop[tree.n_internal :] - tree.start[tree.n_internal :]
    assert sizes.min() >= 4 and sizes.max() <= 8  # balanced leaves of at most LEAF_SIZE = 8
    an = 0.5 * np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    mids = 0.5 * (tri + np.roll(tri, -1, axis=1))  # edge midpoints: exact quadrature for quadratics on a triangle
    for k in range(len(tree.start)):
        s, e = tree.start[k], tree.stop[k]
        if k < tree.n_internal:  # children split the range at the median along the longest centroid axis
            left, right = 2 * k + 1, 2 * k + 2
            assert tree.start[left] == s and tree.stop[left] == tree.start[right] and tree.stop[right] == e
            axis = np.argmax(np.ptp(cen[s:e], axis=0))
            assert cen[s : tree.stop[left], axis].max() <= cen[tree.start[right] : e, axis].min()
        if k % 37:
            continue  # the sums below on a sample of nodes (all levels)
        rel = tri[s:e] - tree.centre[k]
        # radius: the largest centre-to-corner distance, to round-off
        assert tree.radius[k] == pytest.approx(np.linalg.norm(rel, axis=2).max(), rel=1e-12)
        np.testing.assert_allclose(tree.normal[k], an[s:e].sum(axis=0), rtol=0, atol=1e-13)
        np.testing.assert_allclose(tree.moment[k], np.einsum("ti,tj->ij", an[s:e], rel.mean(axis=1)), atol=1e-13)
        # second moments by the edge-midpoint rule (independent of the closed form used in the tree)
        y = mids[s:e] - tree.centre[k]
        second = np.einsum("tcj,tck->tjk", y, y) / 3.0  # (1/area) int y y^T dA
        quad = np.einsum("ti,tjk->ijk", an[s:e], second)
        pairs = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
        np.testing.assert_allclose(tree.quad[k], np.stack([quad[:, j, k2] for j, k2 in pairs], axis=1), atol=1e-13)


def test_far_field_error_of_the_second_order_expansion_decays_like_distance_to_the_minus_five():
    # same single cluster as above: with the second-order term the truncation error is O(d^-5)
    rng = np.random.default_rng(2)
    v = rng.normal(size=(30, 3))
    f = np.array([t for t in rng.integers(0, 30, (60, 3)) if len(set(t)) == 3][:40])
    tree = build_tree(v, f, leaf_size=1000)
    errs = []
    for d in (20.0, 40.0, 80.0):
        p = np.array([[d, 0.3 * d, 0.1]])
        errs.append(abs(winding_number(v, f, p, tree=tree, beta=1.0)[0] - winding_number_brute(v, f, p)[0]))
    rates = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(rates > 4.5), rates  # expected 5, measured 4.84, 4.92 (without the term it would be 4)


def test_fast_matches_brute_force_near_the_surface_and_near_holes():
    v, f = _holey_sphere(40)
    rng = np.random.default_rng(4)
    tri = v[f]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    pick = rng.choice(len(f), 600)
    bary = rng.dirichlet(np.ones(3), 600)
    on = np.einsum("pc,pcx->px", bary, tri[pick])
    off = rng.choice([-1, 1], 600) * 10.0 ** rng.uniform(-4, -1, 600)  # 1e-4 .. 0.1 from a face, either side
    near = on + off[:, None] * normal[pick]
    rim = [0.3, 0.3, 0.9] / np.linalg.norm([0.3, 0.3, 0.9]) * rng.uniform(0.8, 1.2, (300, 1))
    rim = rim + rng.normal(scale=0.1, size=(300, 3))  # around the big hole, where w takes every value in (0, 1)
    p = np.vstack([near, rim, rng.uniform(-1.5, 1.5, (300, 3))])
    wb = winding_number_brute(v, f, p)
    assert wb[600:900].min() < 0.4 and wb[600:900].max() > 0.6  # the rim points do see fractional w
    err = {beta: np.abs(winding_number(v, f, p, beta=beta) - wb).max() for beta in (1.5, 3.0)}
    # default beta 1.5: measured max 0.021; 0.05 keeps the 0.5 threshold safe wherever |w - 0.5| > 0.05
    assert err[1.5] < 0.05, err
    # truncation error O((1/beta)^3): doubling beta must gain at least 4 (expected >= 8; measured 33)
    assert err[3.0] < err[1.5] / 4, err
    # a huge beta never approximates: the exact leaf sums reproduce the brute-force sum to round-off
    np.testing.assert_allclose(winding_number(v, f, p, beta=1e6), wb, atol=1e-10)
