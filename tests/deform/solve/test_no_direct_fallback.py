"""No direct factorisation of a large tangent: above DIRECT_FALLBACK_MAX unknowns an iterative solve that
stops short is handled on the multigrid path (Newton) or fails at once with its reason (solve_linear)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import voxflex.deform.solve.linear as linear
import voxflex.deform.solve.newton as newton
import voxflex.deform.solve.stepping as stepping
from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.deform.solve.boundary import FixedRegion, fixed_dofs
from voxflex.deform.solve.multigrid.hierarchy import clear_cache
from voxflex.deform.solve.options import SolverOptions
from voxflex.deform.solve.stepping import solve
from voxflex.errors import ConvergenceError
from voxflex.image.label_image import LabelImage


INDEFINITE = ("negative curvature", "preconditioner indefinite")


def _spy_factorisations(monkeypatch):
    """Record the size of every sparse LU of a tangent (the fallback and the stability check's inertia)."""
    sizes = []
    direct, below = linear._direct, stepping._below

    def spy_direct(A, b):
        sizes.append(A.shape[0])
        return direct(A, b)

    def spy_below(A, shift):
        sizes.append(A.shape[0])
        return below(A, shift)

    monkeypatch.setattr(linear, "_direct", spy_direct)
    monkeypatch.setattr(stepping, "_below", spy_below)
    return sizes


def _limit(monkeypatch, n):
    for mod in (linear, newton):
        monkeypatch.setattr(mod, "DIRECT_FALLBACK_MAX", n)
    monkeypatch.setattr(stepping, "INERTIA_MAX", n)


def _indefinite_beam(nx, shift=None):
    """The clamped Hooke beam's free stiffness block shifted down by ``shift`` (default half its smallest
    diagonal entry): its diagonal stays positive (CG starts) but its lowest (bending) eigenvalues turn
    negative."""
    model = VoxelModel.from_image(LabelImage(np.ones((nx, nx // 4, nx // 4)), spacing=(4.0 / nx,) * 3),
                                  {1: material("hooke", young=1e4, poisson=0.3, strain="linear")})
    dofs, _ = fixed_dofs(model, [FixedRegion([-1, -1, -1], [1e-9, 9, 9])])
    free = np.setdiff1d(np.arange(3 * model.n_nodes), dofs)
    K = model.constant_stiffness_block(free)
    shift = 0.5 * K.diagonal().min() if shift is None else shift
    A = (K - shift * sp.identity(len(free))).tocsr()
    b = model.gravity_force({1: 1.0}, [0, 0, -9.81]).ravel()[free]
    return model, free, A, b


def test_an_indefinite_system_above_the_limit_fails_with_its_reason_without_factorising(monkeypatch):
    """Multigrid-CG on a 16x4x4-beam block shifted above its two lowest eigenvalues (the two bending
    modes, equal on a square section: two negative eigenvalues, smooth ones, so the coarse levels see
    them too and the V-cycle itself is indefinite): below the limit the sparse LU answers (as
    before), above it solve_linear raises naming the cause, or with partial=True returns CG's last
    iterate flagged unconverged, and never factorises."""
    model, free, K, b = _indefinite_beam(16, shift=0.0)
    lam = np.sort(spla.eigsh(K, k=3, sigma=0, which="LM", return_eigenvectors=False))
    assert lam[2] > 1.5 * lam[1]
    model, free, A, b = _indefinite_beam(16, shift=0.5 * (lam[1] + lam[2]))
    sizes = _spy_factorisations(monkeypatch)
    clear_cache()
    x, info = linear.solve_linear(A, b, method="multigrid", rtol=1e-8, grid=model.grid, free=free)
    assert info.fell_back and info.reason in INDEFINITE and sizes == [len(free)]
    assert np.linalg.norm(A @ x - b) <= 1e-8 * np.linalg.norm(b)
    _limit(monkeypatch, len(free) - 1)
    sizes.clear()
    with pytest.raises(ConvergenceError, match="(negative curvature|preconditioner indefinite).*not attempted"):
        linear.solve_linear(A, b, method="multigrid", rtol=1e-8, grid=model.grid, free=free)
    x, info = linear.solve_linear(A, b, method="multigrid", rtol=1e-8, grid=model.grid, free=free, partial=True)
    assert not info.converged and info.reason in INDEFINITE and not info.fell_back
    assert info.method == "multigrid" and np.all(np.isfinite(x))
    # the iterate before the negative curvature descends on the quadratic x.A x / 2 - b.x (or is zero)
    assert np.dot(x, A @ x) / 2 - np.dot(b, x) <= 0.0
    assert sizes == []
    # fallback="direct" still factorises when asked
    _, info = linear.solve_linear(A, b, method="multigrid", rtol=1e-8, grid=model.grid, free=free, fallback="direct")
    assert info.fell_back and sizes == [len(free)]


def test_at_the_real_limit_an_indefinite_multigrid_solve_fails_within_its_iterations(monkeypatch):
    """The same indefinite block at 24k unknowns (above DIRECT_FALLBACK_MAX as shipped): no factorisation
    (it would take 4 s and 290 MB here, minutes and gigabytes at the bunny's size), a ConvergenceError
    (the V-cycle of this matrix is itself indefinite: CG stops at its first step)."""
    model, free, A, b = _indefinite_beam(48)
    assert len(free) > linear.DIRECT_FALLBACK_MAX
    sizes = _spy_factorisations(monkeypatch)
    clear_cache()
    with pytest.raises(ConvergenceError, match="negative curvature|preconditioner indefinite"):
        linear.solve_linear(A, b, method="multigrid", rtol=1e-8, grid=model.grid, free=free)
    assert sizes == []


def test_newton_through_a_collapse_stays_on_the_multigrid_path(monkeypatch):
    """A soft neo-Hooke column (2x2x16 voxels of 0.5 m, E = 1e3 Pa, clamped at its foot) under gravity
    with a 5 % lateral part folds over and hangs down (its top moves ~14 m): Newton meets indefinite
    tangents on the way.  With the direct limit below its 459 unknowns, every solve stays on multigrid-CG
    (truncated at the negative curvature, or shifted), nothing is factorised, and the answer is the
    direct solver's to 1e-6 relative."""
    image = LabelImage(np.ones((2, 2, 16), dtype=np.uint8), spacing=(0.5, 0.5, 0.5))
    model = VoxelModel.from_image(image, {1: material("neo-hookean", young=1e3, poisson=0.3)})
    kw = dict(fixed=[FixedRegion([-1, -1, -1], [9, 9, 1e-9])], gravity=[0.49, 0, -9.81], densities={1: 1.0})
    ref = solve(model, **kw, options=SolverOptions(steps=1, linear_solver="direct"))
    _limit(monkeypatch, 50)
    sizes = _spy_factorisations(monkeypatch)
    infos = []
    solve_linear = linear.solve_linear

    def spy_solve(A, b, **kw_):
        x, info = solve_linear(A, b, **kw_)
        infos.append(info)
        return x, info

    monkeypatch.setattr(newton, "solve_linear", spy_solve)
    clear_cache()
    got = solve(model, **kw, options=SolverOptions(steps=1, linear_solver="multigrid"))
    assert sizes == []
    assert any(i.reason in INDEFINITE for i in infos)
    assert all(i.method == "multigrid" for i in infos)
    u_ref = ref[-1].q - model.rest
    assert np.abs(u_ref).max() > 10.0
    assert np.abs(got[-1].q - ref[-1].q).max() <= 1e-6 * np.abs(u_ref).max()
