"""Static and implicit-Euler solvers for any :class:`~voxflex.deform.model.Model`.

Statics: the equilibrium ``dE/dq = f`` is the minimum of the total potential
``Pi(q) = E(q) - f . (q - X)``, found by Newton's method with a backtracking
(Armijo) line search on Pi, under load stepping: step k of ``steps`` applies
the load factor ``s = k / steps`` to the forces and to the prescribed motions.

Dynamics: backward (implicit) Euler.  With ``xhat = q_n + h v_n`` the new
positions minimise the incremental potential

    Phi(q) = 1/(2h^2) |q - xhat|_M^2 + 1/(2h) |q - q_n|_D^2 + E(q) - f . q,

with Rayleigh damping ``D = alpha M + beta K(q_n)`` (the stiffness frozen at
the start of the step so that Phi is a true potential); then
``v_{n+1} = (q_{n+1} - q_n) / h``.  Backward Euler dissipates: a single mode of
frequency w loses the factor ``1 / (1 + w^2 h^2)`` of its energy per step.

Fixed DOFs are eliminated (the system is reduced to the free DOFs), never
penalised.  When prescribed DOFs move, the first Newton iteration of a step is
the linearised predictor ``K_ff dq_f = -r_f - K_fc dq_c``, which carries the
interior along with the boundary and avoids inverted voxels.

Non-convergence raises :class:`~voxflex.errors.ConvergenceError` stating the
step, the iterations, the residual, the line search and the linear solver.

Hot path.  A static problem of a constant-tangent model that assembles its
own free-DOF block (the voxel model's ``constant_stiffness_block``) takes the
lean path: that block is built once, compacted in place, and every solve uses
it; the full stiffness is never built nor cached and gradients are
matrix-free (linear beam 128x32x32, ``auto`` = multigrid-CG: peak resident
memory 3443 -> 2122 bytes/DOF).  Implicit Euler adds ``M/h^2 + D/h``, built
once per step, into each Hessian's own pattern (positions found once)
instead of a sparse sum per iteration.  The line search judges its trials
by the energy alone (a rejected full step costs no gradient nor Hessian), and
an iterate where Newton's rate predicts convergence is evaluated without
its Hessian (:func:`_predict_converged`): on the neo-Hooke beam 32x8x8
(5 steps, sparse LU, 30 solves) 40 Hessians were built, now 32
(``benchmarks/bench_solver_waste.py``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

import numpy as np
import scipy.sparse as sp

from ..errors import ConvergenceError, InputError, check_choice
from .boundary import FixedRegion, ForceRegion, fixed_dofs, prescribed_positions, region_forces
from .model import END_STEP_PASSES, end_step
from .supports import check_supports
from .linear_solvers import METHODS, cg_on_free_dofs, choose_method, solve_linear, vdot, vnorm

KINDS = ("static", "implicit-euler")
MASS_KINDS = ("lumped", "consistent")
TANGENT_PROJECTIONS = ("auto", "always", "never")
"""``tangent_projection`` choices: per-sample tangents projected to positive semi-definite after the
exact tangent was indefinite along a Newton step, until a full step (``auto``, see
:func:`_project_tangents`), at every iterate, or never."""
ARMIJO = 1e-4
MAX_HALVINGS = 30
DENSE_AUTO_MAX = 6000  # unknowns up to which a nearly dense Hessian goes to dense Cholesky under "auto"
DENSE_FILL = 0.2  # fraction of non-zeros above which a Hessian counts as nearly dense
ROUNDOFF = 1e-11  # relative energy slack of the line search (differences of Pi below it are round-off)
NOISE = 1e-7  # relative energy change under which a full Newton step that cuts the residual is accepted


@dataclass(frozen=True)
class SolverOptions:
    """Solver settings.

    Parameters
    ----------
    kind : {"static", "implicit-euler"}
    steps : int
        Static: load increments; implicit Euler: time steps.
    dt : float (s)
        Time step (implicit Euler).
    tolerance : float
        Newton stops when ``|r_free| <= tolerance * scale``, with ``scale`` the
        largest of the external forces, the first residual of the step and the
        reactions on the fixed DOFs (N).
    max_iterations : int
        Newton iterations per attempt at a step (static attempts that run out after
        lowering the potential continue, see :data:`MAX_CONTINUATIONS`).
    line_search : bool
        Backtracking Armijo line search on the (incremental) potential.
    linear_solver : {"auto", "cholesky", "direct", "cg", "amg"}
        See :mod:`voxflex.deform.linear_solvers`.
    rayleigh_mass, rayleigh_stiffness : float
        Damping ``D = rayleigh_mass * M + rayleigh_stiffness * K`` (1/s and s).
    mass : {"lumped", "consistent"}
        Mass matrix of implicit Euler.
    check_stability : bool
        Check every converged state for a negative eigenvalue of the free
        tangent (always done when Newton met negative curvature).
    tangent_projection : {"auto", "always", "never"}
        Hessians built from per-sample tangents dP/dF projected to positive
        semi-definite (negative eigenvalues set to 0; the assembled Hessian is
        then PSD and every Newton direction descends): ``auto`` uses the exact
        tangent until it is indefinite along a Newton step, then the projected
        one until a step is accepted in full (the exact tangent near the
        solution keeps quadratic convergence); models or labels without
        projection (rigid frames, F-bar labels, elastons) stay exact.
    """

    kind: str = "static"
    steps: int = 1
    dt: float = 0.01
    tolerance: float = 1e-8
    max_iterations: int = 50
    line_search: bool = True
    linear_solver: str = "auto"
    rayleigh_mass: float = 0.0
    rayleigh_stiffness: float = 0.0
    mass: str = "lumped"
    check_stability: bool = False
    tangent_projection: str = "auto"

    def __post_init__(self):
        check_choice("solver kind", self.kind, KINDS)
        check_choice("tangent projection", self.tangent_projection, TANGENT_PROJECTIONS)
        check_choice("linear solver", self.linear_solver, METHODS)
        check_choice("mass", self.mass, MASS_KINDS)
        if int(self.steps) != self.steps or self.steps < 1:
            raise InputError(f"solver steps must be a positive integer, got {self.steps!r}")
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise InputError(f"time step dt must be > 0 (s), got {self.dt!r}")
        if not (np.isfinite(self.tolerance) and 0 < self.tolerance < 1):
            raise InputError(f"solver tolerance must be in (0, 1), got {self.tolerance!r}")
        if int(self.max_iterations) != self.max_iterations or self.max_iterations < 1:
            raise InputError(f"max_iterations must be a positive integer, got {self.max_iterations!r}")
        for name in ("rayleigh_mass", "rayleigh_stiffness"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise InputError(f"{name} must be >= 0, got {v!r}")


@dataclass
class StepRecord:
    """State after one step (the first record is the rest state at time 0).

    ``time`` is the load factor for statics, seconds for dynamics; ``q`` (n, d)
    the node state (positions in m for point nodes); ``v`` (n, d) its velocity or None (statics);
    energies in J; ``residual`` the final relative residual; ``linear_iterations``
    summed over the step's Newton iterations (0 for direct solvers).
    """

    time: float
    q: np.ndarray
    v: np.ndarray | None
    newton_iterations: int
    seconds: float
    elastic_energy: float
    kinetic_energy: float
    residual: float
    linear_iterations: int = 0
    linear_solver: str = ""
    line_search_halvings: int = 0
    load_cuts: int = 0


class _Problem:
    """The potential of one step over the increment ``delta`` (N,) from the step's start ``base``.

    The state is ``base + delta``.  Inertia and damping see ``delta`` plus the
    differences ``base - xhat`` and ``base - xn`` computed once, never the
    difference of two absolute states: with tiny time steps ``M / h^2`` would
    otherwise amplify the round-off of the positions (eps |x|) into forces
    that swamp the physics.
    """

    def __init__(self, model, f, base, M=None, h=None, xhat=None, xn=None, D=None, *, block=None, adder=None):
        self.model = model
        self.f = f
        self.M = M
        self.h = h
        self.base = base
        self.off_hat = None if xhat is None else base - xhat
        self.off_n = None if xn is None else base - xn
        self.D = D
        self.rest = np.asarray(model.rest, dtype=float).ravel()
        self.shape = np.shape(model.rest)
        self.constant = bool(model.constant_tangent)
        self.work0 = vdot(f, base - self.rest)
        self.elastic_diagonal = None
        self.negative_curvature = False  # set by Newton when a direction of negative curvature was met
        self.on_iteration = None  # optional callable(dict) told about every Newton iterate (progress, logs)
        # the lean static path of constant-tangent models: the free-DOF block (F, F) assembled once by the
        # model, no full Hessian ever built (gradients then matrix-free); Newton solves with it
        self.block = block
        self.elements = None
        if block is not None:
            self.elastic_diagonal = block.diagonal()  # of the free DOFs only (what the round-off floor reads)
            # the block's matrix as voxel element matrices: multigrid forms its first coarse level from them
            elements = getattr(model, "stiffness_elements", None)
            self.elements = elements() if callable(elements) else None
        # the inertia (and damping) matrix of the step, M / h^2 + D / h, built once, added to each Hessian
        self.inertia = None
        if M is not None:
            self.inertia = sp.csr_matrix(M / h**2 if D is None else M / h**2 + D / h)
        self._adder = adder if adder is not None else _PatternAdd()
        # waste counters (benchmarks, tests): model evaluations, Hessians assembled, Hessians solved (Newton
        # counts them) and the iterates whose Hessian the line search skipped but which needed one after all
        self.evaluations = 0
        self.energy_only = 0
        self.hessians = 0
        self.solves = 0
        self.hessian_misses = 0
        self.projected = 0  # Hessians built from projected tangents

    def __call__(self, delta, hessian=True, gradient=True, project=False):
        q = (self.base + delta).reshape(self.shape)
        hessian = hessian and self.block is None
        self.evaluations += 1
        self.hessians += bool(hessian and gradient)
        self.energy_only += not gradient
        setter = getattr(self.model, "set_tangent_projection", None) if project and hessian and gradient else None
        if setter is not None:
            self.projected += bool(setter(True))
            try:
                E, g, H = self.model.energy_gradient_hessian(q, hessian=True)
            finally:
                setter(False)  # the model's Hessians stay exact outside this call (stability check, damping)
        else:
            E, g, H = self.model.energy_gradient_hessian(q, hessian=hessian) if gradient else (
                self.model.energy(q), None, None)
        work = self.work0 + vdot(self.f, delta)
        pot = E - work
        mag = abs(E) + abs(work)
        if H is not None and self.elastic_diagonal is None:
            self.elastic_diagonal = H.diagonal()  # read once, at the step's start (the round-off floor)
        if g is not None:
            g = g.ravel() - self.f
        if self.M is not None:
            dx = delta + self.off_hat
            Mdx = self.M @ dx
            kin = 0.5 * vdot(dx, Mdx) / self.h**2
            pot += kin
            mag += kin
            if g is not None:
                g = g + Mdx / self.h**2
            if self.D is not None:
                dn = delta + self.off_n
                Ddn = self.D @ dn
                damp = 0.5 * vdot(dn, Ddn) / self.h
                pot += damp
                mag += damp
                if g is not None:
                    g = g + Ddn / self.h
            if H is not None:
                H = self._adder(H, self.inertia)
        if H is not None and not isinstance(H, np.ndarray):
            H = sp.csr_matrix(H)
        return pot, E, g, H, mag


class _PatternAdd:
    """``H + S`` for Hessians H that share one sparsity pattern and a fixed sparse S inside it.

    scipy's sparse sum merges the two patterns on every call (a new CSR per
    Newton iteration of implicit Euler); here the positions of S's entries in
    H's pattern are found once per (pattern, S) and each call is a copy of
    H's values plus a scatter-add.  Dense Hessians (frame models) get S's dense
    form, made once.  Falls back to the plain sum when S has an entry outside H's pattern.
    """

    def __init__(self):
        self._key = None
        self._pos = None
        self._dense = None

    def __call__(self, H, S):
        if isinstance(H, np.ndarray):
            if self._dense is None or self._dense[0] is not S:
                self._dense = (S, S.toarray())
            return H + self._dense[1]
        H = sp.csr_matrix(H)
        if not H.has_canonical_format:
            return H + S
        if not self._same(H, S):
            self._pos = _positions_in(H, S)
            self._key = (H.indptr, H.indices, S.indptr.copy(), S.indices.copy())
        if self._pos is None:
            return H + S
        data = H.data.copy()  # never write into the model's arrays (a constant model shares its cached data)
        np.add.at(data, self._pos, S.data)
        return sp.csr_matrix((data, H.indices, H.indptr), shape=H.shape)


    def _same(self, H, S) -> bool:
        """Whether H and S have the patterns the cached positions were found for (S's may be a new matrix)."""
        if self._key is None:
            return False
        hp, hi, sp_, si = self._key
        if len(hi) != len(H.indices) or len(hp) != len(H.indptr) or len(si) != len(S.indices) or \
                len(sp_) != len(S.indptr):
            return False
        same_h = (hp is H.indptr and hi is H.indices) or (np.array_equal(hp, H.indptr) and np.array_equal(hi, H.indices))
        return same_h and np.array_equal(sp_, S.indptr) and np.array_equal(si, S.indices)


def _positions_in(H, S):
    """Index (S.nnz,) of each stored entry of the CSR S in the canonical CSR H's data, or None when one is missing."""
    S = sp.csr_matrix(S)
    rows = np.repeat(np.arange(S.shape[0]), np.diff(S.indptr))
    cols = S.indices
    starts, ends = H.indptr[rows], H.indptr[rows + 1]
    # binary search of each column inside its row of H (indices sorted per row): global offsets into H.indices
    keys = rows.astype(np.int64) * H.shape[1] + cols
    hrows = np.repeat(np.arange(H.shape[0], dtype=np.int64), np.diff(H.indptr))
    hkeys = hrows * H.shape[1] + H.indices
    pos = np.searchsorted(hkeys, keys)
    ok = (pos < len(hkeys)) & (pos >= starts) & (pos < ends)
    ok[ok] = hkeys[pos[ok]] == keys[ok]
    return pos if bool(np.all(ok)) else None


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
            raise ValueError("free DOFs must be sorted and unique")  # internal: solve() passes setdiff1d
        self.size = int(size)
        self.direct_only = False  # set once an "auto" iterative solve fell back to direct in this run
        self.fixed = np.setdiff1d(np.arange(self.size), self.free)  # once, not per Jacobi-CG solve
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
        return sp.csr_matrix((H.data[self.sel], self.indices_ff, self.indptr_ff), shape=(nf, nf))


def _solve_free(H, rhs, free, reduce, options, eta, near_null, grid=None, block=None, elements=None):
    """Solve ``H[free][:, free] d = rhs``; returns d, info and the submatrix when it was built.

    Jacobi-CG (``"cg"``, and ``"auto"`` on large systems without a voxel grid)
    runs on H itself with the fixed DOFs masked; the other methods (and CG's
    direct fallback) take the submatrix from ``reduce``.  ``grid`` is the
    model's :attr:`dof_grid` (voxel models): with it ``auto`` picks sparse LU or
    geometric-multigrid CG (see :func:`voxflex.deform.linear_solvers.choose_method`).
    ``block``: the submatrix itself (the lean path; H is then None), solved as given;
    ``elements``: its matrix as voxel element matrices (multigrid's first coarse level).
    """
    method = options.linear_solver
    if method == "auto" and getattr(reduce, "direct_only", False):
        method = "direct"  # an iterative solve of this run already fell back: do not pay for it again
    if block is not None:
        if method == "auto":
            nf = len(free)
            dense = nf <= DENSE_AUTO_MAX and block.nnz >= DENSE_FILL * nf**2
            method = "cholesky" if dense else choose_method(nf, grid=grid)
        nn = near_null if method == "amg" else None
        mg = method == "multigrid"
        d, info = solve_linear(block, rhs, method=method, rtol=eta, near_null=nn, grid=grid if mg else None,
                               free=free if mg else None, elements=elements if mg else None)
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
        d, info = cg_on_free_dofs(H, rhs, free, rtol=eta, fixed=reduce.fixed)
        if d is not None:
            return d, info, None
        Hff = reduce(H)
        d, direct = solve_linear(Hff, rhs, method="direct")
        direct.note = f"cg stopped after {info.iterations} iterations above rtol {eta:.1e}; fell back to direct"
        direct.fell_back = True
        direct.iterations = info.iterations
        return d, direct, Hff
    Hff = reduce(H)
    nn = near_null if method == "amg" else None
    d, info = solve_linear(Hff, rhs, method=method, rtol=eta, near_null=nn,
                           grid=grid if method == "multigrid" else None, free=free if method == "multigrid" else None)
    return d, info, Hff


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
    step_length, last_lin, t_last = 0.0, 0, time.perf_counter()
    lean = problem.block is not None
    history = []  # residuals of the iterates so far (Newton's rate)
    pot_start = None  # the potential at the attempt's first iterate
    indefinite = project = False  # the last tangent was indefinite along the step / was projected
    for it in range(options.max_iterations + 1):
        # the Hessian of an iterate where Newton's rate predicts convergence would never be solved: skip it
        # (built below after all when the iterate does not converge)
        skip = len(history) >= 2 and step_length == 1.0 and _predict_converged(
            history[-1], history[-2], tol * scale, floor)
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
        if it == 0:
            scale = max(scale, rn)
            # round-off floor: the elastic forces come from absolute positions, known to eps |x|, so
            # the residual cannot drop below ~eps |diag(K)| |x|; taken at the step's start and frozen
            diag = problem.elastic_diagonal if lean else problem.elastic_diagonal[free]
            floor = 16.0 * np.finfo(float).eps * vnorm(diag * np.abs(problem.base[free]))
        if it <= 1:
            scale = max(scale, vnorm(g[fixed]) if len(fixed) else 0.0)
        rel = rn / scale if scale > 0 else 0.0
        if problem.on_iteration is not None:
            now = time.perf_counter()
            problem.on_iteration({"label": label, "iteration": it, "residual": rel, "step_length": step_length,
                                  "linear_solver": solver_used, "linear_iterations": last_lin,
                                  "seconds": now - t_last})
            t_last = now
        if not moving and (scale == 0.0 or rn <= max(tol * scale, floor)):
            return x, it, rel, lin_its, solver_used, halvings_total
        if it == options.max_iterations:
            break
        if H is None and not lean:
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
        d, info, Hff = _solve_free(H, rhs, free, reduce, options, eta, near_null, problem.model.dof_grid,
                                   block=problem.block, elements=problem.elements)
        lin_its += info.iterations
        last_lin = info.iterations
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
        if Hff is not None:
            curvature = vdot(d, Hff @ d)
        else:
            dfull = np.zeros(len(x))
            dfull[free] = d
            curvature = vdot(d, (H @ dfull)[free])
        indefinite = False
        if curvature < 0:
            problem.negative_curvature = True
            indefinite = True
        if slope >= 0:
            # not a descent direction (indefinite tangent): regularise with a scaled identity, direct solve
            Hff = reduce(H) if Hff is None else Hff
            diag = np.abs(Hff.diagonal())
            mu = 1e-4 * float(np.mean(diag)) if len(diag) else 1.0
            for _ in range(12):
                shift = mu * np.eye(Hff.shape[0]) if isinstance(Hff, np.ndarray) else mu * sp.identity(Hff.shape[0], format="csr")
                d, info = solve_linear(Hff + shift, rhs, method="cholesky" if isinstance(Hff, np.ndarray) else "direct")
                slope = vdot(r, d)
                if slope < 0:
                    break
                mu *= 10.0
            else:
                raise ConvergenceError(f"{label}: no descent direction found at iteration {it} (tangent indefinite)")
            solver_used = "direct (shifted: tangent indefinite)"
            indefinite = True
        if not options.line_search:
            x = x.copy()
            x[free] += d
            step_length = 1.0
            continue
        H = Hff = None  # release them before the next Hessian is built (peak memory)
        alpha = 1.0
        accepted = False
        for _ in range(MAX_HALVINGS):
            x_try = x.copy()
            x_try[free] += alpha * d
            # trials by their energy alone: a rejected full step costs no gradient nor Hessian (the
            # accepted iterate gets its gradient and Hessian at the top of the next iteration)
            pot_try = problem(x_try, hessian=False, gradient=False)[0]
            trial = None
            if np.isfinite(pot_try) and pot_try <= pot + ARMIJO * alpha * slope + ROUNDOFF * mag:
                accepted = True
            elif alpha == 1.0 and np.isfinite(pot_try) and pot_try - pot <= NOISE * mag:
                # near a solution of a high-contrast problem the energy's decrease (~|r|^2 / k_soft) falls
                # below the round-off of the stiff parts' energy (~eps E_stiff V): judge the full Newton
                # step by the residual it leaves instead, when the energy stays flat to NOISE
                trial = problem(x_try, hessian=False)
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


MAX_CUTS = 8
"""Static load increments are halved at most this many times (to 1/256 of a step) before giving up."""

MAX_CONTINUATIONS = 7
"""A static Newton attempt that runs out of iterations after lowering the potential continues from its
last iterate, at most this many times (so up to 8 x
``max_iterations`` per increment), before the increment is cut.  Measured on a neo-Hooke beam whose tip
half is 1e6 times stiffer (16x4x4, gravity, 5 steps): each step needs 150-250 iterations, as the stiff half
turns by linear updates; cutting the increment does not lower that count, so cutting failed (8 cuts)
where continuing converges."""


def _static_increment(model, f_full, x, s0, s1, free, dofs, owner, fixed, options, near_null, reduce, label,
                      on_iteration=None, block=None):
    """Equilibrium at load factor ``s1`` from the converged state ``x`` at ``s0``, cutting the increment.

    A failed Newton solve (no convergence, a failed line search, a non-finite
    state) is retried from the last converged state with half the increment,
    at most :data:`MAX_CUTS` times; after a success the increment grows back.
    Returns the state, Newton iterations, relative residual, linear
    iterations, linear solver, halvings and the number of cuts.
    """
    N = x.size
    s, h = s0, s1 - s0
    its_total = lin_total = halv_total = cuts = 0
    rel, solver_used = 0.0, ""
    while s < s1:
        s_next = s1 if s + h >= s1 - 1e-12 * (s1 - s0) else s + h
        x_start = model.begin_step(s_next, x, x.copy())
        x_fixed = prescribed_positions(model, fixed, dofs, owner, s_next) if len(dofs) else np.zeros(0)
        problem = _Problem(model, s_next * f_full, x_start, block=block)
        problem.on_iteration = on_iteration
        sub = label if s_next == s1 and s == s0 else f"{label}, sub-step to load factor {s_next:.4g}"
        try:
            delta, scale0, spent, continued = np.zeros(N), 0.0, (0, 0, 0), 0
            while True:
                try:
                    delta, its, rel, lin_its, solver_used, halvings = _newton(
                        problem, delta, free, dofs, x_fixed - x_start[dofs], options, near_null, sub, reduce,
                        scale0=scale0)
                    break
                except ConvergenceError as exc:
                    if not getattr(exc, "progress", False) or continued >= MAX_CONTINUATIONS:
                        raise
                    continued += 1  # still converging: go on from the last iterate rather than cut
                    delta, scale0 = exc.iterate, exc.scale
                    spent = tuple(a + b for a, b in zip(spent, exc.effort))
            its, lin_its, halvings = its + spent[0], lin_its + spent[1], halvings + spent[2]
            x_new = x_start + delta
            if not np.all(np.isfinite(x_new)):
                raise ConvergenceError(f"{sub}: the state is not finite after {its} Newton iterations")
        except ConvergenceError as exc:
            cuts += 1
            if cuts > MAX_CUTS:
                raise ConvergenceError(
                    f"{exc} (after cutting the load increment {MAX_CUTS} times, to {h:.3g} of the load)") from None
            h *= 0.5
            continue
        if problem.negative_curvature or options.check_stability:
            _check_stable(problem, delta, free, reduce, sub)
        its_total += its
        lin_total += lin_its
        halv_total += halvings
        x, s = x_new, s_next
        h = min(2.0 * h, s1 - s0)
    return x, its_total, rel, lin_total, solver_used, halv_total, cuts


INERTIA_MAX = 60000
"""Free unknowns up to which the stability check counts negative eigenvalues by a symmetric sparse
factorisation (Sylvester's inertia) instead of Lanczos: Lanczos for the smallest eigenvalue of a
tangent with a 1e5 stiffness contrast ran for minutes (a two-bone limb, 4557 unknowns)."""


def _below(A, shift):
    """How many eigenvalues of the sparse symmetric ``A`` lie below ``shift``, and the one nearest it.

    ``A - shift I`` is factorised with symmetric ordering and diagonal pivots
    (SuperLU in symmetric mode), so ``U``'s diagonal is the D of ``L D Lᵀ`` and
    its negative entries count the eigenvalues below ``shift`` (Sylvester's
    law of inertia).  When there are some, shift-inverted Lanczos gives the
    one nearest below the shift (the shift itself if it does not converge).
    Returns ``(0, None)`` when none lies below, ``None`` when the count is not
    known (the factorisation had to pivot off the diagonal).
    """
    import scipy.sparse.linalg as spla

    n = A.shape[0]
    M = (A - shift * sp.identity(n, format="csc")).tocsc()
    try:
        lu = spla.splu(M, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                       options={"SymmetricMode": True})
    except RuntimeError:  # an exactly singular pivot: an eigenvalue at the shift itself
        return 1, float(shift)
    if not np.array_equal(lu.perm_r, lu.perm_c):  # pivoting broke the symmetry: cannot count
        return None
    count = int(np.count_nonzero(lu.U.diagonal() < 0))
    if count == 0:
        return 0, None
    try:
        op = spla.LinearOperator((n, n), matvec=lu.solve, dtype=float)
        mu = spla.eigsh(op, k=1, which="SA", tol=1e-8, maxiter=50 * n, v0=np.ones(n) / np.sqrt(n),
                        return_eigenvectors=False)[0]  # mu = 1 / (lam - shift) < 0
        return count, (float(shift + 1.0 / mu) if mu < 0 else float(shift))
    except spla.ArpackNoConvergence:
        return count, float(shift)


def _check_stable(problem, delta, free, reduce, label):
    """Raise when the converged state is a saddle: the smallest eigenvalue of the free tangent < 0.

    Up to 400 free unknowns a dense eigensolver; up to :data:`INERTIA_MAX` the
    inertia of a symmetric sparse factorisation (:func:`_below`); beyond,
    Lanczos (ARPACK, smallest algebraic, relative tolerance 1e-6).  An
    eigenvalue below ``-1e-8`` times the largest diagonal entry is an unstable
    equilibrium (the structure buckles or the material softens there).
    """
    import scipy.sparse.linalg as spla

    if problem.block is not None:
        Hff = problem.block  # the lean path: the constant free block
    else:
        _, _, _, H, _ = problem(delta, hessian=True)
        Hff = reduce(H)
    n = Hff.shape[0]
    if n == 0:
        return
    top = float(np.abs(Hff.diagonal()).max())
    if n <= 400:
        lam = float(np.linalg.eigvalsh(Hff if isinstance(Hff, np.ndarray) else Hff.toarray())[0])
    elif n <= INERTIA_MAX:
        found = _below(sp.csc_matrix(Hff), -1e-8 * top)
        if found is None or found[0] == 0:
            return  # no eigenvalue below the threshold (or the count is unknown: never report a guess)
        lam = found[1]
    else:
        try:
            lam = float(spla.eigsh(Hff, k=1, which="SA", tol=1e-6, maxiter=20 * n,
                                   v0=np.ones(n) / np.sqrt(n), return_eigenvectors=False)[0])
        except spla.ArpackNoConvergence:
            return  # could not tell: never report a guess
    if lam < -1e-8 * top:
        raise ConvergenceError(
            f"{label}: unstable equilibrium (buckling or material instability): the tangent has a negative "
            f"eigenvalue {lam:.3g} at the converged state; perturb the load or the geometry, use smaller load "
            "steps with a small lateral load, or simulate dynamics"
        )


def _lean(model, options) -> bool:
    """Whether :func:`solve` takes the lean path: a static problem of a model whose tangent is constant
    and which assembles its free-DOF block on its own (``constant_stiffness_block``: voxel models)."""
    return (options.kind == "static" and bool(model.constant_tangent)
            and callable(getattr(model, "constant_stiffness_block", None)))


def solve(
    model,
    *,
    fixed: Sequence[FixedRegion] = (),
    forces: Sequence[ForceRegion] = (),
    gravity=None,
    densities: Mapping[int, float] | None = None,
    options: SolverOptions = SolverOptions(),
    callback: Callable | None = None,
    q0=None,
    v0=None,
    newton_callback: Callable | None = None,
    sink: Callable | None = None,
) -> list[StepRecord]:
    """Run a static (load-stepped) or implicit-Euler simulation of ``model``.

    Parameters
    ----------
    model : Model
        Any model of the protocol in :mod:`voxflex.deform.model` (voxel or frame model).
    fixed : FixedRegion sequence
        Held or moved regions (prescribed motions reach their transform at the end).
    forces : ForceRegion sequence
    gravity : (3,) float, m/s^2, optional
        Needs ``densities``.
    densities : mapping label -> kg/m^3, optional
        Needed for gravity and implicit Euler.
    options : SolverOptions
    callback : callable(StepRecord), optional
        Called after each step.
    newton_callback : callable(dict), optional
        Called at every Newton iterate with ``label`` (the step), ``iteration``, ``residual``
        (relative), ``step_length`` (line-search factor of the step that led there, 0 at the
        start), ``linear_solver`` and ``linear_iterations`` of that step, ``seconds`` since the
        previous call.
    q0, v0 : (n, d) float, optional
        Initial state (default: rest) and its velocity (implicit Euler; default 0).
        Fixed DOFs still follow their regions.
    sink : callable(StepRecord), optional
        Receives every record in order, the rest state first (before ``callback`` for a step).
        With a sink the returned list (and a ConvergenceError's ``records``) holds only the rest
        state and the latest record, so that memory does not grow with the steps.

    Returns
    -------
    list of StepRecord, ``steps + 1`` long (the rest state first); with a ``sink``, the rest
    state and the last record only.

    Raises
    ------
    InputError
        Bad regions or loads (e.g. gravity or dynamics without densities); a static
        problem with a part that is not held against every rigid motion (see
        :mod:`voxflex.deform.supports`).
    ConvergenceError
        A step did not converge (the message says what was tried); its attribute ``records``
        holds the records of the steps that converged before it (the rest state first).
    """
    if not isinstance(options, SolverOptions):
        raise InputError("options must be a SolverOptions")
    fixed = list(fixed)
    forces = list(forces)
    for r in fixed:
        if not isinstance(r, FixedRegion):
            raise InputError(f"fixed entries must be FixedRegion, got {type(r).__name__}")
    for r in forces:
        if not isinstance(r, ForceRegion):
            raise InputError(f"forces entries must be ForceRegion, got {type(r).__name__}")
    dynamic = options.kind == "implicit-euler"
    if (gravity is not None or dynamic) and densities is None:
        raise InputError("gravity and implicit-euler need densities (kg/m^3) for every material label")
    shape = np.shape(model.rest)
    X = np.asarray(model.rest, dtype=float).ravel()
    N = X.size
    dofs, owner = fixed_dofs(model, fixed)
    if not dynamic and not model.supported_by_contact:
        check_supports(model, dofs)  # an unsupported part or a mechanism: refuse before solving
    free = np.setdiff1d(np.arange(N), dofs)
    f_full = region_forces(model, forces).ravel() if forces else np.zeros(N)
    if gravity is not None:
        f_full = f_full + model.gravity_force(densities, gravity).ravel()
    near_null = model.rigid_modes()[free] if options.linear_solver == "amg" else None
    reduce = _FreeBlock(free, N)
    block = None
    if _lean(model, options):
        # a constant-tangent static problem: the free-DOF block is all Newton solves with; assembled once
        # on its own and compacted in place, the full stiffness is never built nor cached (peak memory)
        block = model.constant_stiffness_block(free)

    M = None
    if dynamic:
        M = model.mass_matrix(densities, lumped=options.mass == "lumped")
    x = X.copy()
    if q0 is not None:
        q0 = np.asarray(q0, dtype=float)
        if q0.shape != shape or not np.all(np.isfinite(q0)):
            raise InputError(f"q0 must be a finite {shape} array (the node state), got shape {q0.shape}")
        x = q0.ravel().copy()
    v = np.zeros(N) if dynamic else None
    if v0 is not None:
        v0 = np.asarray(v0, dtype=float)
        if not dynamic or v0.shape != shape or not np.all(np.isfinite(v0)):
            raise InputError(f"v0 must be a finite {shape} array and needs kind='implicit-euler'")
        v = v0.ravel().copy()
    kin0 = 0.5 * vdot(v, M @ v) if dynamic else 0.0
    records = [StepRecord(0.0, x.reshape(shape).copy(), None if v is None else v.reshape(shape).copy(), 0, 0.0,
                          float(model.energy(x.reshape(shape))), kin0, 0.0)]
    if sink is not None:
        sink(records[0])
    try:
        _steps(model, options, records, x, v, M, f_full, free, dofs, owner, fixed, near_null, reduce, shape,
               callback, newton_callback, block, sink)
    except ConvergenceError as exc:
        exc.records = records  # the converged steps survive a later failure (partial results)
        raise
    return records


def _steps(model, options, records, x, v, M, f_full, free, dofs, owner, fixed, near_null, reduce, shape,
           callback, newton_callback, block=None, sink=None):
    """The loop over the steps of :func:`solve`, appending a StepRecord per converged step
    (with a ``sink``: handing it each record and keeping only the rest state and the latest)."""
    dynamic = options.kind == "implicit-euler"
    adder = _PatternAdd()  # H + M/h^2 + D/h positions found once for all steps
    N = x.size
    t_end = options.steps * options.dt
    for k in range(1, options.steps + 1):
        t0 = time.perf_counter()
        if dynamic:
            t = k * options.dt
            factor = t / t_end
            label = f"implicit Euler step {k}/{options.steps} (t = {t:.4g} s)"
            D = None
            if options.rayleigh_mass or options.rayleigh_stiffness:
                D = options.rayleigh_mass * M
                if options.rayleigh_stiffness:
                    D = D + options.rayleigh_stiffness * model.hessian(x.reshape(shape))
            xhat = x + options.dt * v
            x_start = xhat.copy()
        else:
            t = k / options.steps
            label = f"static step {k}/{options.steps} (load factor {t:.4g})"
            x_new, its, rel, lin_its, solver_used, halvings, cuts = _static_increment(
                model, f_full, x, (k - 1) / options.steps, t, free, dofs, owner, fixed, options, near_null,
                reduce, label, newton_callback, block)
        if dynamic:
            x_fixed = prescribed_positions(model, fixed, dofs, owner, factor) if len(dofs) else np.zeros(0)
            x_start[dofs] = x[dofs]  # fixed DOFs start from their previous values so the predictor sees their motion
            moved = model.begin_step(factor, x, x_start)  # e.g. contact: a start the barrier admits
            if moved is not x_start:
                v = (moved - x) / options.dt  # so that the new velocity stays (x_new - x) / h
                x_start = moved
            problem = _Problem(model, f_full, x_start, M=M, h=options.dt, xhat=xhat, xn=x, D=D, adder=adder)
            problem.on_iteration = newton_callback
            delta, its, rel, lin_its, solver_used, halvings = _newton(
                problem, np.zeros(N), free, dofs, x_fixed - x_start[dofs], options, near_null, label, reduce
            )
            cuts = 0
            x_new = x_start + delta
            if not np.all(np.isfinite(x_new)):
                raise ConvergenceError(f"{label}: the state is not finite after {its} Newton iterations")
            if problem.negative_curvature or options.check_stability:
                _check_stable(problem, x_new - x_start, free, reduce, label)
        passes = 0
        while end_step(model, x_new.reshape(shape)):  # internal variables (plasticity) changed: solve again
            passes += 1
            if passes > END_STEP_PASSES:
                raise ConvergenceError(f"{label}: the model's internal variables still change after {END_STEP_PASSES} "
                                       "re-solves of the step; use more, smaller steps")
            if dynamic:
                delta, its_p, rel, lin_p, solver_used, halv_p = _newton(
                    problem, delta, free, dofs, x_fixed - x_start[dofs], options, near_null, label, reduce)
                x_new = x_start + delta
                cuts_p = 0
            else:
                x_new, its_p, rel, lin_p, solver_used, halv_p, cuts_p = _static_increment(
                    model, f_full, x_new, (k - 1) / options.steps, t, free, dofs, owner, fixed, options, near_null,
                    reduce, label, newton_callback, block)
            if not np.all(np.isfinite(x_new)):
                raise ConvergenceError(f"{label}: the state is not finite after re-solving the step")
            its, lin_its, halvings, cuts = its + its_p, lin_its + lin_p, halvings + halv_p, cuts + cuts_p
        E = float(model.energy(x_new.reshape(shape)))
        kin = 0.0
        if dynamic:
            # x_new - x = h v + delta on the free DOFs (x_start = x + h v there) and delta on the fixed
            # ones: the velocity from the increment keeps its precision for any h
            v_start = v.copy()
            v_start[dofs] = 0.0
            v = v_start + delta / options.dt
            kin = 0.5 * vdot(v, M @ v)
        x = x_new
        rec = StepRecord(
            float(t), x.reshape(shape).copy(), None if v is None else v.reshape(shape).copy(), int(its),
            time.perf_counter() - t0, E, kin, float(rel), int(lin_its), solver_used, int(halvings), int(cuts),
        )
        if sink is not None:
            sink(rec)
            del records[1:]  # the sink has it: keep the rest state and the latest record only
        records.append(rec)
        if callback is not None:
            callback(rec)


__all__ = ["SolverOptions", "StepRecord", "solve", "FixedRegion", "ForceRegion"]
