"""The frame model alone: derivatives, mass, free-body modes, dynamics.

Shape functions here are hand-made (Shepard weights over the frames, a
partition of unity), so these tests stand apart from the Voronoi stage; the
scene-level tests with natural-neighbour weights are in test_frames_scene.py.
Tolerances: central differences with h = 1e-6 on energies of order 1e1 have
truncation ~1e-12 and round-off ~1e-10 relative; 1e-6 leaves margin and still
catches any wrong term (those give O(1) errors).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

import voxflex as vf
from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.frames.model import FrameModel
from voxflex.deform.solve.options import SolverOptions
from voxflex.deform.solve.stepping import solve
from voxflex.image.label_image import LabelImage
from voxflex.voronoi.shape_functions import shepard

FRAMES = np.array([[0.25, 0.5, 0.5], [1.5, 0.25, 0.25], [1.5, 0.75, 0.75], [2.75, 0.5, 0.5], [2.0, 0.5, 0.9]])


@dataclass(frozen=True, eq=False)
class ShepardSF:
    """A hand-made shape function with the interface of vf.shape_function's result."""

    image: object
    frames: np.ndarray
    parents: int = 4
    kind: str = "shepard"

    def __call__(self, points):
        return shepard(np.asarray(points, dtype=float), self.frames, n_parents=min(self.parents, len(self.frames)))

    def voxel_values(self):
        ijk = np.argwhere(self.image.labels > 0)
        return self(self.image.index_to_world(ijk + 0.5))


def _image():
    return LabelImage(np.ones((6, 2, 2), dtype=np.uint8), spacing=(0.5, 0.5, 0.5))


def _model(mat, *, quadrature="gauss-legendre", samples=None, parents=5, hourglass="none", count=40):
    image = _image()
    sf = ShepardSF(image, FRAMES, parents=parents)
    if quadrature in ("midpoint", "elaston") and samples is None:
        samples = vf.sample(image, sf, kind=quadrature, count=count)
    return FrameModel.from_image(image, FRAMES, sf, {1: mat}, samples=samples, quadrature=quadrature,
                                 hourglass=hourglass)


def _perturbed(model, scale=1e-2, seed=0):
    rng = np.random.default_rng(seed)
    return model.rest + scale * rng.standard_normal(model.rest.shape)


CASES = [
    ("neo-hookean", dict(young=1e3, poisson=0.3), "gauss-legendre", "none"),
    ("hooke", dict(young=1e3, poisson=0.3, strain="corotational"), "midpoint", "none"),
    ("neo-hookean", dict(young=1e3, poisson=0.3), "midpoint", "stiffness"),
    ("ogden", dict(young=1e3, poisson=0.3), "midpoint", "stiffness"),
    ("hooke", dict(young=1e3, poisson=0.3, strain="linear"), "midpoint", "stiffness"),
    ("stvk", dict(young=1e3, poisson=0.3), "elaston", "none"),
    ("hooke", dict(young=1e3, poisson=0.3, strain="linear"), "elaston", "none"),
]


@pytest.mark.parametrize("name, kw, quadrature, hourglass", CASES)
def test_gradient_and_hessian_against_finite_differences(name, kw, quadrature, hourglass):
    model = _model(material(name, **kw), quadrature=quadrature, hourglass=hourglass, count=12)
    q = _perturbed(model)
    E, g, H = model.energy_gradient_hessian(q)
    rng = np.random.default_rng(1)
    d = rng.standard_normal(q.shape)
    h = 1e-6
    fd = (model.energy(q + h * d) - model.energy(q - h * d)) / (2 * h)
    assert fd == pytest.approx(float((g * d).sum()), rel=1e-6)
    gd = (model.gradient(q + h * d) - model.gradient(q - h * d)) / (2 * h)
    Hd = (H @ d.ravel()).reshape(q.shape)
    assert np.max(np.abs(gd - Hd)) <= 1e-6 * np.max(np.abs(Hd))
    assert abs(H - H.T).max() <= 1e-12 * abs(H).max()


def _every_material():
    sys.path.insert(0, str(Path(__file__).parent))
    from contract_materials import MATERIAL_SPECS

    return sorted(MATERIAL_SPECS)


@pytest.mark.parametrize("label", _every_material())
def test_elastons_integrate_every_material_with_exact_derivatives(label):
    """Elastons (moment-fitted sub-rules of the sampler's regions) with every registered material: the
    model's gradient and Hessian against central differences of its energy and gradient at a random
    state (h = 1e-6, rel 1e-6, as above).  The former Taylor elastons refused neo-Hooke, stable
    neo-Hooke, Mooney-Rivlin, Ogden, Arruda-Boyce and the corotational strains."""
    from contract_materials import make

    model = _model(make(label), quadrature="elaston", count=12)
    assert model.samples.kind == "elaston" and model.regions is not None
    q = _perturbed(model)
    E, g, H = model.energy_gradient_hessian(q)
    assert np.isfinite(E)
    rng = np.random.default_rng(1)
    d = rng.standard_normal(q.shape)
    h = 1e-6
    fd = (model.energy(q + h * d) - model.energy(q - h * d)) / (2 * h)
    assert fd == pytest.approx(float((g * d).sum()), rel=1e-6)
    gd = (model.gradient(q + h * d) - model.gradient(q - h * d)) / (2 * h)
    Hd = (H @ d.ravel()).reshape(q.shape)
    assert np.max(np.abs(gd - Hd)) <= 1e-6 * np.max(np.abs(Hd))


@pytest.mark.parametrize("count", [3, 12])
def test_stabilised_midpoint_is_gauss_legendre_for_a_linear_material(count):
    """Linear strain Hooke: each region's mean F plus its fluctuation energy is the Gauss-Legendre
    energy of the same frames exactly (W quadratic, fluctuations of zero mean), so energy, gradient
    and Hessian agree to round-off (1e-12 relative; measured 2e-16 to 6e-16) at a large random state,
    with 3 or 12 regions for 5 frames."""
    mat = material("hooke", young=1e3, poisson=0.3, strain="linear")
    gl = _model(mat)
    mid = _model(mat, quadrature="midpoint", hourglass="stiffness", count=count)
    assert mid.n_samples == count
    q = _perturbed(gl, 0.3, seed=3)
    for a, b in zip(mid.energy_gradient_hessian(q), gl.energy_gradient_hessian(q)):
        assert np.max(np.abs(np.asarray(a) - np.asarray(b))) <= 1e-12 * np.max(np.abs(np.asarray(b)))
    # the bare one-point rule is not (it is too soft)
    bare = _model(mat, quadrature="midpoint", count=count)
    assert bare.energy(q) < 0.95 * gl.energy(q)


def test_stabilised_midpoint_is_objective_and_exact_at_rest():
    """Neo-Hooke: the fluctuation term's Hessian at rest is the Gauss-minus-region-mean stiffness, so the
    rest Hessian equals Gauss-Legendre's (1e-10 relative); a deformed state turned by a finite rotation
    keeps its energy (the pulled-back fluctuation is objective; 1e-10 relative), and an affine state has
    no fluctuation energy."""
    mat = material("neo-hookean", young=1e3, poisson=0.3)
    gl = _model(mat)
    mid = _model(mat, quadrature="midpoint", hourglass="stiffness", count=12)
    Hg, Hm = gl.hessian(gl.rest), mid.hessian(mid.rest)
    assert np.max(np.abs(Hg - Hm)) <= 1e-10 * np.max(np.abs(Hg))
    q = _perturbed(mid, 0.05, seed=5)
    c, s = np.cos(1.1), np.sin(1.1)
    R = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    qr = q.copy()
    for a in range(len(q)):  # x -> R x: every frame's A and t turned
        qr[a, :9] = (R @ q[a, :9].reshape(3, 3)).ravel()
        qr[a, 9:] = R @ q[a, 9:]
    assert mid.energy(qr) == pytest.approx(mid.energy(q), rel=1e-10)
    assert mid._fluct.evaluate(q, mid.deformation_gradients(q), gradient=False, hessian=False)[0] > 0
    T = np.hstack([R @ np.diag([1.1, 0.9, 1.0]), [[0.1], [0.2], [0.3]]])
    qa = mid.moved_state(T)
    assert abs(mid._fluct.evaluate(qa, mid.deformation_gradients(qa), gradient=False, hessian=False)[0]) \
        <= 1e-12 * mid.energy(qa)


def test_fluctuation_kernel_equals_its_numpy_twin():
    """The compiled fluctuation kernel (energy, gradient, Hessian added into dense arrays) against the
    numpy twin at a random state, to 1e-12 relative (round-off of sums of ~100 terms)."""
    model = _model(material("ogden", young=1e3, poisson=0.3), quadrature="midpoint", hourglass="stiffness",
                   count=12)
    q = _perturbed(model, 0.05, seed=2)
    a = model.energy_gradient_hessian(q)
    model._fluct.backend = "numpy"
    b = model.energy_gradient_hessian(q)
    for x, y in zip(a, b):
        assert np.max(np.abs(np.asarray(x) - np.asarray(y))) <= 1e-12 * np.max(np.abs(np.asarray(y)))


def test_affine_motion_is_exact_and_stress_free_rigid_motion_has_no_energy():
    model = _model(material("neo-hookean", young=1e3, poisson=0.3))
    T = np.array([[1.1, 0.2, 0.0, 0.3], [-0.1, 0.95, 0.05, -0.2], [0.0, 0.1, 1.05, 0.4]])
    q = model.moved_state(T)
    F = model.deformation_gradients(q)
    assert np.max(np.abs(F - T[:, :3])) < 1e-12
    pts = np.array([[0.1, 0.1, 0.1], [2.9, 0.9, 0.9], [1.3, 0.4, 0.6]])
    assert np.max(np.abs(model.point_mapping(pts).apply(q) - (pts @ T[:, :3].T + T[:, 3]))) < 1e-12
    c, s = np.cos(0.7), np.sin(0.7)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    q = model.moved_state(np.hstack([R, [[1.0], [2.0], [3.0]]]))
    E, g, _ = model.energy_gradient_hessian(q, hessian=False)
    assert abs(E) < 1e-9 and np.max(np.abs(g)) < 1e-9


def test_free_body_with_enough_samples_has_exactly_six_zero_modes():
    """Per-voxel Gauss samples over 24 voxels and 5 frames: the rigid modes span the null space."""
    model = _model(material("hooke", young=1.0, poisson=0.3, strain="linear"))
    K = np.asarray(model.hessian(model.rest))
    ev = np.linalg.eigvalsh(K)
    assert np.sum(ev < 1e-9 * ev.max()) == 6
    B = model.rigid_modes()
    assert np.max(np.abs(K @ B)) < 1e-10 * ev.max()


def test_mass_matrices_carry_the_mass_and_momentum():
    """Both mass matrices give the translation mode the body's mass (rho V) and are SPD."""
    model = _model(material("neo-hookean", young=1e3, poisson=0.3))
    rho = 1100.0
    mass = rho * _image().labels.sum() * 0.125
    t = model.rigid_modes()[:, 0]  # translation along x
    for lumped in (True, False):
        M = model.mass_matrix({1: rho}, lumped=lumped)
        assert float(t @ (M @ t)) == pytest.approx(mass, rel=1e-12)
        assert np.linalg.eigvalsh(M.toarray()).min() > 0
    g = model.gravity_force({1: rho}, [0.0, 0.0, -9.81])
    assert float(t @ g.ravel()) == pytest.approx(0.0, abs=1e-9)
    assert float(model.rigid_modes()[:, 2] @ g.ravel()) == pytest.approx(-9.81 * mass, rel=1e-12)


def test_lumped_mass_blocks_are_the_per_entry_sums():
    """The lumped mass's per-frame 4x4 blocks (one compiled pass) equal the sums over the voxel centres'
    parent entries written out in numpy (``sum m w [r; 1][r; 1]^T``), bit for bit: the same products added
    in the same order."""
    model = _model(material("neo-hookean", young=1e3, poisson=0.3))
    rho = {1: 1100.0}
    M = model.mass_matrix(rho, lumped=True).toarray()
    mp = model._point_masses(rho)
    v = model._mass_layer()[2].shape
    assert np.all(v.w >= 0)  # the per-frame path (Shepard weights)
    want = np.zeros((model.n_nodes, 4, 4))
    for s_ in range(v.m):
        for p in range(v.index.shape[1]):
            a = v.index[s_, p]
            if a >= 0:
                r = np.append(v.rest[s_] - model.frames[a], 1.0)
                want[a] += np.outer(v.w[s_, p] * mp[s_] * r, r)
    for a in range(model.n_nodes):
        for i in range(3):
            d = [12 * a + 3 * i, 12 * a + 3 * i + 1, 12 * a + 3 * i + 2, 12 * a + 9 + i]
            assert np.allclose(M[np.ix_(d, d)], want[a], rtol=1e-14, atol=0)
    assert np.count_nonzero(M) == model.n_nodes * 3 * 16  # block-diagonal, nothing between frames


def test_held_dofs_are_those_of_the_frames_in_the_voxels_the_box_touches():
    """held_dofs tests only the frames' voxels; the answer is the one of the whole grid's touched voxels."""
    from voxflex.voronoi.placement import voxels_touching_box

    model = _model(material("neo-hookean", young=1e3, poisson=0.3))
    for lo, hi in (([-1, -1, -1], [0.0, 2, 2]), ([1.0, -1, -1], [1.5, 2, 2]), ([2.5, 0.4, 0.4], [9, 9, 9]),
                   ([5, 5, 5], [6, 6, 6])):
        lo, hi = np.array(lo, float), np.array(hi, float)
        ijk = np.floor(model.image.world_to_index(model.frames) + 1e-9).astype(int)
        touched = voxels_touching_box(model.image, lo, hi)[tuple(ijk.T)]
        inside = np.all((model.frames >= lo) & (model.frames <= hi), axis=1)
        frames = np.flatnonzero(touched | inside)
        want = np.sort((12 * frames[:, None] + np.arange(12)[None, :]).ravel())
        assert np.array_equal(model.held_dofs(lo, hi), want)


def test_fields_of_the_solvers_answer_reuse_its_F():
    """The recorder's F at a dynamic step's answer is the solver's last F, formed from the displacement (no
    pass of its own), and equals the F formed from the positions to round-off; another state gets its own."""
    from voxflex.deform.solve.boundary import FixedRegion

    model = _model(material("neo-hookean", young=1e3, poisson=0.3))
    records = solve(model, fixed=[FixedRegion([-1, -1, -1], [0.3, 2, 2])], densities={1: 1000.0},
                    gravity=[0.0, 0.0, -9.81], options=SolverOptions(kind="implicit-euler", dt=0.01, steps=3))
    q = records[-1].q
    F = model.sample_fields(q)["F"]
    assert F is model._last_F[1] and model._last_F[2] is False  # the displacement form's, kept
    Fq = FrameModel.from_image(model.image, model.frames, model.shape_function, model.materials,
                               quadrature="gauss-legendre").deformation_gradients(q)
    assert np.abs(F - Fq).max() < 1e-12 and np.abs(F - np.eye(3)).max() > 1e-4
    other = model.sample_fields(records[1].q)["F"]
    assert other is not F and np.abs(other - F).max() > 1e-6
    # and the energies the steps record are the model's at their states (Newton's own evaluation reused)
    for r in records[1:]:
        assert r.elastic_energy == pytest.approx(float(model.energy(r.q)), rel=1e-9)


def test_implicit_euler_with_frames_never_gains_energy():
    """A clamped bar released from a bent state: total energy never increases (backward Euler dissipates)."""
    model = _model(material("neo-hookean", young=1e3, poisson=0.3))
    from voxflex.deform.solve.boundary import FixedRegion

    clamp = FixedRegion([-1, -1, -1], [0.3, 2, 2])
    q0 = model.rest.copy()
    q0[1:, 11] += 0.05 * (model.frames[1:, 0] / 3.0) ** 2  # bend the free frames upward
    records = solve(model, fixed=[clamp], densities={1: 1000.0},
                    options=SolverOptions(kind="implicit-euler", dt=0.01, steps=15, mass="consistent"), q0=q0)
    total = np.array([r.elastic_energy + r.kinetic_energy for r in records])
    assert total[0] > 0 and np.all(np.diff(total) <= 1e-12 * total[0])
    assert total[-1] < 0.999 * total[0]


def test_structured_kernels_equal_their_numpy_twins_and_the_generic_chain():
    """F, forces and stiffness of the I3 (x) G kernels equal the numpy twins and the generic
    DeformationGradientMapping chain (J^T w P, J^T w A J) to 1e-12 relative (round-off of sums of
    a few hundred terms is ~1e-15; a wrong index gives O(1) errors)."""
    from voxflex.deform.chain.mappings import DeformationGradientMapping
    from voxflex.deform.models.frames import _kernels as K

    model = _model(material("neo-hookean", young=1e3, poisson=0.3), quadrature="midpoint")
    q = _perturbed(model, 0.05)
    idx, G = model._index, model._G
    F = np.empty((model.n_samples, 3, 3))
    K.frame_F(idx, G, q, F)
    fmap = DeformationGradientMapping(model.nodes, model.samples.values)
    assert np.allclose(F, fmap.apply(q), rtol=0, atol=1e-12) and np.allclose(F, K.frame_F_numpy(idx, G, q), atol=1e-12)
    rng = np.random.default_rng(4)
    P = rng.standard_normal(F.shape)
    w = rng.uniform(0.5, 2.0, len(F))
    g = np.zeros((model.n_nodes, 12))
    K.frame_forces(idx, G, P, w, g)
    assert np.allclose(g, fmap.vjp(q, w[:, None, None] * P), atol=1e-12 * np.abs(g).max())
    assert np.allclose(g, K.frame_forces_numpy(idx, G, P, w, model.n_nodes), atol=1e-12 * np.abs(g).max())
    A = rng.standard_normal((len(F), 9, 9))
    A = (A + A.transpose(0, 2, 1)).reshape(-1, 3, 3, 3, 3)
    Kd = K.frame_stiffness_dense(idx, G, A, model.n_nodes, w)
    J = fmap.jacobian(q).toarray()
    D = np.zeros((9 * len(F), 9 * len(F)))
    for s in range(len(F)):
        D[9 * s:9 * s + 9, 9 * s:9 * s + 9] = w[s] * A[s].reshape(9, 9)
    ref = J.T @ D @ J
    assert np.allclose(Kd, ref, atol=1e-12 * np.abs(ref).max())
    assert np.allclose(Kd, K.frame_stiffness_numpy(idx, G, A, w, model.n_nodes), atol=1e-12 * np.abs(ref).max())
    assert np.array_equal(Kd, Kd.T)  # both triangles written from the same pair block


@pytest.mark.parametrize("quadrature", ["midpoint", "gauss-legendre", "elaston"])
def test_point_samples_take_f_and_forces_from_weights_and_gradients(quadrature):
    """Point samples carry (w, dw, X) per parent instead of G's 12 numbers: F and the forces from them equal
    the G kernels' and the generic chain's to 1e-12 relative (a wrong sign or index gives O(1) errors);
    stabilised regions (averages over their Gauss points) keep G."""
    from voxflex.deform.chain.mappings import DeformationGradientMapping
    from voxflex.deform.models.frames import _kernels as K

    model = _model(material("neo-hookean", young=1e3, poisson=0.3), quadrature=quadrature, count=12)
    assert model._points is not None
    q = _perturbed(model, 0.05)
    F = model.deformation_gradients(q)
    Fg = np.empty_like(F)
    K.frame_F(model._index, model._G, q, Fg)
    np.testing.assert_allclose(F, Fg, rtol=0, atol=1e-12)
    chain = DeformationGradientMapping(model.nodes, model.samples.values).apply(q)
    np.testing.assert_allclose(F, chain, rtol=0, atol=1e-12)
    P = np.random.default_rng(5).standard_normal(F.shape)
    g = model._forces(P)
    gg = np.zeros_like(g)
    K.frame_forces(model._index, model._G, P, model._volume, gg)
    np.testing.assert_allclose(g, gg, rtol=0, atol=1e-12 * np.abs(gg).max())
    regions = _model(material("neo-hookean", young=1e3, poisson=0.3), quadrature="midpoint", hourglass="stiffness",
                     count=12)
    assert regions._points is None


def test_pair_tables_sort_parents_and_list_each_coupled_pair_once():
    """frame_pairs against a brute-force set of the frame pairs sharing a sample; parents given in
    any order (and padded) give the same stiffness as sorted ones (to round-off)."""
    from voxflex.deform.models.frames import _kernels as K

    rng = np.random.default_rng(7)
    n, m, P = 9, 40, 4
    index = np.array([rng.choice(n, size=P, replace=False) for _ in range(m)])
    index[::5, -1] = -1  # padding
    index[1::7, 0] = -1  # padding first: sorted last
    G = rng.standard_normal((m, P, 4, 3)) * (index >= 0)[..., None, None]
    idx2, G2, pairs, pair_id = K.frame_pairs(index, G, n)
    brute = {(min(a, b), max(a, b)) for row in index for a in row for b in row if a >= 0 and b >= 0}
    assert {tuple(p) for p in pairs} == brute and len(pairs) == len(brute)
    assert np.all(pair_id[pairs[:, 0], pairs[:, 1]] == np.arange(len(pairs)))
    ok = idx2 >= 0
    assert np.all(np.diff(ok.astype(int), axis=1) <= 0)  # padding last
    assert np.all((np.diff(idx2, axis=1) > 0) | ~ok[:, 1:])  # frames increasing
    A = rng.standard_normal((m, 9, 9))
    A = (A + A.transpose(0, 2, 1)).reshape(-1, 3, 3, 3, 3)
    w = np.ones(m)
    ref = K.frame_stiffness_numpy(index, G, A, w, n)
    assert np.allclose(K.frame_stiffness_dense(index, G, A, n), ref, rtol=0, atol=1e-12 * np.abs(ref).max())


def test_isotropic_dense_products_equal_the_pair_kernel(monkeypatch):
    """isotropic_stiffness_dense (dense products of the tables, parents in any order, padding anywhere) against
    the pair-block kernel with the isotropic tangent, from tables and from point arrays, with positive weights
    (the symmetric product of sqrt-scaled rows) and signed ones, in chunks of 7 samples: to 1e-12 relative
    (round-off).  isotropic_moduli reads (mu, lambda) back and refuses an anisotropic tangent; the choice of path
    prefers dense products where most frames are parents of every sample and the pairs where few are."""
    from voxflex.deform.models.frames import _kernels as K

    rng = np.random.default_rng(11)
    n, m, P = 9, 40, 6
    frames = rng.standard_normal((n, 3))
    index = np.array([rng.choice(n, size=P, replace=False) for _ in range(m)])
    index[::5, -1] = -1
    index[1::7, 0] = -1  # padding first
    ok = index >= 0
    w = rng.random((m, P)) * ok
    dw = rng.standard_normal((m, P, 3)) * ok[..., None]
    rest = rng.standard_normal((m, 3))
    mu, lam = 0.7, 2.3
    I = np.eye(3)
    A1 = mu * (np.einsum("ik,jl->ijkl", I, I) + np.einsum("il,jk->ijkl", I, I)) + lam * np.einsum("ij,kl->ijkl", I, I)
    assert K.isotropic_moduli(A1) == pytest.approx((mu, lam), rel=1e-15)
    A2 = A1.copy()
    A2[0, 0, 0, 0] *= 1.01
    assert K.isotropic_moduli(A2) is None
    A = np.ascontiguousarray(np.broadcast_to(A1, (m, 3, 3, 3, 3)))
    from voxflex.voronoi.shape_functions import ShapeValues

    G = K.frame_tables(ShapeValues(rest=rest, index=index, w=w, dw=dw, ddw=None), frames)
    full = np.array([rng.permutation(40) for _ in range(3000)])  # every frame a parent of every sample
    few = np.array([rng.choice(40, size=4, replace=False) for _ in range(3000)])
    assert K.isotropic_worth_dense(full, 40) and not K.isotropic_worth_dense(few, 40)
    monkeypatch.setattr(K, "ISO_CHUNK", 7)
    for weight in (rng.random(m) + 0.1, rng.standard_normal(m)):
        ref = K.frame_stiffness_numpy(index, G, A, weight, n)
        tol = 1e-12 * np.abs(ref).max()
        np.testing.assert_allclose(K.isotropic_stiffness_dense(index, n, weight, mu, lam, G=G), ref, rtol=0, atol=tol)
        np.testing.assert_allclose(K.isotropic_stiffness_dense(index, n, weight, mu, lam, points=(w, dw, rest, frames)),
                                   ref, rtol=0, atol=tol)
    # a model's rest stiffness by either path: two labels (a product per label), tables and point samples
    labels = np.ones((6, 2, 2), dtype=np.uint8)
    labels[3:] = 2
    image = LabelImage(labels, spacing=(0.5, 0.5, 0.5))
    mats = {1: material("neo-hookean", young=1e3, poisson=0.3), 2: material("stvk", young=3e3, poisson=0.2)}
    for quadrature, hourglass in (("midpoint", "stiffness"), ("gauss-legendre", "none")):
        model = FrameModel.from_image(image, FRAMES, ShepardSF(image, FRAMES), mats, quadrature=quadrature,
                                      hourglass=hourglass)
        out = []
        for dense in (True, False):
            monkeypatch.setattr(K, "isotropic_worth_dense", lambda index, n, dense=dense: dense)
            out.append(model.rest_stiffness())
        np.testing.assert_allclose(out[0], out[1], rtol=0, atol=1e-12 * np.abs(out[1]).max())


def test_sorted_point_tables_equal_the_tables_sorted_afterwards():
    """The point arrays in frame order (sorted_parents, point_arrays) and the tables made from them against
    frame_tables then frame_pairs' permutation, and the compiled tables against their defining formula
    G = w I + r (x) dw, G[3] = dw, zero where padded."""
    from voxflex.deform.models.frames import _kernels as K
    from voxflex.voronoi.shape_functions import ShapeValues

    rng = np.random.default_rng(3)
    n, m, P = 7, 30, 4
    frames = rng.standard_normal((n, 3))
    index = np.array([rng.choice(n, size=P, replace=False) for _ in range(m)])
    index[::4, 1] = -1
    ok = index >= 0
    values = ShapeValues(rest=rng.standard_normal((m, 3)), index=index, w=rng.random((m, P)) * ok,
                         dw=rng.standard_normal((m, P, 3)) * ok[..., None], ddw=None)
    G = K.frame_tables(values, frames)
    r = values.rest[:, None, :] - frames[np.where(ok, index, 0)]
    ref = np.zeros((m, P, 4, 3))
    ref[..., :3, :] = values.w[..., None, None] * np.eye(3) + r[..., :, None] * values.dw[..., None, :]
    ref[..., 3, :] = values.dw
    ref *= ok[..., None, None]
    assert np.allclose(G, ref, rtol=0, atol=1e-14)
    idx_s, order = K.sorted_parents(values)
    G_s = K.tables_from_points(idx_s, K.point_arrays(values, frames, order))
    idx_p, G_p, _, _ = K.frame_pairs(index, G, n)
    assert np.array_equal(idx_s, idx_p) and np.array_equal(G_s, G_p)
    assert np.array_equal(np.take_along_axis(index, order, axis=1), idx_s)


def test_two_materials_assemble_like_the_generic_chain():
    """Two labels with different materials (the per-label gather / scatter path): energy, gradient
    and Hessian equal sum vol W, J^T (vol P) and J^T (vol A) J of the generic mapping, to 1e-12
    relative (round-off only)."""
    from voxflex.deform.chain.mappings import DeformationGradientMapping

    labels = np.ones((6, 2, 2), dtype=np.uint8)
    labels[3:] = 2
    image = LabelImage(labels, spacing=(0.5, 0.5, 0.5))
    sf = ShepardSF(image, FRAMES)
    mats = {1: material("neo-hookean", young=1e3, poisson=0.3), 2: material("stvk", young=3e3, poisson=0.2)}
    model = FrameModel.from_image(image, FRAMES, sf, mats, quadrature="midpoint")
    q = _perturbed(model, 0.05)
    E, g, H = model.energy_gradient_hessian(q)
    s = model.samples
    fmap = DeformationGradientMapping(model.nodes, s.values)
    F = fmap.apply(q)
    W = np.zeros(len(F))
    P = np.zeros_like(F)
    A = np.zeros((len(F), 9, 9))
    for label, mat in mats.items():
        ids = np.flatnonzero(s.label == label)
        W[ids], P[ids], Al = mat.evaluate(F[ids])
        A[ids] = s.volume[ids, None, None] * Al.reshape(-1, 9, 9)
    assert len(np.unique(s.label)) == 2
    assert E == pytest.approx(float(s.volume @ W), rel=1e-12)
    ref_g = fmap.vjp(q, s.volume[:, None, None] * P)
    assert np.max(np.abs(g - ref_g)) <= 1e-12 * np.abs(ref_g).max()
    J = fmap.jacobian(q).toarray()
    D = np.zeros((9 * len(F), 9 * len(F)))
    for k in range(len(F)):
        D[9 * k:9 * k + 9, 9 * k:9 * k + 9] = A[k]
    ref_H = J.T @ D @ J
    assert np.max(np.abs(H - ref_H)) <= 1e-12 * np.abs(ref_H).max()


def test_gauss_moment_kernel_equals_its_numpy_twin():
    """The compiled accumulations of sum_q v_q G_q G_q^T and of the weights' moments per region (over each
    point's own parents) equal their numpy twins to 1e-13 relative, on random tables with padded parents and
    ragged regions."""
    from voxflex.deform.models.frames.stabilise import _gauss_moments, _gauss_moments_numpy

    rng = np.random.default_rng(6)
    K, Pq, R = 60, 3, 4
    region = rng.integers(0, R, K)
    sizes = np.array([3, 4, 5, 6])
    slot = np.stack([rng.choice(sizes[r], Pq, replace=False) for r in region])
    slot[::4, -1] = -1
    Gq = rng.standard_normal((K, Pq, 4, 3))
    vol = rng.uniform(0.1, 1.0, K)
    size = 12 * sizes
    offset = np.concatenate([[0], np.cumsum(size ** 2)[:-1]])
    a = np.zeros(int((size ** 2).sum()))
    b = np.zeros_like(a)
    _gauss_moments(region, slot, Gq, vol, offset, size, a)
    _gauss_moments_numpy(region, slot, Gq, vol, offset, size, b)
    assert np.abs(b).max() > 0 and np.max(np.abs(a - b)) <= 1e-13 * np.abs(b).max()
    # the weights' moments (rows a: [w_a w_b | w_a G_b]) over the same points
    from voxflex.deform.models.frames.stabilise import _weight_moments, _weight_moments_numpy

    w = rng.uniform(0.0, 1.0, (K, Pq))
    woff = np.concatenate([[0], np.cumsum(13 * sizes ** 2)[:-1]])
    a = np.zeros(int((13 * sizes ** 2).sum()))
    b = np.zeros_like(a)
    _weight_moments(region, slot, Gq, w, vol, woff, sizes, a)
    _weight_moments_numpy(region, slot, Gq, w, vol, woff, sizes, b)
    assert np.abs(b).max() > 0 and np.max(np.abs(a - b)) <= 1e-13 * np.abs(b).max()
    # regions over the threads (chunks of REGION_CHUNK): 1 and 2 threads give the same bits on 300 regions
    import numba

    R = 300
    region = rng.integers(0, R, 5000)
    sizes = rng.integers(3, 7, R)
    slot = np.stack([rng.choice(sizes[r], Pq, replace=False) for r in region])
    Gq = rng.standard_normal((len(region), Pq, 4, 3))
    w = rng.uniform(0.0, 1.0, (len(region), Pq))
    vol = rng.uniform(0.1, 1.0, len(region))
    size = 12 * sizes
    offset = np.concatenate([[0], np.cumsum(size ** 2)[:-1]])
    woff = np.concatenate([[0], np.cumsum(13 * sizes ** 2)[:-1]])
    threads = numba.get_num_threads()
    out = []
    try:
        for t in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)}):
            numba.set_num_threads(t)
            a = np.zeros(int((size ** 2).sum()))
            c = np.zeros(int((13 * sizes ** 2).sum()))
            _gauss_moments(region, slot, Gq, vol, offset, size, a)
            _weight_moments(region, slot, Gq, w, vol, woff, sizes, c)
            out.append((a, c))
    finally:
        numba.set_num_threads(threads)
    assert np.array_equal(out[0][0], out[-1][0]) and np.array_equal(out[0][1], out[-1][1])
    b = np.zeros_like(out[0][0])
    _gauss_moments_numpy(region, slot, Gq, vol, offset, size, b)
    assert np.max(np.abs(out[0][0] - b)) <= 1e-13 * np.abs(b).max()


def test_a_state_evaluated_for_its_energy_gives_its_gradient_from_the_kept_stress():
    """The energy pass keeps the state's stress (a line search's accepted trial then needs only the forces):
    the gradient after it equals a cold model's bit for bit; replacing a material or evaluating a plastic
    one is never answered from the kept stress."""
    mat = material("neo-hookean", young=1e3, poisson=0.3)
    model, cold = _model(mat), _model(mat)
    q = _perturbed(model, 0.05)
    E = model.energy(q)
    assert model._last_P is not None and model._last_P[0] is model._gradients_at(q)
    E2, g, _ = model.energy_gradient_hessian(q, hessian=False)
    Ec, gc, _ = cold.energy_gradient_hessian(q, hessian=False)
    assert E == E2 == Ec
    np.testing.assert_array_equal(g, gc)
    # another material at the same state: evaluated afresh, not read from the kept stress
    model.materials = {1: material("neo-hookean", young=2e3, poisson=0.3)}
    E3, g3, _ = model.energy_gradient_hessian(q, hessian=False)
    assert E3 == pytest.approx(2 * E, rel=1e-12)
    np.testing.assert_allclose(g3, 2 * g, rtol=0, atol=1e-12 * np.abs(g).max())
    # a material with state (plasticity) is never kept
    from voxflex.deform.layers.plasticity import PlasticMaterial

    model.materials = {1: PlasticMaterial(material("stvk", young=1e3, poisson=0.3), model.n_samples,
                                          yield_strain=0.01)}
    model.energy(q)
    assert model._last_P is None


def test_parallel_frame_kernels_give_the_same_bits_for_any_thread_count(monkeypatch):
    """The stiffness and the point kernels cut the samples into fixed chunks summed in chunk order: 1 or 2
    threads give the same bits, and the chunked sums equal the serial ones to round-off (1e-12)."""
    import numba

    from voxflex.deform.models.frames import _kernels as K

    monkeypatch.setattr(K, "POINT_CHUNK_ENTRIES", 1)  # chunk even this small model (the default would not)
    model = _model(material("neo-hookean", young=1e3, poisson=0.3), quadrature="gauss-legendre")
    q = _perturbed(model, 0.05)
    m = model.n_samples
    assert K.point_chunks(*model._index.shape) > 1
    rng = np.random.default_rng(6)
    A = rng.standard_normal((m, 9, 9))
    A = (A + A.transpose(0, 2, 1)).reshape(-1, 3, 3, 3, 3)
    P = rng.standard_normal((m, 3, 3))
    monkeypatch.setattr(K, "STIFFNESS_CHUNKS", 3)
    monkeypatch.setattr(K, "STIFFNESS_CHUNK_SAMPLES", 1)
    threads = numba.get_num_threads()
    out = []
    try:
        for t in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)}):
            numba.set_num_threads(t)
            model._last_F = None
            out.append((model.deformation_gradients(q), model._forces(P),
                        K.frame_stiffness_dense(model._index, None, A, model.n_nodes, model._volume,
                                                (model._index, None, model._pairs, model._pair_id), model._points)))
    finally:
        numba.set_num_threads(threads)
    for a, b in zip(out[0], out[-1]):
        assert np.array_equal(a, b)
    F, g, H = out[0]
    Fs = np.empty_like(F)
    K.frame_F(model._index, model._G, q, Fs)
    gs = np.zeros_like(g)
    K.frame_forces(model._index, model._G, P, model._volume, gs)
    Bs = np.zeros((len(model._pairs), 4, K.PAD))
    K._stiffness_range(model._index, model._G, *(np.zeros((0,) + d) for d in ((model._index.shape[1],), (model._index.shape[1], 3), (3,), (3,))),
                       A, model._volume, model._pair_id, Bs, 0, m)
    Hs = np.zeros_like(H)
    K.frame_pairs_to_dense(model._pairs, Bs, Hs)
    np.testing.assert_allclose(F, Fs, rtol=0, atol=1e-12)
    np.testing.assert_allclose(g, gs, rtol=0, atol=1e-12 * np.abs(gs).max())
    np.testing.assert_allclose(H, Hs, rtol=0, atol=1e-12 * np.abs(Hs).max())


@pytest.mark.parametrize("name, kw, quadrature, hourglass", CASES)
def test_the_displacement_form_is_the_position_form(name, kw, quadrature, hourglass):
    """``energy_gradient_hessian_u(q - rest)`` (F = I + J u, the regions' fluctuation from u, a linear
    material's K u) equals ``energy_gradient_hessian(q)`` to round-off (1e-8 relative at strains of 1e-2:
    measured 1e-12), and a linear material's forces are K u exactly at rest and beyond."""
    from voxflex.deform.models.protocol import FromDisplacement

    model = _model(material(name, **kw), quadrature=quadrature, hourglass=hourglass, count=12)
    assert isinstance(model, FromDisplacement)
    q = _perturbed(model)
    E1, g1, H1 = model.energy_gradient_hessian(q)
    E2, g2, H2 = model.energy_gradient_hessian_u(q - model.rest)
    assert E2 == pytest.approx(E1, rel=1e-8)
    np.testing.assert_allclose(g2, g1, rtol=0, atol=1e-8 * np.abs(g1).max())
    np.testing.assert_allclose(H2, H1, rtol=0, atol=1e-8 * np.abs(H1).max())
    E0, g0, _ = model.energy_gradient_hessian_u(np.zeros_like(q))
    assert E0 == 0.0 and np.abs(g0).max() <= 1e-12 * np.abs(g1).max()


def test_reproducing_kernel_gauge_motions_are_pinned_and_move_no_point():
    """Linearly precise weights describe a motion redundantly: their gauge motions move no point, so the
    static tangent was singular along them to round-off (smallest eigenvalues ~1e-17 of the largest
    diagonal entry; whether a Cholesky passed depended on the scene's units).  The energy pins them
    (``alpha |G^T (q - rest)|^2 / 2``): the free tangent is now positive definite with room (> 1e-10), and
    the pinned motions still move no material point (to 1e-12)."""
    from robust import beam

    from voxflex.deform.solve.boundary import FixedRegion, fixed_dofs
    from voxflex.scene import Scene

    text = beam("affine", model="neo-hookean", elasticity='quadrature = "elaston"',
                nodes='count = 8\nshape_function = "reproducing-kernel"')
    model = vf.model(Scene.from_toml_text(text), cache=False)
    G = model.gauge_modes()
    assert G.shape[1] > 0
    H = model.energy_gradient_hessian(model.rest)[2]
    dofs, _ = fixed_dofs(model, [FixedRegion([-1e9] * 3, [1e-6, 1e9, 1e9])])
    free = np.setdiff1d(np.arange(H.shape[0]), dofs)
    Hff = H[np.ix_(free, free)]
    assert np.linalg.eigvalsh(Hff)[0] > 1e-10 * np.abs(np.diagonal(Hff)).max()
    pts = model.image.index_to_world(np.argwhere(model.image.labels > 0) + 0.5)
    pmap = model.point_mapping(pts)
    for k in range(G.shape[1]):
        moved = pmap.apply(model.rest + G[:, k].reshape(model.rest.shape)) - pts
        assert np.abs(moved).max() <= 1e-12 * np.ptp(pts, axis=0).max()


def test_gauge_motions_of_frames_on_a_line_are_found_without_a_singular_solve():
    """Frames on a line (a 16x1x1 bar, 4 reproducing-kernel frames) make the gauge candidates dependent: the search
    solved with their singular QR triangle and the build died with a LinAlgError traceback.  It now takes an
    orthonormal basis of the candidates' span: the model builds, its gauge basis is orthonormal and its motions
    move no voxel centre (1e-12 of the body)."""
    import warnings

    from voxflex.image import LabelImage
    from voxflex.scene import ElasticitySpec, MaterialSpec, NodesSpec, ObjectSpec, Scene

    image = LabelImage(np.ones((16, 1, 1), dtype=np.uint8), spacing=(1.0, 1.0, 1.0))
    scene = Scene(object=ObjectSpec(shape="box", size=(16.0, 1.0, 1.0), voxel_size=1.0),
                  materials=(MaterialSpec(model="neo-hookean", young=1e3, poisson=0.3),),
                  nodes=NodesSpec(kind="affine", count=4, shape_function="reproducing-kernel"),
                  elasticity=ElasticitySpec(quadrature="elaston"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # frames on a line: the kernels warn (partly linear precision)
        model = vf.model(scene, image=image, cache=False)
    G = model.gauge_modes()
    assert G.shape[1] > 0
    np.testing.assert_allclose(G.T @ G, np.eye(G.shape[1]), rtol=0, atol=1e-12)
    pts = image.index_to_world(np.argwhere(image.labels > 0) + 0.5)
    pmap = model.point_mapping(pts)
    for k in range(G.shape[1]):
        moved = pmap.apply(model.rest + G[:, k].reshape(model.rest.shape)) - pts
        assert np.abs(moved).max() <= 1e-12 * np.ptp(pts, axis=0).max()


def test_the_gauge_pin_reads_the_rest_diagonal_without_assembling_it():
    """The pin's alpha (the rest stiffness's mean matrix-entry diagonal) from the point samples' weights equals
    the assembled stiffness's to 1e-12 relative (sums of positive terms in another order), for reproducing
    kernels on a beam whose elaston regions are sub-rules (fewer points than Gauss) and for Gauss points, and
    for two materials; region tables (their fluctuation adds to the diagonal) are left to the assembled one."""
    from robust import beam

    from voxflex.scene import Scene

    for quad in ("elaston", "gauss-legendre"):
        text = beam("affine", model="neo-hookean", size=(4.0, 1.0, 1.0), h=0.125, elasticity=f'quadrature = "{quad}"',
                    nodes='count = 10\nshape_function = "reproducing-kernel"')
        model = vf.model(Scene.from_toml_text(text), cache=False)
        if quad == "elaston":
            assert model.n_samples < 8 * int((model.image.labels > 0).sum())  # sub-rules, not the Gauss rule
        a_ = (np.arange(12 * model.n_nodes) % 12) < 9
        want = float(np.abs(np.diagonal(model.rest_stiffness()))[a_].mean())
        assert model._rest_entry_diagonal() == pytest.approx(want, rel=1e-12)
        assert model._gauge_pin()[1] == pytest.approx(want, rel=1e-12)
    # two materials (a hand-made image, Shepard weights, elaston samples)
    labels = np.ones((6, 2, 2), dtype=np.uint8)
    labels[3:] = 2
    image = LabelImage(labels, spacing=(0.5, 0.5, 0.5))
    sf = ShepardSF(image, FRAMES, parents=5)
    mats = {1: material("neo-hookean", young=1e3, poisson=0.3), 2: material("hooke", young=5e4, poisson=0.45)}
    model = FrameModel.from_image(image, FRAMES, sf, mats, samples=vf.sample(image, sf, kind="elaston", count=12),
                                  quadrature="elaston")
    a_ = (np.arange(12 * model.n_nodes) % 12) < 9
    want = float(np.abs(np.diagonal(model.rest_stiffness()))[a_].mean())
    assert len(model._groups) == 2 and model._rest_entry_diagonal() == pytest.approx(want, rel=1e-12)
    stab = _model(material("neo-hookean", young=1e3, poisson=0.3), quadrature="midpoint", hourglass="stiffness")
    assert stab.tables is not None and stab._rest_entry_diagonal() is None


def test_hidden_gauge_motions_move_nothing_and_are_pinned():
    """modes.hidden_modes: on 22 eigenmode frames in a 32-voxel ball, 3 motions beyond the 18 gauge candidates
    move no voxel centre and deform none (measured: 1e-14 of a unit row); the model's gauge basis holds all 21,
    orthonormal, and the free body's stiffness with them deflated has exactly the 6 rigid zero modes."""
    from dataclasses import replace

    import voxflex as vf
    from voxflex.deform.models.frames.modes import dimensionless, gauge_modes, hidden_modes
    from voxflex.scene import Scene

    from paths import EXAMPLES

    sc = Scene.from_toml(EXAMPLES / "ball_on_plane.toml")
    sc = replace(sc, nodes=replace(sc.nodes, kind="affine", shape_function="eigenmode"))
    model = vf.model(sc, cache=False).inner
    vv = model.shape_function.voxel_values()
    G18 = gauge_modes(model.frames, vv)
    G = hidden_modes(model.frames, vv, G18)
    assert G18.shape[1] == 18 and G.shape[1] == 21
    np.testing.assert_allclose(G.T @ G, np.eye(21), atol=1e-12)
    pm = model.point_mapping(vv.rest)
    for k in range(21):  # every basis motion moves no voxel centre (at 1e-3 of the DOFs: below 1e-12 m)
        q = model.rest + 1e-3 * G[:, k].reshape(model.rest.shape)
        assert np.abs(pm.apply(q) - pm.apply(model.rest)).max() < 1e-12
    K = model.rest_stiffness()
    K = K.toarray() if hasattr(K, "toarray") else np.asarray(K)
    Ks = dimensionless(K, model.samples)
    ev = np.linalg.eigvalsh(Ks + np.trace(Ks) / len(Ks) * (G @ G.T))
    assert int((ev < 1e-8 * ev.max()).sum()) == 6


def test_the_mass_matrix_is_kept_on_the_model_and_handed_out_as_a_copy():
    """Every run of a scene on one model asks for the same mass matrix (0.22 s of a 10-step run of the bunny with
    reproducing kernels): kept per (densities, lumped); a caller that edits its copy changes nothing kept, and
    other densities get their own matrix (twice the density: twice the mass)."""
    from voxflex.voronoi import place_frames, shape_function

    image = LabelImage(np.ones((8, 3, 3), np.uint8), spacing=(0.25,) * 3)
    frames = place_frames(image, 6, seed=0)
    sf = shape_function(image, frames, kind="reproducing-kernel")
    model = FrameModel.from_image(image, frames, sf, {1: material("hooke", young=1e3, poisson=0.3)},
                                  quadrature="gauss-legendre")
    M1 = model.mass_matrix({1: 2.0})
    ref = M1.toarray().copy()
    M1.data[:] = 0.0
    assert np.array_equal(model.mass_matrix({1: 2.0}).toarray(), ref)
    assert np.allclose(model.mass_matrix({1: 4.0}).toarray(), 2.0 * ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
