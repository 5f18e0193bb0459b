"""Linear solvers agree on a 3-D elasticity system; rigid modes; auto selection."""

from __future__ import annotations

import numpy as np
import pytest

from voxflex.deform.chain.rigid_modes import rigid_body_modes
from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.deform.solve.linear import (
    DENSE_MAX,
    DIRECT_MAX,
    choose_method,
    solve_linear,
)
from voxflex.errors import InputError
from voxflex.image.label_image import LabelImage


def _system():
    image = LabelImage(np.ones((8, 3, 3)), spacing=(0.5, 1 / 3, 1 / 3))
    model = VoxelModel.from_image(image, {1: material("hooke", young=1e4, poisson=0.3, strain="linear")})
    K = model.hessian(model.rest)
    free = np.flatnonzero(np.repeat(model.rest[:, 0] > 1e-9, 3))
    b = np.random.default_rng(0).standard_normal(len(free))
    return model, K, free, K[free][:, free], b


@pytest.mark.slow
def test_methods_agree_to_their_tolerance():
    model, K, free, A, b = _system()
    ref, info = solve_linear(A, b, method="cholesky")
    assert info.residual < 1e-12
    for method in ("direct", "cg", "amg", "multigrid"):
        x, info = solve_linear(A, b, method=method, rtol=1e-10, near_null=rigid_body_modes(model.rest)[free],
                               grid=model.grid, free=free)
        assert info.method == method and info.residual <= 1e-10 * 1.01
        # solution error <= condition number x residual; kappa ~ 1e4 here, so 1e-5 is the bound
        assert np.linalg.norm(x - ref) <= 1e-5 * np.linalg.norm(ref)
        if method in ("cg", "amg", "multigrid"):
            assert info.iterations > 0
    # amg with rigid modes needs far fewer iterations than Jacobi-CG
    nn = rigid_body_modes(model.rest)[free]
    assert solve_linear(A, b, method="amg", rtol=1e-10, near_null=nn)[1].iterations < \
        solve_linear(A, b, method="cg", rtol=1e-10)[1].iterations


def test_rigid_modes_span_the_null_space_of_a_free_body():
    model, K, _, _, _ = _system()
    B = rigid_body_modes(model.rest)
    assert np.abs(K @ B).max() < 1e-9 * abs(K).max() * np.abs(B).max()
    assert np.linalg.matrix_rank(B) == 6


def test_auto_selection_and_errors():
    assert choose_method(DENSE_MAX) == "cholesky"
    assert choose_method(DENSE_MAX + 1) == "direct" and choose_method(DIRECT_MAX) == "direct"
    assert choose_method(DIRECT_MAX + 1) == "cg"
    # with the voxel grid, multigrid-CG beyond the direct range (the grid only changes the large-system choice)
    model, _, free, _, _ = _system()
    from voxflex.deform.solve.linear import MULTIGRID_MIN

    assert choose_method(MULTIGRID_MIN + 1, grid=model.grid) == "multigrid"
    assert choose_method(MULTIGRID_MIN, grid=model.grid) == "direct"
    assert choose_method(DENSE_MAX, grid=model.grid) == "cholesky"
    _, _, _, A, b = _system()
    x, info = solve_linear(A, b)  # 7 * 4 * 4 * 3 = 336 unknowns -> direct
    assert info.method == "direct"
    with pytest.raises(InputError, match="linear solver"):
        solve_linear(A, b, method="lu")
    # an iterative method that cannot reach the tolerance falls back to direct and says so
    x, info = solve_linear(A, b, method="cg", rtol=1e-12, maxiter=3)
    assert info.method == "direct" and "fell back" in info.note and info.residual < 1e-12


def test_cg_detects_an_indefinite_matrix_and_falls_back():
    import scipy.sparse as sp

    from voxflex._linalg import vdot, vnorm

    # positive diagonal, eigenvalues 3 and -1: CG meets non-positive curvature, the direct solve takes over
    A = sp.kron(sp.identity(50), sp.csr_matrix([[1.0, 2.0], [2.0, 1.0]]), format="csr")
    b = np.random.default_rng(1).standard_normal(100)
    x, info = solve_linear(A, b, method="cg", rtol=1e-10)
    assert info.method == "direct" and "fell back" in info.note
    assert np.linalg.norm(A @ x - b) <= 1e-12 * np.linalg.norm(b)  # LU on a well-conditioned 2x2-block matrix
    # the BLAS-free reductions agree with numpy's to round-off of a 100-term sum
    assert vdot(x, b) == pytest.approx(float(np.dot(x, b)), rel=1e-13)
    assert vnorm(b) == pytest.approx(float(np.linalg.norm(b)), rel=1e-14)


def test_cg_on_free_dofs_equals_cg_on_the_submatrix():
    from voxflex.deform.solve.linear import cg_on_free_dofs

    model, K, free, A, b = _system()
    ref, _ = solve_linear(A, b, method="cholesky")
    x, info = cg_on_free_dofs(K, b, free, rtol=1e-10)
    y, info_sub = solve_linear(A, b, method="cg", rtol=1e-10)
    assert info.method == "cg" and info.residual <= 1e-10 * 1.01
    # the same iteration in exact arithmetic: iteration counts within round-off (+-2), and the
    # error bound kappa x residual (kappa ~ 1e4) of the method-agreement test
    assert abs(info.iterations - info_sub.iterations) <= 2
    assert np.linalg.norm(x - ref) <= 1e-5 * np.linalg.norm(ref)
    assert np.linalg.norm(x - y) <= 1e-5 * np.linalg.norm(ref)
    # not reaching the tolerance returns None (the caller solves the submatrix directly)
    x, info = cg_on_free_dofs(K, b, free, rtol=1e-12, maxiter=3)
    assert x is None and info.iterations == 3


def test_free_block_equals_fancy_indexing_in_blocks_and_in_place(monkeypatch):
    """The gathered block holds exactly scipy's ``A[free][:, free]`` (a gather: bitwise equal), compiled and
    by the numpy twin with row blocks smaller than the matrix; in place it reuses A's buffers."""
    import scipy.sparse as sp

    import voxflex._linalg as ls

    model, K, free, A, b = _system()
    ref = K[free][:, free].tocsr()
    ref.sort_indices()
    monkeypatch.setattr(ls, "FREE_BLOCK_ROWS", 37)  # several blocks, boundaries inside the rows' structure
    twin = ls._free_block_impl(K.indptr, K.indices, K.data, free.astype(np.int64), K.shape[0], False)
    B = ls.free_block(K, free)
    for M in (B, twin):  # the compiled gather and its numpy twin
        assert M.has_sorted_indices and np.array_equal(M.indptr, ref.indptr)
        assert np.array_equal(M.indices, ref.indices) and np.array_equal(M.data, ref.data)
    K2 = K.copy()
    C = ls.free_block(K2, free, overwrite=True)
    assert np.array_equal(C.toarray(), ref.toarray())
    assert np.shares_memory(C.data, K2.data) and np.shares_memory(C.indices, K2.indices)
    with pytest.raises(InputError, match="sorted unique"):
        ls.free_block(K, free[::-1])
    ro = K.copy()
    ro.data.setflags(write=False)
    with pytest.raises(InputError, match="writable"):
        ls.free_block(ro, free, overwrite=True)
    with pytest.raises(InputError, match="square CSR"):
        ls.free_block(sp.csc_matrix(K), free)


def _spd(n, cond, seed=0):
    """A symmetric positive-definite matrix with eigenvalues log-spaced over [1, cond]."""
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return (Q * np.logspace(0, np.log10(cond), n)) @ Q.T


@pytest.mark.slow
def test_mixed_precision_cholesky_reaches_the_double_solution(monkeypatch):
    # above MIXED_MIN the dense path factors in float32 and refines in float64: the residual must reach
    # the rtol asked (1e-10 by default, 1e-13 here too) or the round-off of a double solve, and the answer
    # LAPACK's double solve to cond * rtol * 10 (the forward error such a relative residual allows)
    from voxflex.deform.solve import linear as ls

    n = ls.MIXED_MIN + 20
    b = np.random.default_rng(1).standard_normal(n)
    real = ls._mixed_cholesky
    for cond in (1e2, 1e5):
        A = _spd(n, cond)
        ref = np.linalg.solve(A, b)
        for rtol in (1e-10, 1e-13):
            calls = []
            monkeypatch.setattr(ls, "_mixed_cholesky", lambda A, b, tol: calls.append(real(A, b, tol)) or calls[-1])
            x, info = solve_linear(A, b, method="cholesky", rtol=rtol)
            assert calls and calls[0] is not None  # the single-precision path answered
            # rtol, or where that is below a double residual's own round-off, no worse than LAPACK's double solve
            assert info.residual <= max(rtol, 10 * np.linalg.norm(A @ ref - b) / np.linalg.norm(b))
            # the residual reported is the true one
            assert info.residual == pytest.approx(np.linalg.norm(A @ x - b) / np.linalg.norm(b), rel=1e-6, abs=1e-17)
            assert np.linalg.norm(x - ref) <= 10 * cond * max(rtol, 1e-15) * np.linalg.norm(ref)


@pytest.mark.slow
def test_mixed_precision_cholesky_falls_back_when_single_precision_cannot_refine(monkeypatch):
    # cond 1e9 > 1/eps_single: the float32 factor is useless (or fails); the double Cholesky answers, with a
    # residual at the round-off of LAPACK's general double solve (within 10x)
    from voxflex.deform.solve import linear as ls

    n = ls.MIXED_MIN + 20
    A = _spd(n, 1e9, seed=2)
    b = np.random.default_rng(3).standard_normal(n)
    assert ls._mixed_cholesky(A, b, 1e-10) is None
    # cond 3e6: each refinement gains about 1 / (cond eps_single) ~ 5x, too slow to reach 1e-10 within
    # max_refine solves: given up after the second (the double factorisation is then cheaper)
    A3 = _spd(n, 3e6, seed=2)
    calls = []
    real = ls.sla.lapack.spotrs
    monkeypatch.setattr(ls.sla.lapack, "spotrs", lambda *a, **k: calls.append(1) or real(*a, **k))
    assert ls._mixed_cholesky(A3, b, 1e-10) is None
    assert len(calls) == 2
    x, info = solve_linear(A3, b, method="cholesky")
    assert info.residual <= 10 * np.linalg.norm(A3 @ np.linalg.solve(A3, b) - b) / np.linalg.norm(b)
    x, info = solve_linear(A, b, method="cholesky")
    ref = np.linalg.solve(A, b)
    assert info.note == "" and info.residual <= 10 * np.linalg.norm(A @ ref - b) / np.linalg.norm(b)
    # indefinite: LDL^T answers, and says so
    A[0, 0] = -1.0
    x, info = solve_linear(A, b, method="cholesky")
    assert "not positive definite" in info.note
    assert np.linalg.norm(A @ x - b) <= 1e-6 * np.linalg.norm(b)


def test_diagonal_reads_the_stored_diagonal_of_any_csr_matrix():
    """The compiled diagonal equals scipy's for CSR matrices with and without diagonal entries, with empty
    rows, unsorted indices (the fallback) and other formats; the dtype is kept."""
    import scipy.sparse as sp

    from voxflex._linalg import diagonal

    rng = np.random.default_rng(3)
    for density in (0.0, 0.02, 0.3, 1.0):
        A = sp.random(60, 60, density=density, format="csr", random_state=rng)
        A = A + sp.diags(np.where(rng.random(60) < 0.5, rng.standard_normal(60), 0.0))  # some diagonals missing
        A = sp.csr_matrix(A)
        A.eliminate_zeros()
        np.testing.assert_array_equal(diagonal(A), A.diagonal())
        np.testing.assert_array_equal(diagonal(A.astype(np.float32)), A.astype(np.float32).diagonal())
        assert diagonal(A.astype(np.float32)).dtype == np.float32
        np.testing.assert_array_equal(diagonal(A.tocsc()), A.diagonal())
        np.testing.assert_array_equal(diagonal(A.toarray()), A.diagonal())
    # unsorted column indices: read by the matrix's own diagonal()
    A = sp.csr_matrix((np.array([1.0, 2.0, 3.0]), np.array([1, 0, 1]), np.array([0, 2, 3])), shape=(2, 2))
    A.has_sorted_indices = False
    np.testing.assert_array_equal(diagonal(A), [2.0, 3.0])
