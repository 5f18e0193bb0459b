"""Benchmark: the full-resolution voxel model against scikit-fem on the shared cantilever.

Problems (beam [0,4]x[0,1]x[0,1], x = 0 clamped, rho g = 9.81 along -z, nu = 0.3):

1. linear (Hooke, small strain), E = 1e4, 64x16x16 voxels (56k DOF), one solve;
2. large-deflection Neo-Hooke, E = 1e3, 32x8x8 voxels, 5 load steps, Newton.

Each is timed end to end in voxflex, in scikit-fem and, when warp-lang is
installed (``pip install warp-lang``; CPU is fine), in warp.fem (trilinear
hexahedra, 2x2x2 Gauss, the same linear solver so that the comparison isolates the model
and assembly), columns build / assemble / solve / total, and the ratio.  Then
the linear solvers on the 56k-DOF clamped stiffness matrix.  voxflex columns:
build = model and sparsity pattern; assemble = one energy, gradient and
Hessian at rest (for a constant-tangent material this is the cached stiffness
that the solve then reuses, so total = what a user's run costs); solve =
load steps, with every Newton assembly of a nonlinear material inside it.

    python benchmarks/bench_voxel_model.py [--quick] [--colamd] [--memory NXxNYxNZ]

``--quick`` runs 32x8x8 / 16x4x4 instead; ``--colamd`` adds scipy's default
splu ordering (slow: ~40 s); ``--memory 128x44x44`` only measures time and
peak resident memory (``resource.getrusage``) of building, assembling and
solving a linear beam of that many voxels (2.5e5 here) in this fresh process.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

TIP = np.array([4.0, 0.5, 0.5])


def _beam_image(nx):
    from voxflex.image.label_image import LabelImage

    ny = nz = nx // 4
    return LabelImage(np.ones((nx, ny, nz)), spacing=(4 / nx, 1 / ny, 1 / nz))


def voxflex_run(nx, mat, steps, linear_solver):
    from voxflex.deform.boundary import FixedRegion
    from voxflex.deform.solvers import SolverOptions, solve
    from voxflex.deform.voxel_model import VoxelModel

    t0 = time.perf_counter()
    model = VoxelModel.from_image(_beam_image(nx), {1: mat})
    model._ensure_pattern()
    t1 = time.perf_counter()
    # one assembly, timed alone; a constant stiffness is cached by the model, so the solve reuses it
    # (a nonlinear material reassembles at every Newton iteration, inside "solve")
    model.energy_gradient_hessian(model.rest)
    t2 = time.perf_counter()
    rec = solve(model, fixed=[FixedRegion([-1, -1, -1], [1e-9, 2, 2])], gravity=[0, 0, -9.81], densities={1: 1.0},
                options=SolverOptions(steps=steps, linear_solver=linear_solver))
    t3 = time.perf_counter()
    uz = float(model.point_mapping([TIP]).apply(rec[-1].q)[0, 2] - TIP[2])
    its = sum(r.newton_iterations for r in rec)
    lin = sum(r.linear_iterations for r in rec)
    return dict(build=t1 - t0, assemble=t2 - t1, solve=t3 - t2, uz=uz, newton=its, linear=lin,
                solver=rec[-1].linear_solver)


def skfem_run(nx, young, poisson, kind, steps, linear_solver):
    from skfem import Basis, BilinearForm, ElementHex1, ElementVector, LinearForm, MeshHex, condense
    from skfem.helpers import ddot, det, grad, inv, sym_grad, trace, transpose

    from voxflex.deform.linear_solvers import solve_linear

    mu = young / (2 * (1 + poisson))
    lam = young * poisson / ((1 + poisson) * (1 - 2 * poisson))
    t0 = time.perf_counter()
    ny = nz = nx // 4
    mesh = MeshHex.init_tensor(np.linspace(0, 4, nx + 1), np.linspace(0, 1, ny + 1), np.linspace(0, 1, nz + 1))
    basis = Basis(mesh, ElementVector(ElementHex1()), intorder=3)
    D = basis.get_dofs(lambda x: x[0] < 1e-9).all()
    node = int(np.flatnonzero(np.all(np.isclose(mesh.p.T, TIP), axis=1))[0])
    t1 = time.perf_counter()

    @LinearForm
    def gravity(v, w):
        return -9.81 * v[2]

    def mm(a, b):
        return np.einsum("ij...,jk...->ik...", a, b)

    def kin(w):
        F = grad(w["u"]).copy()
        for i in range(3):
            F[i, i] += 1.0
        FinvT = transpose(inv(F))
        return F, FinvT, np.log(det(F))

    @BilinearForm
    def linear(u, v, w):
        e = sym_grad(u)
        return 2 * mu * ddot(e, sym_grad(v)) + lam * trace(e) * trace(sym_grad(v))

    @LinearForm
    def internal(v, w):
        F, FinvT, L = kin(w)
        return ddot(mu * (F - FinvT) + lam * L * FinvT, grad(v))

    @BilinearForm
    def tangent(du, v, w):
        F, FinvT, L = kin(w)
        dF = grad(du)
        return ddot(mu * dF + (mu - lam * L) * mm(mm(FinvT, transpose(dF)), FinvT) + lam * ddot(FinvT, dF) * FinvT,
                    grad(v))

    fg = gravity.assemble(basis)
    t_asm = 0.0
    t_sol = 0.0
    newton = 0
    u = np.zeros(basis.N)
    if kind == "linear":
        ta = time.perf_counter()
        K = linear.assemble(basis)
        t_asm += time.perf_counter() - ta
        ts = time.perf_counter()
        A, b, x, I = condense(K, fg, D=D)
        x, _ = solve_linear(A, b, method=linear_solver, rtol=1e-8)
        u[I] = x
        t_sol += time.perf_counter() - ts
        newton = 1
    else:
        for k in range(1, steps + 1):
            for _ in range(50):
                ta = time.perf_counter()
                uf = basis.interpolate(u)
                r = internal.assemble(basis, u=uf) - k / steps * fg
                r[D] = 0
                t_asm += time.perf_counter() - ta
                if np.linalg.norm(r) <= 1e-8 * np.linalg.norm(fg):
                    break
                ta = time.perf_counter()
                K = tangent.assemble(basis, u=uf)
                t_asm += time.perf_counter() - ta
                ts = time.perf_counter()
                A, b, x, I = condense(K, -r, D=D)
                x, _ = solve_linear(A, b, method=linear_solver, rtol=1e-8)
                u[I] += x
                t_sol += time.perf_counter() - ts
                newton += 1
    uz = float(u[basis.nodal_dofs[2, node]])
    return dict(build=t1 - t0, assemble=t_asm, solve=t_sol, uz=uz, newton=newton, linear=0, solver=linear_solver)


def solver_table(nx):
    from voxflex.deform.linear_solvers import rigid_body_modes, solve_linear
    from voxflex.deform.materials import material
    from voxflex.deform.voxel_model import VoxelModel

    model = VoxelModel.from_image(_beam_image(nx), {1: material("hooke", young=1e4, poisson=0.3, strain="linear")})
    K = model.hessian(model.rest)
    free = np.flatnonzero(np.repeat(model.rest[:, 0] > 1e-9, 3))
    A = K[free][:, free]
    b = -model.gravity_force({1: 1.0}, [0, 0, -9.81]).ravel()[free]
    rows = []
    for method in ("cg", "amg", "direct"):
        x, info = solve_linear(A, b, method=method, rtol=1e-8, near_null=rigid_body_modes(model.rest)[free])
        rows.append((method, info.seconds, info.iterations, info.residual))
    return len(free), rows


def memory_run(shape):
    """Peak resident memory after each phase of the linear beam of ``shape`` voxels (fresh process)."""
    import resource

    from voxflex.deform.boundary import FixedRegion
    from voxflex.deform.materials import material
    from voxflex.deform.solvers import SolverOptions, solve
    from voxflex.deform.voxel_model import VoxelModel
    from voxflex.image.label_image import LabelImage

    def peak():
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB -> MB on Linux

    nx, ny, nz = shape
    rows = [("start (python, numpy, scipy, numba imported)", 0.0, peak())]
    t = time.perf_counter()
    image = LabelImage(np.ones((nx, ny, nz), dtype=np.uint8), spacing=(4 / nx, 1 / ny, 1 / nz))
    model = VoxelModel.from_image(image, {1: material("hooke", young=1e4, poisson=0.3, strain="linear")})
    rows.append(("image + model", time.perf_counter() - t, peak()))
    t = time.perf_counter()
    model._ensure_pattern()
    rows.append(("sparsity pattern", time.perf_counter() - t, peak()))
    t = time.perf_counter()
    H = model.hessian(model.rest)
    rows.append(("stiffness (cached)", time.perf_counter() - t, peak()))
    del H
    t = time.perf_counter()
    rec = solve(model, fixed=[FixedRegion([-1, -1, -1], [1e-9, 2, 2])], gravity=[0, 0, -9.81], densities={1: 1.0},
                options=SolverOptions(linear_solver="cg"))
    rows.append((f"static solve (cg, {rec[-1].linear_iterations} iterations)", time.perf_counter() - t, peak()))
    print(f"\n| linear beam {nx}x{ny}x{nz}: {model.n_elements} voxels, {3 * model.n_nodes} DOF | seconds | "
          f"peak RSS MB |")
    print("|---|---|---|")
    for name, sec, mb in rows:
        print(f"| {name} | {sec:.2f} | {mb:.0f} |", flush=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--colamd", action="store_true")
    parser.add_argument("--memory", default="", metavar="NXxNYxNZ")
    args = parser.parse_args()
    if args.memory:
        memory_run(tuple(int(v) for v in args.memory.lower().split("x")))
        return
    from voxflex.deform.materials import material

    nl, nn = (32, 16) if args.quick else (64, 32)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}, NUMBA_NUM_THREADS={os.environ.get('NUMBA_NUM_THREADS', 'default')}")
    # warm-up: compile the kernels once (numba cache) so that timings are of the run, not the compiler
    voxflex_run(8, material("neo-hookean", young=1e3, poisson=0.3), 1, "auto")
    hooke = material("hooke", young=1e4, poisson=0.3, strain="linear")
    nh = material("neo-hookean", young=1e3, poisson=0.3)
    try:  # optional peer: warp.fem on the CPU (compiles its kernels once, timed apart)
        from _warp_cantilever import warp_run
    except ImportError:
        warp_run = None
        print("warp.fem: not installed (pip install warp-lang) - its rows are skipped")
    problems = [
        (f"linear {nl}x{nl // 4}x{nl // 4}", lambda: voxflex_run(nl, hooke, 1, "cg"),
         lambda: skfem_run(nl, 1e4, 0.3, "linear", 1, "cg"),
         lambda: warp_run(nl, 1e4, 0.3, "linear", 1, "cg")),
        (f"neo-hooke E=1e3 {nn}x{nn // 4}x{nn // 4} 5 steps", lambda: voxflex_run(nn, nh, 5, "auto"),
         lambda: skfem_run(nn, 1e3, 0.3, "neo-hooke", 5, "direct"),
         lambda: warp_run(nn, 1e3, 0.3, "neo-hooke", 5, "direct")),
    ]
    print("\n| problem | code | build s | assemble s | solve s | total s | newton | u_z tip | solver |")
    print("|---|---|---|---|---|---|---|---|---|")
    compile_notes = []
    for name, ours, skfem, warp in problems:
        res = {}
        codes = [("voxflex", ours), ("scikit-fem", skfem)] + ([("warp.fem", warp)] if warp_run else [])
        for code, fn in codes:
            r = fn()
            r["total"] = r["build"] + r["assemble"] + r["solve"]
            res[code] = r
            if "compile" in r:
                compile_notes.append(f"{code} {name}: kernel compile/warm-up {r['compile']:.2f} s (not in total)")
            print(f"| {name} | {code} | {r['build']:.2f} | {r['assemble']:.2f} | {r['solve']:.2f} | {r['total']:.2f} | "
                  f"{r['newton']} | {r['uz']:.6f} | {r['solver']} |", flush=True)
        for peer in [c for c, _ in codes[1:]]:
            print(f"| {name} | ratio {peer} / voxflex (total) | | | | {res[peer]['total'] / res['voxflex']['total']:.1f}x "
                  f"| | | |", flush=True)
    for note in compile_notes:
        print(note)
    n, rows = solver_table(nl)
    print(f"\n| linear solver on the {n}-DOF clamped beam stiffness | seconds | iterations | relative residual |")
    print("|---|---|---|---|")
    for method, sec, its, res in rows:
        print(f"| {method} | {sec:.2f} | {its} | {res:.1e} |", flush=True)
    if args.colamd:
        import time as _t

        import scipy.sparse as sp
        import scipy.sparse.linalg as spla

        from voxflex.deform.materials import material as _m
        from voxflex.deform.voxel_model import VoxelModel

        model = VoxelModel.from_image(_beam_image(nl), {1: _m("hooke", young=1e4, poisson=0.3, strain="linear")})
        free = np.flatnonzero(np.repeat(model.rest[:, 0] > 1e-9, 3))
        A = sp.csc_matrix(model.hessian(model.rest)[free][:, free])
        t = _t.perf_counter()
        spla.splu(A).solve(np.ones(len(free)))
        print(f"| splu default (COLAMD) | {_t.perf_counter() - t:.2f} | 0 | |")


if __name__ == "__main__":
    main()
