"""Benchmark: what ``solve()`` adds on top of the lean linear solve, and how both grow with the DOF count.

The clamped linear Hooke beam ``4n x n x n`` voxels (E = 1e4 Pa, nu = 0.3, gravity along -z,
``linear_solver = "auto"``: multigrid-CG at these sizes).  Per size and round, alternated, each
from a fresh multigrid cache (the kernels warmed on a small beam first):

* ``solve()``: ``voxflex.deform.solve.stepping.solve`` on a model built just before (not timed):
  the support check, the loads, the operator (``FreeStiffness`` above
  :data:`~voxflex.deform.solve.linear.DIRECT_FALLBACK_MAX` unknowns, the assembled block below),
  Newton's gradient and energy evaluations, the solve and the records;
* ``lean``: ``solve_linear(A, b, method="multigrid", rtol=..., elements=...)``, the linear solve
  alone (hierarchy, first coarse level, stencil and multigrid-CG), on a model built just before
  like solve()'s, with the free block, its element matrices and the load assembled beforehand
  (not timed), at the relative tolerance solve()'s Newton step asked of its linear solve
  (``linear_rtol`` of its iteration callback: ``0.5 tolerance |f| / |f_free|``, 5e-9 here, so that
  the recomputed residual passes Newton's test with margin; at 1e-8 the lean solve takes one CG
  iteration less from 180k DOF) -- the same solver at the same tolerance from the same state;
* ``lean, reused model``: the same lean solve on one model kept over the rounds, for comparison:
  a model whose arrays earlier solves have worked on solves faster than a freshly built one
  (2.4 million DOF: 6.81 against 8.20 s, min of 3), a state no run of ``solve()`` starts from;
* ``ratio``: solve() / lean (fresh model).

Then the exponent of a least-squares fit ``time ~ DOF^p`` of each column over the sizes from 50k
DOF.  Min and median of ``--repeat`` runs; the load average is printed.  ``--operator``: the lean
solve runs on the matrix-free block (``FreeStiffness``) instead of the assembled one (what fits
at 6.4 million DOF: ``--shapes 256x90x90 --operator --repeat 3``, about 6 GB).

    python benchmarks/bench_lean_overhead.py [--sizes 16,24,32,40 | --shapes 256x90x90] [--repeat 3] [--operator]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np


def _beam(shape):
    from voxflex.deform.materials.constitutive import material
    from voxflex.deform.models.voxel.model import VoxelModel
    from voxflex.image.label_image import LabelImage

    nx, ny, nz = shape
    image = LabelImage(np.ones(shape, dtype=np.uint8), spacing=(4.0 / nx, 1.0 / ny, 1.0 / nz))
    return VoxelModel.from_image(image, {1: material("hooke", young=1e4, poisson=0.3, strain="linear")})


def _runs(shape, operator=False):
    from voxflex.deform.solve.boundary import FixedRegion, fixed_dofs
    from voxflex.deform.solve.linear import solve_linear
    from voxflex.deform.solve.multigrid.hierarchy import clear_cache
    from voxflex.deform.solve.options import SolverOptions
    from voxflex.deform.solve.stepping import solve

    clamp = FixedRegion([-1, -1, -1], [1e-9, 9, 9])

    def setup():
        model = _beam(shape)
        dofs, _ = fixed_dofs(model, [clamp])
        free = np.setdiff1d(np.arange(3 * model.n_nodes), dofs)
        A = model.constant_stiffness_operator(free) if operator else model.constant_stiffness_block(free)
        b = model.gravity_force({1: 1.0}, [0, 0, -9.81]).ravel()[free]
        return model, free, A, b, model.stiffness_elements()

    kept = setup()

    def lean(rtol=1e-8, fresh=True):
        model, free, A, b, elements = setup() if fresh else kept
        clear_cache()
        t = time.perf_counter()
        _, info = solve_linear(A, b, method="multigrid", rtol=rtol, grid=model.grid, free=free, elements=elements)
        return time.perf_counter() - t, info.iterations

    asked = []  # the relative tolerance of solve()'s linear solve(s)

    def full():
        clear_cache()
        m = _beam(shape)
        asked.clear()

        def seen(info):
            if info["linear_rtol"] > 0:
                asked.append(info["linear_rtol"])

        t = time.perf_counter()
        rec = solve(m, fixed=[clamp], gravity=[0, 0, -9.81], densities={1: 1.0}, options=SolverOptions(),
                    newton_callback=seen)
        elapsed = time.perf_counter() - t
        if len(asked) != 1:
            raise SystemExit(f"solve() ran {len(asked)} linear solves on a linear scene; expected one")
        return elapsed, rec[-1].linear_iterations, asked[0]

    return len(kept[1]), lean, full


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--sizes", default="16,24,32,40")
    p.add_argument("--shapes", default=None, help="voxel shapes NXxNYxNZ instead of --sizes")
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--operator", action="store_true", help="the lean solve on the matrix-free block")
    a = p.parse_args()
    if a.shapes:
        shapes = [tuple(int(v) for v in s.lower().split("x")) for s in a.shapes.split(",")]
    else:
        shapes = [(4 * n, n, n) for n in map(int, a.sizes.split(","))]
    _, lean, full = _runs((16, 4, 4), a.operator)
    lean(), full()  # compile the kernels
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    print("| beam | DOF | solve()'s rtol | lean s (min / median) | CG its | lean, reused model s (min / median) "
          "| solve() s (min / median) | CG its | ratio (min) |")
    print("|---|---|---|---|---|---|---|---|---|")
    pts = []
    for shape in shapes:
        dof, lean, full = _runs(shape, a.operator)
        tl, tf, tk = [], [], []
        for _ in range(a.repeat):
            t, jf, rtol = full()
            tf.append(t)
            t, il = lean(rtol)
            tl.append(t)
            tk.append(lean(rtol, fresh=False)[0])
        pts.append((dof, min(tl), min(tf)))
        print(f"| {shape[0]}x{shape[1]}x{shape[2]} | {dof} | {rtol:.2g} | "
              f"{min(tl):.2f} / {statistics.median(tl):.2f} | {il} | {min(tk):.2f} / {statistics.median(tk):.2f} | "
              f"{min(tf):.2f} / {statistics.median(tf):.2f} | {jf} | {min(tf) / min(tl):.2f} |", flush=True)
    d, tl, tf = np.array(pts).T
    big = d >= 50000
    if big.sum() >= 2:
        print(f"exponents over >= 50k DOF: lean DOF^{np.polyfit(np.log(d[big]), np.log(tl[big]), 1)[0]:.2f}, "
              f"solve() DOF^{np.polyfit(np.log(d[big]), np.log(tf[big]), 1)[0]:.2f}")
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
