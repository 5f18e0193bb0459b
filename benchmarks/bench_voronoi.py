"""Voronoi stage: geodesic distances, frame placement and shape-function weights.

For a full cube of n³ voxels and k frames it times

* ``distances``: :func:`voxflex.voronoi.geodesic_distance` from the k frames, second-order
  fast marching (``fmm``) and 26-neighbour Dijkstra (``dijkstra``);
* ``placement``: :func:`voxflex.voronoi.place_frames` (farthest point + Lloyd, at most 10 iterations;
  from 200,000 material voxels on, first at half resolution, then at most 3 full-resolution ones);
* ``weights``: :func:`voxflex.voronoi.weights` (natural neighbours by default) and its
  weights at every material voxel centre (the input of the smoothing), i.e. everything the
  frame model needs before the smoothing blend (fast-marching frame distances, node regions,
  stolen sets of the weight nodes, fits, centre weights);

min and median of ``--repeat`` runs (kernels warmed first), the CPU seconds of the fastest run
(process time, all threads: on a shared machine wall time is inflated by the other loads, CPU
time much less; the weights run on 2 threads), the load average when the row was run, and the
peak resident memory of the process that ran the configuration (each configuration runs in its
own process, so the figure is that configuration's peak, interpreter and numba included).

    python benchmarks/bench_voronoi.py                      # 64³ and 128³, 10/50/200 frames
    python benchmarks/bench_voronoi.py --sizes 256 --frames 50 --repeat 1

``total`` is placement + weights, the Voronoi stage's share of building a frame model (the
target of issue 8: under 20 s at 128³ with 50 frames on a 2-core machine).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time

import numpy as np


def _one(n, k, repeat, kind):
    from voxflex.image import LabelImage
    from voxflex.voronoi import geodesic_distance, place_frames, shape_function

    warm = LabelImage(np.ones((10, 10, 10), np.uint8))
    wf = place_frames(warm, 6)
    geodesic_distance(warm, wf, method="dijkstra")
    shape_function(warm, wf, kind=kind)._centre_weights()
    img = LabelImage(np.ones((n, n, n), np.uint8))
    out = {}

    def timed(name, f):
        ts, cs = [], []
        r = None
        for _ in range(repeat):
            t, c = time.perf_counter(), time.process_time()
            r = f()
            ts.append(time.perf_counter() - t)
            cs.append(time.process_time() - c)
        out[name] = (min(ts), float(np.median(ts)), cs[int(np.argmin(ts))])
        return r

    frames = timed("placement", lambda: place_frames(img, k))
    timed("fmm", lambda: geodesic_distance(img, frames))
    timed("dijkstra", lambda: geodesic_distance(img, frames, method="dijkstra"))
    timed("weights", lambda: shape_function(img, frames, kind=kind)._centre_weights())
    out["peak_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    out["load"] = os.getloadavg()[0]
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="64,128", help="cube edges in voxels, comma-separated")
    ap.add_argument("--frames", default="10,50,200", help="frame counts, comma-separated")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs per configuration (min and median)")
    ap.add_argument("--kind", default="natural-neighbour", help="shape-function kind")
    ap.add_argument("--one", nargs=2, type=int, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.one:
        print(json.dumps(_one(a.one[0], a.one[1], a.repeat, a.kind)))
        return
    print(f"# {platform.platform()}, {platform.processor() or platform.machine()}, os.cpu_count() = {os.cpu_count()}, "
          f"python {platform.python_version()}; kind = {a.kind}, repeat = {a.repeat}")
    print(f"{'voxels':>8} {'frames':>6} | {'fmm s (min/med)':>16} {'dijkstra s':>14} {'us/vox fmm':>10} | "
          f"{'placement s':>14} {'cpu':>6} | {'weights s':>14} {'cpu':>6} | {'total s':>7} {'cpu':>6} | "
          f"{'load':>5} | {'peak MB':>8}")
    for n in [int(s) for s in a.sizes.split(",")]:
        for k in [int(s) for s in a.frames.split(",")]:
            r = subprocess.run([sys.executable, __file__, "--one", str(n), str(k), "--repeat", str(a.repeat),
                                "--kind", a.kind], capture_output=True, text=True)
            if r.returncode:
                print(f"{n:>5}^3 {k:>6} | failed: {r.stderr.strip().splitlines()[-1] if r.stderr.strip() else r.returncode}")
                continue
            o = json.loads(r.stdout.strip().splitlines()[-1])
            f = lambda key: f"{o[key][0]:6.2f}/{o[key][1]:6.2f}"  # noqa: E731
            tot = o["placement"][0] + o["weights"][0]
            cpu = o["placement"][2] + o["weights"][2]
            print(f"{n:>5}^3 {k:>6} | {f('fmm'):>16} {f('dijkstra'):>14} {o['fmm'][0] / n ** 3 * 1e6:>10.2f} | "
                  f"{f('placement'):>14} {o['placement'][2]:>6.1f} | {f('weights'):>14} {o['weights'][2]:>6.1f} | "
                  f"{tot:>7.1f} {cpu:>6.1f} | {o['load']:>5.1f} | {o['peak_mb']:>8.0f}", flush=True)


if __name__ == "__main__":
    main()
