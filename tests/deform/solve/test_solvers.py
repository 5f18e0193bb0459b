"""Static Newton and implicit Euler against closed forms: uniaxial tension, patch test, one mode."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import brentq

from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.deform.solve.boundary import FixedRegion, ForceRegion
from voxflex.deform.solve.options import SolverOptions
from voxflex.deform.solve.stepping import solve
from voxflex.errors import ConvergenceError, InputError
from voxflex.image.label_image import LabelImage

BIG = 10.0


def _block(n=2, mat=None):
    return VoxelModel.from_image(LabelImage(np.ones((n, n, n)), spacing=(1 / n,) * 3), {1: mat})


def _sliding_supports():
    eps = 1e-9
    return [
        FixedRegion([-BIG, -BIG, -BIG], [eps, BIG, BIG], "x"),
        FixedRegion([-BIG, -BIG, -BIG], [BIG, eps, BIG], "y"),
        FixedRegion([-BIG, -BIG, -BIG], [BIG, BIG, eps], "z"),
    ]


def test_uniaxial_stvk_prescribed_stretch_matches_closed_form():
    young, stretch = 1e4, 1.3
    model = _block(2, material("stvk", young=young, poisson=0.0))
    pull = FixedRegion([1 - 1e-9, -BIG, -BIG], [BIG, BIG, BIG], "x", transform=np.diag([stretch, 1, 1, 0])[:3])
    rec = solve(model, fixed=[*_sliding_supports(), pull], options=SolverOptions(steps=2, tolerance=1e-12))
    q = rec[-1].q
    # homogeneous state: x scaled by the stretch, no lateral contraction at nu = 0 (E_yy = 0)
    assert np.allclose(q, model.rest * [stretch, 1, 1], atol=1e-10)
    # reaction on the pulled face = P_xx * area with P_xx = E lambda (lambda^2 - 1) / 2
    face = model.nodes_in_box([1 - 1e-9, -BIG, -BIG], [BIG, BIG, BIG])
    reaction = model.gradient(q)[face, 0].sum()
    assert reaction == pytest.approx(young * stretch * (stretch**2 - 1) / 2, rel=1e-10)


def test_uniaxial_neo_hooke_total_force_matches_lateral_stress_free_root():
    young, poisson, stretch = 1e4, 0.3, 1.25
    mu = young / (2 * (1 + poisson))
    lam = young * poisson / ((1 + poisson) * (1 - 2 * poisson))

    def p_lateral(t):  # P_yy of F = diag(stretch, t, t) for W = mu/2 (I1-3) - mu ln J + lam/2 ln^2 J
        return mu * (t - 1 / t) + lam * np.log(stretch * t * t) / t

    t = brentq(p_lateral, 0.5, 1.0, xtol=1e-15)
    P = mu * (stretch - 1 / stretch) + lam * np.log(stretch * t * t) / stretch
    model = _block(2, material("neo-hookean", young=young, poisson=poisson))
    load = ForceRegion([1 - 1e-9, -BIG, -BIG], [BIG, BIG, BIG], [P * 1.0, 0, 0], kind="force")
    rec = solve(model, fixed=_sliding_supports(), forces=[load], options=SolverOptions(steps=3, tolerance=1e-12))
    # a uniform traction on a flat face of a homogeneous block gives the homogeneous state:
    # the stretches match the closed form to solver precision (residual 1e-12 relative)
    assert np.allclose(rec[-1].q, model.rest * [stretch, t, t], atol=1e-10)
    # traction kind: same face, force per unit area P on an area of 1 m^2
    trac = ForceRegion([1 - 1e-9, -BIG, -BIG], [BIG, BIG, BIG], [P, 0, 0], kind="traction")
    rec2 = solve(model, fixed=_sliding_supports(), forces=[trac], options=SolverOptions(steps=3, tolerance=1e-12))
    assert np.allclose(rec2[-1].q, rec[-1].q, atol=1e-10)


def test_patch_test_interior_is_exactly_affine():
    model = _block(3, material("neo-hookean", young=1e4, poisson=0.3))
    A = np.array([[1.2, 0.1, -0.05], [0.05, 0.9, 0.1], [0.0, -0.1, 1.1]])
    T = np.hstack([A, [[0.1], [0.2], [-0.3]]])
    eps = 1e-9
    faces = []
    for a in range(3):
        for lo, hi in ((-BIG, eps), (1 - eps, BIG)):
            mn, mx = np.full(3, -BIG), np.full(3, BIG)
            mn[a], mx[a] = lo, hi
            faces.append(FixedRegion(mn, mx, transform=T))
    rec = solve(model, fixed=faces, options=SolverOptions(steps=2, tolerance=1e-12))
    expected = model.rest @ A.T + T[:, 3]
    interior = np.all((model.rest > eps) & (model.rest < 1 - eps), axis=1)
    assert interior.sum() == 8
    assert np.abs(rec[-1].q - expected).max() < 1e-10  # exact affine reproduction up to round-off
    # halfway the boundary is at the interpolated map and the interior follows it
    half = model.rest + 0.5 * (model.rest @ A.T + T[:, 3] - model.rest)
    assert np.abs(rec[1].q - half).max() < 1e-10


def test_implicit_euler_single_mode_energy_decay():
    young, rho, h = 1e4, 1000.0, 0.15
    model = VoxelModel.from_image(LabelImage(np.ones((1, 1, 1))), {1: material("hooke", young=young, poisson=0.3,
                                                                                 strain="linear")})
    free_node = int(np.flatnonzero(np.all(model.rest == 1.0, axis=1))[0])
    fixed = [FixedRegion([-BIG] * 3, [BIG, BIG, 1 - 1e-9]), FixedRegion([-BIG] * 3, [1 - 1e-9, BIG, BIG]),
             FixedRegion([-BIG] * 3, [BIG, 1 - 1e-9, BIG])]
    dofs = np.arange(3 * free_node, 3 * free_node + 3)
    K = model.hessian(model.rest).toarray()[np.ix_(dofs, dofs)]
    m = rho / 8.0  # lumped mass of a corner of a 1 m^3 voxel
    w2, vecs = np.linalg.eigh(K / m)
    q0 = model.rest.copy()
    q0[free_node] += 0.01 * vecs[:, 0]
    opts = SolverOptions(kind="implicit-euler", steps=5, dt=h, tolerance=1e-12)
    rec = solve(model, fixed=fixed, densities={1: rho}, options=opts, q0=q0)
    energy = np.array([r.elastic_energy + r.kinetic_energy for r in rec])
    ratio = energy[1:] / energy[:-1]
    # backward Euler multiplies a mode's energy by 1/(1 + w^2 h^2) per step; the linear solve is
    # exact, so the ratio holds to round-off (1e-10 relative)
    assert np.allclose(ratio, 1 / (1 + w2[0] * h * h), rtol=1e-10)
    assert w2[0] * h * h > 0.1  # a step large enough for the decay to be visible


def test_implicit_euler_free_vibration_never_gains_energy():
    mat = material("neo-hookean", young=1e3, poisson=0.3)
    model = VoxelModel.from_image(LabelImage(np.ones((4, 1, 1)), spacing=(0.25, 0.25, 0.25)), {1: mat})
    clamp = FixedRegion([-BIG] * 3, [1e-9, BIG, BIG])
    tip = ForceRegion([1 - 1e-9, -BIG, -BIG], [BIG] * 3, [0, 0, -3.0])
    pre = solve(model, fixed=[clamp], forces=[tip], options=SolverOptions(steps=2))[-1].q
    opts = SolverOptions(kind="implicit-euler", steps=15, dt=0.02, tolerance=1e-10)
    rec = solve(model, fixed=[clamp], densities={1: 100.0}, options=opts, q0=pre)
    total = np.array([r.elastic_energy + r.kinetic_energy for r in rec])
    assert total[0] > 0 and max(r.kinetic_energy for r in rec) > 0.1 * total[0]  # it really moves
    # backward Euler is dissipative: the total energy decreases at every step (round-off slack 1e-12)
    assert np.all(np.diff(total) <= 1e-12 * total[0])
    damped = solve(model, fixed=[clamp], densities={1: 100.0}, q0=pre,
                   options=SolverOptions(kind="implicit-euler", steps=15, dt=0.02, tolerance=1e-10,
                                         rayleigh_mass=2.0, rayleigh_stiffness=1e-3))
    assert damped[-1].elastic_energy + damped[-1].kinetic_energy < total[-1]


def test_non_convergence_and_bad_input_are_reported(monkeypatch):
    import voxflex.deform.solve.stepping as S

    monkeypatch.setattr(S, "MAX_CONTINUATIONS", 0)  # 2 iterations per attempt, no attempt continued: it fails
    model = _block(2, material("neo-hookean", young=1e3, poisson=0.3))
    clamp = FixedRegion([-BIG] * 3, [1e-9, BIG, BIG])
    push = ForceRegion([1 - 1e-9, -BIG, -BIG], [BIG] * 3, [0, 0, -500.0])
    with pytest.raises(ConvergenceError, match=r"static step 1/1.*2 iterations.*residual"):
        solve(model, fixed=[clamp], forces=[push], options=SolverOptions(max_iterations=2))
    with pytest.raises(InputError, match="densities"):
        solve(model, fixed=[clamp], gravity=[0, 0, -9.81], options=SolverOptions())
    with pytest.raises(InputError, match="contains no voxel node"):
        solve(model, fixed=[FixedRegion([5, 5, 5], [6, 6, 6])], options=SolverOptions())
    with pytest.raises(InputError, match=r"\[solver\] kind"):
        SolverOptions(kind="explicit")
    with pytest.raises(InputError, match=r"\[solver\] linear_solver"):
        SolverOptions(linear_solver="lu")


def test_free_block_gather_equals_scipy_slicing_and_follows_pattern_changes():
    import scipy.sparse as sp

    from voxflex.deform.solve.newton import _FreeBlock

    rng = np.random.default_rng(0)
    N = 40
    free = np.sort(rng.choice(N, 27, replace=False))
    reduce = _FreeBlock(free, N)

    def random_symmetric(density):
        A = sp.random(N, N, density=density, random_state=rng, format="csr")
        keep = np.ones(N)
        keep[5] = 0.0  # an empty row and column
        A = sp.csr_matrix(sp.diags(keep) @ (A + A.T) @ sp.diags(keep))
        A.eliminate_zeros()
        return A

    A = random_symmetric(0.2)
    B = random_symmetric(0.05)
    cases = [
        A,  # builds the map
        sp.csr_matrix((rng.standard_normal(A.nnz), A.indices, A.indptr), shape=A.shape),  # same arrays: reuse
        sp.csr_matrix((rng.standard_normal(A.nnz), A.indices.copy(), A.indptr.copy()), shape=A.shape),  # equal
        B,  # another pattern: rebuild
    ]
    for M in cases:
        # a gather of the same entries: exactly equal, structure included
        got = reduce(M)
        ref = M[free][:, free]
        assert got.shape == ref.shape and (got != ref).nnz == 0
        assert np.array_equal(got.toarray(), M.toarray()[np.ix_(free, free)])
    with pytest.raises(ValueError, match="sorted"):
        _FreeBlock(free[::-1], N)
