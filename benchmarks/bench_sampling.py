"""Sampling time for 64^3 and 128^3 images with 50 frames and 200 / 1000 / 5000 samples.

Usage: ``python benchmarks/bench_sampling.py [--sizes 64,128] [--counts 200,1000,5000] [--repeat 3]``

The object is a ball filling the image (radius 0.45 n voxels, ~38 % of the
voxels) with two labels (the half x < centre is label 2).  The shape function
is ``voxflex.voronoi.weights(kind="natural-neighbour", parents=4)`` when
that stage exists, else renormalized Shepard weights on the 4 nearest frames
(the stand-in of the tests); its voxel values are computed once, outside the
timings (the column ``sf s``).  Kernels are warmed on a small image first;
each time is the min and median of ``--repeat`` runs.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from dataclasses import dataclass

import numpy as np

from voxflex.image import LabelImage
from voxflex.sampling import sample
from voxflex.voronoi.shape_functions import shepard


@dataclass(frozen=True, eq=False)
class CachedShepard:
    image: LabelImage
    frames: np.ndarray
    parents: int = 4

    def __call__(self, points):
        return shepard(points, self.frames, n_parents=self.parents)

    def voxel_values(self):
        if not hasattr(self, "_vv"):
            object.__setattr__(self, "_vv", self(self.image.voxel_centers()))
        return self._vv


class Cached:
    def __init__(self, sf):
        self.sf, self.frames, self.parents = sf, sf.frames, getattr(sf, "parents", 4)
        self._vv = None

    def __call__(self, points):
        return self.sf(points)

    def voxel_values(self):
        if self._vv is None:
            self._vv = self.sf.voxel_values()
        return self._vv


def ball(n):
    x = (np.indices((n, n, n)) + 0.5 - n / 2) / n
    inside = (x**2).sum(0) < 0.45**2
    lab = inside.astype(np.uint8)
    lab[(x[0] < 0) & inside] = 2
    return LabelImage(lab, spacing=[1.0 / n] * 3)


def shape_function(image, frames):
    try:
        from voxflex.voronoi import shape_function as real

        return Cached(real(image, frames, kind="natural-neighbour", parents=4)), "natural-neighbour"
    except (ImportError, AttributeError):
        return CachedShepard(image, frames), "shepard stand-in"


def frames_for(image, k, seed=0):
    c = image.voxel_centers()
    return c[np.sort(np.random.default_rng(seed).choice(len(c), k, replace=False))] + 0.2 / image.shape[0]


def timed(f, repeat):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        out = f()
        times.append(time.perf_counter() - t)
    return out, min(times), statistics.median(times)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="64,128")
    ap.add_argument("--counts", default="200,1000,5000")
    ap.add_argument("--kinds", default="midpoint,elaston")
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    print(f"# {platform.platform()} | {platform.processor() or platform.machine()} | cpu_count={os.cpu_count()}")
    warm = ball(12)
    wsf, _ = shape_function(warm, frames_for(warm, 6))
    for kind in ("midpoint", "elaston", "gauss-legendre"):
        sample(warm, wsf, kind=kind, count=20)
    print(f"{'size':>5} {'voxels':>8} {'sf':>18} {'sf s':>7} {'kind':>9} {'count':>6} {'m':>6} {'P':>3} {'min s':>8} {'median s':>8}")
    for n in (int(v) for v in args.sizes.split(",")):
        image = ball(n)
        sf, name = shape_function(image, frames_for(image, args.frames))
        t = time.perf_counter()
        sf.voxel_values()
        t_sf = time.perf_counter() - t
        for kind in args.kinds.split(","):
            for count in (int(v) for v in args.counts.split(",")):
                s, tmin, tmed = timed(lambda: sample(image, sf, kind=kind, count=count), args.repeat)
                print(
                    f"{n:>4}^3 {int((image.labels > 0).sum()):>8} {name:>18} {t_sf:>7.2f} {kind:>9} {count:>6} {s.m:>6} "
                    f"{s.values.n_parents:>3} {tmin:>8.2f} {tmed:>8.2f}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
