"""Throughput of the node -> child mappings: numba kernels vs their numpy twins.

Prints one row per (node type, mapping, operation, backend): best wall time of
``--repeat`` runs after a warm-up call (numba compilation excluded) and the
throughput in children per second (from the wall time); the process CPU
time (all threads) is printed too, as it is less sensitive to other load.

    python benchmarks/bench_mappings.py [--m 100000] [--parents 8] [--nodes 2000] [--repeat 3]

Set ``NUMBA_NUM_THREADS`` to control the numba threads (parallel kernels:
apply, jvp, jacobian; vjp is a serial scatter).
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from voxflex.deform.chain.mappings import DeformationGradientMapping, PointMapping
from voxflex.deform.chain.nodes import AffineFrames, Points
from voxflex.voronoi.shape_functions import shepard


def _best(fn, repeat):
    """Best wall time and best process CPU time (all threads) of ``repeat`` calls after a warm-up."""
    fn()  # warm-up (compilation, caches)
    wall = cpu = np.inf
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall = min(wall, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    return wall, cpu


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--m", type=int, default=100_000, help="children (points or samples)")
    ap.add_argument("--parents", type=int, default=8, help="parents per child P")
    ap.add_argument("--nodes", type=int, default=2000, help="number of nodes")
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args(argv)

    import numba

    rng = np.random.default_rng(0)
    Xn = rng.random((args.nodes, 3))
    sv = shepard(rng.random((args.m, 3)), Xn, n_parents=args.parents, hessians=False)
    print(
        f"machine: {platform.machine()} {platform.processor() or ''} {os.cpu_count()} cpus, "
        f"numba {numba.__version__} threads={numba.config.NUMBA_NUM_THREADS}, numpy {np.__version__}"
    )
    print(f"m = {args.m} children, P = {args.parents} parents, n = {args.nodes} nodes; best of {args.repeat}")
    print(f"load average before: {os.getloadavg()[0]:.1f} (shared machine: wall times vary; CPU times are steadier)")
    print(
        f"{'nodes':7s} {'mapping':8s} {'op':9s} {'numba wall':>10s} {'numba cpu':>10s} {'numpy wall':>10s} "
        f"{'numpy cpu':>10s} {'numba ch/s':>11s} {'numpy ch/s':>11s} {'speed-up':>8s}"
    )
    for node_type in (Points, AffineFrames):
        nodes = node_type(Xn)
        s = nodes.rest + 0.01 * rng.standard_normal(nodes.rest.shape)
        dq = rng.standard_normal((nodes.n, nodes.dofs_per_node))
        for label, mt in (("points", PointMapping), ("F", DeformationGradientMapping)):
            maps = {b: mt(nodes, sv, backend=b) for b in ("numba", "numpy")}
            f = rng.standard_normal((args.m, maps["numba"].child_size))
            ops = {
                "apply": lambda mp: mp.apply(s),
                "jvp": lambda mp: mp.jvp(s, dq),
                "vjp": lambda mp: mp.vjp(s, f),
                "jacobian": lambda mp: mp.jacobian(s),
            }
            for op, fn in ops.items():
                t = {b: _best(lambda: fn(maps[b]), args.repeat) for b in maps}
                (nw, nc), (pw, pc) = t["numba"], t["numpy"]
                print(
                    f"{nodes.kind:7s} {label:8s} {op:9s} {nw:10.4f} {nc:10.4f} {pw:10.4f} {pc:10.4f} "
                    f"{args.m / nw:11.3e} {args.m / pw:11.3e} {pw / nw:8.1f}"
                )


if __name__ == "__main__":
    main()
