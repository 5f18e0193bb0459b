"""The voxel model: energy, forces, stiffness, mass, gravity, boundary surface."""

from __future__ import annotations

import numpy as np
import pytest

from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.voxel import _kernels as kern
from voxflex.deform.models.voxel.model import VoxelModel, tangent_is_constant
from voxflex.errors import InputError
from voxflex.image.label_image import LabelImage
from voxflex.sampling.quadrature import unit_cube_rule
from voxflex.voronoi.trilinear import trilinear_quadrature_values


class _SmallStrainHooke:
    """Private small-strain linear elasticity with the Material.evaluate signature (test oracle)."""

    name = "private-hooke"

    def __init__(self, young, poisson):
        self.mu = young / (2 * (1 + poisson))
        self.lam = young * poisson / ((1 + poisson) * (1 - 2 * poisson))

    def evaluate(self, F, tangent=True):
        I = np.eye(3)
        eps = 0.5 * (F + F.transpose(0, 2, 1)) - I
        tr = np.trace(eps, axis1=1, axis2=2)
        P = 2 * self.mu * eps + self.lam * tr[:, None, None] * I
        W = self.mu * np.einsum("nij,nij->n", eps, eps) + 0.5 * self.lam * tr**2
        A = None
        if tangent:
            A4 = self.mu * (np.einsum("ik,jl->ijkl", I, I) + np.einsum("il,jk->ijkl", I, I))
            A4 = A4 + self.lam * np.einsum("ij,kl->ijkl", I, I)
            A = np.broadcast_to(A4, (len(F), 3, 3, 3, 3)).copy()
        return W, P, A


def _image(occupancy=False):
    labels = np.zeros((3, 3, 2), dtype=np.uint8)
    labels[:, :, 0] = 1
    labels[1, 1, 1] = 2
    labels[2, 0, 1] = 2
    c, s = np.cos(0.4), np.sin(0.4)
    direction = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    occ = None
    if occupancy:
        occ = np.where(labels > 0, 0.25 + 0.75 * np.random.default_rng(1).random(labels.shape), 0.0)
    return LabelImage(labels, spacing=(0.4, 0.5, 0.3), origin=(0.1, 0.2, -0.3), direction=direction, occupancy=occ)


MATS = {1: material("neo-hookean", young=1e4, poisson=0.3), 2: material("stvk", young=3e3, poisson=0.2)}


def _state(model, scale=0.05, seed=0):
    rng = np.random.default_rng(seed)
    return model.rest + scale * 0.3 * rng.standard_normal(model.rest.shape)


@pytest.mark.parametrize("quadrature", ["gauss-legendre", "midpoint"])
def test_gradient_and_hessian_match_finite_differences(quadrature):
    model = VoxelModel.from_image(_image(occupancy=True), MATS, quadrature=quadrature)
    q = _state(model)
    E, g, H = model.energy_gradient_hessian(q)
    rng = np.random.default_rng(3)
    h = 1e-6
    for _ in range(2):
        v = rng.standard_normal(q.shape)
        fd = (model.energy(q + h * v) - model.energy(q - h * v)) / (2 * h)
        # central differences: truncation ~h^2 and round-off ~1e-16 E/h, both < 1e-8 relative
        assert np.vdot(g, v) == pytest.approx(fd, rel=1e-7)
        fdg = (model.gradient(q + h * v) - model.gradient(q - h * v)) / (2 * h)
        Hv = (H @ v.ravel()).reshape(-1, 3)
        assert np.linalg.norm(Hv - fdg) <= 1e-6 * np.linalg.norm(Hv)
    assert abs(H - H.T).max() <= 1e-12 * abs(H).max()
    assert model.energy(q) == pytest.approx(E, rel=1e-15)


def test_rest_state_and_rigid_motion_have_no_energy_or_force():
    model = VoxelModel.from_image(_image(), MATS)
    assert model.energy(model.rest) == pytest.approx(0.0, abs=1e-12)
    assert np.abs(model.gradient(model.rest)).max() < 1e-10
    c, s = np.cos(1.1), np.sin(1.1)
    R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    q = model.rest @ R.T + [3.0, -1.0, 2.0]
    assert abs(model.energy(q)) < 1e-9  # Pa m^3 scale 1e4 * 0.03: round-off level
    assert np.abs(model.gradient(q)).max() < 1e-8


def test_stiffness_kernel_matches_numpy_twin_and_private_hooke():
    rng = np.random.default_rng(0)
    G = rng.standard_normal((8, 8, 3))
    A = rng.standard_normal((3 * 8, 9, 9))
    A = (A + A.transpose(0, 2, 1)).reshape(3 * 8, 3, 3, 3, 3)  # major symmetry, as every tangent (its contract)
    vol = rng.random(3 * 8)
    K = kern.element_stiffness(G, A, vol)
    assert np.allclose(K, kern.element_stiffness_numpy(G, A, vol), rtol=0, atol=1e-12)
    assert np.array_equal(K, K.transpose(0, 2, 1))  # the upper node blocks mirrored: exactly symmetric
    # the library's linear Hooke and the private oracle give the same model
    image = _image()
    hooke = material("hooke", young=1e4, poisson=0.3, strain="linear")
    assert tangent_is_constant(hooke) and not tangent_is_constant(MATS[1])
    a = VoxelModel.from_image(image, {1: hooke, 2: hooke})
    b = VoxelModel.from_image(image, {1: _SmallStrainHooke(1e4, 0.3), 2: _SmallStrainHooke(1e4, 0.3)})
    q = _state(a)
    Ea, ga, Ha = a.energy_gradient_hessian(q)
    Eb, gb, Hb = b.energy_gradient_hessian(q)
    assert Ea == pytest.approx(Eb, rel=1e-12)
    assert np.allclose(ga, gb, rtol=0, atol=1e-10 * np.abs(gb).max())
    assert abs(Ha - Hb).max() <= 1e-10 * abs(Hb).max()
    # cached constant stiffness: the energy is quadratic, E = 1/2 u^T K u
    u = (q - a.rest).ravel()
    assert a.constant_tangent and Ea == pytest.approx(0.5 * u @ (Ha @ u), rel=1e-12)
    assert abs(a.hessian(a.rest) - Ha).max() == 0.0


def test_neo_hookean_element_stiffness_from_three_coefficients_is_the_general_one(monkeypatch):
    """The neo-Hookean element stiffness from F, det F and (dW/dI1, dW/dJ, d2W/dJ2) equals the general
    kernel on the material's full (9, 9) tangent and the numpy twin (1e-12 relative; round-off only),
    gives NaN blocks where a sample is inverted, and the model's Hessian is the same with it or without
    it (the general path stays for projected tangents and every other material)."""
    import voxflex.deform.models.voxel.model as VM

    rng = np.random.default_rng(4)
    G = rng.standard_normal((8, 8, 3))
    mat = material("neo-hookean", young=1e4, poisson=0.3)
    assert mat.linear_in_i1 and not MATS[2].linear_in_i1
    for spread in (1e-3, 0.3):
        F = np.eye(3) + spread * rng.standard_normal((5 * 8, 3, 3))
        vol = rng.random(5 * 8)
        W, P, (s1, s3, k33, J) = mat.evaluate_i1j(F)
        W0, P0, A0 = mat.evaluate(F)
        assert np.array_equal(W, W0) and np.allclose(P, P0, rtol=0, atol=1e-13 * np.abs(P0).max())
        K = kern.element_stiffness_i1j(G, F, J, s1, s3, k33, vol)
        K0 = kern.element_stiffness(G, A0, vol)
        assert np.abs(K - K0).max() <= 1e-12 * np.abs(K0).max()
        assert np.abs(kern.element_stiffness_i1j_numpy(G, F, J, s1, s3, k33, vol) - K0).max() <= 1e-12 * np.abs(K0).max()
        assert np.array_equal(K, K.transpose(0, 2, 1))
    F[3] = np.diag([1.0, 1.0, -0.5])  # an inverted sample of element 0: its block is NaN, the others not
    _, _, parts = mat.evaluate_i1j(F)
    K = kern.element_stiffness_i1j(G, F, parts[3], *parts[:3], vol)
    assert np.all(np.isnan(K[0])) and np.all(np.isfinite(K[1:]))
    with pytest.raises(InputError, match="W = a I1"):
        MATS[2].evaluate_i1j(F)
    model = VoxelModel.from_image(_image(), MATS)
    q = _state(model, scale=0.3)
    E1, g1, H1 = model.energy_gradient_hessian(q)
    monkeypatch.setattr(VM, "I1J_TANGENT", False)
    E0, g0, H0 = model.energy_gradient_hessian(q)
    assert E1 == E0 and np.array_equal(g1, g0) and abs(H1 - H0).max() <= 1e-13 * abs(H0).max()


def _zero_modes(model):
    K = model.hessian(model.rest).toarray()
    ev = np.linalg.eigvalsh(K)
    return int(np.sum(ev < 1e-9 * ev.max()))


def test_free_body_zero_modes_gauss_vs_midpoint_hourglass():
    image = LabelImage(np.ones((2, 2, 2)))
    hooke = material("hooke", young=1e4, poisson=0.3, strain="linear")
    # full integration: exactly the 6 rigid-body modes
    assert _zero_modes(VoxelModel.from_image(image, {1: hooke})) == 6
    # mid-point rule: hourglass modes appear on top of the rigid ones (documented, not hidden);
    # a single voxel has 24 - 6 (strain components at one point) = 18 zero modes
    assert _zero_modes(VoxelModel.from_image(LabelImage(np.ones((1, 1, 1))), {1: hooke}, quadrature="midpoint")) == 18
    assert _zero_modes(VoxelModel.from_image(image, {1: hooke}, quadrature="midpoint")) > 6


def test_mass_matrices_and_gravity():
    image = _image(occupancy=True)
    model = VoxelModel.from_image(image, MATS)
    dens = {1: 1000.0, 2: 500.0}
    occ = image.occupancy[image.labels > 0]
    lab = image.labels[image.labels > 0]
    total = float(np.sum(np.where(lab == 1, 1000.0, 500.0) * occ) * image.voxel_volume)
    Mc = model.mass_matrix(dens, lumped=False)
    Ml = model.mass_matrix(dens, lumped=True)
    ones = np.zeros(3 * model.n_nodes)
    ones[0::3] = 1.0
    # a uniform translation carries the total mass, consistent and lumped alike
    assert ones @ (Mc @ ones) == pytest.approx(total, rel=1e-12)
    assert ones @ (Ml @ ones) == pytest.approx(total, rel=1e-12)
    assert np.allclose(np.asarray(Mc.sum(axis=1)).ravel(), Ml.diagonal(), rtol=1e-12)
    # symmetric up to the summation order of duplicate entries (round-off)
    assert abs(Mc - Mc.T).max() <= 1e-14 * abs(Mc).max() and np.linalg.eigvalsh(Mc.toarray()).min() > 0
    # consistent mass integrates the kinetic energy of an affine velocity field exactly:
    # 1/2 int rho |A X|^2 equals the mass-point sum at the 2x2x2 Gauss points
    A = np.array([[0.3, -1.0, 0.2], [0.5, 0.1, 0.0], [0.0, 0.7, -0.4]])
    v = (model.rest @ A.T).ravel()
    local, qw = unit_cube_rule("gauss-legendre")
    sv = trilinear_quadrature_values(model.grid, local)
    ms = np.repeat(model.element_masses(dens), 8) * np.tile(qw, model.n_elements)
    assert v @ (Mc @ v) == pytest.approx(np.sum(ms * np.sum((sv.rest @ A.T) ** 2, axis=1)), rel=1e-12)
    g = np.array([0.0, -9.81, 1.0])
    fg = model.gravity_force(dens, g)
    assert np.allclose(fg.sum(axis=0), total * g, rtol=1e-12)
    with pytest.raises(InputError, match="no density"):
        model.mass_matrix({1: 1.0})


def test_boundary_surface_is_closed_outward_and_encloses_the_volume():
    image = _image()
    model = VoxelModel.from_image(image, MATS)
    V, F, vmap = model.boundary_surface()
    assert np.array_equal(vmap.apply(model.rest), V)
    assert np.array_equal(V, model.rest[vmap.shape.index[:, 0]])
    # closed and consistently oriented: each directed edge is matched by as many reversed ones
    # (voxels (1,1,1) and (2,0,1) touch along an edge, where 4 faces meet: counts, not a set)
    from collections import Counter

    edges = Counter(map(tuple, np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]).tolist()))
    assert all(edges[(b, a)] == c for (a, b), c in edges.items())
    # divergence theorem: the enclosed volume equals the occupied volume (outward orientation)
    vol = np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum() / 6.0
    assert vol == pytest.approx(int((image.labels > 0).sum()) * image.voxel_volume, rel=1e-12)


def test_point_mapping_reproduces_affine_motion_and_errors():
    image = _image()
    model = VoxelModel.from_image(image, MATS)
    pts = image.index_to_world([[0.3, 0.2, 0.5], [3.0, 3.0, 0.0], [1.5, 1.5, 1.5]])
    pm = model.point_mapping(pts)
    A = np.array([[1.1, 0.2, 0.0], [0.0, 0.9, 0.3], [0.1, 0.0, 1.0]])
    q = model.rest @ A.T + 0.5
    assert np.allclose(pm.apply(q), pts @ A.T + 0.5, atol=1e-12)
    assert np.allclose(pm.jacobian(q) @ q.ravel(), pm.apply(q).ravel(), atol=1e-12)
    assert pm.jacobian(q).shape == (9, 3 * model.n_nodes)
    with pytest.raises(InputError, match="outside the material"):
        model.point_mapping(image.index_to_world([[0.5, 0.5, 1.5]]))


def test_input_errors():
    with pytest.raises(InputError, match=r"label\(s\) \[2\]"):
        VoxelModel.from_image(_image(), {1: MATS[1]})
    with pytest.raises(InputError, match="no occupied voxel"):
        VoxelModel.from_image(LabelImage(np.zeros((2, 2, 2))), MATS)
    with pytest.raises(InputError, match="quadrature"):
        VoxelModel.from_image(_image(), MATS, quadrature="gauss")
    model = VoxelModel.from_image(_image(), MATS)
    with pytest.raises(InputError, match="shape"):
        model.energy(np.zeros((3, 3)))


def _random_image(seed=0, shape=(7, 6, 5), fill=0.45):
    """Scattered occupancy (isolated voxels, holes, edge and corner contacts) with two labels."""
    rng = np.random.default_rng(seed)
    labels = np.where(rng.random(shape) < fill, rng.integers(1, 3, shape), 0).astype(np.uint8)
    labels[0, 0, 0] = 1
    labels[-1, -1, -1] = 2
    occ = np.where(labels > 0, 0.2 + 0.8 * rng.random(shape), 0.0)
    return LabelImage(labels, spacing=(0.3, 0.5, 0.2), occupancy=occ)


@pytest.mark.parametrize("seed, fill", [(0, 0.45), (1, 0.15), (2, 1.0)])
def test_grid_pattern_equals_the_sorting_reference(seed, fill):
    grid = VoxelModel.from_image(_random_image(seed, fill=fill), {1: MATS[1], 2: MATS[2]}).grid
    ref = kern.block_csr_pattern(grid.element_nodes, grid.n_nodes)
    new = kern.grid_block_pattern(grid.element_nodes, grid.n_nodes)
    # the same sparsity, block map and index types: exact equality, not a tolerance
    for a, b in zip(ref, new):
        assert a.dtype == b.dtype and np.array_equal(a, b)


def test_scatter_kernel_matches_numpy_twin_with_shared_matrix_and_scale():
    grid = VoxelModel.from_image(_random_image(3), {1: MATS[1], 2: MATS[2]}).grid
    indptr, indices, indptr_b, blockmap = kern.grid_block_pattern(grid.element_nodes, grid.n_nodes)
    rng = np.random.default_rng(4)
    m = grid.n_elements
    for Ke, scale in ((rng.standard_normal((m, 24, 24)), None), (rng.standard_normal((1, 24, 24)), rng.random(m))):
        a = np.zeros(len(indices))
        b = np.zeros(len(indices))
        kern.scatter_blocks(Ke, grid.element_nodes, blockmap, indptr_b, a, scale=scale)
        kern.scatter_blocks_numpy(Ke, grid.element_nodes, blockmap, indptr_b, b, scale=scale)
        # same products summed in a different order: round-off of a few terms (1e-13 of the largest)
        assert np.abs(a - b).max() <= 1e-13 * np.abs(b).max()


def test_constant_stiffness_equals_per_element_assembly_with_occupancy():
    image = _random_image(5)
    hooke1 = material("hooke", young=1e4, poisson=0.3, strain="linear")
    hooke2 = material("hooke", young=2e3, poisson=0.1, strain="linear")
    model = VoxelModel.from_image(image, {1: hooke1, 2: hooke2})
    oracle = VoxelModel.from_image(image, {1: _SmallStrainHooke(1e4, 0.3), 2: _SmallStrainHooke(2e3, 0.1)})
    assert model.constant_tangent and not oracle.constant_tangent
    q = _state(model)
    E, g, H = model.energy_gradient_hessian(q)
    Eo, go, Ho = oracle.energy_gradient_hessian(q)  # per-sample tangents, per-element 24x24 matrices
    # one unit matrix x volume weight vs per-sample sums: round-off only (1e-12 relative)
    assert abs(H - Ho).max() <= 1e-12 * abs(Ho).max()
    # energy and gradient from the cached quadratic form E0 + g0.u + u.Ku/2 equal the sample sums
    assert E == pytest.approx(Eo, rel=1e-12)
    assert np.abs(g - go).max() <= 1e-12 * np.abs(go).max()
    # a translated, unstrained body: the voxel-wise centred quadratic form keeps the energy at
    # second-order round-off (strain ~1e-15 gives ~1e-26 of young * volume; a global u.Ku would
    # leave eps |K| |u|^2 ~ 1e-13 of it), the forces at first-order round-off
    volume = float(model.element_volume.sum())
    Et, gt, _ = model.energy_gradient_hessian(model.rest + [30.0, -10.0, 20.0], hessian=False)
    assert abs(Et) <= 1e-20 * 1e4 * volume
    assert np.abs(gt).max() <= 1e-9 * np.abs(g).max()
    Ku = model.unit_stiffness(1)
    assert np.allclose(Ku, Ku.T, rtol=0, atol=1e-14 * np.abs(Ku).max())
    # a rigid translation of one voxel is a zero mode of its unit stiffness
    assert np.abs(Ku @ np.tile([1.0, -2.0, 0.5], 8)).max() <= 1e-12 * np.abs(Ku).max()
    with pytest.raises(InputError, match="constant-tangent"):
        VoxelModel.from_image(image, MATS).unit_stiffness(1)


def test_mixed_constant_and_nonlinear_labels_match_finite_differences():
    image = _random_image(6)
    hooke = material("hooke", young=1e4, poisson=0.3, strain="linear")
    model = VoxelModel.from_image(image, {1: hooke, 2: MATS[1]})
    oracle = VoxelModel.from_image(image, {1: _SmallStrainHooke(1e4, 0.3), 2: MATS[1]})
    q = _state(model, seed=2)
    E, g, H = model.energy_gradient_hessian(q)
    Eo, go, Ho = oracle.energy_gradient_hessian(q)
    assert E == pytest.approx(Eo, rel=1e-12)  # round-off of two summation orders
    assert np.abs(g - go).max() <= 1e-12 * np.abs(go).max()
    assert abs(H - Ho).max() <= 1e-12 * abs(Ho).max()
    v = np.random.default_rng(7).standard_normal(q.shape)
    h = 1e-6
    # central differences: truncation ~h^2 and round-off ~1e-16 E/h, both < 1e-7 relative
    fd = (model.energy(q + h * v) - model.energy(q - h * v)) / (2 * h)
    assert np.vdot(g, v) == pytest.approx(fd, rel=1e-7)
    fdg = (model.gradient(q + h * v) - model.gradient(q - h * v)) / (2 * h)
    Hv = (H @ v.ravel()).reshape(-1, 3)
    assert np.linalg.norm(Hv - fdg) <= 1e-6 * np.linalg.norm(Hv)


def test_constant_model_shares_its_cached_stiffness_read_only():
    # an all-constant (linear) model hands out the cached stiffness data without copying it,
    # protected against writes; a model with a nonlinear label gets a fresh array per call
    image = LabelImage(np.ones((3, 2, 2)), spacing=0.5)
    lin = VoxelModel.from_image(image, {1: material("hooke", young=1e4, poisson=0.3, strain="linear")})
    H1, H2 = lin.hessian(lin.rest), lin.hessian(lin.rest + 0.01)
    assert np.shares_memory(H1.data, H2.data) and not H1.data.flags.writeable
    labels = np.ones((3, 2, 2), dtype=np.uint8)
    labels[2] = 2
    mixed = VoxelModel.from_image(
        LabelImage(labels, spacing=0.5),
        {1: material("hooke", young=1e4, poisson=0.3, strain="linear"), 2: material("neo-hookean", young=1e4, poisson=0.3)},
    )
    M1, M2 = mixed.hessian(mixed.rest), mixed.hessian(mixed.rest)
    assert not np.shares_memory(M1.data, M2.data) and M1.data.flags.writeable
    np.testing.assert_array_equal(M1.data, M2.data)


def test_scatter_by_parity_colour_on_threads_matches_the_serial_scatter(monkeypatch):
    """With the elements' voxel indices the scatter runs colour by colour on numba's threads (voxels of one
    parity share no node): equal to the serial scatter to round-off (1e-13 of the largest entry), and the
    same bits on 1 and 2 threads."""
    import numba

    grid = VoxelModel.from_image(_random_image(6, fill=0.8), {1: MATS[1], 2: MATS[2]}).grid
    indptr, indices, indptr_b, blockmap = kern.grid_block_pattern(grid.element_nodes, grid.n_nodes)
    monkeypatch.setattr(kern, "SCATTER_PARALLEL_MIN", 1)
    Ke = np.random.default_rng(7).standard_normal((grid.n_elements, 24, 24))
    serial = np.zeros(len(indices))
    kern.scatter_blocks(Ke, grid.element_nodes, blockmap, indptr_b, serial)
    threads, out = numba.get_num_threads(), []
    try:
        for t in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)}):
            numba.set_num_threads(t)
            a = np.zeros(len(indices))
            kern.scatter_blocks(Ke, grid.element_nodes, blockmap, indptr_b, a, ijk=grid.element_ijk)
            out.append(a)
    finally:
        numba.set_num_threads(threads)
    assert np.array_equal(out[0], out[-1])
    assert np.abs(out[0] - serial).max() <= 1e-13 * np.abs(serial).max()
    assert not np.array_equal(out[0], np.zeros_like(serial))


@pytest.mark.parametrize("law", ["neo-hookean", "hooke"])
def test_the_displacement_form_is_the_position_form_without_the_positions_round_off(law):
    """``energy_gradient_hessian_u(u)`` (F = I + grad u; a linear model's K u) equals
    ``energy_gradient_hessian(rest + u)`` to round-off (1e-8 relative at strains of 1e-2), is exactly
    stress-free at u = 0, and keeps the digits of a motion of strain 2e-11 at 1 km from the origin: its forces
    are K u to eps / strain (1e-5 for neo-Hooke, whose F = I + H rounds H to eps; exact for a linear model),
    where the positions' round-off, eps |x| / h = 4e-13 of strain, leaves them about 2 % off."""
    from voxflex.deform.models.protocol import FromDisplacement

    mat = material(law, young=1e3, poisson=0.3, **({} if law == "neo-hookean" else {"strain": "linear"}))
    image = LabelImage(np.ones((4, 3, 2), dtype=np.uint8), spacing=(0.5, 0.5, 0.5), origin=(1e3, 1e3, 1e3))
    m = VoxelModel.from_image(image, {1: mat})
    assert isinstance(m, FromDisplacement)
    u = 1e-2 * np.random.default_rng(3).standard_normal(m.rest.shape)
    E1, g1, H1 = m.energy_gradient_hessian(m.rest + u)
    E2, g2, H2 = m.energy_gradient_hessian_u(u)
    assert E2 == pytest.approx(E1, rel=1e-8)
    np.testing.assert_allclose(g2, g1, rtol=0, atol=1e-8 * np.abs(g1).max())
    np.testing.assert_allclose(H2.toarray(), H1.toarray(), rtol=0, atol=1e-8 * np.abs(H1.data).max())
    E0, g0, _ = m.energy_gradient_hessian_u(np.zeros_like(u))
    assert E0 == 0.0 and not np.any(g0)
    tiny = 1e-11 * u / np.abs(u).max()
    Ku = m.energy_gradient_hessian_u(np.zeros_like(u))[2] @ tiny.ravel()
    err_u = np.abs(m.energy_gradient_hessian_u(tiny, hessian=False)[1].ravel() - Ku).max() / np.abs(Ku).max()
    err_x = np.abs(m.energy_gradient_hessian(m.rest + tiny, hessian=False)[1].ravel() - Ku).max() / np.abs(Ku).max()
    assert err_u < 1e-4 and err_x > 1e-3, (err_u, err_x)


def test_layers_give_their_own_displacement_form():
    """A layer's energy is its own plus the wrapped model's: handing out the wrapped model's displacement form
    would drop the layer's (a cable's pull vanished from a solve that way), so a layer that adds an energy has
    a form of its own (the wrapped model's plus its term at the positions; ``tests/test_robustness_roundoff.py``
    checks its values), and the wrapped model's strain lengths; a layer without an energy of its own passes the
    wrapped model's form on, and one whose energy cannot take the displacement is evaluated at the positions."""
    from voxflex.deform.layers.cables import CableModel
    from voxflex.deform.models.protocol import FromDisplacement

    m = VoxelModel.from_image(LabelImage(np.ones((4, 1, 1), dtype=np.uint8)), {1: material("neo-hookean", young=1.0,
                                                                                            poisson=0.3)})
    assert isinstance(m, FromDisplacement)
    layer = CableModel.__new__(CableModel)  # the forwarding alone (no cable needed)
    layer.inner = m
    assert layer.energy_gradient_hessian is not None and layer.n_nodes == m.n_nodes  # the rest is forwarded
    assert isinstance(layer, FromDisplacement)
    assert layer.energy_gradient_hessian_u == layer._layered_u and layer.energy_gradient_hessian_u != \
        m.energy_gradient_hessian_u
    assert layer.strain_lengths == m.strain_lengths

    from voxflex.deform.layers.base import ModelLayer

    class Passes(ModelLayer):  # no energy of its own (as plasticity): the wrapped model's form
        def __init__(self, inner):
            self.inner = inner

    class OwnWithoutU(Passes):  # an energy of its own that cannot take u: evaluated at the positions
        def energy_gradient_hessian(self, q, *, gradient=True, hessian=True):
            return self.inner.energy_gradient_hessian(q, gradient=gradient, hessian=hessian)

    assert Passes(m).energy_gradient_hessian_u == m.energy_gradient_hessian_u
    assert not isinstance(OwnWithoutU(m), FromDisplacement)
