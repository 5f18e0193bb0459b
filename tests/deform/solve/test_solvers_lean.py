"""The solver's hot path without waste: the lean constant-tangent block, the pattern-aware inertia sum,
Hessians skipped where Newton converges, energy-only line-search evaluations."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.deform.solve import newton as _solvers
from voxflex.deform.solve import potential as _potential
from voxflex.deform.solve.boundary import FixedRegion
from voxflex.deform.solve.options import SolverOptions
from voxflex.deform.solve.stepping import solve
from voxflex.image.label_image import LabelImage

CLAMP = FixedRegion([-1, -1, -1], [1e-9, 2, 2])
G = [0.0, 0.0, -9.81]


def _beam(nx=8, mat=None, **kw):
    n = nx // 4
    mat = mat or material("hooke", young=1e4, poisson=0.3, strain="linear")
    return VoxelModel.from_image(LabelImage(np.ones((nx, n, n)), spacing=(4 / nx, 1 / n, 1 / n)), {1: mat}, **kw)


def _free(model):
    return np.flatnonzero(np.repeat(model.rest[:, 0] > 1e-9, 3))


@pytest.mark.parametrize("method", ["direct", "cg", "multigrid", "amg", "auto"])
def test_lean_static_solve_equals_direct_solution_and_caches_no_stiffness(method):
    model = _beam(8)
    # check_stability: the stability test reads the lean block too (a stable linear beam passes it)
    rec = solve(model, fixed=[CLAMP], gravity=G, densities={1: 1.0},
                options=SolverOptions(linear_solver=method, tolerance=1e-10, check_stability=method == "auto"))
    # the lean path never built the full stiffness (the model caches none)
    assert model._constant is None
    # oracle: the free block of an independently assembled stiffness, solved by dense LU
    ref = _beam(8)
    free = _free(ref)
    K = ref.hessian(ref.rest).toarray()[np.ix_(free, free)]
    f = ref.gravity_force({1: 1.0}, G).ravel()[free]
    u = np.zeros(3 * ref.n_nodes)
    u[free] = np.linalg.solve(K, f)
    got = (rec[-1].q - model.rest).ravel()
    # Newton stops at |r| <= 1e-10 |f| (iterative solvers within it); K's condition number here is ~1e4,
    # so the displacement agrees to ~1e-10 * cond relative: 1e-6 is a safe bound, far below any modelling change
    assert np.max(np.abs(got - u)) <= 1e-6 * np.max(np.abs(u))


def test_lean_static_solve_with_prescribed_motion_equals_condensed_solution():
    model = _beam(8)
    shift = np.array([[1, 0, 0, 0.0], [0, 1, 0, 0.0], [0, 0, 1, 0.05]])  # the clamped face lifted by 5 cm
    moved = FixedRegion([-1, -1, -1], [1e-9, 2, 2], transform=shift)
    rec = solve(model, fixed=[moved], gravity=G, densities={1: 1.0}, options=SolverOptions(tolerance=1e-12))
    assert model._constant is None
    ref = _beam(8)
    free = _free(ref)
    fixed = np.setdiff1d(np.arange(3 * ref.n_nodes), free)
    K = ref.hessian(ref.rest).toarray()
    uc = np.zeros(3 * ref.n_nodes)
    uc[fixed[2::3]] = 0.05
    f = ref.gravity_force({1: 1.0}, G).ravel()
    u = uc.copy()
    u[free] = np.linalg.solve(K[np.ix_(free, free)], f[free] - K[np.ix_(free, fixed)] @ uc[fixed])
    # tolerance as above (Newton residual 1e-12 relative, dense LU oracle)
    assert np.max(np.abs((rec[-1].q - model.rest).ravel() - u)) <= 1e-7 * np.max(np.abs(u))


def test_pattern_add_equals_scipy_sum_dense_and_outside_pattern():
    rng = np.random.default_rng(3)
    A = sp.random(40, 40, density=0.2, random_state=4, format="csr") + sp.identity(40, format="csr")
    A.sum_duplicates()
    add = _potential._PatternAdd()
    S = sp.diags(rng.random(40)).tocsr()  # inside A's pattern (the diagonal)
    for _ in range(2):  # the second call reuses the positions
        A2 = sp.csr_matrix((rng.random(A.nnz), A.indices, A.indptr), shape=A.shape)
        got = add(A2, S)
        # same entries added in a different order: equal to round-off (1 ulp of the sums)
        np.testing.assert_allclose(got.toarray(), (A2 + S).toarray(), rtol=1e-15, atol=1e-15)
    # a new S with the same pattern (the next time step) still adds its own values
    S2 = sp.diags(rng.random(40)).tocsr()
    np.testing.assert_allclose(add(A2, S2).toarray(), (A2 + S2).toarray(), rtol=1e-15, atol=1e-15)
    # an S with an entry outside the pattern falls back to scipy's sum (exact)
    out = sp.csr_matrix(([1.0], ([0], [39])), shape=(40, 40))
    if A2[0, 39] == 0:
        assert _potential._positions_in(A2, out) is None
    np.testing.assert_array_equal(add(A2, out).toarray(), (A2 + out).toarray())
    # dense Hessians (frame models) get S's dense form
    D = rng.random((40, 40))
    np.testing.assert_array_equal(add(D, S), D + S.toarray())
    # the caller's values are never written
    before = A2.data.copy()
    add(A2, S)
    np.testing.assert_array_equal(A2.data, before)


def test_implicit_euler_damped_step_equals_its_linear_system():
    # one implicit Euler step of a linear model from rest: (M/h^2 + D/h + K) u = f on the free DOFs,
    # D = a M + b K (Rayleigh); the inertia matrix is added to each Hessian by _PatternAdd
    h, a, b = 0.01, 0.5, 1e-3
    model = _beam(8)
    opts = SolverOptions(kind="implicit-euler", steps=1, dt=h, rayleigh_mass=a, rayleigh_stiffness=b,
                         tolerance=1e-12, linear_solver="direct")
    rec = solve(model, fixed=[CLAMP], gravity=G, densities={1: 1.0}, options=opts)
    ref = _beam(8)
    free = _free(ref)
    K = ref.hessian(ref.rest).toarray()
    M = ref.mass_matrix({1: 1.0}).toarray()
    A = M / h**2 + (a * M + b * K) / h + K
    f = ref.gravity_force({1: 1.0}, G).ravel()
    u = np.linalg.solve(A[np.ix_(free, free)], f[free])
    got = (rec[-1].q - model.rest).ravel()[free]
    # Newton residual 1e-12 relative on a well-conditioned (mass-dominated) system
    assert np.max(np.abs(got - u)) <= 1e-9 * np.max(np.abs(u))


def test_skipped_hessians_leave_the_iterates_unchanged(monkeypatch):
    mat = material("neo-hookean", young=1e3, poisson=0.3)
    probs = []
    init = _potential._Problem.__init__

    def record(self, *args, **kw):
        init(self, *args, **kw)
        probs.append(self)

    monkeypatch.setattr(_potential._Problem, "__init__", record)

    def run():
        probs.clear()
        model = _beam(8, mat)
        rec = solve(model, fixed=[CLAMP], gravity=G, densities={1: 1.0},
                    options=SolverOptions(steps=3, linear_solver="direct"))
        return rec, sum(p.hessians for p in probs), sum(p.solves for p in probs), sum(p.hessian_misses for p in probs)

    rec, built, solved, misses = run()
    monkeypatch.setattr(_solvers, "_predict_converged", lambda *a: False)
    rec0, built0, solved0, _ = run()
    # the Hessian at an iterate does not depend on when it is assembled: identical iterates, bit for bit
    for r, r0 in zip(rec, rec0):
        np.testing.assert_array_equal(r.q, r0.q)
        assert r.newton_iterations == r0.newton_iterations
    assert solved == solved0
    # every step's converged iterate had its Hessian assembled for nothing before; now at least one is skipped
    assert built < built0
    assert built >= solved  # every solved Hessian was built (a wrong skip rebuilds it: counted in misses)
    assert built - misses <= built0


@pytest.mark.parametrize("volumetric", ["full", "reduced"])
def test_energy_only_pass_equals_the_full_pass(volumetric):
    model = _beam(8, material("neo-hookean", young=1e3, poisson=0.45), volumetric=volumetric)
    rng = np.random.default_rng(0)
    q = model.rest + 0.02 * rng.standard_normal(model.rest.shape)
    E_full = model.energy_gradient_hessian(q, hessian=False)[0]
    # the same energy densities summed in the same order: equal to round-off of the sum
    assert model.energy(q) == pytest.approx(E_full, rel=1e-13)
    # an inverted voxel stays infinite (or NaN) in both
    bad = q.copy()
    bad[model.grid.element_nodes[0, 7]] = model.rest[model.grid.element_nodes[0, 0]] - 0.3
    e_only, e_full = model.energy(bad), model.energy_gradient_hessian(bad, hessian=False)[0]
    assert not np.isfinite(e_only) and not np.isfinite(e_full)
