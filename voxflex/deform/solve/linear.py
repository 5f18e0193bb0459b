"""Linear solvers for the symmetric systems of the voxel model.

``solve_linear(A, b, method=...)`` with the named methods

* ``"cholesky"``: dense Cholesky (LAPACK); for small systems.  Falls back to a
  symmetric-indefinite dense solve when A is not positive definite.
* ``"direct"``: sparse LU with the ``MMD_AT_PLUS_A`` fill-reducing ordering
  (scipy's default COLAMD ordering is ~3x slower on voxel elasticity: 38 s vs
  11.6 s for a sparse LU at 56k DOF), diagonal pivots first (kept when the
  refined answer's residual is at round-off; partial pivoting otherwise:
  nearly incompressible tangents filled 8x more with it, :func:`_direct`).
* ``"cg"``: conjugate gradients with the Jacobi (diagonal) preconditioner.
* ``"amg"``: conjugate gradients preconditioned by pyamg smoothed aggregation
  with the rigid-body modes as near-null space (needs node positions).  Its
  setup is seeded, so two runs give bitwise identical answers.
* ``"multigrid"``: conjugate gradients preconditioned by one V-cycle of the
  geometric voxel multigrid of :mod:`voxflex.deform.solve.multigrid.hierarchy` (needs the
  voxel grid: ``grid=model.grid, free=...``).  Its prolongations are cached
  per grid and free-DOF set, and a Newton run's next tangents reuse the coarse
  levels of an earlier one for up to three solves (rebuilt when a solve on
  them slows down or stalls); ``elements=model.stiffness_elements()`` lets a
  constant-tangent model's first coarse level be summed from its element
  matrices and its finest level be applied through the voxel stencil.  Iterations at rtol 1e-8 on the clamped beam under gravity: 12 at
  each of 16x4x4, 32x8x8, 64x16x16, 128x32x32 (Jacobi-CG: 78, 158, 318, 651); deterministic
  (no random start).
* ``"auto"``: ``"cholesky"`` up to :data:`DENSE_MAX` unknowns; with the voxel
  grid (``grid=``), ``"direct"`` up to :data:`MULTIGRID_MIN` and
  ``"multigrid"`` beyond; without it, ``"direct"`` up to :data:`DIRECT_MAX`
  and ``"cg"`` beyond.  Measured for the multigrid rule (clamped beam, rtol
  1e-8, fresh hierarchy, 2 loaded shared cores, min of 3, seconds; unknowns:
  sparse LU (MMD) / multigrid-CG (iterations) / Jacobi-CG (iterations)):
  nu = 0.3: 1200: 0.019 / 0.050 (1, coarsest level only) / 0.006 (78); 2160:
  0.034 / 0.052 (12) / 0.027 (98); 3528: 0.126 / 0.064 (12) / 0.054 (118);
  7776: 0.42 / 0.14 (12) / 0.11 (158); 14520: 1.25 / 0.14 (12) / 0.25 (198).
  nu = 0.45: 2160: 0.087 / 0.068 (22) / 0.071 (175); 3528: 0.147 / 0.133 (22)
  / 0.159 (212); 7776: 0.94 / 0.32 (21) / 0.28 (284).  Since the coarsest
  level goes down to :data:`~voxflex.deform.solve.multigrid.hierarchy.MAX_COARSE_CUBIC` on
  these beams (it stopped at 1500 DOFs), one run alternating sparse LU and
  multigrid-CG (min / median of 5, seconds): nu = 0.3: 1200: 0.0093 / 0.0098
  against 0.0088 / 0.0089; 2160: 0.035 / 0.035 against 0.017 / 0.018; 3528:
  0.058 / 0.060 against 0.025 / 0.026; nu = 0.45: 1200: 0.0088 / 0.0095
  against 0.0118 / 0.0121; 2160: 0.032 / 0.040 against 0.023 / 0.024; 3528:
  0.059 / 0.065 against 0.042 / 0.054.  Sparse LU stops winning between 1.2k
  and 3.5k unknowns (the threshold stays at 3000: the gain below it is
  milliseconds, and LU is immune to ill-conditioned tangents); Jacobi-CG is
  close on these well-conditioned beams but its iterations grow with the grid
  (651 at 418k unknowns against 12) and with ill-conditioning (thin plate,
  nu = 0.49: 2786 against 115).  Faster direct solvers that install from wheels did not win:
  cholespy (CHOLMOD) 0.17 / 0.72 / 4.0 s and qdldl 0.13 / 2.3 s at 3528 /
  7776 / 14520 unknowns; pypardiso needs the MKL wheels (not tried).
  Measured for the grid-less rule on the clamped voxel beam
  (2 shared cores, rtol 1e-8, best of 3): unknowns / dense Cholesky / sparse LU
  (MMD) / Jacobi-CG in seconds: 216 / 0.0007 / 0.001 / 0.002; 1200 / 0.028 /
  0.012 / 0.012; 3528 / 0.78 / 0.10 / 0.07; 7776 / - / 0.53 / 0.20; 56k / - /
  11.6-34 / 0.7-1.9.  Dense Cholesky never wins beyond toy sizes on these sparse
  systems, and multi-threaded OpenBLAS on a loaded 2-core machine made a
  216-unknown factorisation take 0.5 s, so it is kept for tiny systems only; the
  direct solver is kept up to a few thousand unknowns because it is immune to
  the ill-conditioning of large-deformation tangents.

Iterative methods stop at ``||A x - b|| <= rtol ||b||``; when they do not reach
it they fall back to ``"direct"`` up to :data:`DIRECT_FALLBACK_MAX` unknowns and
say so in the returned info; beyond, where a factorisation costs minutes and
gigabytes, they raise :class:`~voxflex.errors.ConvergenceError` with the reason,
or return their last iterate flagged unconverged (``partial=True``, what the
Newton solver asks for, see :mod:`voxflex.deform.solve.newton`): never a silent
failure.  :func:`cg_on_free_dofs` runs the same Jacobi-CG on a
submatrix ``A[free][:, free]`` without building it (what the Newton solver
uses for ``"cg"``).  The CG reductions avoid BLAS (:func:`vdot`): threaded
OpenBLAS dot products stall on a busy 2-core machine.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..._linalg import DIRECT_FALLBACK_MAX, diagonal, vdot, vnorm
from ...errors import ConvergenceError, InputError, check_choice
from .options import METHODS

FALLBACKS = ("auto", "direct", "none")


"""What :func:`solve_linear` does when an iterative method stops short of its tolerance: ``"auto"``
factorises directly up to :data:`DIRECT_FALLBACK_MAX` unknowns and not beyond, ``"direct"`` always,
``"none"`` never."""


STOP_REASONS = ("iterations", "negative curvature", "preconditioner indefinite", "stencil does not match the matrix")


"""Why an iterative solve stopped short (``LinearSolveInfo.reason``)."""


INDEFINITE_REASONS = ("negative curvature", "preconditioner indefinite")


"""The reasons that show the matrix is not positive definite (see :func:`_pcg`)."""


DENSE_MAX = 64


DIRECT_MAX = 5000

MULTIGRID_MIN = 3000


MULTIGRID_MAXITER = 300




@dataclass
class LinearSolveInfo:
    """What a linear solve did: method used, iterations (0 for direct), relative residual, seconds."""

    method: str
    iterations: int
    residual: float
    seconds: float
    note: str = ""
    fell_back: bool = False  # an iterative method missed rtol and the direct solver answered
    converged: bool = True  # False: an iterative method stopped short and nothing answered (partial=True)
    reason: str = ""  # why it stopped short (STOP_REASONS), also when the direct solver answered


def choose_method(n: int, *, grid=None) -> str:
    """The method ``"auto"`` picks for ``n`` unknowns (``grid``: the voxel grid, when there is one)."""
    if n <= DENSE_MAX:
        return "cholesky"
    if grid is not None:
        return "direct" if n <= MULTIGRID_MIN else "multigrid"
    if n <= DIRECT_MAX:
        return "direct"
    return "cg"


def solve_linear(A, b, *, method: str = "auto", rtol: float = 1e-10, maxiter: int | None = None,
                 x0=None, near_null=None, grid=None, free=None, elements=None, fallback: str = "auto",
                 partial: bool = False):
    """Solve the symmetric system ``A x = b``.

    Parameters
    ----------
    A : (N, N) sparse or dense symmetric matrix, or FreeStiffness
        A matrix-free block (:class:`~voxflex.deform.models.voxel.elements.FreeStiffness`)
        is solved by ``"multigrid"`` (``"auto"`` with a grid; its finest level
        through the voxel stencil, the answer checked against its voxel-by-voxel
        product) or ``"cg"``, never factorised.
    b : (N,) float
    method : {"auto", "cholesky", "direct", "cg", "amg", "multigrid"}
    rtol : float
        Relative residual for the iterative methods, and for ``"cholesky"`` from
        :data:`MIXED_MIN` unknowns on, where a single-precision factorisation is
        refined in double precision until it is met (below that, LAPACK's double
        Cholesky: round-off, about 1e-15, whatever rtol).
    maxiter : int, optional
        Iteration cap of the iterative methods (default ``max(1000, N // 4)``).
    x0 : (N,) float, optional
        Initial guess (iterative methods).
    near_null : (N, k) float, optional
        Near-null space for ``"amg"`` (rigid-body modes restricted to the unknowns).
    grid : TrilinearGrid, optional
        The voxel grid the unknowns live on (``model.grid``); needed by
        ``"multigrid"``, and lets ``"auto"`` pick it on large systems.
    free : (N,) int, optional
        With ``grid``: the DOFs (``3 * node + component``, sorted) that the
        unknowns are, i.e. ``A = H[free][:, free]``; default all ``3 * grid.n_nodes``.
    elements : voxflex.deform.models.voxel.elements.ElementMatrices, optional
        With ``grid``: H as voxel element matrices (``model.stiffness_elements()``
        of a constant-tangent voxel model); multigrid then forms its first coarse
        level from them instead of by a sparse product, and applies the finest
        level through the voxel stencil where it can (the same matrices, to
        round-off; see :class:`voxflex.deform.solve.multigrid.stencil.VoxelStencil`).  The
        answer is checked against A itself: element matrices that do not
        describe A end in the direct solver's answer.
    fallback : {"auto", "direct", "none"}
        When an iterative method stops short of ``rtol``: factorise A directly
        up to :data:`DIRECT_FALLBACK_MAX` unknowns (``"auto"``), always
        (``"direct"``: minutes and gigabytes on large systems) or never.
    partial : bool
        When the iterative method stopped short and no fallback answers: return
        its last iterate with ``info.converged`` False and ``info.reason``
        instead of raising (a descent direction of ``x . A x / 2 - b . x``, or
        zero, see :func:`_pcg`).  The caller then also handles an indefinite A
        itself (:data:`INDEFINITE_REASONS`): such a solve returns its iterate at
        any size and only a stalled one falls back to the direct solver.

    Returns
    -------
    x : (N,) float
    info : LinearSolveInfo

    Raises
    ------
    ConvergenceError
        An iterative method stopped short, no fallback was allowed and
        ``partial`` is False (the message gives the reason), or the answer is
        not finite.
    """
    check_choice("linear solver", method, METHODS)
    check_choice("linear solver fallback", fallback, FALLBACKS)
    b = np.asarray(b, dtype=float)
    N = b.shape[0]
    if A.shape != (N, N):
        raise InputError(f"matrix shape {A.shape} does not match right-hand side length {N}")
    if grid is not None:
        from ...image.grid import TrilinearGrid

        if not isinstance(grid, TrilinearGrid):
            raise InputError(f"grid must be the voxel model's TrilinearGrid (model.grid), got {type(grid).__name__}")
        free = np.arange(3 * grid.n_nodes) if free is None else np.asarray(free)
        if free.shape != (N,):
            raise InputError(f"free has {free.size} DOFs but the system has {N} unknowns; pass A = H[free][:, free]")
    elif method == "multigrid":
        raise InputError("linear solver 'multigrid' needs the voxel grid: pass grid=model.grid (and free=...)")
    if N == 0:
        return np.zeros(0), LinearSolveInfo(method, 0, 0.0, 0.0)
    matrix_free = _matrix_free(A)
    if method == "auto":
        method = choose_method(N, grid=grid)
        if matrix_free:
            method = "multigrid" if grid is not None else "cg"
    if matrix_free and method not in ("multigrid", "cg"):
        raise InputError(f"a matrix-free block (FreeStiffness) is solved by multigrid or cg, not {method!r}")
    t0 = time.perf_counter()
    bnorm = vnorm(b)
    if bnorm == 0.0:
        return np.zeros(N), LinearSolveInfo(method, 0, 0.0, 0.0)
    fell_back = False
    converged, reason = True, ""
    res = None
    if method == "cholesky":
        x, note, res = _dense(A, b, rtol)
        its = 0
    elif method == "direct":
        x = _direct(A, b)
        its, note = 0, ""
    else:
        # multigrid-CG takes 12-25 iterations on well-posed voxel systems and ~115 on a thin
        # near-incompressible plate: beyond MULTIGRID_MAXITER the direct fallback is cheaper
        maxiter = maxiter or (MULTIGRID_MAXITER if method == "multigrid" else max(1000, N // 4))
        if method == "cg":
            x, its, ok, reason = _cg_jacobi(A, b, rtol, maxiter, x0)
        elif method == "multigrid":
            status = {}
            x, its, ok, rnorm = _cg_multigrid(A, b, rtol, maxiter, x0, grid, free, elements, status)
            reason = status["reason"]
            res = rnorm / bnorm if ok and rnorm is not None else None  # its true residual, if it has one
        else:
            x, its, ok, reason = _cg_amg(A, b, rtol, maxiter, x0, near_null)
        note = ""
        if not ok:
            why = f"{method} stopped after {its} iterations above rtol {rtol:.1e} ({reason})"
            # with partial=True the caller has its own remedies for an indefinite matrix (Newton: the
            # truncated step, projected or shifted tangents): only a stalled solve is factorised
            own_remedy = (partial and reason in INDEFINITE_REASONS) or matrix_free  # nothing to factorise
            if not own_remedy and (fallback == "direct" or (fallback == "auto" and N <= DIRECT_FALLBACK_MAX)):
                note = f"{why}; fell back to direct"
                x = _direct(A, b)
                method = "direct"
                fell_back = True
            elif partial:
                note = why
                converged = False
            else:
                limit = (f"above {DIRECT_FALLBACK_MAX} unknowns a direct factorisation is not attempted "
                         "(minutes and gigabytes)" if fallback == "auto" else "no fallback was allowed")
                raise ConvergenceError(f"linear solve of {N} unknowns: {why}; {limit}. The matrix is "
                                       + ("not positive definite (an unstable or inverted state)"
                                          if reason == "negative curvature" else "ill-conditioned or indefinite"))
    if res is None:
        res = vnorm(A @ x - b) / bnorm
    if not np.all(np.isfinite(x)):
        raise ConvergenceError(f"linear solve ({method}, {N} unknowns) produced non-finite values; the matrix is singular")
    return x, LinearSolveInfo(method, int(its), res, time.perf_counter() - t0, note, fell_back, converged, reason)


MIXED_MIN = 500  # dense systems from this size factor in single precision and refine (see _mixed_cholesky)


def _dense(A, b, rtol):
    """Dense Cholesky (LDL^T when not positive definite) with BLAS pinned to one thread: on a busy
    2-core machine threaded OpenBLAS stalled a 468x468 Cholesky for 0.31 s (a few ms on one thread);
    at 552 unknowns, load average 3.8, factor + solve took min / median 3.4 / 7.6 ms on one thread and
    3.0 / 11.9 ms on two (benchmarks/bench_frames.py prints both).  The pin goes through a controller
    made once (:func:`voxflex._blas.one_thread`).

    Returns x, a note, and the relative residual when the refinement computed it (else None)."""
    from ..._blas import one_thread

    Ad = A.toarray() if sp.issparse(A) else np.asarray(A, dtype=float)
    with one_thread():
        if Ad.shape[0] >= MIXED_MIN:
            out = _mixed_cholesky(Ad, b, rtol)
            if out is not None:
                return out[0], "", out[1]
        try:
            c = sla.cho_factor(Ad, lower=True, check_finite=False)
            return sla.cho_solve(c, b, check_finite=False), "", None
        except np.linalg.LinAlgError:
            pass
        with warnings.catch_warnings():  # an ill-conditioned tangent is said by the note and judged by the residual
            warnings.simplefilter("ignore", sla.LinAlgWarning)
            return (sla.solve(Ad, b, assume_a="sym", check_finite=False), "not positive definite: symmetric LDL^T solve",
                    None)


def _mixed_cholesky(A, b, rtol, max_refine: int = 6):
    """Cholesky in single precision refined to a double-precision residual: ``(x, |r| / |b|)`` or None.

    The factorisation, the cost at these sizes, runs in float32, about 1.7x
    as fast as in float64 (552 unknowns, one thread: 0.98 against
    1.79 ms); each refinement step is a double residual ``r = b - A x`` (A
    itself is never rounded) and two float32 triangular solves, O(N^2) (0.2
    ms at 552).  It stops at ``|r| <= rtol |b|`` (the Newton solvers' dense
    solves ask 1e-10, two orders below their own tolerance): each step gains
    about ``1 / (cond eps_single)``, so two solves at ``cond(A)`` about 1e4
    (the 552-unknown free block of a 50-frame model, cond 7.7e3: 2.4e-7,
    then 2.4e-12), three on random matrices of that condition; or when the
    residual stops falling at the round-off of a double residual itself,
    ``4 eps |A|_F |x|`` (where a double Cholesky's residual lies too on
    ill-conditioned systems).  It returns None (the caller factors in double)
    when A is not positive definite in single precision, or when the
    refinement stalls above that or is too slow to reach ``rtol`` within
    ``max_refine`` solves (judged after the second: that happens once
    ``cond(A)`` nears 1/eps_single, about 1e7).  A is symmetric, so its
    transpose is the Fortran-ordered copy LAPACK wants, without a transposing copy.
    Factor + solve, one thread (rtol 1e-13, min of 3x20 or 3x30 runs): random SPD
    matrices (cond 6e3) of 1000 / 2000 unknowns 14.9 / 91 ms against 17.3 / 119 ms by
    cho_factor / cho_solve.  At rtol 1e-10 on random SPD matrices of cond 1e4 (three solves;
    min of 100, quiet): 552 unknowns 2.23 against 2.20 ms, 700: 3.89 against 4.27 ms; on the
    50-frame free block (two solves) 1.65 against 2.03 ms.  Below :data:`MIXED_MIN` (400: 1.04
    against 1.01 ms) the double factorisation is as fast.
    """
    # the lower factor of the Fortran-ordered copy (A is symmetric): OpenBLAS's upper one took 1.34 ms
    # against 0.98 at 552 unknowns
    c, info = sla.lapack.spotrf(A.T.astype(np.float32), lower=1, clean=0, overwrite_a=1)
    if info != 0:
        return None
    bn = vnorm(b)
    target = rtol * bn
    x = np.zeros_like(b)
    r, rn = b, np.inf
    for k in range(1, max_refine + 1):
        dx, info = sla.lapack.spotrs(c, r.astype(np.float32), lower=1)
        if info != 0 or not np.all(np.isfinite(dx)):
            return None
        x += dx
        r = b - A @ x
        rn_last, rn = rn, vnorm(r)
        if rn <= target:
            return x, rn / bn
        if rn > rn_last / 4:  # stagnated: good only at the round-off of the residual itself, 4 eps |A|_F |x|
            floor = 4 * np.finfo(float).eps * np.sqrt(vdot(A.ravel(), A.ravel()))
            return (x, rn / bn) if rn <= floor * vnorm(x) else None
        if k >= 2 and rn * (rn / rn_last) ** (max_refine - k) > target:
            return None  # at this rate not within max_refine solves: the double factorisation is cheaper
    return None


DIAGONAL_PIVOT_RTOL = 1e-12
"""Normwise backward error ``|b - A x| / (|A|_F |x| + |b|)`` a sparse LU with diagonal pivots must reach after
one step of refinement to be kept (else the system is factorised again with partial pivoting).  A stable
factorisation gives a few eps (measured 5e-19 on the clamped beam of 55k DOF, whose relative residual
``|r| / |b|`` is 1.3e-11 with either pivoting: the residual grows with the condition number, the backward
error does not, so a large well-posed system is not factorised twice)."""


def _direct(A, b):
    """Sparse LU (SuperLU) with the ``MMD_AT_PLUS_A`` ordering, diagonal pivots first.

    The tangents are symmetric, so the fill-reducing ordering of ``A + A^T`` holds only if the pivots stay
    on the diagonal; SuperLU's partial pivoting leaves it wherever a column's diagonal is small against the
    column, which a nearly incompressible material makes common: the neo-Hooke F-bar tangent of the
    cantilever 32x8x8 at nu = 0.4999 (7776 unknowns) filled 36 million entries in 9.8 s, against 4.3 million
    in 0.2 s with diagonal pivots (scipy's COLAMD ordering: 6.2 million, 0.46 s).  So the factorisation
    takes diagonal pivots (threshold 0, SymmetricMode), refines the answer once with the factors, and keeps
    it when the backward error is below :data:`DIAGONAL_PIVOT_RTOL` (measured 3e-18 there); an indefinite
    or singular-looking matrix that fails this is factorised again with partial pivoting, as before.

    Reusing the ordering across Newton's tangents (one pattern: the matrix
    permuted once by the first MMD permutation, then ``NATURAL``) was
    measured and dropped: same fill, 0.30-0.36 CPU s per factorisation either
    way at 7776 unknowns (neo-Hooke beam 32x8x8); the numeric factorisation
    is the cost, not the ordering.
    """
    A = sp.csc_matrix(A)
    b = np.asarray(b, dtype=float)
    bn = vnorm(b)
    try:
        lu = spla.splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        x = lu.solve(b)
        x = x + lu.solve(b - A @ x)
        An = float(np.sqrt(vdot(A.data, A.data)))
        if np.all(np.isfinite(x)) and vnorm(b - A @ x) <= DIAGONAL_PIVOT_RTOL * (An * vnorm(x) + bn):
            return x
    except RuntimeError:  # a zero pivot on the diagonal: the pivoting factorisation below decides
        pass
    try:
        lu = spla.splu(A, permc_spec="MMD_AT_PLUS_A")
    except RuntimeError as exc:  # SuperLU: "Factor is exactly singular"
        raise ConvergenceError(f"sparse LU of {A.shape[0]} unknowns failed ({exc}): the tangent is singular "
                               "(a mechanism, zero-energy modes or an unsupported part)") from None
    return lu.solve(b)


def _pcg(A, b, inv_diag, rtol, maxiter, x0, precond=None):
    """Preconditioned conjugate gradients; stops at ``|r| <= rtol |b|`` (recursive residual).

    The preconditioner is ``z = inv_diag * r`` (Jacobi), or ``z = precond(r)``
    when given (multigrid).  Returns x, iterations, converged and the reason it
    stopped short (:data:`STOP_REASONS`; "" when converged): ``"iterations"``
    (``maxiter`` reached), ``"negative curvature"`` (a direction with
    ``p . A p <= 0``: A is not positive definite) or ``"preconditioner
    indefinite"`` (``r . z <= 0``: a V-cycle of an indefinite A, whose smooth
    negative modes its coarse levels see, is indefinite too).  x is then the
    last iterate, made of steps of positive curvature along directions with
    ``r . p = r . z > 0``, so from ``x0 = None`` it lowers the quadratic
    ``x . A x / 2 - b . x`` below 0 (a descent direction, or zero).
    """
    if x0 is None:
        x = np.zeros_like(b)
        r = b.copy()
    else:
        x = np.array(x0, dtype=float)
        r = b - A @ x
    target = rtol * vnorm(b)
    z = inv_diag * r if precond is None else precond(r)
    p = z.copy()
    rz = vdot(r, z)
    its = 0
    if not rz > 0.0 and vnorm(r) > target:
        return x, its, False, "preconditioner indefinite"
    while vnorm(r) > target:
        if its >= maxiter:
            return x, its, False, "iterations"
        Ap = A @ p
        pAp = vdot(p, Ap)
        if not pAp > 0.0:
            return x, its, False, "negative curvature"
        alpha = rz / pAp
        x += alpha * p
        r -= alpha * Ap
        if precond is None:
            np.multiply(inv_diag, r, out=z)
        else:
            z = precond(r)
        rz_new = vdot(r, z)
        its += 1
        if not rz_new > 0.0 and vnorm(r) > target:  # the preconditioner is not positive definite
            return x, its, False, "preconditioner indefinite"
        p *= rz_new / rz
        p += z
        rz = rz_new
    return x, its, True, ""


class _Masked:
    """``A`` restricted to the free DOFs without extracting the submatrix: products with vectors
    that vanish on the fixed DOFs, the fixed entries of the result zeroed."""

    def __init__(self, A, fixed):
        self.A = A
        self.fixed = fixed

    def __matmul__(self, p):
        y = self.A @ p
        y[self.fixed] = 0.0
        return y


def cg_on_free_dofs(A, b, free, *, rtol: float = 1e-10, maxiter: int | None = None, fixed=None,
                    partial: bool = False):
    """Jacobi-CG for ``A[free][:, free] x = b`` run on the whole matrix A.

    The iterates live in the full space with zeros on the other DOFs, so the
    submatrix is never built (at 1e6 voxels it is ~3 GB and takes ~15 s to
    extract).  Same iteration, stopping rule and result as
    ``solve_linear(A[free][:, free], b, method="cg")`` up to round-off.

    Parameters
    ----------
    A : (N, N) sparse symmetric matrix
    b : (F,) float
    free : (F,) int, sorted unique DOF indices
    fixed : (N - F,) int, optional
        The other DOFs (sorted), when the caller has them (saves a set difference per call).
    partial : bool
        Return CG's last iterate (``info.converged`` False, ``info.reason`` why)
        instead of None when it stops short of ``rtol``.

    Returns
    -------
    x : (F,) float, or None when CG did not reach ``rtol`` (or A is not
        positive definite on the free DOFs) and ``partial`` is False: then solve
        the submatrix directly.
    info : LinearSolveInfo (iterations also when x is None)
    """
    t0 = time.perf_counter()
    b = np.asarray(b, dtype=float)
    N = A.shape[0]
    if fixed is None:
        fixed = np.setdiff1d(np.arange(N), free)
    bf = np.zeros(N)
    bf[free] = b
    bnorm = vnorm(b)
    if bnorm == 0.0:
        return np.zeros(len(free)), LinearSolveInfo("cg", 0, 0.0, 0.0)
    d = diagonal(A)[free]
    if np.any(d <= 0):
        info = LinearSolveInfo("cg", 0, 1.0, time.perf_counter() - t0, converged=False, reason="negative curvature")
        return (np.zeros(len(free)) if partial else None), info
    inv = np.zeros(N)
    inv[free] = 1.0 / d
    maxiter = maxiter or max(1000, len(free) // 4)
    Am = _Masked(A, fixed)
    x, its, ok, reason = _pcg(Am, bf, inv, rtol, maxiter, None)
    res = vnorm(Am @ x - bf) / bnorm
    info = LinearSolveInfo("cg", int(its), res, time.perf_counter() - t0, converged=ok, reason=reason)
    return (x[free] if ok or partial else None), info


def _cg_jacobi(A, b, rtol, maxiter, x0):
    A = A if _matrix_free(A) else sp.csr_matrix(A)
    d = diagonal(A)
    if np.any(d <= 0):
        return np.zeros_like(b), 0, False, "negative curvature"
    return _pcg(A, b, 1.0 / d, rtol, maxiter, x0)


def _matrix_free(A) -> bool:
    """Whether A is a matrix-free block (:class:`~voxflex.deform.models.voxel.elements.FreeStiffness`)."""
    from ..models.voxel.elements import FreeStiffness

    return isinstance(A, FreeStiffness)


_AMG_SEED = 20240601


def _cg_multigrid(A, b, rtol, maxiter, x0, grid, free, elements=None, status=None):
    """Multigrid-CG: x, iterations, converged, and ``|A x - b|`` when it was computed (None otherwise).

    ``status`` (a dict), when given, receives ``"reason"``: why it stopped short (see :func:`_pcg`)."""
    from ..._blas import one_thread
    from .multigrid.hierarchy import STALE_GROWTH, hierarchy, multigrid_preconditioner

    status = {} if status is None else status
    status["reason"] = ""
    A = A if _matrix_free(A) else sp.csr_matrix(A)
    if np.any(diagonal(A) <= 0):
        status["reason"] = "negative curvature"  # e_i . A e_i <= 0
        return np.zeros_like(b), 0, False, None
    # BLAS on one thread for the coarse factorisation and the small dense coarse solves of every cycle
    h = hierarchy(grid, free)
    with one_thread():
        try:
            # the coarse levels of the previous tangent (same pattern) serve a few more solves: the
            # Galerkin products and the coarse factorisation are then skipped (see multigrid.MAX_STALE_SOLVES)
            apply, ml = multigrid_preconditioner(A, grid, free, stale=True, elements=elements)
            stale = ml.stale
            budget = min(maxiter, int(STALE_GROWTH * (h.fresh_iterations or 0)) + 10) if stale else maxiter
            # CG's products through the finest level's stencil when it has one (the same matrix)
            op = A if getattr(ml, "fine", None) is None else ml.fine
            x, its, ok, rnorm = _cg_multigrid_impl(op, b, rtol, budget, x0, apply, status)
            if ok and op is not A:
                rnorm = vnorm(A @ x - b)  # against A itself: the stencil must be this matrix
                if rnorm > 1.01 * rtol * vnorm(b):
                    ok = False  # elements that do not describe A: fall back
                    status["reason"] = "stencil does not match the matrix"
            h.report(its, ok, stale)
            if stale and not ok and status["reason"] != "negative curvature":
                # too slow on the old levels (or a cycle made indefinite by them): rebuild them, go on from x
                apply, ml = multigrid_preconditioner(A, grid, free, elements=elements)
                x, more, ok, rnorm = _cg_multigrid_impl(A, b, rtol, maxiter - its, x, apply, status)
                h.report(more, ok, False)
                its += more
            return x, its, ok, rnorm
        finally:
            h.release()  # the cached levels must not keep this matrix alive


def _cg_multigrid_impl(A, b, rtol, maxiter, x0, apply, status=None):
    """PCG with the V-cycle ``apply``; x, iterations, converged, and the true residual norm ``|A x - b|``
    of the returned x when it was computed (None otherwise); ``status["reason"]`` as in :func:`_cg_multigrid`."""
    x, its, ok, reason = _pcg(A, b, None, rtol, maxiter, x0, precond=apply)
    target = rtol * vnorm(b)
    # the recursive residual drifts from the true one over a hundred iterations (2 % on a thin plate):
    # restart from x until the true residual meets rtol, so the reported residual is what was asked
    rnorm = None
    for _ in range(3):
        if not ok:
            break
        rnorm = vnorm(A @ x - b)
        if rnorm <= target:
            break
        x, more, ok, reason = _pcg(A, b, None, rtol, maxiter - its, x, precond=apply)
        its += more
        rnorm = None
    if status is not None:
        status["reason"] = reason
    return x, its, ok, rnorm


def _cg_amg(A, b, rtol, maxiter, x0, near_null):
    import pyamg

    A = sp.csr_matrix(A)
    B = None if near_null is None else np.ascontiguousarray(near_null, dtype=float)
    # pyamg draws the start vector of its spectral-radius estimate from numpy's
    # global generator: seed it for run-to-run identical answers and give the
    # caller's generator state back afterwards
    state = np.random.get_state()
    np.random.seed(_AMG_SEED)
    try:
        ml = pyamg.smoothed_aggregation_solver(A, B=B, symmetry="symmetric", max_coarse=500)
    finally:
        np.random.set_state(state)
    residuals = []
    x = ml.solve(b, x0=x0, tol=rtol, maxiter=maxiter, accel="cg", residuals=residuals)
    its = max(len(residuals) - 1, 0)
    ok = bool(vnorm(A @ x - b) <= 1.01 * rtol * vnorm(b))
    return x, its, ok, "" if ok else "iterations"
