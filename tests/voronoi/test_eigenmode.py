"""Skinning-eigenmode frame weights (voxflex/voronoi/eigenmode.py).

Oracles: the scalar operators' energy of linear fields (exact: the trilinear space holds them);
the LOBPCG + multigrid eigensolver against scipy's dense ``eigh`` (eigenvalues and the spanned
subspace); the weights' identities (partition of unity, linear reproduction without fixed
regions, the cardinal property at the frames, exact zeros of the other frames on a clamp) to
round-off; central finite differences of w and its gradient; that the blended space depends on
the frame count and not on where the free frames sit (principal angles); refusal of frames that
cannot tell the modes apart; the frame model's patch tests and gauge motions; the pure-bending
stiffness ratio 1; material awareness (a soft segment carries the first mode's variation); the
scene keys and the precompute cache.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.linalg as sla
from precision import check_linear_precision

from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.frames.model import FrameModel
from voxflex.deform.models.frames.modes import gauge_modes
from voxflex.errors import InputError
from voxflex.image import LabelImage
from voxflex.voronoi import shape_function
from voxflex.voronoi import eigenmode as EM

H = 0.1  # voxel edge (m)


def _inside(image, m, seed=0):
    rng = np.random.default_rng(seed)
    ijk = np.argwhere(image.labels > 0)
    return image.index_to_world(ijk[rng.integers(0, len(ijk), m)] + rng.random((m, 3)))


def _dense(sv, what, n):
    out = np.zeros((sv.m, n) + what.shape[2:])
    rows = np.repeat(np.arange(sv.m), sv.n_parents).reshape(sv.index.shape)
    ok = sv.index >= 0
    out[rows[ok], sv.index[ok]] = what[ok]
    return out


def _lshape():
    lab = np.ones((12, 12, 4), np.uint8)
    lab[6:, 6:] = 0
    return LabelImage(lab, spacing=(H, H, H))


def test_operators_integrate_linear_fields_exactly():
    """For f = a . X (nodal values), f^T K f = V a^T D a and 1^T M 1 = rho V (trilinear functions hold
    linear fields, 2x2x2 Gauss points integrate their products exactly); K 1 = 0."""
    image = _lshape()
    D = np.array([[3.0, 0.5, 0.0], [0.5, 2.0, 0.2], [0.0, 0.2, 1.0]])
    K, M = EM.scalar_operators(image, stiffness={1: D}, density={1: 7.0})
    from voxflex.image.grid import TrilinearGrid

    X = TrilinearGrid.from_image(image).node_positions
    V = float((image.labels > 0).sum()) * H ** 3
    a = np.array([0.3, -1.2, 0.7])
    f = X @ a
    assert f @ (K @ f) == pytest.approx(V * a @ D @ a, rel=1e-12)
    one = np.ones(K.shape[0])
    assert np.abs(K @ one).max() < 1e-12 * np.abs(K).max()
    assert one @ (M @ one) == pytest.approx(7.0 * V, rel=1e-12)
    with pytest.raises(InputError, match="positive definite"):
        EM.scalar_operators(image, stiffness={1: -np.eye(3)})
    with pytest.raises(InputError, match="label 1"):
        EM.scalar_operators(image, density={2: 1.0})


@pytest.mark.parametrize("dirichlet", [False, True])
def test_multigrid_lobpcg_matches_dense_eigh(dirichlet):
    """The iterative path (forced with dense_max = 50) against scipy's dense eigh: eigenvalues to 1e-7
    relative (of the largest wanted), the same subspace (largest principal angle below 1e-3)."""
    image = LabelImage(np.ones((16, 6, 6), np.uint8), spacing=(H, H, H))
    K, M = EM.scalar_operators(image)
    if dirichlet:  # the corners of the face x = 0 held
        from voxflex.image.grid import TrilinearGrid

        free = np.flatnonzero(TrilinearGrid.from_image(image).node_ijk[:, 0] > 0)
        K, M = K[free][:, free].tocsr(), M[free][:, free].tocsr()
    k = 12
    ref_l, ref_x = sla.eigh(K.toarray(), M.toarray(), subset_by_index=[0, k - 1])
    lam, X, info = EM.lowest_modes(K, M, k, dense_max=50)
    assert info["iterations"] and info["residual"] < EM.MODE_TOL
    assert np.abs(lam - ref_l).max() < 1e-7 * ref_l[-1]
    # same subspace up to the last (possibly degenerate) cluster: compare the first 10
    ang = sla.subspace_angles(X[:, :10], ref_x[:, :12])
    assert ang.max() < 1e-3
    np.testing.assert_allclose(X.T @ (M @ X), np.eye(k), atol=1e-10)


def test_free_body_weights_are_exact_and_cardinal():
    """Without fixed regions: sum w = 1 and sum w X = X (values, gradients, Hessians) to 1e-12 at random
    points of an L-shape, w_i(X_j) = delta_ij at the frames, the weights sign-changing and global."""
    image = _lshape()
    sf = shape_function(image, np.zeros((0, 3)), kind="eigenmode", count=10)
    assert sf.linear and len(sf.frames) == 10 and sf.parents == 10
    F = sf.frames
    sv = sf(_inside(image, 300))
    L = 1.2
    Xa = F[np.maximum(sv.index, 0)]
    assert np.abs(sv.w.sum(1) - 1).max() < 1e-12
    assert np.abs(sv.dw.sum(1)).max() * H < 1e-12
    assert np.abs(sv.ddw.sum(1)).max() * H * H < 1e-12
    assert np.abs(np.einsum("mp,mpi->mi", sv.w, Xa) - sv.rest).max() / L < 1e-12
    assert np.abs(np.einsum("mpi,mpj->mij", Xa, sv.dw) - np.eye(3)).max() < 1e-12
    at = sf(F)
    np.testing.assert_allclose(_dense(at, at.w, 10), np.eye(10), atol=1e-12)
    assert sv.w.min() < -0.01


def test_values_match_finite_differences():
    """dw and ddw against central differences of w and dw inside voxels (h = 1e-6 voxel)."""
    image = _lshape()
    sf = shape_function(image, np.zeros((0, 3)), kind="eigenmode", count=8)
    n = 8
    ijk = np.argwhere(image.labels > 0)[::11]
    X = image.index_to_world(ijk + 0.25 + 0.5 * np.random.default_rng(2).random((len(ijk), 3)))
    sv = sf(X)
    dw, ddw = _dense(sv, sv.dw, n), _dense(sv, sv.ddw, n)
    h = 1e-6 * H
    for a in range(3):
        e = np.zeros(3)
        e[a] = h
        p, m = sf(X + e), sf(X - e)
        fd = (_dense(p, p.w, n) - _dense(m, m.w, n)) / (2 * h)
        np.testing.assert_allclose(fd, dw[..., a], rtol=0, atol=1e-7 * np.abs(dw).max())
        fd2 = (_dense(p, p.dw, n) - _dense(m, m.dw, n)) / (2 * h)
        np.testing.assert_allclose(fd2, ddw[..., a, :], rtol=0, atol=1e-6 * np.abs(ddw).max())


def _clamped(count, positions=None):
    """A 16x4x4 bar clamped on its first layer of voxels (owned by frame 0 at its centre)."""
    image = LabelImage(np.ones((16, 4, 4), np.uint8), spacing=(H, H, H))
    owner = -np.ones(image.shape, dtype=np.int64)
    owner[0] = 0
    given = np.array([[0.05, 0.15, 0.15]]) if positions is None else np.concatenate([[[0.05, 0.15, 0.15]], positions])
    return image, shape_function(image, given, kind="eigenmode", count=count, seed_owner=owner)


def test_a_clamp_moves_with_its_frame_alone():
    """The corners of the clamped face carry frame 0 alone (weight exactly 1, every other exactly 0), so
    holding frame 0 holds them; partition of unity everywhere; no linear precision (given up there)."""
    image, sf = _clamped(9)
    assert not sf.linear and list(sf.lifted) == [0]
    W = sf.weights.toarray()
    X = sf.grid.node_positions
    face = X[:, 0] < 1e-12
    assert np.all(W[face, 0] == 1.0) and np.all(W[face, 1:] == 0.0)
    assert np.abs(W.sum(1) - 1).max() < 1e-12
    assert np.abs(W[~face, 1:]).max() > 0.5
    at = sf(sf.frames[1:])  # the free frames are cardinal among themselves
    np.testing.assert_allclose(_dense(at, at.w, 9)[:, 1:], np.eye(8), atol=1e-12)


def test_the_span_does_not_depend_on_where_the_free_frames_sit():
    """Two sets of free frames (Q-DEIM points, or given ones) give the same weight space (largest
    principal angle ~ 1e-12), so the frame model's answer depends on the count only."""
    image, a = _clamped(7)
    # given free positions: shifted voxel centres the modes can tell apart
    pos = a.frames[1:] + np.array([H, 0.0, 0.0])
    pos[:, 0] = np.clip(pos[:, 0], H * 1.5, 1.55)
    _, b = _clamped(7, positions=pos)
    np.testing.assert_allclose(b.frames[1:], pos)
    ang = sla.subspace_angles(a.weights.toarray(), b.weights.toarray())
    assert ang.max() < 1e-9


def test_frames_that_cannot_tell_the_modes_apart_are_refused():
    """Two free frames mirrored across the axis of a clamped bar whose 3 lowest modes vary along it only:
    the interpolation matrix is singular -> InputError naming the fix (no NaN, no dependent weights)."""
    pos = np.array([[0.85, 0.15, 0.15], [0.85, 0.25, 0.25], [1.45, 0.15, 0.15]])
    with pytest.raises(InputError, match="tell the 3 modes apart"):
        _clamped(4, positions=pos)
    with pytest.raises(InputError, match="fewer than the"):
        shape_function(LabelImage(np.ones((4, 4, 4), np.uint8)), [[0.5, 0.5, 0.5], [1.5, 1.5, 1.5]],
                       kind="eigenmode", count=1)
    with pytest.raises(InputError, match="eigenmode"):
        shape_function(LabelImage(np.ones((4, 4, 4), np.uint8)), [[0.5, 0.5, 0.5]], count=3)
    for count, what in ((9, "exceeds the 8 material voxels"), (0, "count must be an integer >= 1")):
        with pytest.raises(InputError, match=what) as err:
            shape_function(LabelImage(np.ones((2, 2, 2), np.uint8)), np.zeros((0, 3)), kind="eigenmode", count=count)
        assert "\n" not in str(err.value)


def test_soft_segment_carries_the_first_mode():
    """Material awareness: a clamped bar whose far half is 100x softer; the first Dirichlet mode (a frame's
    weight with 2 frames: the clamp's lift and one mode) changes across the soft half 100x more per length
    than across the stiff half, as the 1-D eigenproblem (-(D u')' = lambda u) says for lambda << D / L^2."""
    lab = np.ones((20, 2, 2), np.uint8)
    lab[10:] = 2
    image = LabelImage(lab, spacing=(H, H, H))
    owner = -np.ones(image.shape, dtype=np.int64)
    owner[0] = 0
    sf = shape_function(image, [[0.05, 0.05, 0.05]], kind="eigenmode", count=2, seed_owner=owner,
                        stiffness={1: 100.0, 2: 1.0})
    w = sf.weights.toarray()[:, 1]
    x = sf.grid.node_positions[:, 0]
    at = {round(v, 6): w[np.isclose(x, v)].mean() for v in (0.1, 0.9, 1.1, 1.9)}
    stiff, soft = abs(at[0.9] - at[0.1]), abs(at[1.9] - at[1.1])
    assert 50 < soft / stiff < 200


@pytest.fixture(scope="module")
def free_beam():
    """A free 16x4x4 beam (voxels 0.25 m), 10 eigenmode frames, Gauss points."""
    image = LabelImage(np.ones((16, 4, 4), np.uint8), spacing=(0.25,) * 3)
    sf = shape_function(image, np.zeros((0, 3)), kind="eigenmode", count=10)
    mats = {1: material("hooke", young=1e3, poisson=0.3, strain="linear")}
    return FrameModel.from_image(image, sf.frames, sf, mats, quadrature="gauss-legendre")


def test_patch_tests_and_gauge_modes(free_beam):
    """An affine motion of every frame gives F = its matrix at every Gauss point; a quadratic field is
    represented exactly (linear precision); the 18 gauge motions move nothing."""
    m = free_beam
    check_linear_precision(m, x_tol=1e-10)
    assert gauge_modes(m.frames, m.samples.values).shape[1] == 18


def test_pure_bending_is_exact(free_beam):
    """Constant bending moment on the free beam (end tractions of sigma_xx = -E kappa (z - z0)): the
    compliance equals the exact E I kappa^2 L to 1e-6 (linear precision makes the quadratic field exact)."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spl

    m = free_beam
    E, kappa, L, h = 1e3, 1e-3, 4.0, 0.25
    g = 0.5 / np.sqrt(3.0)
    loc = np.array([0.5 - g, 0.5 + g])
    s = ((np.arange(4)[:, None] + loc[None]) * h).ravel()
    Y, Z = np.meshgrid(s, s, indexing="ij")
    q0 = m.rest
    f = np.zeros(q0.size)
    for x, sgn in ((0.0, -1.0), (L, 1.0)):
        pts = np.stack([np.full(Y.size, x), Y.ravel(), Z.ravel()], 1)
        Fo = np.zeros((len(pts), 3))
        Fo[:, 0] = sgn * (-E * kappa * (pts[:, 2] - 0.5)) * h * h / 4
        f += np.asarray(m.point_mapping(pts).vjp(q0, Fo)).ravel()
    K = sp.csr_matrix(m.hessian(q0))
    R = m.rigid_modes()
    A = sp.bmat([[K, sp.csr_matrix(R)], [sp.csr_matrix(R.T), None]]).tocsc()
    sol = spl.spsolve(A, np.concatenate([f, np.zeros(R.shape[1])]))
    exact = E * kappa ** 2 / 12.0 * L
    assert exact / float(f @ sol[:q0.size]) == pytest.approx(1.0, abs=1e-6)


def test_scene_keys_and_the_cache_round_trip(tmp_path, monkeypatch):
    """[nodes] shape_function = "eigenmode" builds a frame model whose frames are the clamp's and the modes'
    points, every frame a parent; a second build loads the stored weights; placement = "strain" is refused
    with eigenmodes, support too; rigid frames do not take eigenmodes."""
    import voxflex as vf
    from voxflex.scene import NodesSpec, Scene

    with pytest.raises(InputError, match="eigenmode"):
        NodesSpec(count=4, shape_function="eigenmode", placement="strain")
    with pytest.raises(InputError, match="support"):
        NodesSpec(count=4, shape_function="eigenmode", support=2.0)
    with pytest.raises(InputError, match="does not apply"):
        NodesSpec(kind="rigid", count=4, shape_function="eigenmode")
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
count = 7
shape_function = "eigenmode"
[elasticity]
quadrature = "gauss-legendre"
[[fixed]]
min = [-1, -1, -1]
max = [1e-6, 1, 1]
"""
    scene = Scene.from_toml_text(text)
    assert Scene.from_toml_text(scene.to_toml()) == scene
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        a = vf.model(scene)
        b = vf.model(scene)
    assert not a.info["precompute_cached"] and b.info["precompute_cached"]
    assert a.info["shape_function"] == "eigenmode" and a.info["parents"] == 7 == a.samples.values.n_parents
    assert a.info["eigenmode_lifted"] == 1 and not a.info["eigenmode_linear"]
    assert a.frames[0][0] < 0.1  # the clamp's frame first
    np.testing.assert_array_equal(a.frames, b.frames)
    np.testing.assert_array_equal(a.samples.values.w, b.samples.values.w)
    assert (a.shape_function.weights != b.shape_function.weights).nnz == 0
    # the weights do not depend on the materials' scale (D and rho both scaled), but the key does
    assert a.samples.values.ddw is None  # Gauss points: no Hessians stored


def test_a_degenerate_cluster_is_taken_whole_and_the_frames_do_not_depend_on_the_unit():
    """The clamped square bar's modes come in pairs (bending about y and z): asking for 6 frames (the clamp's
    and 5 modes) would cut the pair of modes 5 and 6, leaving a round-off-driven direction of it; the pair is
    completed (7 frames).  The same bar at 1 m, 1 um and 1 km: the same frames (Q-DEIM ties broken scale-free;
    LAPACK's pivoting put them 3 voxels apart; at 1 km the rows' squared norms, below 1, tied with the -1
    marking the rows already taken until that sentinel left the tolerance's magnitude) and the same weights."""
    out = {}
    for s in (1.0, 1e-6, 1e3):
        image = LabelImage(np.ones((16, 4, 4), np.uint8), spacing=(s * H,) * 3)
        owner = -np.ones(image.shape, dtype=np.int64)
        owner[0] = 0
        out[s] = shape_function(image, [[0.5 * s * H, 1.5 * s * H, 1.5 * s * H]], kind="eigenmode", count=6,
                                seed_owner=owner)
    a, b = out[1.0], out[1e-6]
    assert len(a.frames) == 7 and len(a.eigenvalues) == 6
    lam = a.eigenvalues
    assert abs(lam[5] - lam[4]) < 1e-9 * lam[5] and lam[4] > lam[3] * (1 + 1e-3)
    np.testing.assert_allclose(b.frames / 1e-6, a.frames, rtol=0, atol=1e-12 * 1.6)
    np.testing.assert_allclose(b.weights.toarray(), a.weights.toarray(), rtol=0, atol=1e-9)
    np.testing.assert_allclose(out[1e3].frames / 1e3, a.frames, rtol=0, atol=1e-12 * 1.6)
    np.testing.assert_allclose(out[1e3].weights.toarray(), a.weights.toarray(), rtol=0, atol=1e-9)
    assert len(shape_function(image, [[0.5 * H * 1e-6, 1.5e-6 * H, 1.5e-6 * H]], kind="eigenmode", count=7,
                              seed_owner=owner).frames) == 7
