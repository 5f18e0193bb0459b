"""Frame model: precompute time and time per Newton iteration against the flop bound.

For an object (a voxelized sphere) at 64^3 (and 128^3 with --big) and 10, 50,
200 frames with 1000 samples, it prints

* precompute: placement, natural-neighbour weights (blended), mid-point
  samples, the model's tables (seconds, one run);
* one Newton iteration split into assembly (energy, gradient and dense
  Hessian of a neo-Hooke material at a perturbed state) and the dense
  Cholesky solve of the free system, min and median of --repeat runs after one
  warm-up run (kernels compiled and cached first);
* the flop bound: m * 450 P^2 for assembly plus (12n)^3 / 3 for the
  factorisation at this machine's measured GFLOP/s (numpy matmul of 2000^2,
  one BLAS thread: the same thread count the timed parts use).

Usage: python benchmarks/bench_frames.py [--big] [--repeat 5] [--samples 1000] [--parents 6]
"""

from __future__ import annotations

import argparse
import os
import platform
import time
import warnings

import numpy as np


def _gflops(threads=1):
    from threadpoolctl import threadpool_limits

    a = np.random.default_rng(0).standard_normal((2000, 2000))
    with threadpool_limits(threads):
        a @ a
        t = min(_timed(lambda: a @ a) for _ in range(3))
    return 2 * 2000**3 / t / 1e9


def _timed(f):
    t = time.perf_counter()
    f()
    return time.perf_counter() - t


def _sphere(n):
    from voxflex.image.label_image import LabelImage

    c = (np.indices((n, n, n)) + 0.5 - n / 2) / (n / 2)
    labels = ((c**2).sum(0) <= 1.0).astype(np.uint8)
    return LabelImage(labels, spacing=(1.0 / n,) * 3)


def run(n_grid, counts, samples, parents, repeat, flops):
    from threadpoolctl import threadpool_limits

    from voxflex.deform.linear_solvers import solve_linear

    from voxflex.deform.frame_model import FrameModel
    from voxflex.deform.materials import material
    from voxflex.sampling import sample
    from voxflex.voronoi import place_frames, shape_function
    from voxflex.voronoi.shape_functions import keep_largest

    image = _sphere(n_grid)
    nvox = int((image.labels > 0).sum())
    mats = {1: material("neo-hookean", young=1e4, poisson=0.3)}
    rows = []
    for count in counts:
        t0 = time.perf_counter()
        frames = place_frames(image, count, seed=0)
        t1 = time.perf_counter()
        sf = shape_function(image, frames, parents=parents)
        sf.voxel_values()
        t2 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            s = sample(image, sf, kind="midpoint", count=samples)
        import dataclasses

        s = dataclasses.replace(s, values=keep_largest(s.values, parents))
        t3 = time.perf_counter()
        model = FrameModel.from_image(image, frames, sf, mats, samples=s)
        t4 = time.perf_counter()
        q = model.rest + 1e-3 * np.random.default_rng(1).standard_normal(model.rest.shape)
        free = np.arange(12, 12 * len(frames))  # one frame held
        with threadpool_limits(1):
            model.energy_gradient_hessian(q)  # warm-up (compiled kernels)
            ta, ts = [], []
            for _ in range(repeat):
                t = time.perf_counter()
                _, g, H = model.energy_gradient_hessian(q)
                ta.append(time.perf_counter() - t)
                t = time.perf_counter()
                Hff = H[np.ix_(free, free)]
                solve_linear(Hff, -g.ravel()[free], method="cholesky")  # the solver's dense path (LDL^T if not PD)
                ts.append(time.perf_counter() - t)
        P = model.samples.values.n_parents
        bound = (model.n_samples * 450 * P**2 + (12 * len(frames)) ** 3 / 3) / (flops * 1e9)
        rows.append((n_grid, nvox, count, model.n_samples, P, t1 - t0, t2 - t1, t3 - t2, t4 - t3,
                     min(ta), np.median(ta), min(ts), np.median(ts), bound))
        print(f"  done {n_grid}^3, {count} frames", flush=True)
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--big", action="store_true", help="also the 128^3 grid (minutes)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--samples", type=int, default=1000)
    ap.add_argument("--parents", type=int, default=6)
    ap.add_argument("--counts", default="10,50,200")
    args = ap.parse_args()
    counts = [int(c) for c in args.counts.split(",")]
    flops = _gflops(1)
    print(f"machine: {platform.machine()} {platform.processor() or ''}, {os.cpu_count()} cores, "
          f"numpy matmul {flops:.1f} GFLOP/s (1 thread); python {platform.python_version()}")
    rows = run(64, counts, args.samples, args.parents, args.repeat, flops)
    if args.big:
        rows += run(128, counts, args.samples, args.parents, args.repeat, flops)
    print()
    print("| grid | voxels | frames | samples | P | place s | weights s | samples s | model s | "
          "assembly ms min / med | Cholesky ms min / med | Newton it. ms | flop bound ms |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        (g, nv, n, m, P, tp, tw, tsmp, tm, amin, amed, smin, smed, bound) = r
        print(f"| {g}^3 | {nv} | {n} | {m} | {P} | {tp:.2f} | {tw:.2f} | {tsmp:.2f} | {tm:.2f} | "
              f"{amin * 1e3:.1f} / {amed * 1e3:.1f} | {smin * 1e3:.1f} / {smed * 1e3:.1f} | "
              f"{(amin + smin) * 1e3:.1f} | {bound * 1e3:.2f} |")


if __name__ == "__main__":
    main()
