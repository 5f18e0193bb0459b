"""The shared cantilever in warp.fem (CPU), a peer reference for ``bench_voxel_model.py``.

Beam [0,4]x[0,1]x[0,1] on an nx x nx/4 x nx/4 ``fem.Grid3D`` (float64) with a
degree-1 vector polynomial space (trilinear hexahedra), 2x2x2 Gauss points
(``RegularQuadrature(order=2)``: Gauss-Legendre, 2 points per axis, exact to
degree 3), the face x = 0 fully clamped (its DOFs condensed out of each
system; or a Dirichlet projector, ``fem.project_linear_system``), rho g = 9.81 along -z with rho = 1.  Output:
u_z at the tip-face centre (4, 0.5, 0.5), a grid node when nx is a multiple of 8.

warp.fem assembles (``fem.integrate`` -> ``warp.sparse`` BSR with 3x3 float64
blocks); the linear systems are solved by scipy through
``voxflex.deform.solve.linear.solve_linear`` (``"cg"``: Jacobi-preconditioned
CG, ``"direct"``: ``splu(permc_spec="MMD_AT_PLUS_A")``), the same solvers the
scikit-fem column of the benchmark uses, so the comparison isolates assembly.

    from benchmarks._warp_cantilever import warp_run
    warp_run(64, 1e4, 0.3, "linear", 1)

warp generates C++ for each integrand (and for its own sparse / Dirichlet
kernels) and compiles it with its bundled clang on first use, caching the
binaries on disk (``~/.cache/warp/<version>``, or ``$WARP_CACHE_PATH``):
``warp_run`` first runs the same problem at nx = 8 and reports that wall time
as ``compile`` (cold cache: compilation; warm cache: loading); the other
timings are of the requested run with every kernel loaded.  warp's CPU kernels
run on one thread.

Timing split: ``build`` = grid, space, quadrature, clamped DOFs (and the
Dirichlet projector with ``condense="project"``), tip node; ``assemble`` = ``fem.integrate`` of gravity, stiffness / tangent and
residual (the Newton residual includes copying u into the field); ``solve`` =
BSR -> scipy CSR, the free-DOF block (scipy indexing, as scikit-fem's
``condense``; ``condense="project"`` uses ``fem.project_linear_system``
instead, slower), and the scipy solve.

Checked with warp-lang 1.19.0 (``pip install warp-lang``: a 149 MB wheel that
runs on the CPU; not a voxflex dependency).
"""

import time

import numpy as np
import scipy.sparse as sp
import warp as wp

from voxflex.deform.solve.linear import solve_linear
from voxflex.errors import ConvergenceError, InputError, check_choice

# set before warp.fem is imported (its import initializes warp): no per-module load log, and no adjoint
# code generated for the kernels (nothing here is differentiated; halves the first-use compile time)
wp.config.log_level = wp.LOG_WARNING
wp.config.enable_backward = False
import warp.fem as fem  # noqa: E402

TIP = np.array([4.0, 0.5, 0.5])
KINDS = ("linear", "neo-hooke")

f64 = wp.float64


@fem.integrand
def clamp_form(s: fem.Sample, domain: fem.Domain, u: fem.Field, v: fem.Field):
    # nodal assembly on the boundary sides: 1 on the nodes of the face x = 0
    if domain(s)[0] < f64(1.0e-9):
        return wp.dot(u(s), v(s))
    return f64(0.0)


@fem.integrand
def gravity_form(s: fem.Sample, v: fem.Field, g: wp.vec3d):
    return wp.dot(v(s), g)


@fem.integrand
def hooke_form(s: fem.Sample, u: fem.Field, v: fem.Field, mu: f64, lam: f64):
    e = fem.D(u, s)
    sigma = f64(2.0) * mu * e + lam * wp.trace(e) * wp.identity(n=3, dtype=f64)
    return wp.ddot(fem.D(v, s), sigma)


@wp.func
def _kinematics(G: wp.mat33d):
    F = G + wp.identity(n=3, dtype=f64)
    return F, wp.transpose(wp.inverse(F)), wp.log(wp.determinant(F))


@fem.integrand
def nh_internal_form(s: fem.Sample, u: fem.Field, v: fem.Field, mu: f64, lam: f64):
    # first Piola-Kirchhoff stress of W = mu/2 (I1 - 3) - mu ln J + lam/2 (ln J)^2
    F, FinvT, L = _kinematics(fem.grad(u, s))
    P = mu * (F - FinvT) + lam * L * FinvT
    return wp.ddot(P, fem.grad(v, s))


@fem.integrand
def nh_tangent_form(s: fem.Sample, u: fem.Field, du: fem.Field, v: fem.Field, mu: f64, lam: f64):
    # dP[dF] = mu dF + (mu - lam ln J) F^-T dF^T F^-T + lam (F^-T : dF) F^-T
    F, FinvT, L = _kinematics(fem.grad(u, s))
    dF = fem.grad(du, s)
    dP = mu * dF + (mu - lam * L) * (FinvT * wp.transpose(dF) * FinvT) + lam * wp.ddot(FinvT, dF) * FinvT
    return wp.ddot(dP, fem.grad(v, s))


FORMS = dict(clamp=clamp_form, gravity=gravity_form, hooke=hooke_form, internal=nh_internal_form,
             tangent=nh_tangent_form)


def bsr_to_scipy(A):
    """Convert a ``warp.sparse`` BSR matrix (host) to a scipy CSR matrix.

    Parameters
    ----------
    A : warp.sparse.BsrMatrix
        Square or rectangular, blocks (b, c).

    Returns
    -------
    scipy.sparse.csr_matrix, shape (nrow * b, ncol * c)
    """
    nnz = A.nnz_sync()
    offsets = A.offsets.numpy()[: A.nrow + 1]
    columns = A.columns.numpy()
    values = A.values.numpy().reshape(-1, *A.block_shape)
    if A.row_counts is not None:  # non-compact storage: keep the active slots of each row only
        counts = A.row_counts.numpy()[: A.nrow]
        keep = np.concatenate([np.arange(o, o + c) for o, c in zip(offsets[:-1], counts)]).astype(np.int64)
        offsets = np.concatenate([[0], np.cumsum(counts)])
        columns, values = columns[keep], values[keep]
    else:
        columns, values = columns[:nnz], values[:nnz]
    b, c = A.block_shape
    return sp.bsr_matrix((values, columns, offsets), shape=(A.nrow * b, A.ncol * c)).tocsr()


def _lame(young, poisson):
    return young / (2 * (1 + poisson)), young * poisson / ((1 + poisson) * (1 - 2 * poisson))


def node_positions(nx):
    """The node positions of the run's degree-1 space on the nx x nx/4 x nx/4 grid, (n, 3) m.

    Node ``i`` carries DOFs ``3 i + c`` (c = 0, 1, 2 for x, y, z) in the systems ``warp_run`` solves.
    """
    n = nx // 4
    geo = fem.Grid3D(res=wp.vec3i(nx, n, n), bounds_lo=wp.vec3d(0.0, 0.0, 0.0), bounds_hi=wp.vec3d(4.0, 1.0, 1.0),
                     scalar_type=wp.float64)
    return fem.make_polynomial_space(geo, degree=1, dtype=wp.vec3d).node_positions().numpy()


def _run(nx, young, poisson, kind, steps, linear_solver, rtol, condense="scipy", free_solver=None,
         newton_rtol=None):
    forms = FORMS
    mu, lam = (wp.float64(x) for x in _lame(young, poisson))
    t0 = time.perf_counter()
    n = nx // 4
    geo = fem.Grid3D(res=wp.vec3i(nx, n, n), bounds_lo=wp.vec3d(0.0, 0.0, 0.0), bounds_hi=wp.vec3d(4.0, 1.0, 1.0),
                     scalar_type=wp.float64)
    space = fem.make_polynomial_space(geo, degree=1, dtype=wp.vec3d)
    cells = fem.Cells(geo)
    quad = fem.RegularQuadrature(cells, order=2)  # Gauss-Legendre, 2 points per axis
    test, trial = fem.make_test(space, domain=cells), fem.make_trial(space, domain=cells)
    P = None
    if condense == "project":
        sides = fem.BoundarySides(geo)
        P = fem.integrate(forms["clamp"], fields={"u": fem.make_trial(space, domain=sides),
                                                  "v": fem.make_test(space, domain=sides)},
                          assembly="nodal", output_dtype=wp.float64)
        fem.normalize_dirichlet_projector(P)
    nodes = space.node_positions().numpy()
    tip = np.flatnonzero(np.all(np.isclose(nodes, TIP), axis=1))
    if tip.size != 1:
        raise InputError(f"no grid node at the tip centre {TIP}; nx must be a multiple of 8, got {nx}")
    tip = int(tip[0])
    fixed = np.repeat(nodes[:, 0] < 1e-9, 3)
    t1 = time.perf_counter()

    t_asm = t_sol = 0.0
    ta = time.perf_counter()
    fg_w = fem.integrate(forms["gravity"], fields={"v": test}, quadrature=quad,
                         values={"g": wp.vec3d(0.0, 0.0, -9.81)}, output_dtype=wp.vec3d)
    fg = fg_w.numpy().ravel()
    t_asm += time.perf_counter() - ta
    u = np.zeros(3 * space.node_count())
    newton = lin_its = 0
    solver = linear_solver
    t_adapt = 0.0  # seconds of free_solver's adapter work (taken out of t_sol)

    free = np.flatnonzero(~fixed)
    fallbacks = []  # per linear solve: whether the iterative method fell back to direct

    def linear_solve(K, rhs, tol=rtol):
        nonlocal solver, lin_its, t_adapt
        if condense == "project":
            # Dirichlet by warp.fem's projection: K <- (I-P) K (I-P) + P, rhs <- (I-P) rhs (zero prescribed values)
            rhs_w = wp.array(rhs.reshape(-1, 3), dtype=wp.vec3d)
            fem.project_linear_system(K, rhs_w, P, normalize_projector=False)
            A = bsr_to_scipy(K)
            x, info = solve_linear(A, rhs_w.numpy().ravel(), method=linear_solver, rtol=tol)
        else:
            # the free-DOF block taken in scipy, as scikit-fem's condense does (faster than the projection)
            A = bsr_to_scipy(K)[free][:, free]
            x = np.zeros(len(rhs))
            if free_solver is None:
                x[free], info = solve_linear(A, rhs[free], method=linear_solver, rtol=tol)
            else:
                x[free], info, adapt = free_solver(A, rhs[free], tol)
                t_adapt += adapt
        solver, lin_its = info.method, lin_its + info.iterations
        fallbacks.append(info.fell_back)
        return x

    if kind == "linear":
        ta = time.perf_counter()
        K = fem.integrate(forms["hooke"], fields={"u": trial, "v": test}, quadrature=quad,
                          values={"mu": mu, "lam": lam}, output_dtype=wp.float64)
        t_asm += time.perf_counter() - ta
        ts = time.perf_counter()
        u = linear_solve(K, fg)
        t_sol += time.perf_counter() - ts
        newton = 1
    else:
        field = fem.make_discrete_field(space)
        fnorm = np.linalg.norm(fg[~fixed])
        for k in range(1, steps + 1):
            for _ in range(50):
                ta = time.perf_counter()
                field.dof_values = wp.array(u.reshape(-1, 3), dtype=wp.vec3d)
                r = fem.integrate(forms["internal"], fields={"u": field, "v": test}, quadrature=quad,
                                  values={"mu": mu, "lam": lam}, output_dtype=wp.vec3d).numpy().ravel()
                r -= k / steps * fg
                r[fixed] = 0.0
                t_asm += time.perf_counter() - ta
                if np.linalg.norm(r) <= 1e-8 * fnorm:
                    break
                ta = time.perf_counter()
                K = fem.integrate(forms["tangent"], fields={"u": field, "du": trial, "v": test}, quadrature=quad,
                                  values={"mu": mu, "lam": lam}, output_dtype=wp.float64)
                t_asm += time.perf_counter() - ta
                ts = time.perf_counter()
                u += linear_solve(K, -r, rtol if newton_rtol is None else newton_rtol(
                    np.linalg.norm(r), np.linalg.norm(r), fnorm))
                t_sol += time.perf_counter() - ts
                newton += 1
            else:
                raise ConvergenceError(f"warp.fem Newton did not converge in 50 iterations at load step {k}")
    t_sol -= t_adapt
    return dict(build=t1 - t0, assemble=t_asm, solve=t_sol, total=(t1 - t0) + t_asm + t_sol,
                uz=float(u[3 * tip + 2]), newton=newton, linear=lin_its, solver=solver, permute=t_adapt,
                fallbacks=int(sum(fallbacks)))


def warp_run(nx, young, poisson, kind, steps, linear_solver=None, *, rtol=1e-8, warmup=True, condense="scipy",
             free_solver=None, newton_rtol=None):
    """Solve the cantilever in warp.fem and time it like ``skfem_run``.

    Parameters
    ----------
    nx : int
        Cells along x (a multiple of 8 so that the tip centre is a node); nx/4 along y and z.
    young : float
        Young's modulus, Pa.
    poisson : float
        Poisson's ratio.
    kind : {"linear", "neo-hooke"}
        Hooke small strain (one solve) or compressible Neo-Hooke
        W = mu/2 (I1 - 3) - mu ln J + lam/2 (ln J)^2 (Newton, ``steps`` load steps,
        stop at ||r_free|| <= 1e-8 ||f_free||).
    steps : int
        Load steps (Neo-Hooke).
    linear_solver : {"cg", "direct", ...}, optional
        Method of ``voxflex.deform.solve.linear.solve_linear``; default "cg"
        for linear, "direct" for Neo-Hooke (as the benchmark's scikit-fem column).
    rtol : float
        Relative residual of the iterative solver (1e-8 as ``skfem_run``).
    warmup : bool
        Run the problem at nx = 8 first and report its wall time as ``compile``
        (kernel code generation + compilation, or loading from warp's disk cache).
    condense : {"scipy", "project"}
        How the clamp enters the systems: the free-DOF block taken in scipy
        (the default: what scikit-fem's ``condense`` does) or warp.fem's
        ``project_linear_system`` (its documented Dirichlet route; at 64x16x16
        the projection took 1.6-2.1 s against 0.3 s for scipy's block on this
        loaded 2-core machine, so the benchmark gives warp the faster one).
    free_solver : callable, optional
        ``free_solver(nx)`` returns ``solve(A, b, rtol) -> (x, info, adapter_s)``
        that replaces ``solve_linear`` on the free-DOF block (``condense="scipy"``;
        free DOFs in warp's order, ``3 * node + component`` of :func:`node_positions`):
        the benchmark's multigrid-CG in voxflex's DOF order.  ``adapter_s``
        (its reordering) is returned as ``permute`` and left out of ``solve``.
        Called before the timed part of each run (for nx = 8 and ``nx``).
    newton_rtol : callable, optional
        ``newton_rtol(residual_norm, rhs_norm, scale)`` -> the relative
        tolerance of each Newton solve (Neo-Hooke; ``scale`` = the free-DOF load
        norm of the convergence test); default ``rtol`` for every solve.

    Returns
    -------
    dict
        build, assemble, solve, total, compile (s); compile_cpu (CPU s of the warm-up);
        permute (s, ``free_solver``'s adapter, not in solve or total);
        uz (m, tip-centre u_z); newton (iterations); linear (Krylov iterations);
        solver (method used); fallbacks (iterative solves answered by direct).
    """
    check_choice("cantilever kind", kind, KINDS)
    check_choice("condensation", condense, ("scipy", "project"))
    if nx < 8 or nx % 8:
        raise InputError(f"nx must be a positive multiple of 8 so that the tip centre is a grid node, got {nx}")
    linear_solver = linear_solver or ("cg" if kind == "linear" else "direct")
    t, c = time.perf_counter(), time.process_time()
    if free_solver is not None and condense != "scipy":
        raise InputError('free_solver needs condense="scipy" (it solves the free-DOF block)')
    if warmup:
        _run(8, young, poisson, kind, 1, linear_solver, rtol, condense, free_solver and free_solver(8), newton_rtol)
    compile_s, compile_cpu = time.perf_counter() - t, time.process_time() - c
    out = _run(nx, young, poisson, kind, steps, linear_solver, rtol, condense, free_solver and free_solver(nx),
               newton_rtol)
    out["compile"] = compile_s
    out["compile_cpu"] = compile_cpu
    return out
