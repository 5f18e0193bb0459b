"""Shape functions on label images: partition of unity, positivity, interpolation, 1-D bar,
slit, derivatives against finite differences, linear precision, the local algorithm vs the naive one.

The voxel-by-voxel values (``smooth=False``) carry the natural-neighbour properties
(interpolation at the frames, the 1-D bar formula); the default blended values
(``smooth=True``, voxflex/voronoi/smoothing.py) are what models integrate, and are
tested for continuity of values and gradients, the partition of unity, positivity,
no leak, and derivatives against finite differences anywhere."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from voxflex.errors import InputError
from voxflex.image import LabelImage
from voxflex.voronoi import _march as M
from voxflex.voronoi import shape_function
from voxflex.voronoi._sight import frame_distances
from voxflex.voronoi.geodesic import _prepare, voxel_coordinates
from voxflex.voronoi.natural_neighbour import natural_naive, natural_weights


@pytest.fixture(scope="module")
def cube():
    img = LabelImage(np.ones((16, 16, 16), np.uint8), spacing=(0.01, 0.01, 0.01))
    rng = np.random.default_rng(0)
    frames = img.index_to_world(rng.integers(1, 15, size=(6, 3)) + 0.5)
    frames = np.unique(frames, axis=0)
    return img, frames


@pytest.mark.parametrize("kind", ["natural-neighbour", "laplace", "distance-ratio", "shepard"])
def test_partition_of_unity_positivity_interpolation(cube, kind):
    img, frames = cube
    sf = shape_function(img, frames, kind=kind, parents=4, smooth=False)
    sv = sf.voxel_values()
    assert sv.m == 16 ** 3 and sv.n_parents == 4
    # sums of <= 4 terms after one division: round-off only
    assert sv.partition_of_unity_error() < 1e-10
    assert np.all(sv.w >= 0)
    at = sf(frames)
    np.testing.assert_array_equal(at.index[:, 0], np.arange(len(frames)))  # w_i = 1 at frame i ...
    np.testing.assert_allclose(at.w[:, 0], 1.0, rtol=0, atol=1e-14)
    assert np.all(at.index[:, 1:] == -1)  # ... and 0 for every other frame


def test_one_dimensional_bar_is_linear():
    L = 40
    img = LabelImage(np.ones((L + 1, 1, 1), np.uint8))
    frames = np.array([[0.5, 0.5, 0.5], [L + 0.5, 0.5, 0.5]])
    sf = shape_function(img, frames, kind="sibson", parents=2, smooth=False)
    x = np.linspace(0.5, L + 0.5, 97)
    sv = sf(np.stack([x, np.full_like(x, 0.5), np.full_like(x, 0.5)], 1))
    w0 = np.where(sv.index == 0, sv.w, 0).sum(1)
    # exact Sibson in 1-D: 1 - x/L; on voxels the stolen segment (L/2 long) is
    # counted in whole voxels, so each weight is off by up to 1 voxel / (L/2) = 2/L
    # (measured 0.051 = 2.03/L with the fit between nodes): allowed 2.5 / L
    np.testing.assert_allclose(w0, 1 - (x - 0.5) / L, atol=2.5 / L)


def test_distance_ratio_on_a_bar_is_exactly_linear():
    """1 - d/L between two frames: 1 at a frame, 1/2 at the border, 0 at the other frame.
    Oracle: the formula.  Distances along a bar are exact sums of voxel steps and every
    voxel of this bar is a weight node, so the centre values match to round-off (1e-12);
    between centres the per-node quadratic fit reproduces the linear function up to its
    1e-8 ridge (measured 3.5e-10; allowed 1e-8)."""
    L = 40
    img = LabelImage(np.ones((L + 1, 1, 1), np.uint8))
    frames = np.array([[0.5, 0.5, 0.5], [L + 0.5, 0.5, 0.5]])
    sf = shape_function(img, frames, kind="distance-ratio", parents=2, smooth=False)
    c = sf.centre_values()
    w0 = np.where(c.index == 0, c.w, 0).sum(1)
    np.testing.assert_allclose(w0, 1 - np.arange(L + 1) / L, rtol=0, atol=1e-12)
    assert w0[L // 2] == pytest.approx(0.5, abs=1e-12)
    x = np.linspace(0.5, L + 0.5, 97)
    sv = sf(np.stack([x, np.full_like(x, 0.5), np.full_like(x, 0.5)], 1))
    np.testing.assert_allclose(np.where(sv.index == 0, sv.w, 0).sum(1), 1 - (x - 0.5) / L, rtol=0, atol=1e-8)


def test_distance_ratio_is_one_half_on_a_two_cell_border():
    """Two frames in a box: every point has just these two natural neighbours, so on the
    bisector plane (the slice of voxel centres equidistant from both) w = 1/2.  The centre
    values come from per-node quadratic fits of nodes off the plane; measured max deviation 2.4e-5;
    allowed 1e-3 (the fit of a smooth function over nodes 2 voxels apart)."""
    img = LabelImage(np.ones((21, 9, 9), np.uint8))
    frames = np.array([[3.5, 4.5, 4.5], [17.5, 4.5, 4.5]])
    sf = shape_function(img, frames, kind="distance-ratio", parents=2, smooth=False)
    c = sf.centre_values()
    ijk = np.argwhere(img.labels > 0)
    mid = ijk[:, 0] == 10
    w0 = np.where(c.index == 0, c.w, 0).sum(1)
    assert np.abs(w0[mid] - 0.5).max() < 1e-3
    assert np.all(w0[ijk[:, 0] < 10] > 0.5) and np.all(w0[ijk[:, 0] > 10] < 0.5)


def test_shepard_on_a_bar_matches_inverse_square_distance():
    """Oracle: w_i = d_i^-2 / sum_j d_j^-2 with exact distances along the bar; every voxel is
    a weight node here, so centre values agree to round-off (1e-12)."""
    L = 40
    img = LabelImage(np.ones((L + 1, 1, 1), np.uint8))
    xs = np.array([0, 15, 40])
    frames = np.stack([xs + 0.5, np.full(3, 0.5), np.full(3, 0.5)], 1)
    sf = shape_function(img, frames, kind="shepard", parents=3, smooth=False)
    c = sf.centre_values()
    x = np.arange(L + 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        g = 1.0 / (x[:, None] - xs[None]) ** 2
        ref = np.where(np.isinf(g).any(1, keepdims=True), np.isinf(g).astype(float), g / g.sum(1, keepdims=True))
    got = np.zeros((L + 1, 3))
    for j in range(3):
        got[np.arange(L + 1), np.maximum(c.index[:, j], 0)] += np.where(c.index[:, j] >= 0, c.w[:, j], 0)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12)


@pytest.mark.parametrize("kind", ["sibson", "distance-ratio"])
def test_no_leak_across_a_one_voxel_slit(kind):
    labels = np.ones((20, 21, 2), np.uint8)
    labels[:16, 10, :] = 0  # slit along x, open at x >= 16
    img = LabelImage(labels)
    frames = np.array([[2.5, 4.5, 0.5], [2.5, 16.5, 0.5], [18.5, 10.5, 0.5]])
    for smooth in (False, True):
        _no_leak(img, frames, labels, smooth, kind)


def _no_leak(img, frames, labels, smooth, kind):
    sf = shape_function(img, frames, kind=kind, parents=3, smooth=smooth)
    sv = sf.voxel_values()
    ijk = np.argwhere(labels > 0)
    below = (ijk[:, 1] < 10) & (ijk[:, 0] < 8)
    w1 = np.where(sv.index == 1, sv.w, 0).sum(1)
    assert np.all(w1[below] == 0)  # the frame across the slit has no weight there
    above = (ijk[:, 1] > 10) & (ijk[:, 0] < 8)
    w0 = np.where(sv.index == 0, sv.w, 0).sum(1)
    assert np.all(w0[above] == 0)


def test_gradients_and_hessians_against_finite_differences(cube):
    img, frames = cube
    sf = shape_function(img, frames, kind="sibson", parents=4, smooth=False)
    rng = np.random.default_rng(2)
    X = img.index_to_world(rng.integers(2, 14, size=(20, 3)) + 0.3 + 0.4 * rng.random((20, 3)))
    sv = sf(X)
    h = 1e-6 * 0.01  # well inside the voxel (points are >= 0.3 voxel from its faces)
    for a in range(3):
        e = np.zeros(3)
        e[a] = h
        p, m = sf(X + e), sf(X - e)
        assert np.array_equal(p.index, sv.index) and np.array_equal(m.index, sv.index)
        fd = (p.w - m.w) / (2 * h)
        # central differences of a quadratic (renormalised): error ~ h² |∇³w| ~ 1e-9 relative
        np.testing.assert_allclose(sv.dw[..., a], fd, rtol=0, atol=1e-6 * np.abs(sv.dw).max())
        fdd = (p.dw - m.dw) / (2 * h)
        np.testing.assert_allclose(sv.ddw[..., a], fdd, rtol=0, atol=1e-5 * np.abs(sv.ddw).max())


def test_local_algorithm_matches_naive_reprogagation(cube):
    img, frames = cube
    mask, cost, ps, sp = _prepare(img, None)
    fp = img.world_to_index(frames) + M.PAD
    d, own = frame_distances(mask, cost, ps, sp, fp, np.arange(len(frames)))  # what shape_function uses
    pts = img.world_to_index(img.index_to_world(np.array([[3, 4, 5], [8, 8, 8], [12, 2, 9]]) + 0.5)) + M.PAD
    for lap in (False, True):
        F, W, _ = natural_weights(mask, cost, ps, sp, d, own, pts, len(frames), laplace=lap)
        for q in range(len(pts)):
            dense = np.zeros(len(frames))
            dense[F[q][F[q] >= 0]] = W[q][F[q] >= 0]
            ref = natural_naive(mask, cost, ps, sp, fp, pts[q], laplace=lap)
            # the node sees its whole stolen set in a box: the span fill measures the same
            # straight-line distances as the full propagation and finds the same set; measured
            # equal to 6e-17 (with fast-marching stolen sets it was 0.0024 Sibson, 0.0153
            # Laplace, against the 0.01 / 0.03 allowed then); allowed 1e-12
            np.testing.assert_allclose(dense, ref, rtol=0, atol=1e-12)


def test_linear_precision_in_a_convex_interior():
    n = 24
    img = LabelImage(np.ones((n, n, n), np.uint8))
    g = np.array([3.5, 9.5, 14.5, 20.5])
    frames = np.array(np.meshgrid(g, g, g, indexing="ij")).reshape(3, -1).T
    rng = np.random.default_rng(5)
    frames[:, :] += rng.integers(-1, 2, size=frames.shape)
    sf = shape_function(img, frames, kind="sibson", parents=16, smooth=False)
    X = np.array(np.meshgrid([10.5, 12.5], [10.5, 12.5], [10.5, 12.5], indexing="ij")).reshape(3, -1).T
    sv = sf(X)
    Xa = frames[np.maximum(sv.index, 0)] * (sv.index[..., None] >= 0)
    err = np.abs(np.einsum("mp,mpi->mi", sv.w, Xa) - X).max()
    # Sibson coordinates reproduce linear fields; voxel counting and fitting: within a voxel
    assert err < 1.0


def test_errors(cube):
    img, frames = cube
    with pytest.raises(InputError, match="kind"):
        shape_function(img, frames, kind="mls")
    with pytest.raises(InputError, match="parents"):
        shape_function(img, frames, parents=0)
    sf = shape_function(img, frames, kind="sibson")
    with pytest.raises(InputError, match="point 1"):
        sf(np.array([[0.05, 0.05, 0.05], [0.5, 0.5, 0.5]]))
    sv = sf(np.array([[0.16 + 0.004, 0.05, 0.05]]))  # 0.4 voxel outside: accepted
    assert sv.w.sum() == pytest.approx(1.0)


def _dense(sv, n):
    W = np.zeros((sv.m, n))
    G = np.zeros((sv.m, n, 3))
    for j in range(sv.n_parents):
        ok = sv.index[:, j] >= 0
        W[np.flatnonzero(ok), sv.index[ok, j]] += sv.w[ok, j]
        G[np.flatnonzero(ok), sv.index[ok, j]] += sv.dw[ok, j]
    return W, G


def test_blended_values_are_smooth_positive_and_a_partition_of_unity(cube):
    """Across voxel faces and voxel centres (where the voxel-by-voxel values jump): values and
    gradients continuous (differences across 2e-9 voxel of O(1e-9)), FD of w equals dw
    everywhere (1e-5 of max |dw|, h = 1e-7 m against O(1) curvature: truncation 1e-10)."""
    img, frames = cube
    sf = shape_function(img, frames, kind="sibson", parents=4)
    rng = np.random.default_rng(3)
    ijk = rng.integers(2, 14, size=(30, 3)).astype(float)
    ijk[:10, 0] = np.floor(ijk[:10, 0])  # on a voxel face
    ijk[10:20] += 0.5  # at voxel centres
    ijk[20:] += rng.random((10, 3))
    X = img.index_to_world(ijk)
    sv = sf(X)
    assert sv.partition_of_unity_error() < 1e-12 and np.all(sv.w >= 0)
    n = len(frames)
    W, G = _dense(sv, n)
    for a in range(3):
        e = np.zeros(3)
        e[a] = 1e-11
        Wp, Gp = _dense(sf(X + e), n)
        Wm, Gm = _dense(sf(X - e), n)
        assert np.abs(Wp - Wm).max() < 1e-7 and np.abs(Gp - Gm).max() < 1e-5 * np.abs(G).max()
        e[a] = 1e-7
        Wp, _ = _dense(sf(X + e), n)
        Wm, _ = _dense(sf(X - e), n)
        np.testing.assert_allclose((Wp - Wm) / 2e-7, G[..., a], rtol=0, atol=1e-5 * np.abs(G).max())


def test_a_seed_region_belongs_to_its_frame():
    """Voxels owned outright by a frame (a clamp): every point on them, faces included, has weight 1
    for that frame alone (exactly), so a fixed frame holds all the material of the region."""
    img = LabelImage(np.ones((12, 4, 4), np.uint8))
    frames = np.array([[0.5, 1.5, 1.5], [6.5, 1.5, 1.5], [11.5, 2.5, 2.5]])
    owner = -np.ones(img.shape, np.int64)
    owner[0] = 0  # the first voxel layer
    sf = shape_function(img, frames, kind="sibson", parents=3, seed_owner=owner)
    face = np.array([[0.0, y, z] for y in np.linspace(0, 4, 5) for z in np.linspace(0, 4, 5)])
    sv = sf(face)
    assert np.all(sv.index[:, 0] == 0) and np.allclose(sv.w[:, 0], 1.0, atol=1e-14)
    assert np.all(sv.w[:, 1:] == 0)


def test_compiled_blend_equals_its_numpy_twin():
    """The compiled B-spline blend gives the numpy twin's w, dw, ddw to round-off (1e-12 relative),
    on an anisotropic image with a slot, at random points, voxel centres and voxel corners."""
    from voxflex.voronoi.smoothing import SmoothWeights

    labels = np.ones((14, 10, 8), np.uint8)
    labels[4:10, 5, :5] = 0
    img = LabelImage(labels, spacing=(0.01, 0.02, 0.015))
    rng = np.random.default_rng(0)
    frames = np.unique(img.index_to_world(rng.integers(1, 7, size=(6, 3)) + 0.5), axis=0)
    c = shape_function(img, frames, parents=4).centre_values()
    ijk = np.argwhere(labels > 0)
    X = img.index_to_world(np.concatenate([ijk[rng.integers(0, len(ijk), 300)] + rng.random((300, 3)),
                                           ijk[:20] + 0.5, ijk[20:40].astype(float)]))
    n = len(frames)
    got = _dense_all(SmoothWeights(img, c.index, c.w, n)(X), n)
    ref = _dense_all(SmoothWeights(img, c.index, c.w, n, backend="numpy")(X), n)
    for a, b in zip(got, ref):
        assert np.abs(a - b).max() <= 1e-12 * np.abs(b).max()


def test_values_without_hessians_are_the_same_bits():
    """hessians=False (what the elastons' and stabilised regions' Gauss points ask for) leaves ddw None and gives
    the parents, weights and gradients of the full evaluation bit for bit: the compiled blend with and without a
    prune, its numpy twin, and the frame families' shape functions (blended, and reproducing kernels)."""
    from voxflex.voronoi.smoothing import SmoothWeights

    labels = np.ones((14, 10, 8), np.uint8)
    labels[4:10, 5, :5] = 0
    img = LabelImage(labels, spacing=(0.01, 0.02, 0.015))
    rng = np.random.default_rng(0)
    frames = np.unique(img.index_to_world(rng.integers(1, 7, size=(6, 3)) + 0.5), axis=0)
    ijk = np.argwhere(labels > 0)
    X = img.index_to_world(np.concatenate([ijk[rng.integers(0, len(ijk), 300)] + rng.random((300, 3)),
                                           ijk[:20] + 0.5, ijk[20:40].astype(float)]))
    sf = shape_function(img, frames, parents=4)
    c = sf.centre_values()
    n = len(frames)
    calls = [lambda h, b=b, p=p: SmoothWeights(img, c.index, c.w, n, backend=b)(X, prune=p, hessians=h)
             for b in ("numba", "numpy") for p in (0.0, 0.05)]
    calls += [lambda h, k=k: shape_function(img, frames, kind=k)(X, hessians=h)
              for k in ("natural-neighbour", "reproducing-kernel")]
    for call in calls:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # six frames: reproducing kernels warn about corners with too few
            full, lean = call(True), call(False)
        assert full.ddw is not None and lean.ddw is None
        for name in ("index", "w", "dw", "rest"):
            assert np.array_equal(getattr(full, name), getattr(lean, name)), name


def _dense_all(sv, n):
    W, G = _dense(sv, n)
    H = np.zeros((sv.m, n, 3, 3))
    for j in range(sv.n_parents):
        ok = sv.index[:, j] >= 0
        H[np.flatnonzero(ok), sv.index[ok, j]] += sv.ddw[ok, j]
    return W, G, H


def test_voxels_of_points_outside_match_a_brute_force_search():
    """Oracle: for points just outside the material (surface vertices at voxel corners, points
    up to half a voxel out), the voxel used is the material voxel of the 27 around the point
    with the smallest gap to it (first in offset order on ties), found here by a plain loop."""
    labels = np.zeros((8, 7, 6), np.uint8)
    labels[2:6, 2:5, 1:5] = 1
    labels[3, 5, 2] = 1
    img = LabelImage(labels, spacing=(0.5, 0.7, 0.9))
    sf = shape_function(img, img.index_to_world([[3.5, 3.5, 2.5], [4.5, 2.5, 3.5]]), kind="sibson", smooth=False)
    rng = np.random.default_rng(2)
    corners = np.argwhere(labels > 0)[:, None, :] + np.array([[0, 0, 0], [1, 1, 1], [1, 0, 1], [0, 1, 0]])[None]
    c = np.concatenate([corners.reshape(-1, 3).astype(float), 1.0 + rng.random((300, 3)) * 6.0])
    c = c[np.linalg.norm(c[:, None, :] - (np.argwhere(labels > 0) + 0.5)[None], axis=2).min(1) < 2.2]
    X = img.index_to_world(c)
    half = 0.5 * 0.9 * (1 + 1e-9)

    def brute(ci):
        ijk = np.floor(ci).astype(int)
        if np.all((ijk >= 0) & (ijk < labels.shape)) and labels[tuple(ijk)]:
            return ijk, 0.0
        best, bestd = None, np.inf
        for o in np.array(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1], indexing="ij")).reshape(3, -1).T:
            v = ijk + o
            if np.any(v < 0) or np.any(v >= labels.shape) or not labels[tuple(v)]:
                continue
            dd = np.linalg.norm(np.maximum(np.maximum(v - ci, ci - (v + 1)), 0.0) * img.spacing)
            if dd < bestd:
                best, bestd = v, dd
        return best, bestd

    # the same coordinates as the code under test: corners at exact integers (the units' round-off taken out)
    ref = [brute(ci) for ci in voxel_coordinates(img, X)]
    ok = np.array([r[0] is not None and r[1] <= half for r in ref])
    assert ok.sum() > 50 and (~ok).sum() > 5  # both cases are exercised
    np.testing.assert_array_equal(sf._voxels_of(X[ok]), np.array([r[0] for r in ref if r[0] is not None and r[1] <= half]))
    first_bad = int(np.flatnonzero(~ok)[0])
    with pytest.raises(InputError, match=f"point {first_bad} "):
        sf._voxels_of(X)


def test_centre_weights_node_by_node_equal_the_pointwise_evaluation(cube):
    """The smoothing's input, evaluated node by node, equals the per-point evaluation of the same
    polynomials (centre_values; same parents, weights to round-off: 1e-12)."""
    img, frames = cube
    sf = shape_function(img, frames, kind="sibson", parents=3)
    index, w = sf._centre_weights()
    ref = sf.centre_values()
    np.testing.assert_array_equal(index, ref.index)
    np.testing.assert_allclose(w, ref.w, rtol=0, atol=1e-12)


def test_compiled_centre_weights_equal_the_numpy_twin():
    """_centre_kernel against _weights_impl node by node, on an anisotropic, rotated image with a slot
    and more candidate frames than parents: same weights per frame to round-off (1e-12), except at
    voxels where the parents-th and the next raw value tie to 1e-9 (either frame is a right pick;
    the two evaluations differ by round-off there: at most 5 % of the voxels, asserted)."""
    from voxflex.voronoi.weights import _basis, _weights_impl

    labels = np.ones((14, 10, 8), np.uint8)
    labels[4:10, 5, :5] = 0
    c, s_ = np.cos(0.3), np.sin(0.3)
    img = LabelImage(labels, spacing=(0.01, 0.02, 0.015), origin=(0.1, -0.2, 0.3),
                     direction=[[c, -s_, 0], [s_, c, 0], [0, 0, 1]])
    rng = np.random.default_rng(4)
    ijk = np.unique(rng.integers(1, 7, size=(12, 3)), axis=0)
    frames = img.index_to_world(ijk[labels[tuple(ijk.T)] > 0] + 0.5)
    P = 3
    sf = shape_function(img, frames, parents=P, smooth=False)
    assert sf._node_frames.shape[1] > P
    index, w = sf._centre_weights()
    mask = labels > 0
    X = img.voxel_centers(mask)
    nodes = sf._node_of_voxel[mask]
    checked = tied = 0
    for q in np.unique(nodes):
        sel = np.flatnonzero(nodes == q)
        ri, rw = _weights_impl(X[sel], sf._node_pos[q], sf._node_frames[q], sf._node_coef[q], sf._scale, P)
        phi, _, _ = _basis((X[sel] - sf._node_pos[q]) / sf._scale)
        raw = np.sort(sf._node_coef[q][:, 0] + phi @ sf._node_coef[q][:, 1:].T, axis=1)[:, ::-1]
        tie = np.abs(raw[:, P - 1] - raw[:, P]) < 1e-9 if raw.shape[1] > P else np.zeros(len(sel), bool)
        dense = []
        for a, b in ((index[sel], w[sel]), (ri, rw)):
            D = np.zeros((len(sel), len(frames)))
            for j in range(P):
                ok = a[:, j] >= 0
                D[np.flatnonzero(ok), a[ok, j]] = b[ok, j]
            dense.append(D)
        np.testing.assert_allclose(dense[0][~tie], dense[1][~tie], rtol=0, atol=1e-12)
        checked += int((~tie).sum())
        tied += int(tie.sum())
    assert tied <= 0.05 * (checked + tied) and checked > 500


def test_stolen_sets_out_of_sight_fall_back_to_the_march():
    """A point near the end of a wall steals voxels behind it: the span fill sees that it cannot
    reach them in a straight line and gives up (returns < 0), the bounded line-of-sight march
    takes over.  Oracle: the naive full propagation (natural_naive): the bounded march follows
    the same line-of-sight rule and finds the same set (a voxel on a shortest path to a stolen
    voxel is stolen); measured equal to 1.1e-16, allowed 1e-12."""
    from voxflex.voronoi import _sight as S
    from voxflex.voronoi.natural_neighbour import _span_steal

    labels = np.ones((22, 21, 3), np.uint8)
    labels[:14, 10, :] = 0  # a wall, open at x >= 14
    img = LabelImage(labels)
    frames = np.array([[4.5, 4.5, 1.5], [4.5, 16.5, 1.5], [18.5, 3.5, 1.5], [18.5, 17.5, 1.5], [11.5, 6.5, 1.5]])
    mask, cost, ps, sp = _prepare(img, None)
    fp = frames + M.PAD
    d, own = frame_distances(mask, cost, ps, sp, fp, np.arange(len(frames)))
    pts = np.array([[13.5, 8.5, 1.5], [13.5, 12.5, 1.5], [19.5, 10.5, 1.5]]) + M.PAD
    table = S.empty_table(mask, ps)
    state = M.state_of(mask)
    spans = np.empty((mask.shape[0], 2), np.int64)
    r = [_span_steal(mask, table, ps, sp, 1.0, d, p, state, spans, len(spans)) for p in pts[:1]]
    assert r[0] < 0  # the first point sees past the wall's end into the other side, not all of it
    for lap in (False, True):
        F, W, _ = natural_weights(mask, cost, ps, sp, d, own, pts, len(frames), laplace=lap)
        for q in range(len(pts)):
            dense = np.zeros(len(frames))
            dense[F[q][F[q] >= 0]] = W[q][F[q] >= 0]
            ref = natural_naive(mask, cost, ps, sp, fp, pts[q], laplace=lap)
            np.testing.assert_allclose(dense, ref, rtol=0, atol=1e-12)
