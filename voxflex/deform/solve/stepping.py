"""Static and implicit-Euler solvers for any :class:`~voxflex.deform.models.protocol.Model`.

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
from typing import Callable, Mapping, Sequence

import numpy as np
import scipy.sparse as sp

from ..._linalg import diagonal, vdot, vnorm
from ...errors import ConvergenceError, InputError
from ..models.protocol import END_STEP_PASSES, ConstantStiffness, end_step
from .boundary import (
    FixedRegion,
    ForceRegion,
    fixed_dofs,
    load_vector,
    prescribed_positions,
)
from .chord import _Chord
from .linear import DIRECT_FALLBACK_MAX
from .newton import _FreeBlock, _grid_of, _newton
from .options import SolverOptions, StepRecord
from .potential import _PatternAdd, _Problem
from .supports import FreeMotionWarning, check_supports, free_rigid_motions

__all__ = ["solve"]

PREDICTOR = True
"""Implicit Euler's Newton starts each step from the extrapolated motion ``u + h (2 v - v_prev)`` (False: from
the inertial prediction ``u + h v``).  Only the start changes, not the answer (judged by the same residual
test).  Measured: the 60-frame NN bunny's first relative residuals 1.2e-2 -> 5e-3 in mid-run steps, about
8 % fewer model passes; a swinging 8-frame beam 77 -> 75 passes."""

MAX_CUTS = 8
"""Static load increments are halved at most this many times (to 1/256 of a step) before giving up."""


MAX_CONTINUATIONS = 7
"""A static Newton attempt that runs out of iterations after lowering the potential continues from its
last iterate, at most this many times (so up to 8 x
``max_iterations`` per increment), before the increment is cut.  Measured on a neo-Hooke beam whose tip
half is 1e6 times stiffer (16x4x4, gravity, 5 steps): each step needs 150-250 iterations, as the stiff half
turns by linear updates; cutting the increment does not lower that count, so cutting failed (8 cuts)
where continuing converges."""


def _moved_start_scale(model, f, x, proposed, x_start, u, free, block) -> float:
    """The free residual at the converged state ``x`` when the model moved the step's start away from it
    (``begin_step``: a pressurised flat membrane lifted to its bubble), else 0: Newton's scale for the step.

    A start the model chose well can be the answer itself (a membrane with one free vertex: the bubble is
    its minimum), and Newton's scale -- its first residual when there are no external forces -- is then
    round-off, which no iterate can go below (the solve stalled at 1e-5 of it).  The residual before the
    move is the force the step has to balance.  Not finite there (a start inside an obstacle): 0."""
    if x_start is proposed:
        return 0.0
    E, g = _Problem(model, f, x, block=block, u_base=u)(np.zeros(u.size), hessian=False)[1:3]
    return vnorm(g[free]) if np.isfinite(E) and np.all(np.isfinite(g)) else 0.0


def _static_increment(model, f_full, u, s0, s1, free, dofs, owner, fixed, options, near_null, reduce, label,
                      on_iteration=None, block=None, chord=None):
    """Equilibrium at load factor ``s1`` from the converged displacement ``u`` (q - X) at ``s0``, cutting the
    increment.

    A failed Newton solve (no convergence, a failed line search, a non-finite
    state) is retried from the last converged state with half the increment,
    at most :data:`MAX_CUTS` times; after a success the increment grows back.
    Returns the displacement, Newton iterations, relative residual, linear
    iterations, linear solver, halvings and the number of cuts.
    """
    N = u.size
    X = np.asarray(model.rest, dtype=float).ravel()
    s, h = s0, s1 - s0
    its_total = lin_total = halv_total = cuts = 0
    rel, solver_used = 0.0, ""
    while s < s1:
        s_next = s1 if s + h >= s1 - 1e-12 * (s1 - s0) else s + h
        x = X + u
        proposed = x.copy()
        x_start = model.begin_step(s_next, x, proposed)
        u_start = u.copy() if x_start is proposed else x_start - X
        u_fixed = prescribed_positions(model, fixed, dofs, owner, s_next) - X[dofs] if len(dofs) else np.zeros(0)
        problem = _Problem(model, s_next * f_full, x_start, block=block, u_base=u_start)
        problem.on_iteration = on_iteration
        problem.chord = chord
        sub = label if s_next == s1 and s == s0 else f"{label}, sub-step to load factor {s_next:.4g}"
        try:
            delta, scale0, spent, continued = np.zeros(N), _moved_start_scale(
                model, s_next * f_full, x, proposed, x_start, u, free, block), (0, 0, 0), 0
            while True:
                try:
                    delta, its, rel, lin_its, solver_used, halvings = _newton(
                        problem, delta, free, dofs, u_fixed - u_start[dofs], options, near_null, sub, reduce,
                        scale0=scale0)
                    break
                except ConvergenceError as exc:
                    if not getattr(exc, "progress", False) or continued >= MAX_CONTINUATIONS:
                        raise
                    continued += 1  # still converging: go on from the last iterate rather than cut
                    delta, scale0 = exc.iterate, exc.scale
                    spent = tuple(a + b for a, b in zip(spent, exc.effort))
            its, lin_its, halvings = its + spent[0], lin_its + spent[1], halvings + spent[2]
            u_new = u_start + delta
            if not np.all(np.isfinite(u_new)):
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
        u, s = u_new, s_next
        h = min(2.0 * h, s1 - s0)
    return u, its_total, rel, lin_total, solver_used, halv_total, cuts, problem.solution_energy


INERTIA_MAX = DIRECT_FALLBACK_MAX


"""Free unknowns up to which the stability check counts negative eigenvalues by a symmetric sparse
factorisation (Sylvester's inertia) instead of an iterative eigensolver: Lanczos for the smallest
eigenvalue of a tangent with a 1e5 stiffness contrast ran for minutes (a two-bone limb, 4557
unknowns).  No larger tangent is factorised (see
:data:`~voxflex.deform.solve.linear.DIRECT_FALLBACK_MAX`): beyond, :func:`_smallest_rayleigh`."""


EIGEN_MAXITER = 60


"""LOBPCG iterations of the stability check above :data:`INERTIA_MAX` unknowns, at most."""

EIGEN_STAGE = 10
"""The check's LOBPCG runs in stages of this many iterations, each from the last one's vectors, and stops
once its smallest Ritz pair has converged (:data:`EIGEN_CONVERGED`) or its value lies below the
threshold (a proof of a saddle)."""

EIGEN_CONVERGED = 1e-2
"""The check's smallest Ritz pair (theta, x) counts as converged when ``|H x - theta x| <= EIGEN_CONVERGED
|theta|`` (|x| = 1): an eigenvalue lies within 1 % of theta, so its sign is known.  Measured on the voxel
bunny at 2 mm (306k unknowns, after the third load step): theta = 7.1740e-4 after 15, 20, 30 and 60
iterations, residual / theta 1.06 / 0.059 / 0.0097 / 9e-5 / 2.7e-6 after 10 / 15 / 20 / 30 / 60;
60 iterations took 10.2 s, 20 took 5.1 s."""

EIGEN_BLOCK = 1
"""Vectors in the check's LOBPCG block.  One vector costs half a two-vector iteration (one V-cycle and one
product instead of two) and a few more iterations: on the voxel bunny above, 30 one-vector iterations took
3.2 s against 5.2 s for 20 two-vector ones, to the same theta (7.17403e-4).  A (near-)degenerate smallest
pair needs no second vector: every vector in its span has a residual within the pair's spread."""


def _smallest_rayleigh(Hff, grid, free):
    """An upper bound of the smallest eigenvalue of the large sparse symmetric ``Hff``: the smallest
    Ritz value of at most :data:`EIGEN_MAXITER` LOBPCG iterations (:data:`EIGEN_BLOCK` vectors, seeded; in stages of
    :data:`EIGEN_STAGE` that stop at convergence, :data:`EIGEN_CONVERGED`, or below the instability
    threshold), preconditioned by the voxel multigrid V-cycle of Hff when there is a grid and Hff's
    diagonal is positive.

    A Ritz value is never below the smallest eigenvalue, so a negative one proves the tangent
    indefinite whether or not LOBPCG converged; a non-negative one proves nothing.  Cost: the
    iterations' products and cycles, bounded (no factorisation).  None when LOBPCG fails."""
    import warnings

    import scipy.sparse.linalg as spla

    n = Hff.shape[0]
    M, release = None, None
    d = diagonal(Hff)
    if grid is not None and np.all(d > 0):
        from ..._blas import one_thread
        from .multigrid.hierarchy import hierarchy, multigrid_preconditioner

        with one_thread():
            # the coarse levels of the last Newton solve (same pattern) when the hierarchy may reuse them: the
            # preconditioner only speeds LOBPCG up, the Ritz value bounds the smallest eigenvalue either way
            apply, _ = multigrid_preconditioner(Hff, grid, free, stale=True)
        M = spla.LinearOperator((n, n), matvec=apply, dtype=float)
        release = hierarchy(grid, free).release
    X = np.random.default_rng(20240601).standard_normal((n, EIGEN_BLOCK))
    threshold = -1e-8 * float(np.abs(d).max())
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # LOBPCG warns when it stops at maxiter: the Ritz value still bounds
            op = Hff if sp.issparse(Hff) else spla.LinearOperator((n, n), matvec=Hff.matvec, dtype=float)
            done, theta = 0, np.inf
            while done < EIGEN_MAXITER:
                its = min(EIGEN_STAGE, EIGEN_MAXITER - done)
                lam, X = spla.lobpcg(op, X, M=M, largest=False, maxiter=its, tol=1e-8)[:2]
                done += its
                k = int(np.argmin(lam))
                theta = min(theta, float(lam[k]))  # every Ritz value bounds the smallest eigenvalue from above
                x = X[:, k] / np.linalg.norm(X[:, k])
                if theta < threshold or vnorm(op @ x - lam[k] * x) <= EIGEN_CONVERGED * abs(float(lam[k])):
                    break
        return theta
    except (np.linalg.LinAlgError, ValueError):
        return None
    finally:
        if release is not None:
            release()


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
    inertia of a symmetric sparse factorisation (:func:`_below`); beyond, the
    smallest Ritz value of a bounded LOBPCG run (:func:`_smallest_rayleigh`: an
    upper bound, so a saddle it reports is one; one it misses goes unreported).  An
    eigenvalue below ``-1e-8`` times the largest diagonal entry is an unstable
    equilibrium (the structure buckles or the material softens there).
    """
    if problem.block is not None:
        Hff = problem.block  # the lean path: the constant free block
    else:
        _, _, _, H, _ = problem(delta, hessian=True)
        Hff = reduce(H)
    n = Hff.shape[0]
    if n == 0:
        return
    top = float(np.abs(diagonal(Hff)).max())
    if n <= 400:
        lam = float(np.linalg.eigvalsh(Hff if isinstance(Hff, np.ndarray) else Hff.toarray())[0])
    elif n <= INERTIA_MAX:
        found = _below(sp.csc_matrix(Hff), -1e-8 * top)
        if found is None or found[0] == 0:
            return  # no eigenvalue below the threshold (or the count is unknown: never report a guess)
        lam = found[1]
    else:
        lam = _smallest_rayleigh(Hff if not sp.issparse(Hff) else sp.csr_matrix(Hff), _grid_of(problem.model), free)
        if lam is None:
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
            and isinstance(model, ConstantStiffness))


def _complement(idx, n: int) -> np.ndarray:
    """The sorted indices in [0, n) not in ``idx``: a mask, O(n) (np.setdiff1d's hashing unique took 0.44 s
    at 421k DOF, a fifth of that linear solve)."""
    keep = np.ones(n, dtype=bool)
    keep[np.asarray(idx, dtype=np.int64)] = False
    return np.flatnonzero(keep)


def _matrix_free_lean(model, options, n_free: int) -> bool:
    """Whether the lean path solves with the model's matrix-free block (``constant_stiffness_operator``)
    instead of an assembled one: above :data:`~voxflex.deform.solve.linear.DIRECT_FALLBACK_MAX` free
    unknowns (no factorisation could read a stored matrix) with multigrid (``auto`` or ``multigrid``)."""
    return (n_free > DIRECT_FALLBACK_MAX and options.linear_solver in ("auto", "multigrid")
            and getattr(model, "dof_grid", None) is not None
            and callable(getattr(model, "constant_stiffness_operator", None)))


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
    held=None,
    loads=None,
    mass=None,
) -> list[StepRecord]:
    """Run a static (load-stepped) or implicit-Euler simulation of ``model``.

    Parameters
    ----------
    model : Model
        Any model of the protocol in :mod:`voxflex.deform.models.protocol` (voxel or frame model).
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
        start), ``linear_solver``, ``linear_iterations`` and ``linear_rtol`` of that step (the
        relative residual asked of its linear solve, ``|A d - b| <= linear_rtol |b|``; 0 where none
        was solved for it, e.g. a chord step), ``seconds`` since the previous call.
    q0, v0 : (n, d) float, optional
        Initial state (default: rest) and its velocity (implicit Euler; default 0).
        Fixed DOFs still follow their regions.
    sink : callable(StepRecord), optional
        Receives every record in order, the rest state first (before ``callback`` for a step).
        With a sink the returned list (and a ConvergenceError's ``records``) holds only the rest
        state and the latest record, so that memory does not grow with the steps.
    held, loads, mass : optional
        What the solver would otherwise compute from the arguments above, when the caller has it
        (a :class:`~voxflex.deform.solve.problem.Problem` does): ``fixed_dofs(model, fixed)``, the
        full load vector (N,) of ``forces`` and ``gravity``, and the mass matrix of ``options``.

    Returns
    -------
    list of StepRecord, ``steps + 1`` long (the rest state first); with a ``sink``, the rest
    state and the last record only.

    Raises
    ------
    InputError
        Bad regions or loads (e.g. gravity or dynamics without densities); a static
        problem with a part that is not held against every rigid motion (see
        :mod:`voxflex.deform.solve.supports`).
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
    dofs, owner = fixed_dofs(model, fixed) if held is None else held
    if not dynamic and not model.supported_by_contact:
        check_supports(model, dofs)  # an unsupported part or a mechanism: refuse before solving
    free = _complement(dofs, N)
    if loads is not None:
        f_full = np.asarray(loads, dtype=float).ravel()
        if f_full.shape != (N,):
            raise InputError(f"loads must hold one value per DOF ({N}), got shape {np.shape(loads)}")
    else:
        f_full = load_vector(model, forces, gravity, densities)
    near_null = model.rigid_modes()[free] if options.linear_solver == "amg" else None
    reduce = _FreeBlock(free, N)
    block = None
    if _lean(model, options):
        # a constant-tangent static problem: the free-DOF block is all Newton solves with; assembled once
        # on its own and compacted in place, the full stiffness is never built nor cached (peak memory);
        # above the direct limit, where only multigrid-CG solves it, not even that: the voxel stencil and
        # the element matrices serve the solves (the model's FreeStiffness)
        if _matrix_free_lean(model, options, len(free)):
            block = model.constant_stiffness_operator(free)
        else:
            block = model.constant_stiffness_block(free)

    M = None
    if dynamic:
        M = model.mass_matrix(densities, lumped=options.mass == "lumped") if mass is None else mass
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
                          float(model.energy(x.reshape(shape))), kin0, 0.0, displacement=(x - X).reshape(shape))]
    if sink is not None:
        sink(records[0])
    try:
        _steps(model, options, records, x - X, v, M, f_full, free, dofs, owner, fixed, near_null, reduce, shape,
               callback, newton_callback, block, sink)
    except ConvergenceError as exc:
        exc.records = records  # the converged steps survive a later failure (partial results)
        raise
    if not dynamic and model.supported_by_contact:  # held by obstacles, unchecked before: is the answer unique?
        k = free_rigid_motions(model, records[-1].q, free)
        if k > 0:
            import warnings

            warnings.warn(f"the static answer is held by the obstacles only, and {k} rigid motion(s) of the body "
                          "(sliding or spinning along a frictionless obstacle) are held by nothing: its position "
                          "along them is arbitrary; hold them with [[fixed]] components, add friction, or simulate "
                          "implicit-euler", FreeMotionWarning, stacklevel=2)
    return records


def _steps(model, options, records, u, v, M, f_full, free, dofs, owner, fixed, near_null, reduce, shape,
           callback, newton_callback, block=None, sink=None):
    """The loop over the steps of :func:`solve`, appending a StepRecord per converged step
    (with a ``sink``: handing it each record and keeping only the rest state and the latest).

    The state is the displacement ``u = q - X`` from rest: the positions the model reads are ``X + u``,
    but the inertial prediction, the increments and the records' displacements are sums of displacements,
    so a step far below the round-off of the positions (eps |X|: a 1 m body at dt = 1e-9 s falls 5e-17 m
    per step) still moves the body."""
    dynamic = options.kind == "implicit-euler"
    adder = _PatternAdd()  # H + M/h^2 + D/h positions found once for all steps
    chord = _Chord()  # a dense tangent factorised once serves later iterations and steps while it contracts
    X = np.asarray(model.rest, dtype=float).ravel()
    N = u.size
    x = X + u
    v_prev = None  # the velocity a step earlier (the start's extrapolation)
    for k in range(1, options.steps + 1):
        t0 = time.perf_counter()
        if dynamic:
            t = k * options.dt
            factor = options.fraction(t)
            label = f"implicit Euler step {k}/{options.steps} (t = {t:.4g} s)"
            D = None
            if options.rayleigh_mass or options.rayleigh_stiffness:
                D = options.rayleigh_mass * M
                if options.rayleigh_stiffness:
                    D = D + options.rayleigh_stiffness * model.hessian(x.reshape(shape))
                if not sp.issparse(D):
                    D = np.asarray(D)  # a sparse mass plus a frame model's dense stiffness is an np.matrix
            uhat = u + options.dt * v
            # Newton starts from the motion extrapolated to second order (the last step's change of velocity
            # carried on: u + h (2 v - v_prev)), not from the inertial prediction uhat; the answer is the
            # same to the tolerance, the first residual about half as large (see PREDICTOR)
            w = v if v_prev is None or not PREDICTOR else 2.0 * v - v_prev
            u_start = u + options.dt * w
        else:
            t = k / options.steps
            label = f"static step {k}/{options.steps} (load factor {t:.4g})"
            u_new, its, rel, lin_its, solver_used, halvings, cuts, E_new = _static_increment(
                model, f_full, u, (k - 1) / options.steps, t, free, dofs, owner, fixed, options, near_null,
                reduce, label, newton_callback, block, chord)
        if dynamic:
            u_fixed = prescribed_positions(model, fixed, dofs, owner, factor) - X[dofs] if len(dofs) else np.zeros(0)
            u_start[dofs] = u[dofs]  # fixed DOFs start from their previous values so the predictor sees their motion
            x_start = X + u_start
            moved = model.begin_step(factor, x, x_start)  # e.g. contact: a start the barrier admits
            if moved is not x_start:
                u_start = moved - X
                w = (u_start - u) / options.dt  # so that the new velocity stays (u_new - u) / h
                x_start = moved
            problem = _Problem(model, f_full, x_start, M=M, h=options.dt, D=D, adder=adder, u_base=u_start,
                               uhat=uhat, un=u)
            problem.on_iteration = newton_callback
            problem.chord = chord
            delta, its, rel, lin_its, solver_used, halvings = _newton(
                problem, np.zeros(N), free, dofs, u_fixed - u_start[dofs], options, near_null, label, reduce
            )
            cuts, E_new = 0, problem.solution_energy
            u_new = u_start + delta
            if not np.all(np.isfinite(u_new)):
                raise ConvergenceError(f"{label}: the state is not finite after {its} Newton iterations")
            if problem.negative_curvature or options.check_stability:
                _check_stable(problem, delta, free, reduce, label)
        passes = 0
        x_new = X + u_new
        while end_step(model, x_new.reshape(shape)):  # internal variables (plasticity) changed: solve again
            passes += 1
            if passes > END_STEP_PASSES:
                raise ConvergenceError(f"{label}: the model's internal variables still change after {END_STEP_PASSES} "
                                       "re-solves of the step; use more, smaller steps")
            if dynamic:
                delta, its_p, rel, lin_p, solver_used, halv_p = _newton(
                    problem, delta, free, dofs, u_fixed - u_start[dofs], options, near_null, label, reduce)
                u_new = u_start + delta
                cuts_p = 0
            else:
                u_new, its_p, rel, lin_p, solver_used, halv_p, cuts_p, E_new = _static_increment(
                    model, f_full, u_new, (k - 1) / options.steps, t, free, dofs, owner, fixed, options, near_null,
                    reduce, label, newton_callback, block, chord)
            x_new = X + u_new
            if not np.all(np.isfinite(x_new)):
                raise ConvergenceError(f"{label}: the state is not finite after re-solving the step")
            its, lin_its, halvings, cuts = its + its_p, lin_its + lin_p, halvings + halv_p, cuts + cuts_p
        if passes or E_new is None:
            E = float(model.energy(x_new.reshape(shape)))
        else:
            E = float(E_new)  # Newton's own evaluation at the answer (a pass over the samples saved)
        kin = 0.0
        if dynamic:
            # u_new - u = h w + delta on the free DOFs (u_start = u + h w there) and delta on the fixed
            # ones: the velocity from the increment keeps its precision for any h
            v_start = np.array(w, dtype=float)
            v_start[dofs] = 0.0
            v_prev, v = v, v_start + delta / options.dt
            kin = 0.5 * vdot(v, M @ v)
        x, u = x_new, u_new
        rec = StepRecord(
            float(t), x.reshape(shape).copy(), None if v is None else v.reshape(shape).copy(), int(its),
            time.perf_counter() - t0, E, kin, float(rel), int(lin_its), solver_used, int(halvings), int(cuts),
            displacement=u.reshape(shape).copy(),
        )
        if sink is not None:
            sink(rec)
            del records[1:]  # the sink has it: keep the rest state and the latest record only
        records.append(rec)
        if callback is not None:
            callback(rec)
