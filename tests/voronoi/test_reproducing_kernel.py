"""Reproducing-kernel frame weights (voxflex/voronoi/reproducing_kernel.py).

Oracles: the partition of unity and linear reproduction (exact identities of the
construction, to round-off) on a box, an L-shape and thin plates with few frames;
central finite differences of the weights and gradients; continuity across voxel
faces; the compiled kernels against their numpy twins; the regularity guard (a
support too small to be regular is grown, frames on a plane fall back with a
warning and never give NaN); the frame model's patch tests (an affine and a
quadratic motion of the frames reproduced exactly in F at every sample), its gauge
motions (they move nothing), and the lumped mass (positive definite, exact total
mass and free fall).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.sparse as sp
from precision import check_linear_precision

from voxflex.deform.chain.mappings import DeformationGradientMapping, PointMapping
from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.frames.model import FrameModel
from voxflex.deform.models.frames.modes import gauge_modes, zero_energy_modes
from voxflex.errors import InputError
from voxflex.image import LabelImage
from voxflex.image.grid import trilinear_weights
from voxflex.voronoi import place_frames, shape_function
from voxflex.voronoi import reproducing_kernel as RK

H = 0.1  # voxel edge (m)


def _image(name):
    if name == "box":
        lab = np.ones((16, 6, 6), np.uint8)
    elif name == "L-shape":
        lab = np.ones((12, 12, 4), np.uint8)
        lab[6:, 6:] = 0
    elif name == "plate":  # two voxels thick, 16 x 16 voxels wide
        lab = np.ones((16, 16, 2), np.uint8)
    else:
        raise ValueError(name)
    return LabelImage(lab, spacing=(H, H, H))


def _inside(image, m, seed=0):
    rng = np.random.default_rng(seed)
    ijk = np.argwhere(image.labels > 0)
    return image.index_to_world(ijk[rng.integers(0, len(ijk), m)] + rng.random((m, 3)))


def _check_exact(sv, frames, L):
    """Partition of unity and linear reproduction, each term made dimensionless (L the extent, H the
    voxel): sums of ~20 terms of order one after one 3x3 solve, so round-off is ~1e-14; allowed 1e-12."""
    Xa = np.where(sv.index[..., None] >= 0, frames[np.maximum(sv.index, 0)], 0.0)
    assert np.abs(sv.w.sum(1) - 1).max() < 1e-12
    assert np.abs(sv.dw.sum(1)).max() * H < 1e-12
    assert np.abs(sv.ddw.sum(1)).max() * H * H < 1e-12
    assert np.abs(np.einsum("mp,mpi->mi", sv.w, Xa) - sv.rest).max() / L < 1e-12
    assert np.abs(np.einsum("mpi,mpj->mij", Xa, sv.dw) - np.eye(3)).max() < 1e-12
    assert np.abs(np.einsum("mpi,mpjk->mijk", Xa, sv.ddw)).max() * H < 1e-12


@pytest.mark.parametrize("name, count", [("box", 6), ("L-shape", 6), ("plate", 6)])
def test_partition_of_unity_and_linear_reproduction(name, count):
    """With 6 frames the kernels are grown where they are too small, and the corrected weights hold
    sum w = 1, sum w X = X (and their derivatives) at random points, to round-off."""
    image = _image(name)
    frames = place_frames(image, count, seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RK.ReproducingKernelWarning)  # no corner may fall back here
        sf = shape_function(image, frames, kind="reproducing-kernel")
    assert sf.fallback_corners == 0
    sv = sf(_inside(image, 400))
    _check_exact(sv, frames, float(np.max(np.asarray(image.shape) * H)))
    assert sv.w.min() < -0.05  # the correction does make weights negative near the surface
    if name == "plate":
        assert len(np.unique(frames[:, 2])) == 2  # frames in both layers: exact across the thickness too


def test_values_match_finite_differences_and_are_continuous():
    """dw and ddw against central differences of w and dw (h = 1e-6 voxel, inside voxels: the
    interpolant is a polynomial there, so only round-off ~1e-16 / 1e-7 remains); across a voxel face
    the values agree to the step times the gradient (conforming: no jump)."""
    image = _image("L-shape")
    frames = place_frames(image, 8, seed=1)
    sf = shape_function(image, frames, kind="reproducing-kernel")
    n = len(frames)
    ijk = np.argwhere(image.labels > 0)[::7]
    X = image.index_to_world(ijk + 0.25 + 0.5 * np.random.default_rng(2).random((len(ijk), 3)))

    def dense(sv, what):
        out = np.zeros((sv.m, n) + what.shape[2:])
        rows = np.repeat(np.arange(sv.m), sv.n_parents).reshape(sv.index.shape)
        ok = sv.index >= 0
        out[rows[ok], sv.index[ok]] = what[ok]
        return out

    sv = sf(X)
    dw, ddw = dense(sv, sv.dw), dense(sv, sv.ddw)
    h = 1e-6 * H
    for a in range(3):
        e = np.zeros(3)
        e[a] = h
        sp_, sm = sf(X + e), sf(X - e)
        fd = (dense(sp_, sp_.w) - dense(sm, sm.w)) / (2 * h)
        np.testing.assert_allclose(fd, dw[..., a], rtol=0, atol=1e-7 * np.abs(dw).max())
        fd2 = (dense(sp_, sp_.dw) - dense(sm, sm.dw)) / (2 * h)
        np.testing.assert_allclose(fd2, ddw[..., a, :], rtol=0, atol=1e-6 * np.abs(ddw).max())
    # across the faces x = const between two material voxels
    face = image.index_to_world(np.array([[6.0, 2.5, 1.5], [3.0, 9.5, 2.5], [9.0, 3.5, 0.5]]))
    eps = 1e-9 * H
    lo, hi = sf(face - [eps, 0, 0]), sf(face + [eps, 0, 0])
    jump = np.abs(dense(lo, lo.w) - dense(hi, hi.w)).max()
    assert jump < 10 * eps * np.abs(dw).max()


def test_compiled_kernels_match_numpy_twins():
    """_rk_corners and _interpolate against their numpy twins on the same inputs (1e-12)."""
    image = _image("box")
    frames = place_frames(image, 7, seed=3)
    sf = shape_function(image, frames, kind="reproducing-kernel")
    grid = sf.grid
    rng = np.random.default_rng(4)
    # corners: random kernel values on random frames, including a row with no kernel and a collinear row
    nc = 60
    rows = [rng.choice(len(frames), size=rng.integers(1, 7), replace=False) for _ in range(nc)]
    rows[5] = np.array([], dtype=np.int64)
    indptr = np.concatenate([[0], np.cumsum([len(r) for r in rows])]).astype(np.int64)
    fidx = np.concatenate(rows).astype(np.int64)
    phi = rng.random(len(fidx))
    corners = grid.node_positions[rng.integers(0, grid.n_nodes, nc)]
    rho = sf.rho
    out = (np.zeros(len(fidx)), np.zeros(nc), np.zeros(nc), np.zeros(nc, np.int64), np.zeros(nc))
    RK._rk_corners(indptr, fidx, phi, frames, rho, corners, RK.CONDITION, 3.0, np.ones(nc, bool), *out)
    twin = RK._rk_corners_numpy(indptr, fidx, phi, frames, rho, corners, RK.CONDITION, 3.0)
    np.testing.assert_allclose(out[0], twin[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(out[1], twin[1], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(out[3], twin[3])
    assert out[3][5] == 3 and out[1][5] == -1  # no kernel: nothing corrected, flagged
    assert np.any((out[3] > 0) & (out[3] < 3))  # some rows dropped a direction (1-3 frames, or sum |w| > 3)
    # interpolation
    elem = rng.integers(0, grid.n_elements, 50)
    local = rng.random((50, 3))
    sv = sf.evaluate(elem, local)
    Wd = sf.weights.toarray()
    from voxflex.voronoi.corner_weights import _interpolate_numpy

    w, dw, ddw = _interpolate_numpy(elem, local, grid.element_nodes, Wd, sf._Dw(), True)
    dense = np.zeros_like(w)
    rows_ = np.repeat(np.arange(50), sv.n_parents).reshape(sv.index.shape)
    ok = sv.index >= 0
    dense[rows_[ok], sv.index[ok]] = sv.w[ok]
    np.testing.assert_allclose(dense, w, rtol=0, atol=1e-13)
    for a in range(3):
        d = np.zeros_like(w)
        d[rows_[ok], sv.index[ok]] = sv.dw[..., a][ok]
        np.testing.assert_allclose(d, dw[..., a], rtol=0, atol=1e-11)
        for b in range(3):
            d = np.zeros_like(w)
            d[rows_[ok], sv.index[ok]] = sv.ddw[..., a, b][ok]
            np.testing.assert_allclose(d, ddw[..., a, b], rtol=0, atol=1e-9)
    # the trilinear functions themselves: the grid's
    N, _, _ = trilinear_weights(local)
    np.testing.assert_allclose(w, np.einsum("mc,mcf->mf", N, Wd[grid.element_nodes[elem]]), atol=1e-14)


def test_small_support_is_grown_not_singular():
    """support = 0.6 frame spacings leaves corners that see fewer than four frames: the guard grows
    the kernels there (no NaN, no fallback), and the result is exact.  Here every kernel sits at its floor
    (the frame's cell and two voxel diagonals), so the asked support acts nowhere: that is said."""
    image = _image("box")
    frames = place_frames(image, 10, seed=0)
    with pytest.warns(RK.ReproducingKernelWarning, match="below every kernel's floor.*raise support"):
        sf = shape_function(image, frames, kind="reproducing-kernel", support=0.6)
    assert sf.grown_frames > 0 and sf.fallback_corners == 0
    assert np.all(np.isfinite(sf.weights.data))
    assert np.all(sf.rho > 0.6 * sf.spacing - 1e-12)
    _check_exact(sf(_inside(image, 200)), frames, 1.6)


def test_coplanar_frames_fall_back_with_a_warning():
    """Frames all in the mid-plane of a three-voxel plate: no weights can reproduce the normal
    coordinate.  The guard drops that direction (warned, counted), keeps the partition of unity
    exactly and linear reproduction in the plane."""
    image = LabelImage(np.ones((16, 16, 3), np.uint8), spacing=(H, H, H))
    frames = image.index_to_world(np.array([[2, 2, 1], [13, 3, 1], [7, 8, 1], [3, 13, 1], [12, 12, 1]]) + 0.5)
    with pytest.warns(RK.ReproducingKernelWarning, match="line or a plane"):
        sf = shape_function(image, frames, kind="reproducing-kernel")
    assert sf.fallback_corners > 0
    sv = sf(_inside(image, 300))
    assert np.all(np.isfinite(sv.w)) and np.abs(sv.w.sum(1) - 1).max() < 1e-12
    Xa = frames[sv.index]
    err = np.einsum("mp,mpi->mi", sv.w, Xa) - sv.rest
    assert np.abs(err[:, :2]).max() < 1e-12  # in the plane: exact
    assert np.abs(err[:, 2]).max() > 0.05 * H  # across: impossible with these frames


def test_parents_are_never_truncated():
    image = _image("box")
    frames = place_frames(image, 8, seed=0)
    with pytest.warns(UserWarning, match="would truncate them"):
        sf = shape_function(image, frames, kind="reproducing-kernel", parents=2)
    assert sf.parents > 2
    sv = sf.voxel_values()
    assert sv.n_parents == sf.parents
    with pytest.raises(InputError, match="support applies"):
        shape_function(image, frames, kind="natural-neighbour", support=2.0)


@pytest.fixture(scope="module")
def beam_model():
    """A 16x4x4 beam (voxels 0.25 m), 12 frames, reproducing kernels, Gauss points."""
    image = LabelImage(np.ones((16, 4, 4), np.uint8), spacing=(0.25,) * 3)
    frames = place_frames(image, 12, seed=0)
    sf = shape_function(image, frames, kind="reproducing-kernel")
    mats = {1: material("hooke", young=1e3, poisson=0.3, strain="linear")}
    return FrameModel.from_image(image, frames, sf, mats, quadrature="gauss-legendre")


def test_patch_tests_affine_and_quadratic(beam_model):
    """An affine motion of every frame gives F = its matrix at every Gauss point (partition of unity);
    the frames' least motion of the quadratic field u = G X + X^T Hq X / 2 (A_a = I + G + Hq X_a / 2,
    t_a = A_a X_a + (X_a^T Hq X_a) / 2 - ... : see below) gives its exact gradient (linear precision)."""
    check_linear_precision(beam_model, x_tol=1e-11 * 4)


def test_gauge_modes_move_nothing(beam_model):
    """Linearly precise weights: the 18 gauge motions give x = 0 and F = 0 at every sample; the free
    body's stiffness has 6 + 18 zero eigenvalues, of which the mode check counts 6 (gauge deflated)."""
    m = beam_model
    G = gauge_modes(m.frames, m.samples.values)
    assert G.shape == (12 * len(m.frames), 18)
    q = m.rest + G[:, 3].reshape(-1, 12)
    assert np.abs(DeformationGradientMapping(m.nodes, m.samples.values).apply(q) - np.eye(3)).max() < 1e-12
    assert np.abs(PointMapping(m.nodes, m.samples.values).apply(q) - m.samples.points).max() < 1e-12
    assert zero_energy_modes(m.frames, m.samples) == 6


def test_gauge_modes_are_the_null_space_of_the_sampled_map(beam_model):
    """gauge_modes (four sums per sample over its parents, ``AffineFrames.gauge_basis``) against the
    assembled Jacobians: the candidates' images under (F, x / L) at the samples, by the mappings' sparse
    Jacobians, have exactly the returned span as their (numerical) null space; chunking changes nothing."""
    m = beam_model
    v = m.samples.values
    Z = m.nodes.gauge_modes()
    L = float(np.ptp(m.frames, axis=0).max())
    JF = DeformationGradientMapping(m.nodes, v).jacobian(m.rest)
    Jx = PointMapping(m.nodes, v).jacobian(m.rest)
    rows = np.vstack([JF @ Z, (Jx @ Z) / L])
    _, sv, Vt = np.linalg.svd(rows, full_matrices=False)
    ref = np.sqrt(v.m / len(m.frames))
    null = Z @ Vt[sv <= 1e-8 * ref].T
    G = gauge_modes(m.frames, v)
    assert G.shape == null.shape == (12 * len(m.frames), 18)
    assert np.abs(G @ G.T - null @ null.T).max() < 1e-10
    chunked = gauge_modes(m.frames, v, chunk=37)
    assert np.abs(chunked @ chunked.T - G @ G.T).max() < 1e-10


def test_gauge_screen_agrees_with_the_assembled_map():
    """Where the weights are not linearly precise everywhere (natural neighbours on the same beam), the Gram
    screen of gauge_modes finds no exact gauge motion, and neither does the SVD of the assembled map (its
    smallest singular value far above 1e-8 of the dilation's response): the screen's shortcut returns what
    the exact QR would."""
    image = LabelImage(np.ones((16, 4, 4), np.uint8), spacing=(0.25,) * 3)
    frames = place_frames(image, 12, seed=0)
    sf = shape_function(image, frames, kind="natural-neighbour")
    m = FrameModel.from_image(image, frames, sf, {1: material("hooke", young=1e3, poisson=0.3)},
                              quadrature="gauss-legendre")
    v = m.samples.values
    Z = m.nodes.gauge_modes()
    L = float(np.ptp(m.frames, axis=0).max())
    rows = np.vstack([DeformationGradientMapping(m.nodes, v).jacobian(m.rest) @ Z,
                      (PointMapping(m.nodes, v).jacobian(m.rest) @ Z) / L])
    sv = np.linalg.svd(rows, compute_uv=False)
    assert sv.min() > 1e-6 * np.sqrt(v.m / len(frames))
    assert gauge_modes(m.frames, v).shape == (12 * len(frames), 0)


def test_lumped_mass_positive_exact_total_and_free_fall(beam_model):
    """Negative weights would lump indefinite per-frame blocks (measured here); the model's lumped mass
    (then J^T diag(m) J at the voxel centres, where gravity acts) is positive definite, carries the
    exact total mass and accelerates every mass point by g under its own weight (to 1e-9); the
    consistent mass is positive definite with the exact total mass."""
    m = beam_model
    pts, vol, _ = m._mass_points()
    v = m.shape_function(pts)
    assert v.w.min() < -0.1
    rho = 2.0
    idx = v.index
    r = np.concatenate([pts[:, None, :] - m.frames[idx], np.ones(idx.shape + (1,))], axis=2)
    raw = np.zeros((len(m.frames), 4, 4))
    np.add.at(raw, idx.ravel(), (rho * vol[:, None, None, None] * v.w[..., None, None]
                                 * r[..., :, None] * r[..., None, :]).reshape(-1, 4, 4))
    assert np.linalg.eigvalsh(raw)[:, 0].min() < 0  # what the fix is for
    g = np.array([0.0, 0.0, -9.81])
    f = m.gravity_force({1: rho}, g).ravel()
    for lumped in (True, False):
        M = m.mass_matrix({1: rho}, lumped=lumped).toarray()
        ev = np.linalg.eigvalsh(M)
        assert ev[0] > 1e-9 * ev[-1]  # positive definite (the 18 gauge motions get mass)
        ex = np.zeros(M.shape[0])
        ex[9::12] = 1.0  # every frame translated by 1 m along x
        assert ex @ M @ ex == pytest.approx(rho * vol.sum(), rel=1e-10)
        if lumped:  # the same points as gravity (the consistent mass integrates on Gauss points, gravity not)
            a = np.linalg.solve(M, f)
            acc = PointMapping(m.nodes, v).apply(m.rest + a.reshape(-1, 12)) - pts
            assert np.abs(acc - g).max() < 1e-9 * 9.81


def test_scene_keys_and_the_cache_round_trip(tmp_path, monkeypatch):
    """[nodes] shape_function = "reproducing-kernel" and support build a frame model that keeps every
    parent; a second build loads the stored weights (equal samples and weights)."""
    import voxflex as vf
    from voxflex.scene import NodesSpec, Scene

    with pytest.raises(InputError, match="support"):
        NodesSpec(count=4, shape_function="natural-neighbour", support=2.0)  # natural neighbours have no kernel radius
    with pytest.raises(InputError, match="> 0"):
        NodesSpec(count=4, shape_function="reproducing-kernel", support=0.0)
    monkeypatch.setenv("VOXFLEX_CACHE_DIR", str(tmp_path))
    text = """
[object]
shape = "box"
size = [1.6, 0.4, 0.4]
voxel_size = 0.1
[[material]]
model = "hooke"
young = 1e3
poisson = 0.3
density = 1.0
[nodes]
count = 8
shape_function = "reproducing-kernel"
support = 2.0
[elasticity]
quadrature = "gauss-legendre"
[[fixed]]
min = [-1, -1, -1]
max = [1e-6, 1, 1]
"""
    scene = Scene.from_toml_text(text)
    assert Scene.from_toml_text(scene.to_toml()) == scene
    a = vf.model(scene)
    b = vf.model(scene)
    assert not a.info["precompute_cached"] and b.info["precompute_cached"]
    assert a.info["shape_function"] == "reproducing-kernel" and a.info["support"] == 2.0
    assert a.info["parents"] == a.samples.values.n_parents > 6  # the scene's parents = 6 does not truncate
    np.testing.assert_array_equal(a.samples.values.w, b.samples.values.w)
    assert (a.shape_function.weights != b.shape_function.weights).nnz == 0


@pytest.mark.parametrize("kind", ["reproducing-kernel", "natural-neighbour"])
def test_point_mass_equals_the_sparse_product(kind):
    """The chunked dense assembly of J^T diag(m) J (the masses of weights negative somewhere, and the
    consistent mass) equals the sparse product of the point mapping's Jacobian (plus the gauge mass),
    and gauge_modes finds 18 exact ones for reproducing kernels, none for natural neighbours."""
    image = _image("box")
    frames = place_frames(image, 9, seed=0)
    sf = shape_function(image, frames, kind=kind)
    model = FrameModel.from_image(image, frames, sf, {1: material("hooke", young=1e3, poisson=0.3)},
                                  quadrature="gauss-legendre")
    pts, vol, _ = model._mass_points()
    v = sf(pts)
    masses = 3.0 * vol
    J = PointMapping(model.nodes, v).jacobian(model.rest)
    ref = (J.T @ sp.diags(np.repeat(masses, 3)) @ J).toarray()
    G = gauge_modes(frames, v)
    assert G.shape[1] == (18 if kind == "reproducing-kernel" else 0)
    if G.shape[1]:
        ref += np.diagonal(ref)[(np.arange(len(ref)) % 12) < 9].mean() * G @ G.T
    got = model._point_mass(v, masses, chunk=100).toarray()
    assert np.abs(got - ref).max() <= 1e-13 * np.abs(ref).max()
