"""Newton's method on the free DOFs of one step (statics or an implicit-Euler step).

Inexact Newton with an energy line search, load-level scaled tolerances,
round-off floors, tangent projection on demand and the choice of the linear
solver per Newton system; :mod:`voxflex.deform.solve.stepping` drives it over
load steps and time steps.  The potential of a step that it minimises is
:class:`~voxflex.deform.solve.potential._Problem`; the factorised dense tangent
it keeps over iterations and steps is :class:`~voxflex.deform.solve.chord._Chord`.

Indefinite tangents on the iterative path: when CG meets negative curvature (or
a V-cycle made indefinite by the tangent) its last iterate is Newton's step
(truncated Newton-CG, Nocedal and Wright, *Numerical Optimization*, 2006,
Alg. 7.1), the next tangents are projected (``tangent_projection = "auto"``),
and a step that does not descend comes from the tangent shifted by a multiple
of the identity, solved on the same path above
:data:`~voxflex.deform.solve.linear.DIRECT_FALLBACK_MAX` unknowns; no tangent
of that size is factorised.  Measured on standing Homer (the shared mesh at 14
mm, 1/3 of gravity, one load step, where the body folds over at the ankles):
59 Newton iterations, 60.6 s; re-solving such an iterate with its projected
tangent at once took 91 (64.6 s), and keeping the projection until the
residual fell a hundredfold 110 (122.6 s).
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from ..._linalg import diagonal, vdot, vnorm
from ...errors import ConvergenceError
from ..models.protocol import OnVoxelGrid
from .chord import CHORD_RATE
from .linear import (
    DIRECT_FALLBACK_MAX,
    INDEFINITE_REASONS,
    LinearSolveInfo,
    cg_on_free_dofs,
    choose_method,
    solve_linear,
)

ARMIJO = 1e-4

MAX_HALVINGS = 30


DENSE_AUTO_MAX = 6000  # unknowns up to which a nearly dense Hessian goes to dense Cholesky under "auto"

DENSE_FILL = 0.2  # fraction of non-zeros above which a Hessian counts as nearly dense


ROUNDOFF = 1e-11  # relative energy slack of the line search (differences of Pi below it are round-off)

NOISE = 1e-7  # relative energy change under which a full Newton step that cuts the residual is accepted


def _predict_converged(rn, rn_last, target, floor) -> bool:
    """Whether a full Newton step from an iterate of residual ``rn`` (after ``rn_last``) should converge.

    The linear-rate estimate ``rn * (rn / rn_last)`` (Newton's rate is at
    least that good once it contracts) against the stopping threshold.  The
    iterate is then evaluated without its Hessian, which would never be
    solved; a wrong guess costs one extra gradient pass (the Hessian is then
    assembled in a second pass).
    """
    if rn_last is None or not rn < 0.5 * rn_last:
        return False
    return rn * (rn / rn_last) <= max(target, floor)


def _project_tangents(mode, step_length, indefinite, projected) -> bool:
    """Whether the next Hessian is built from tangents projected to PSD (:data:`TANGENT_PROJECTIONS`).

    ``auto``: the exact tangent, unless the last exact one was indefinite along
    Newton's step (negative curvature, or not a descent direction); then the
    projected one until a step is accepted in full (no line-search cut), where
    the exact tangent takes over again and keeps Newton's quadratic rate.
    Measured (``benchmarks/bench_robust_newton.py``): projecting from the
    start of every step until a full step halved the residual cost 13 % more
    iterations on the neo-Hooke cantilever and 29 % (with 3 load cuts) on a
    buckling column; projecting always, 2.6 times as many on the cantilever
    and no convergence on the column (linear rate near the solution).
    """
    if mode != "auto":
        return mode == "always"
    return indefinite or (projected and step_length < 1.0)


BULK_FLOOR = 64.0
"""Newton's round-off floor includes ``BULK_FLOOR eps (lambda / mu) |r_0|``: a linear cantilever at nu = 0.49999999
(lambda / mu = 5e7) stalled at relative residuals 2.4e-7 (voxels) and 1.3e-7 (frames), 22 and 12 eps lambda / mu,
for 50 iterations and 8 load cuts, and was refused with "use more load steps" (which cannot help)."""


def _forcing(rn, rn_prev, eta_prev, scale):
    """Relative tolerance of the inexact Newton step (the forcing term): ``min(0.1, |r| / scale)``.

    Measured on the Neo-Hooke beam (E = 1e3, 32x8x8, 5 load steps, Jacobi-CG),
    Newton / CG iterations: this 34 / 3969; Eisenstat-Walker choice 2 (gamma
    0.9, alpha 2) 34 / 3942; ``min(0.1, sqrt(rel))`` 40 / 3995;
    ``min(0.01, rel)`` 31 / 4866; fixed 1e-3 32 / 4909; 1e-6 (near-exact
    Newton) 30 / 5352.  A Newton iteration (assembly and line search) costs
    about as much as 100 CG iterations here, so the tighter choices save
    iterations but not time; the looser one loses both.
    """
    return min(0.1, rn / max(scale, 1e-300))


_BUILD_CHUNK = 1 << 24

DENSE_RUNS_MAX = 24
"""Runs of consecutive free DOFs up to which a dense free block is gathered by slice copies (runs²
copies of contiguous rows) rather than two fancy-indexing passes."""


class _FreeBlock:
    """Extracts ``H[free][:, free]`` by a data gather with an index map built once per pattern.

    The model's Hessians share one CSR pattern, so scipy's two fancy-indexing
    passes per Newton iteration (each copying the matrix) are replaced by
    ``data[sel]``; the map is rebuilt only when the pattern changes.
    """

    def __init__(self, free, size):
        self.free = np.asarray(free, dtype=np.int64)
        if np.any(np.diff(self.free) <= 0):
            raise ValueError("free DOFs must be sorted and unique")  # internal: solve() passes a sorted complement
        self.size = int(size)
        self.direct_only = False  # set once an "auto" iterative solve fell back to direct in this run
        keep = np.ones(self.size, dtype=bool)
        keep[self.free] = False
        self.fixed = np.flatnonzero(keep)  # once, not per Jacobi-CG solve (np.setdiff1d: 0.7 s at 421k DOF)
        # runs of consecutive free DOFs (start in the block, start in H, length): a dense block is
        # gathered by runs x runs slice copies (held frames leave a few runs of 12 DOFs)
        cut = np.flatnonzero(np.diff(self.free) != 1) + 1
        starts = np.concatenate([[0], cut]).astype(np.int64)
        ends = np.concatenate([cut, [len(self.free)]]).astype(np.int64)
        self.runs = [(int(a), int(self.free[a]), int(b - a)) for a, b in zip(starts, ends)] if len(self.free) else []
        self._indptr = None
        self._indices = None

    def _build(self, H):
        N = self.size
        isfree = np.zeros(N, dtype=bool)
        isfree[self.free] = True
        idx = np.int32 if max(H.nnz, N) < np.iinfo(np.int32).max else np.int64
        colpos = np.full(N, -1, dtype=idx)
        colpos[self.free] = np.arange(len(self.free), dtype=idx)
        rowfree = np.repeat(isfree, np.diff(H.indptr))
        parts = []
        for s in range(0, H.nnz, _BUILD_CHUNK):  # chunks keep the int64 temporaries small
            keep = rowfree[s : s + _BUILD_CHUNK] & isfree[H.indices[s : s + _BUILD_CHUNK]]
            parts.append((np.flatnonzero(keep) + s).astype(idx))
        del rowfree
        self.sel = np.concatenate(parts) if parts else np.zeros(0, dtype=idx)
        counts = np.diff(np.searchsorted(self.sel, H.indptr))[self.free]
        self.indptr_ff = np.zeros(len(self.free) + 1, dtype=idx)
        np.cumsum(counts, out=self.indptr_ff[1:])
        self.indices_ff = colpos[H.indices[self.sel]]
        # views, not copies: the model's Hessians share its pattern arrays, nobody writes into them
        self._indptr = H.indptr
        self._indices = H.indices

    def _same_pattern(self, H) -> bool:
        a, b = self._indices, H.indices
        if a is None or len(a) != len(b) or len(self._indptr) != len(H.indptr):
            return False
        if a.__array_interface__["data"][0] == b.__array_interface__["data"][0] and a.dtype == b.dtype and \
                self._indptr.__array_interface__["data"][0] == H.indptr.__array_interface__["data"][0]:
            return True
        return bool(np.array_equal(self._indptr, H.indptr) and np.array_equal(a, b))

    def __call__(self, H) -> sp.csr_matrix:
        """``H[free][:, free]`` of a CSR matrix H (N, N) with sorted indices."""
        if isinstance(H, np.ndarray):  # a dense Hessian (reduced models)
            if len(self.runs) > DENSE_RUNS_MAX:
                return H.take(self.free, 0).take(self.free, 1)  # 0.54-0.68 ms at 552 of 600 (np.ix_: 1.3)
            nf = len(self.free)
            out = np.empty((nf, nf))
            for oi, hi, li in self.runs:  # 0.2 ms at 552 of 600 with 5 runs
                for oj, hj, lj in self.runs:
                    out[oi:oi + li, oj:oj + lj] = H[hi:hi + li, hj:hj + lj]
            return out
        H = sp.csr_matrix(H)
        if not self._same_pattern(H):
            if not H.has_canonical_format:
                H = H.copy()  # never reorder the caller's arrays in place
                H.sum_duplicates()
            self._build(H)
        nf = len(self.free)
        from ..._linalg_kernels import gather_kernel

        data = np.empty(len(self.sel), dtype=H.data.dtype)
        gather_kernel(H.data, self.sel, data)  # H.data[self.sel], compiled (58 -> 16 ms at 23M entries)
        return sp.csr_matrix((data, self.indices_ff, self.indptr_ff), shape=(nf, nf))


def _grid_of(model):
    """The voxel grid of a model whose nodes are its corners (geometric multigrid), or None."""
    return model.dof_grid if isinstance(model, OnVoxelGrid) else None


def _solve_free(H, rhs, free, reduce, options, eta, near_null, grid=None, block=None, elements=None):
    """Solve ``H[free][:, free] d = rhs``; returns d, info and the submatrix when it was built.

    Jacobi-CG (``"cg"``, and ``"auto"`` on large systems without a voxel grid)
    runs on H itself with the fixed DOFs masked; the other methods (and CG's
    direct fallback) take the submatrix from ``reduce``.  ``grid`` is the
    model's :attr:`dof_grid` (voxel models): with it ``auto`` picks sparse LU or
    geometric-multigrid CG (see :func:`voxflex.deform.solve.linear.choose_method`).
    ``block``: the submatrix itself (the lean path; H is then None), solved as given
    (a sparse matrix, or the model's matrix-free ``FreeStiffness``);
    ``elements``: its matrix as voxel element matrices (multigrid's first coarse level).
    Iterative solves that stop short return their last iterate (``info.converged``
    False, ``info.reason`` why) when the tangent is indefinite or too large to
    factorise (:data:`~voxflex.deform.solve.linear.DIRECT_FALLBACK_MAX`): Newton's
    remedies take it from there (see :func:`_newton`); a stalled solve of a smaller
    system still falls back to the direct solver.
    """
    method = options.linear_solver
    if method == "auto" and getattr(reduce, "direct_only", False):
        method = "direct"  # an iterative solve of this run already fell back: do not pay for it again
    if block is not None:
        if method == "auto":
            nf = len(free)
            dense = sp.issparse(block) and nf <= DENSE_AUTO_MAX and block.nnz >= DENSE_FILL * nf**2
            method = "cholesky" if dense else choose_method(nf, grid=grid)
        nn = near_null if method == "amg" else None
        mg = method == "multigrid"
        d, info = solve_linear(block, rhs, method=method, rtol=eta, near_null=nn, grid=grid if mg else None,
                               free=free if mg else None, elements=elements if mg else None, partial=True)
        return d, info, block
    if isinstance(H, np.ndarray):
        # a dense Hessian (frame models): dense Cholesky unless a sparse method was asked for
        if method in ("auto", "cholesky"):
            Hff = reduce(H)
            d, info = solve_linear(Hff, rhs, method="cholesky")
            return d, info, Hff
        H = sp.csr_matrix(H)
    if method == "auto":
        nf = len(free)
        # a reduced model's stiffness is small and nearly dense (frames couple through shared
        # material): a dense Cholesky beats sparse LU there (measured in benchmarks/bench_frames.py)
        dense = nf <= DENSE_AUTO_MAX and H.nnz >= DENSE_FILL * H.shape[0] ** 2  # H is sparse here
        method = "cholesky" if dense else choose_method(nf, grid=grid)
    if method == "cg":
        d, info = cg_on_free_dofs(H, rhs, free, rtol=eta, fixed=reduce.fixed, partial=True)
        # an indefinite tangent, or one too large to factorise: CG's last iterate goes to Newton's remedies
        if info.converged or info.reason in INDEFINITE_REASONS or len(free) > DIRECT_FALLBACK_MAX:
            return d, info, None
        Hff = reduce(H)
        d, direct = solve_linear(Hff, rhs, method="direct")
        direct.note = f"cg stopped after {info.iterations} iterations above rtol {eta:.1e}; fell back to direct"
        direct.reason = info.reason
        direct.fell_back = True
        direct.iterations = info.iterations
        return d, direct, Hff
    Hff = reduce(H)
    nn = near_null if method == "amg" else None
    d, info = solve_linear(Hff, rhs, method=method, rtol=eta, near_null=nn,
                           grid=grid if method == "multigrid" else None, free=free if method == "multigrid" else None,
                           partial=True)
    return d, info, Hff


SHIFT_START = 1e-4


"""First shift of an indefinite tangent, relative to the mean of its diagonal (see :func:`_shifted_direction`)."""


SHIFT_TRIES = 12


def _shifted_direction(Hff, rhs, r, grid, free, eta, label, it):
    """A descent direction from the shifted tangent ``(Hff + mu I) d = rhs``, mu raised tenfold until ``r . d < 0``.

    mu starts at :data:`SHIFT_START` times the mean of ``|diag(Hff)|`` (dimensionless: the same
    verdict at any scale).  Dense tangents get a dense Cholesky, sparse ones the direct solver up to
    :data:`~voxflex.deform.solve.linear.DIRECT_FALLBACK_MAX` unknowns and multigrid-CG (Jacobi-CG
    without a voxel grid) beyond, whose last iterate serves when it descends (CG on a positive
    definite matrix from zero descends at every iterate): never a factorisation of a large tangent.
    Returns the direction and the solver's description; raises ConvergenceError when no shift gives one.
    """
    dense = isinstance(Hff, np.ndarray)
    if not dense and not sp.issparse(Hff):
        raise ConvergenceError(f"{label}: no descent direction from the matrix-free stiffness at iteration {it}")
    n = Hff.shape[0]
    diag = np.abs(diagonal(Hff))
    mu = SHIFT_START * float(np.mean(diag)) if n else 1.0
    if dense:
        method = "cholesky"
    elif n <= DIRECT_FALLBACK_MAX:
        method = "direct"
    else:
        method = "multigrid" if grid is not None else "cg"
    mg = method == "multigrid"
    for _ in range(SHIFT_TRIES):
        shift = mu * np.eye(n) if dense else mu * sp.identity(n, format="csr")
        d, info = solve_linear(Hff + shift, rhs, method=method, rtol=eta, grid=grid if mg else None,
                               free=free if mg else None, partial=True)
        if vdot(r, d) < 0:
            return d, f"{method} (shifted: tangent indefinite)"
        mu *= 10.0
    raise ConvergenceError(f"{label}: no descent direction found at iteration {it} (tangent indefinite)")


def _newton(problem, x, free, fixed, x_fixed, options, near_null, label, reduce=None, scale0: float = 0.0):
    """Minimise ``problem`` over the free DOFs of the increment ``x`` with the fixed ones moved to ``x_fixed``.

    The convergence test is ``|r_free| <= tolerance * scale`` with ``scale`` the
    largest of the external forces, the first residual and the reactions of the
    step's first two iterations (frozen then, so that a diverging iterate cannot
    raise it), or the round-off floor ``16 eps |diag(K) X|`` of the elastic
    stiffness at the step's start and the step's start state (frozen likewise).

    ``scale0`` carries the scale of an earlier attempt at the same step over to its
    continuation (see :func:`_static_increment`), so a continued solve is judged as
    the first one would have been.

    Returns the increment, iterations, relative residual, linear iterations, solver name, halvings.
    When the iterations run out, the ConvergenceError carries ``iterate`` (the last
    increment), ``scale`` and ``progress`` (whether the potential fell over the attempt)
    for a continuation.
    """
    if reduce is None:
        reduce = _FreeBlock(free, len(x))
    tol = options.tolerance
    fnorm = vnorm(problem.f)
    delta_c = x_fixed - x[fixed]
    moving = len(fixed) > 0 and bool(np.any(delta_c != 0))
    lin_its = 0
    halvings_total = 0
    solver_used = ""
    scale = max(fnorm, scale0)
    rn_prev, eta_prev = None, None
    cached = None  # (x, problem(x)) of an accepted full step whose gradient the line search evaluated
    step_length, last_lin, last_eta, t_last = 0.0, 0, 0.0, time.perf_counter()
    lean = problem.block is not None
    history = []  # residuals of the iterates so far (Newton's rate)
    pot_start = None  # the potential at the attempt's first iterate
    indefinite = project = False  # the last tangent was indefinite along the step / was projected
    floor = 0.0  # the round-off floor of the residual, set from the first iterate's Hessian
    bulk_floor = 0.0  # the relative floor of nearly incompressible materials (BULK_FLOOR), set with it
    chord = problem.chord if not lean else None
    chorded = False  # the last step was a chord step
    secant = None  # (free residual, step taken) of the last chord step: its curvature, measured by the next residual
    for it in range(options.max_iterations + 1):
        use_chord = chord is not None and not moving and chord.good and chord.ready(len(free)) and (
            it == 0 or step_length == 1.0) and 2 * it < options.max_iterations
        # the Hessian of an iterate where Newton's rate predicts convergence would never be solved: skip it
        # (built below after all when the iterate does not converge)
        skip = use_chord or (len(history) >= 2 and step_length == 1.0 and _predict_converged(
            history[-1], history[-2], tol * scale, floor))
        project = not moving and _project_tangents(options.tangent_projection, step_length, indefinite, project)
        if cached is not None and cached[0] is x:
            pot, E, g, H, mag = cached[1]
        else:
            pot, E, g, H, mag = problem(x, hessian=not skip, project=project)
        cached = None
        if not np.isfinite(pot) or not np.all(np.isfinite(g)):
            raise ConvergenceError(f"{label}: the energy is not finite at iteration {it} (inverted material?)")
        if it == 0:
            pot_start = pot
        r = g[free]
        rn = vnorm(r)
        history.append(rn)
        if chorded and use_chord and rn > CHORD_RATE * history[-2]:
            chord.good = use_chord = False  # the earlier Hessian no longer contracts fast enough: a fresh one here
        if secant is not None and not chord.secant(secant[1], r - secant[0]):
            # the true tangent's curvature along the chord step (the secant of the residuals) is not positive,
            # which the chord's positive definite factor cannot show: as a fresh Hessian would, report it (the
            # stability check runs after the step) and build a fresh one here
            problem.negative_curvature = indefinite = True
            chord.good = use_chord = False
        secant = None
        if it == 0:
            scale = max(scale, rn)
            # round-off floor: the elastic forces come from positions known to eps |x| (or from the displacement,
            # F = I + grad u known to eps: _Problem.roundoff_lengths), so the residual cannot drop below
            # ~eps |diag(K)| times that length; taken at the step's start and frozen
            # (a chord step's start has no Hessian of its own: the elastic diagonal of the step that built it)
            if problem.elastic_diagonal is None and use_chord:
                diag = chord.elastic
            else:
                diag = problem.elastic_diagonal if lean else problem.elastic_diagonal[free]
            lengths = problem.roundoff_lengths(free)
            if moving:  # the free DOFs follow the prescribed motion this step imposes (a clamp moved 1000 km
                # rigidly: its forces carry eps |u| / h, which the step's start, still at u = 0, does not show)
                lengths = lengths + float(np.max(np.abs(delta_c)))
            floor = 16.0 * np.finfo(float).eps * vnorm(diag * lengths)
            # and the cancellation of a nearly incompressible material's volumetric terms: relative to the forces'
            # scale, BULK_FLOOR eps lambda / mu (dimensionless; ~1e-7 at nu = 0.49999999, 1e-11 at 0.4999)
            bulk_floor = BULK_FLOOR * np.finfo(float).eps * problem.bulk_ratio()
        if it <= 1:
            scale = max(scale, vnorm(g[fixed]) if len(fixed) else 0.0)
        rel = rn / scale if scale > 0 else 0.0
        if problem.on_iteration is not None:
            now = time.perf_counter()
            problem.on_iteration({"label": label, "iteration": it, "residual": rel, "step_length": step_length,
                                  "linear_solver": solver_used, "linear_iterations": last_lin,
                                  "linear_rtol": last_eta,
                                  "seconds": now - t_last})
            t_last = now
        if not moving and (scale == 0.0 or rn <= max(tol * scale, floor, bulk_floor * scale)):
            problem.solution_energy = E  # the model's energy at the answer (the caller's record need not redo it)
            return x, it, rel, lin_its, solver_used, halvings_total
        if it == options.max_iterations:
            break
        if H is None and not lean and not use_chord:
            # the Hessian was skipped (Newton predicted convergence here) or not built by the line search
            problem.hessian_misses += skip
            pot, E, g, H, mag = problem(x, hessian=True, project=project)
        rhs = -r
        if moving:
            if lean:
                # constant tangent: K_fc delta_c = r(x with the fixed DOFs moved) - r(x), matrix-free
                x_moved = x.copy()
                x_moved[fixed] = x_fixed
                rhs = -problem(x_moved, hessian=False)[2][free]
            else:
                dc = np.zeros(len(x))
                dc[fixed] = delta_c
                rhs = rhs - (H @ dc)[free]  # = H[free][:, fixed] @ delta_c
        rhs_n = vnorm(rhs)
        floor_eta = 0.5 * tol * scale / max(rhs_n, 1e-300)  # no need to solve beyond the Newton tolerance
        if problem.constant:
            eta = floor_eta
        else:
            eta = max(_forcing(rn, rn_prev, eta_prev, scale), floor_eta)
        eta = float(np.clip(eta, 1e-14, 0.5))
        rn_prev, eta_prev = rn, eta
        chorded = use_chord
        if use_chord:
            t_solve = time.perf_counter()
            d, Hff = chord.solve(rhs), chord.Hff
            info = LinearSolveInfo("cholesky (an earlier iteration's tangent)", 0, 0.0, time.perf_counter() - t_solve)
        else:
            d, info, Hff = _solve_free(H, rhs, free, reduce, options, eta, near_null, _grid_of(problem.model),
                                       block=problem.block, elements=problem.elements)
            if chord is not None and isinstance(Hff, np.ndarray) and not moving:  # dense (what Cholesky solved)
                chord.store(Hff, problem.elastic_diagonal[free])
        lin_its += info.iterations
        last_lin, last_eta = info.iterations, (0.0 if chorded else eta)
        problem.solves += 1
        solver_used = info.method + (f" ({info.note})" if info.note else "")
        if options.linear_solver == "auto" and info.fell_back:
            # high stiffness contrast or near-incompressibility defeated the iterative solver once:
            # the rest of the run goes straight to the direct solver (a two-bone limb with a 1e5
            # contrast took 394 s with repeated fallbacks, 6.8 s direct)
            reduce.direct_only = True
        if moving:
            # predictor: move the fixed DOFs to their targets, carry the interior along
            x_new = x.copy()
            x_new[fixed] = x_fixed
            alpha = 1.0
            for _ in range(MAX_HALVINGS):
                x_try = x_new.copy()
                x_try[free] += alpha * d
                if np.isfinite(problem(x_try, hessian=False, gradient=False)[0]):
                    break
                alpha *= 0.5
                halvings_total += 1
            else:
                raise ConvergenceError(
                    f"{label}: every predictor step to the prescribed positions gives a non-finite energy "
                    f"({MAX_HALVINGS} halvings); use more load steps"
                )
            x = x_try
            moving = False
            step_length = alpha
            continue
        slope = vdot(r, d)
        full_step = None  # the full step's iterate and its evaluation, when made here
        if use_chord and not problem.constant:
            # the kept factor is positive definite (its Cholesky passed), so d has positive curvature in it, and
            # the trials below are evaluated, not modelled: no product with the dense tangent (a twentieth of
            # an implicit-Euler iteration of 60 frames); the secant of the step judges the true curvature
            curvature = None
        elif lean and problem.constant and not moving and options.line_search:
            # the lean path's quadratic potential: the full step's iterate is evaluated now (its gradient is the
            # next iteration's, reused from the cache), and the difference of the gradients is K d, so the
            # curvature costs no product with the free block (0.5 s at 6.4 million DOF)
            x_full = x.copy()
            x_full[free] += d
            full_step = (x_full, problem(x_full, hessian=False))
            curvature = vdot(d, full_step[1][2][free] - r)
        elif Hff is not None:
            curvature = vdot(d, Hff @ d)
        else:
            dfull = np.zeros(len(x))
            dfull[free] = d
            curvature = vdot(d, (H @ dfull)[free])
        indefinite = False
        if not info.converged and info.reason in INDEFINITE_REASONS:
            # CG met a direction of negative curvature, or a V-cycle made indefinite by the tangent's coarse
            # levels (no direct fallback for these): d is its last iterate, built from steps of positive
            # curvature, so a descent direction of Newton's quadratic model (truncated Newton-CG), or zero
            problem.negative_curvature = True
            indefinite = True
        if curvature is not None and curvature < 0:
            problem.negative_curvature = True
            indefinite = True
        if not slope < 0:
            # not a descent direction (indefinite tangent, or CG stopped before its first step): regularise
            Hff = reduce(H) if Hff is None else Hff
            d, solver_used = _shifted_direction(Hff, rhs, r, _grid_of(problem.model), free, eta, label, it)
            slope = vdot(r, d)
            indefinite = True
        if not options.line_search:
            x = x.copy()
            x[free] += d
            step_length = 1.0
            secant = (r, d) if chorded else None
            continue
        H = Hff = None  # release them before the next Hessian is built (peak memory)
        alpha = 1.0
        accepted = False
        for _ in range(MAX_HALVINGS):
            # trials by their energy alone: a rejected full step costs no gradient nor Hessian (the
            # accepted iterate gets its gradient and Hessian at the top of the next iteration); a constant
            # tangent's potential is quadratic, so its value along d is known exactly without a model pass
            # (53 ms of a 1.3 s linear solve at 421k DOF)
            trial = None
            if full_step is not None and alpha == 1.0:
                x_try, trial = full_step  # evaluated above
                pot_try = trial[0]
            else:
                x_try = x.copy()
                x_try[free] += alpha * d
                if problem.constant:
                    pot_try = pot + alpha * slope + 0.5 * alpha**2 * curvature
                else:
                    pot_try = problem(x_try, hessian=False, gradient=False)[0]
            if np.isfinite(pot_try) and pot_try <= pot + ARMIJO * alpha * slope + ROUNDOFF * mag:
                accepted = True
            elif alpha == 1.0 and np.isfinite(pot_try) and pot_try - pot <= NOISE * mag:
                # near a solution of a high-contrast problem the energy's decrease (~|r|^2 / k_soft) falls
                # below the round-off of the stiff parts' energy (~eps E_stiff V): judge the full Newton
                # step by the residual it leaves instead, when the energy stays flat to NOISE
                trial = problem(x_try, hessian=False) if trial is None else trial
                accepted = vnorm(trial[2][free]) <= 0.9 * rn
            if accepted:
                if trial is not None:
                    cached = (x_try, trial)
                break
            alpha *= 0.5
            halvings_total += 1
        if not accepted:
            raise ConvergenceError(
                f"{label}: line search failed at Newton iteration {it} (relative residual {rel:.2e}, "
                f"{MAX_HALVINGS} halvings, linear solver {solver_used}); use more load steps or a smaller dt"
            )
        x = x_try
        step_length = alpha
        secant = (r, alpha * d) if chorded else None
    exc = ConvergenceError(
        f"{label}: Newton did not converge in {options.max_iterations} iterations: relative residual {rel:.2e} "
        f"(tolerance {tol:.1e}), {halvings_total} line-search halvings, linear solver {solver_used} "
        f"({lin_its} linear iterations); use more load steps, a smaller dt or more iterations"
    )
    # the line search lowered the potential at every iteration: that is the progress (the residual of slow,
    # rotation-bound solves rises a thousandfold on the way, so it cannot judge)
    exc.iterate, exc.scale, exc.progress = x, scale, pot_start is not None and pot < pot_start
    exc.effort = (options.max_iterations, lin_its, halvings_total)
    raise exc
