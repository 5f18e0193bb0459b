"""Robust Newton: load increments cut on failure, stability of the converged state, no silent saddles."""

from __future__ import annotations

import numpy as np
import pytest

from voxflex.deform.boundary import FixedRegion
from voxflex.deform.materials import material
from voxflex.deform.solvers import SolverOptions, solve
from voxflex.deform.voxel_model import VoxelModel
from voxflex.errors import ConvergenceError
from voxflex.image.label_image import LabelImage

CLAMP = FixedRegion([-1, -1, -1], [1e-9, 9, 9])
TIP = np.array([[4.0, 0.5, 0.5]])


def _beam(nx=8, n=2, E=1e3):
    image = LabelImage(np.ones((nx, n, n), dtype=np.uint8), spacing=(4.0 / nx, 1.0 / n, 1.0 / n))
    return VoxelModel.from_image(image, {1: material("neo-hookean", young=E, poisson=0.3)})


def test_a_failed_load_step_is_cut_and_reaches_the_same_equilibrium():
    """Large-deflection neo-Hooke cantilever (tip drop ~ 2.5 m on 4 m) in one load step with only 6
    Newton iterations per attempt: the first attempt fails, the cut increments converge, and the
    answer equals five well-resolved load steps to the solver tolerance (1e-6 relative)."""
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


def test_inertia_counts_the_eigenvalues_below_a_shift():
    """The sparse stability check (Sylvester's inertia of a symmetric factorisation, then shift-inverted
    Lanczos) against a dense eigensolver: the exact count of eigenvalues below the shift, and the one
    nearest below it (1e-8 relative); with a 1e6 spread of the diagonal too."""
    import scipy.sparse as sp

    from voxflex.deform.solvers import _below

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
