"""Benchmark: where a sparse direct factorisation stops being an acceptable fallback for multigrid-CG.

``solve_linear`` falls back to the sparse LU (SuperLU, ``MMD_AT_PLUS_A``) when an iterative
method misses its tolerance, but only up to :data:`voxflex.deform.solve.linear.DIRECT_FALLBACK_MAX`
unknowns: beyond, the factorisation costs minutes and gigabytes (a 315k-DOF bunny tangent sat
30 minutes at 8.7 GB) and the remedies stay on the multigrid path.  This script measures the
two costs that limit compares, on linear Hooke voxel bodies (E = 1e4 Pa, nu = 0.3, clamped at
x = 0, gravity along -z, the free-DOF block of the stiffness):

* ``LU s``: ``splu(A, permc_spec="MMD_AT_PLUS_A")`` and one solve (seconds), with the factor's
  stored entries (``L.nnz + U.nnz``) and their bytes (12 per entry: value and index);
* ``MG s``: ``solve_linear(A, b, method="multigrid", rtol=1e-8)`` from a fresh hierarchy
  (prolongations built inside the timing), its CG iterations;
* ``ratio``: LU time / multigrid time.

Shapes: beams ``4n x n x n`` and cubes ``n^3`` voxels (a cube's separators are wider: its LU
fill grows faster).  Min of ``--repeat`` runs, alternated; the load average is printed.

    python benchmarks/bench_direct_limit.py [--beams 8,12,16,20,24] [--cubes 12,16,20,24,28] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


def _system(shape):
    import voxflex as vf
    from voxflex.deform.models.voxel.model import VoxelModel
    from voxflex.deform.solve.boundary import FixedRegion, fixed_dofs
    from voxflex.image.label_image import LabelImage

    image = LabelImage(np.ones(shape), spacing=(1.0, 1.0, 1.0))
    model = VoxelModel.from_image(image, {1: vf.material("hooke", young=1e4, poisson=0.3, strain="linear")})
    dofs, _ = fixed_dofs(model, [FixedRegion(np.array([-1.0, -1e9, -1e9]), np.array([1e-9, 1e9, 1e9]))])
    free = np.setdiff1d(np.arange(3 * model.n_nodes), dofs)
    A = model.constant_stiffness_block(free)
    b = model.gravity_force({1: 1.0}, [0.0, 0.0, -9.81]).ravel()[free]
    return model, free, A, b


def _lu(A, b):
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    t0 = time.perf_counter()
    lu = spla.splu(sp.csc_matrix(A), permc_spec="MMD_AT_PLUS_A")
    lu.solve(b)
    return time.perf_counter() - t0, lu.L.nnz + lu.U.nnz


def _mg(model, free, A, b):
    from voxflex.deform.solve.linear import solve_linear
    from voxflex.deform.solve.multigrid.hierarchy import clear_cache

    clear_cache()
    t0 = time.perf_counter()
    _, info = solve_linear(A, b, method="multigrid", rtol=1e-8, grid=model.grid, free=free)
    return time.perf_counter() - t0, info.iterations


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--beams", default="8,12,16,20,24")
    p.add_argument("--cubes", default="12,16,20,24,28")
    p.add_argument("--repeat", type=int, default=3)
    a = p.parse_args()
    shapes = [(4 * n, n, n) for n in map(int, filter(None, a.beams.split(",")))]
    shapes += [(n, n, n) for n in map(int, filter(None, a.cubes.split(",")))]
    _mg(*_system((8, 2, 2)))  # compile the kernels
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    print("| voxels | unknowns | LU s (min) | LU factor entries | LU factor MB | MG s (min) | MG iterations | ratio |")
    print("|---|---|---|---|---|---|---|---|")
    for shape in shapes:
        model, free, A, b = _system(shape)
        lu_t, mg_t = [], []
        for _ in range(a.repeat):
            t, nnz = _lu(A, b)
            lu_t.append(t)
            t, its = _mg(model, free, A, b)
            mg_t.append(t)
        print(f"| {shape[0]}x{shape[1]}x{shape[2]} | {len(free)} | {min(lu_t):.3f} | {nnz:,} | {12 * nnz / 1e6:.0f} | "
              f"{min(mg_t):.3f} | {its} | {min(lu_t) / min(mg_t):.0f} |", flush=True)
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
