"""Benchmark: what each removed piece of hot-path waste cost, per Newton iteration and per run.

The neo-Hooke cantilever (E = 1e3, nu = 0.3, 32x8x8 voxels, 5 load steps, sparse
LU, the same-solver problem of ``bench_voxel_model.py``) at its converged state,
and a state of the linear beam.  Each row times the old operation and its
replacement (warm, min and median of ``--repeat`` runs, milliseconds) and
multiplies the saving by how often a solve does it:

* energy-only line-search trials: ``material.evaluate(F, tangent=False)``
  (strain Jacobian and stress) against ``material.energy(F)``;
* a Hessian the line search no longer assembles (a full energy-gradient-Hessian
  pass against an energy-gradient pass; counted by running the solve with the
  prediction on and off);
* ``H.diagonal()`` on every Hessian (now once per step);
* ``np.setdiff1d`` of the fixed DOFs on every Jacobi-CG solve (now once per solve);
* implicit Euler ``H + M / h^2`` (scipy's sparse sum, a new pattern per
  iteration) against :class:`voxflex.deform.solve.potential._PatternAdd`.

    python benchmarks/bench_solver_waste.py [--repeat 5]

Timings on a shared machine: the load average is printed with the table.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import numpy as np


def _time(fn, repeat):
    fn()  # warm
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return 1e3 * min(ts), 1e3 * statistics.median(ts)


def _beam(nx, mat):
    from voxflex.deform.models.voxel.model import VoxelModel
    from voxflex.image.label_image import LabelImage

    n = nx // 4
    return VoxelModel.from_image(LabelImage(np.ones((nx, n, n)), spacing=(4 / nx, 1 / n, 1 / n)), {1: mat})


def _counted_solve(model_factory, predict):
    """The static neo-Hooke solve: records, Hessians built, solves, misses, evaluations, energy-only ones."""
    from voxflex.deform.solve import newton
    from voxflex.deform.solve import stepping as solvers
    from voxflex.deform.solve.boundary import FixedRegion

    probs = []
    init = solvers._Problem.__init__
    pred = newton._predict_converged  # read by Newton's loop, where it lives

    def record(self, *a, **k):
        init(self, *a, **k)
        probs.append(self)

    solvers._Problem.__init__ = record
    if not predict:
        newton._predict_converged = lambda *a: False
    try:
        model = model_factory()
        rec = solvers.solve(model, fixed=[FixedRegion([-1, -1, -1], [1e-9, 2, 2])], gravity=[0, 0, -9.81],
                            densities={1: 1.0}, options=solvers.SolverOptions(steps=5, linear_solver="direct"))
    finally:
        solvers._Problem.__init__ = init
        newton._predict_converged = pred
    return (rec, sum(p.hessians for p in probs), sum(p.solves for p in probs),
            sum(p.hessian_misses for p in probs), sum(p.evaluations for p in probs),
            sum(p.energy_only for p in probs))


def main():
    import scipy.sparse as sp

    from voxflex.deform.materials.constitutive import material
    from voxflex.deform.solve.potential import _PatternAdd

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}, load average {'{:.2f} {:.2f} {:.2f}'.format(*os.getloadavg())}")
    nh = material("neo-hookean", young=1e3, poisson=0.3)
    factory = lambda: _beam(32, nh)  # noqa: E731
    _counted_solve(lambda: _beam(8, nh), True)  # compile the kernels
    rec, built, solves, misses, evals, trials = _counted_solve(factory, True)
    _, built0, solves0, _, evals0, _ = _counted_solve(factory, False)
    model = factory()
    q = rec[-1].q
    F = model.deformation_gradients(q)
    rows = []
    old = _time(lambda: nh.evaluate(F, tangent=False), args.repeat)
    new = _time(lambda: nh.energy(F), args.repeat)
    rows.append(("energy-only trial: evaluate(tangent=False) -> energy(F)", old, new, trials,
                 "energy-only evaluations (halved line-search steps)"))
    full = _time(lambda: model.energy_gradient_hessian(q), args.repeat)
    grad = _time(lambda: model.energy_gradient_hessian(q, hessian=False), args.repeat)
    rows.append(("Hessian skipped at a converging trial: E+g+H pass -> E+g pass", full, grad, built0 - built,
                 f"Hessians built {built0} -> {built} for {solves} solves ({misses} rebuilt)"))
    H = model.hessian(q)
    rows.append(("H.diagonal() per Hessian -> once per step", _time(H.diagonal, args.repeat), (0.0, 0.0),
                 built - 5, "Hessians after each step's first"))
    lin = _beam(64, material("hooke", young=1e4, poisson=0.3, strain="linear"))
    N = 3 * lin.n_nodes
    free = np.flatnonzero(np.repeat(lin.rest[:, 0] > 1e-9, 3))
    rows.append((f"setdiff1d of the fixed DOFs per Jacobi-CG solve ({N} DOF)",
                 _time(lambda: np.setdiff1d(np.arange(N), free), args.repeat), (0.0, 0.0), 1,
                 "per Newton iteration with cg"))
    S = model.mass_matrix({1: 1.0}) / 0.01**2
    add = _PatternAdd()
    old = _time(lambda: sp.csr_matrix(H + S), args.repeat)
    new = _time(lambda: add(H, S), args.repeat)
    rows.append((f"H + M/h^2 per implicit-Euler iteration ({H.shape[0]} DOF)", old, new, 1,
                 "per Newton iteration of implicit Euler"))
    print(f"\nneo-Hooke 32x8x8, 5 steps, sparse LU: {sum(r.newton_iterations for r in rec)} Newton iterations, "
          f"{evals0} -> {evals} model evaluations")
    print("| waste removed | old ms (min / median) | new ms (min / median) | times per run | saved per run ms | note |")
    print("|---|---|---|---|---|---|")
    for name, (o, om), (n, nm), times, note in rows:
        print(f"| {name} | {o:.2f} / {om:.2f} | {n:.2f} / {nm:.2f} | {times} | {(o - n) * times:.0f} | {note} |")
    print(f"load average after: {'{:.2f} {:.2f} {:.2f}'.format(*os.getloadavg())}")


if __name__ == "__main__":
    main()
