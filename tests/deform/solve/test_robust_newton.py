"""Robust Newton: load increments cut on failure, stability of the converged state, no silent saddles."""

from __future__ import annotations

import numpy as np
import pytest

from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.deform.solve.boundary import FixedRegion
from voxflex.deform.solve.options import SolverOptions
from voxflex.deform.solve.stepping import solve
from voxflex.errors import ConvergenceError
from voxflex.image.label_image import LabelImage

CLAMP = FixedRegion([-1, -1, -1], [1e-9, 9, 9])
TIP = np.array([[4.0, 0.5, 0.5]])


def _beam(nx=8, n=2, E=1e3):
    image = LabelImage(np.ones((nx, n, n), dtype=np.uint8), spacing=(4.0 / nx, 1.0 / n, 1.0 / n))
    return VoxelModel.from_image(image, {1: material("neo-hookean", young=E, poisson=0.3)})


def test_a_failed_load_step_is_cut_and_reaches_the_same_equilibrium(monkeypatch):
    """Large-deflection neo-Hooke cantilever (tip drop ~ 2.5 m on 4 m) in one load step with only 6
    Newton iterations per attempt and no continuation of an attempt: the first attempt fails, the cut
    increments converge, and the answer equals five well-resolved load steps to the solver tolerance
    (1e-6 relative)."""
    import voxflex.deform.solve.stepping as S

    monkeypatch.setattr(S, "MAX_CONTINUATIONS", 0)
    model = _beam()
    kw = dict(fixed=[CLAMP], gravity=[0, 0, -9.81], densities={1: 1.0})
    with pytest.raises(ConvergenceError):
        solve(model, **kw, options=SolverOptions(steps=5, max_iterations=2))
    cut = solve(model, **kw, options=SolverOptions(steps=1, max_iterations=6))
    ref = solve(model, **kw, options=SolverOptions(steps=5, max_iterations=50))
    assert cut[-1].load_cuts > 0
    tip = model.point_mapping(TIP)
    u_cut = tip.apply(cut[-1].q) - TIP
    u_ref = tip.apply(ref[-1].q) - TIP
    assert u_ref[0, 2] < -2.0
    assert np.allclose(u_cut, u_ref, rtol=0, atol=1e-6 * np.abs(u_ref).max())


@pytest.mark.slow
def test_an_attempt_out_of_iterations_continues_from_its_last_iterate():
    """The 8x2x2 beam whose tip half is 1e6 times stiffer, under full gravity in one load step: its
    stiff half turns by linear Newton updates, ~520 iterations.  With max_iterations = 100 the attempts
    continue from their last iterates (no load cut) and reach the answer of one long attempt
    (max_iterations = 800) to the solver tolerance; without continuation they are cut, and the cut
    increments (smaller loads, the same rotation-bound count) run out of cuts."""
    import voxflex.deform.solve.stepping as S

    kw = dict(fixed=[CLAMP], gravity=[0, 0, -9.81], densities={1: 1.0, 2: 1.0})
    model = _two_part_beam(1e6)
    one = solve(model, **kw, options=SolverOptions(steps=1, linear_solver="direct", max_iterations=800))
    its = one[-1].newton_iterations
    assert 100 < its <= 8 * 100  # needs continuing, and fits in MAX_CONTINUATIONS + 1 attempts
    cont = solve(model, **kw, options=SolverOptions(steps=1, linear_solver="direct", max_iterations=100))
    assert cont[-1].load_cuts == 0
    tip = model.point_mapping(TIP)
    u_one, u_cont = tip.apply(one[-1].q) - TIP, tip.apply(cont[-1].q) - TIP
    assert np.allclose(u_cont, u_one, rtol=0, atol=1e-6 * np.abs(u_one).max())
    S_before = S.MAX_CONTINUATIONS
    try:
        S.MAX_CONTINUATIONS = 0
        with pytest.raises(ConvergenceError, match="cutting the load increment"):
            solve(model, **kw, options=SolverOptions(steps=1, linear_solver="direct", max_iterations=100))
    finally:
        S.MAX_CONTINUATIONS = S_before


def test_a_buckled_column_is_reported_as_unstable_not_returned_as_equilibrium():
    """A clamped-clamped neo-Hooke column 4 m long, 1 m thick, compressed by 40 % (Euler's critical
    strain 4 pi^2 (t^2 / 12) / L^2 = 21 %): the straight state is an equilibrium, but a saddle."""
    model = _beam(nx=16, n=2)
    push = FixedRegion([4 - 1e-9, -1, -1], [9, 9, 9], transform=[[0.6, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]])
    with pytest.raises(ConvergenceError, match=r"unstable equilibrium \(buckling"):
        solve(model, fixed=[CLAMP, push], options=SolverOptions(steps=4, check_stability=True))
    # below the critical strain the straight state is stable and accepted
    small = FixedRegion([4 - 1e-9, -1, -1], [9, 9, 9], transform=[[0.99, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]])
    records = solve(model, fixed=[CLAMP, small], options=SolverOptions(steps=1, check_stability=True))
    assert np.all(np.isfinite(records[-1].q))


@pytest.mark.slow
def test_inertia_counts_the_eigenvalues_below_a_shift():
    """The sparse stability check (Sylvester's inertia of a symmetric factorisation, then shift-inverted
    Lanczos) against a dense eigensolver: the exact count of eigenvalues below the shift, and the one
    nearest below it (1e-8 relative); with a 1e6 spread of the diagonal too."""
    import scipy.sparse as sp

    from voxflex.deform.solve.stepping import _below

    rng = np.random.default_rng(3)
    n = 600
    R = sp.random(n, n, density=4e-3, random_state=4)
    base = (R + R.T).tocsc()
    for spread, lowest in ((1.0, -1.0), (1e6, -1.0), (1e6, 49.0), (1e6, -30.0)):
        A = (base + sp.diags(rng.uniform(1.0, spread, n))).tocsc()
        ev0 = np.linalg.eigvalsh(A.toarray())[0]
        A = (A - sp.identity(n) * (ev0 - lowest)).tocsc()
        ev = np.linalg.eigvalsh(A.toarray())
        shift = -1e-8 * abs(A.diagonal()).max()
        count, lam = _below(A, shift)
        assert count == int(np.count_nonzero(ev < shift))
        if count == 0:
            assert lam is None
        else:
            assert lam == pytest.approx(ev[count - 1], rel=1e-8)


# ------------------------------------------------------------------------------------------------
# stiffness contrast: energies without cancellation; per-sample PSD projection of the tangents
# ------------------------------------------------------------------------------------------------
def _two_part_beam(contrast, nx=8, n=2, E=1e3):
    """Neo-Hooke beam [0, 4] x [0, 1]^2, E on x < 2 and contrast * E on the tip half."""
    lab = np.ones((nx, n, n), dtype=np.uint8)
    lab[nx // 2:] = 2
    image = LabelImage(lab, spacing=(4.0 / nx, 1.0 / n, 1.0 / n))
    return VoxelModel.from_image(image, {1: material("neo-hookean", young=E, poisson=0.3),
                                         2: material("neo-hookean", young=E * contrast, poisson=0.3)})


@pytest.mark.parametrize("name", ["neo-hookean", "stable-neo-hookean"])
def test_the_energy_near_rest_is_exact_relative_to_itself_not_to_the_moduli(name):
    """W of F = R (I + e) with a symmetric strain e of size 1e-7 against the small-strain energy
    mu |e|^2 + lambda/2 (tr e)^2 (R = I: the next-order terms are 1e-7 relative; tolerance 1e-5).
    Evaluated from the invariants I1 ~ 3, J ~ 1 the error would be eps mu ~ 1e-13 Pa against
    W ~ 1e-12 Pa.  At large F the new path equals the law over (I1, I2, J) to 1e-13 of mu."""
    E, nu = 1e3, 0.3
    mu, lm = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    mat = material(name, young=E, poisson=nu)
    rng = np.random.default_rng(5)
    S = rng.standard_normal((50, 3, 3))
    e = 1e-7 * (S + S.transpose(0, 2, 1)) / 2
    ref = mu * np.einsum("nij,nij->n", e, e) + 0.5 * lm * np.trace(e, axis1=1, axis2=2) ** 2
    W = mat.energy(np.eye(3) + e)
    assert np.allclose(W, ref, rtol=1e-5, atol=0)
    assert np.allclose(mat.evaluate(np.eye(3) + e, tangent=False)[0], W, rtol=0, atol=0)  # one W for both paths
    F = np.eye(3) + 0.3 * rng.standard_normal((200, 3, 3))
    F = F[np.linalg.det(F) > 0.1]
    law = mat.law._evaluate(np.ascontiguousarray(mat.strain.apply(F)), False, "numpy")[0]
    assert np.allclose(mat.energy(F), law, rtol=0, atol=1e-13 * mu)


def test_contrast_1e6_small_load_converges_to_the_linear_answer():
    """A 1e6 stiffness contrast under a small load (gravity 1e-3 g: tip drop ~ 2e-3 m on 4 m): near
    the solution the soft half's energy change falls below the stiff half's round-off when W is
    computed from invariants near 3 and 1 (the line search then fails); from H = F - I it converges.
    Oracle: the same beam with linear-strain Hooke (the load is small: nonlinearity ~ 1e-3, so
    tolerance 1e-2 relative on the tip displacement)."""
    kw = dict(fixed=[CLAMP], gravity=[0, 0, -9.81e-3], densities={1: 1.0, 2: 1.0})
    model = _two_part_beam(1e6)
    recs = solve(model, **kw, options=SolverOptions(steps=1, linear_solver="direct", max_iterations=100))
    lab = np.ones((8, 2, 2), dtype=np.uint8)
    lab[4:] = 2
    lin = VoxelModel.from_image(LabelImage(lab, spacing=(0.5, 0.5, 0.5)), {
        1: material("hooke", young=1e3, poisson=0.3, strain="linear"),
        2: material("hooke", young=1e9, poisson=0.3, strain="linear")})
    ref = solve(lin, **kw, options=SolverOptions(steps=1, linear_solver="direct"))
    u = model.point_mapping(TIP).apply(recs[-1].q) - TIP
    u_ref = lin.point_mapping(TIP).apply(ref[-1].q) - TIP
    assert u_ref[0, 2] < -1e-3
    assert np.allclose(u, u_ref, rtol=0, atol=1e-2 * abs(u_ref[0, 2]))
    assert recs[-1].load_cuts == 0  # no failed attempt on the way


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_psd_projection_against_an_eigen_decomposition(backend):
    """The projection of symmetric 9x9 tangents: equal to V max(lambda, 0) V^T from numpy's eigh
    (1e-12 of the largest eigenvalue: round-off of two eigen-solvers), PSD, idempotent, exactly
    unchanged for a positive definite input, and the compiled kernel equals its numpy twin."""
    from voxflex.deform.materials.constitutive import project_psd

    rng = np.random.default_rng(7)
    B = rng.standard_normal((40, 9, 9))
    A = B + B.transpose(0, 2, 1)
    A[:5] = np.einsum("nij,nkj->nik", B[:5], B[:5]) + 1e-3 * np.eye(9)  # positive definite
    lam, V = np.linalg.eigh(A)
    ref = np.einsum("nik,nk,njk->nij", V, np.maximum(lam, 0), V)
    P = project_psd(A, backend=backend)
    scale = np.abs(lam).max()
    assert np.allclose(P, ref, rtol=0, atol=1e-12 * scale)
    assert np.linalg.eigvalsh(P).min() >= -1e-12 * scale
    assert np.array_equal(P[:5], A[:5])
    assert np.allclose(project_psd(P, backend=backend), P, rtol=0, atol=1e-12 * scale)
    other = project_psd(A, backend="numpy" if backend == "numba" else "numba")
    assert np.allclose(P, other, rtol=0, atol=1e-12 * scale)
    assert project_psd(A.reshape(40, 3, 3, 3, 3), backend=backend).shape == (40, 3, 3, 3, 3)
    # the material's fused pass projects the same way (a squeezed, sheared neo-Hooke sample: not PSD)
    mat = material("neo-hookean", young=1e3, poisson=0.3)
    F = np.array([[[0.4, 0.3, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.05]]])
    exact = mat.evaluate(F, backend=backend)[2]
    assert np.linalg.eigvalsh(exact.reshape(1, 9, 9)).min() < 0
    assert np.allclose(mat.evaluate(F, backend=backend, project=True)[2], project_psd(exact, backend="numpy"),
                       rtol=0, atol=1e-12 * np.abs(exact).max())


def test_the_projected_hessian_is_psd_where_the_exact_one_is_not():
    """A neo-Hooke block (2x2x2 voxels) squeezed to 40 % of its length with a shear: the exact
    Hessian has negative eigenvalues; with the tangents projected (voxel model, and through the
    contact layer's forwarding) every eigenvalue is >= -1e-10 of the largest (round-off)."""
    from voxflex.deform.layers.contact import ContactModel
    from voxflex.deform.layers.obstacles import Plane

    model = VoxelModel.from_image(LabelImage(np.ones((2, 2, 2), dtype=np.uint8), spacing=(0.5, 0.5, 0.5)),
                                  {1: material("neo-hookean", young=1e3, poisson=0.3)})
    X = model.rest
    q = X @ np.array([[0.4, 0, 0], [0.3, 1.0, 0], [0, 0, 1.05]]).T
    exact = np.linalg.eigvalsh(model.hessian(q).toarray())
    assert exact.min() < -1e-3 * exact.max()
    assert model.set_tangent_projection(True)
    proj = np.linalg.eigvalsh(model.hessian(q).toarray())
    model.set_tangent_projection(False)
    assert proj.min() >= -1e-10 * proj.max()
    assert np.allclose(np.linalg.eigvalsh(model.hessian(q).toarray()), exact)  # switched off again
    layer = ContactModel(model, [Plane([0, 0, -5.0], [0, 0, 1.0])])
    assert layer.set_tangent_projection(True)
    H = layer.hessian(q)
    layer.set_tangent_projection(False)
    H = H.toarray() if hasattr(H, "toarray") else H
    assert np.linalg.eigvalsh(H).min() >= -1e-10 * proj.max()


def test_projection_on_demand_saves_iterations_on_a_buckling_column():
    """A neo-Hooke column (8x2x2, 4 m, E = 1e3) compressed to half its length in one step, with a
    lateral gravity of 0.1 g that picks the buckled shape: with the exact tangent Newton meets
    negative curvature and needs 40 iterations; ``auto`` switches to projected tangents there and
    back to the exact one after a full step: 28 iterations, to the same stable equilibrium (the
    middle's position to 1e-6 m, i.e. 1e-6 of the 1.1 m deflection; the solver tolerance is 1e-8).
    ``always`` projects every Hessian and still converges there, to the same state."""
    model = _beam(nx=8, n=2)
    push = FixedRegion([4 - 1e-9, -1, -1], [9, 9, 9], transform=[[0.5, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]])
    kw = dict(fixed=[CLAMP, push], gravity=[0, 0, -0.981], densities={1: 1.0})
    mid = model.point_mapping(np.array([[2.0, 0.5, 0.5]]))
    out = {}
    for mode in ("never", "auto", "always"):
        rec = solve(model, **kw, options=SolverOptions(steps=1, linear_solver="direct", tangent_projection=mode,
                                                       check_stability=True))
        out[mode] = (rec[-1].newton_iterations, mid.apply(rec[-1].q))
    assert out["never"][1][0, 2] < -1.0  # buckled sideways
    assert out["auto"][0] < out["never"][0]
    for mode in ("auto", "always"):
        assert np.allclose(out[mode][1], out["never"][1], rtol=0, atol=1e-6)


def test_the_projected_hessian_of_an_affine_frame_model_is_psd():
    """Affine frames (F linear in the frames' 12 DOFs): the model squeezed as in the voxel test has
    a Hessian with negative eigenvalues; projected, every eigenvalue is >= -1e-10 of the largest."""
    from voxflex.deform.models.frames.model import FrameModel
    from voxflex.voronoi.shape_functions import shepard

    image = LabelImage(np.ones((6, 2, 2), dtype=np.uint8), spacing=(0.5, 0.5, 0.5))
    frames = np.array([[0.25, 0.5, 0.5], [1.5, 0.25, 0.25], [1.5, 0.75, 0.75], [2.75, 0.5, 0.5]])

    class SF:
        kind = "shepard"

        def __init__(self):
            self.image, self.frames = image, frames

        def __call__(self, points):
            return shepard(np.asarray(points, dtype=float), frames, n_parents=4)

        def voxel_values(self):
            return self(image.index_to_world(np.argwhere(image.labels > 0) + 0.5))

    model = FrameModel.from_image(image, frames, SF(), {1: material("neo-hookean", young=1e3, poisson=0.3)})
    q = model.moved_state([[0.4, 0, 0, 0], [0.3, 1.0, 0, 0], [0, 0, 1.05, 0]])
    exact = np.linalg.eigvalsh(model.hessian(q))
    assert exact.min() < -1e-3 * exact.max()
    assert model.set_tangent_projection(True)
    proj = np.linalg.eigvalsh(model.hessian(q))
    model.set_tangent_projection(False)
    assert proj.min() >= -1e-10 * proj.max()


def test_the_scene_key_reaches_the_solver_options_and_refuses_unknown_values():
    """``[solver]`` is SolverOptions itself (one class, validated once); a typo is a one-line
    InputError naming the valid choices."""
    from voxflex.errors import InputError
    from voxflex.scene import SolverSpec

    assert SolverSpec is SolverOptions
    assert SolverOptions(tangent_projection="always").tangent_projection == "always"
    assert SolverOptions().tangent_projection == "auto"
    with pytest.raises(InputError, match=r"\[solver\] tangent_projection.*valid: auto, always, never"):
        SolverOptions(tangent_projection="sometimes")


def test_a_run_stopped_at_the_round_off_floor_says_so(tmp_path):
    """A 1e6 stiffness contrast: the stiff half's forces are known to eps |K x| only, so Newton stops at
    that floor, far above a tolerance of 1e-12: simulate() must warn (RoundoffWarning, naming the residual),
    and a well-conditioned run at the same tolerance must not."""
    import warnings

    import voxflex as vf
    from voxflex.scene import Scene
    from voxflex.simulation import RoundoffWarning

    text = """
[object]
shape = "box"
size = [4.0, 1.0, 1.0]
voxel_size = 0.5
[nodes]
kind = "voxel"
[[material]]
model = "neo-hookean"
young = 1e3
poisson = 0.3
density = 1.0
[[fixed]]
min = [-1.0, -1.0, -1.0]
max = [1e-6, 2.0, 2.0]
[[load]]
kind = "gravity"
vector = [0.0, 0.0, -9.81e-3]
[solver]
steps = 1
tolerance = 1e-12
linear_solver = "direct"
"""
    (tmp_path / "s.toml").write_text(text)
    scene = Scene.from_toml(tmp_path / "s.toml")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        vf.simulate(scene, progress=False)  # one material: the floor is far below 1e-12
    stiff = text.replace('young = 1e3\npoisson = 0.3\ndensity = 1.0',
                         'young = 1e3\npoisson = 0.3\ndensity = 1.0\n[[material]]\nlabel = 2\nmodel = "neo-hookean"\n'
                         'young = 1e9\npoisson = 0.3\ndensity = 1.0')
    assert stiff != text
    (tmp_path / "c.toml").write_text(stiff)
    scene2 = Scene.from_toml(tmp_path / "c.toml")
    model = _two_part_beam(1e6)
    with pytest.warns(RoundoffWarning, match="round-off floor"):
        vf.simulate(scene2, progress=False, model=model)


def test_the_chunked_projection_equals_the_serial_one(monkeypatch):
    """Large batches are projected in chunks on numba's threads: the same bits as one serial pass, the same
    count of changed samples."""
    from voxflex.deform.materials import constitutive as C

    rng = np.random.default_rng(8)
    B = rng.standard_normal((301, 9, 9))
    A = B + B.transpose(0, 2, 1)
    A[::3] = np.einsum("nij,nkj->nik", B[::3], B[::3]) + 1e-3 * np.eye(9)
    serial = np.ascontiguousarray(A.copy())
    n_serial = C._project_psd_range(serial, 0, len(A))
    monkeypatch.setattr(C, "PSD_CHUNK_SAMPLES", 16)
    chunked = np.ascontiguousarray(A.copy())
    assert min(64, len(A) // C.PSD_CHUNK_SAMPLES) >= 2
    assert C._project_psd_kernel(chunked) == n_serial == 200
    assert np.array_equal(chunked, serial)


def test_the_large_stability_check_stops_when_its_ritz_pair_has_converged(monkeypatch):
    """Above the inertia limit the check bounds the smallest eigenvalue by LOBPCG in stages: on a clamped
    Hooke beam's free stiffness it returns the smallest eigenvalue to 1 % (eigsh's, shift-invert) before
    its iteration limit; shifted below zero it returns a value under the instability threshold."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    import voxflex.deform.solve.stepping as S
    from voxflex.deform.solve.boundary import fixed_dofs

    model = VoxelModel.from_image(LabelImage(np.ones((24, 6, 6), dtype=np.uint8), spacing=(4.0 / 24,) * 3),
                                  {1: material("hooke", young=1e4, poisson=0.3, strain="linear")})
    dofs, _ = fixed_dofs(model, [FixedRegion([-1, -1, -1], [1e-9, 9, 9])])
    free = np.setdiff1d(np.arange(3 * model.n_nodes), dofs)
    K = model.constant_stiffness_block(free).tocsr()
    exact = float(spla.eigsh(K.tocsc(), k=1, sigma=0.0, which="LM")[0][0])
    stages = []
    inner = spla.lobpcg

    def counted(*args, **kw):
        stages.append(kw["maxiter"])
        return inner(*args, **kw)

    monkeypatch.setattr(spla, "lobpcg", counted)
    theta = S._smallest_rayleigh(K, model.dof_grid, free)
    assert exact > 0 and theta == pytest.approx(exact, rel=1e-2)
    assert sum(stages) < S.EIGEN_MAXITER, stages
    stages.clear()
    shifted = (K - 2.0 * exact * sp.identity(len(free))).tocsr()
    theta = S._smallest_rayleigh(shifted, model.dof_grid, free)
    assert theta < -1e-8 * np.abs(shifted.diagonal()).max()
    # after a Newton solve the check preconditions with that solve's coarse levels (same pattern, other
    # values): no Galerkin product, and the same bound to 1 %
    from voxflex.deform.solve.linear import solve_linear
    from voxflex.deform.solve.multigrid import hierarchy as Hm

    h = Hm.hierarchy(model.dof_grid, free)
    solve_linear(K, np.ones(len(free)), method="multigrid", grid=model.dof_grid, free=free, rtol=1e-8)
    built, galerkin = [], Hm._galerkin_impl
    monkeypatch.setattr(Hm, "_galerkin_impl", lambda *a: built.append(1) or galerkin(*a))
    stale_before = h.stale_solves
    theta = S._smallest_rayleigh((1.1 * K).tocsr(), model.dof_grid, free)
    assert not built and h.stale_solves == stale_before + 1
    assert theta == pytest.approx(1.1 * exact, rel=1e-2)
