"""Benchmark: the voxel stiffness pattern and element scatter per voxel from 16k to 1M voxels, and first touch.

Issue 26 measured the lean path's element scatter 7x slower per element at 3.26M DOF than at 55k.
This script separates the two causes that could make it so, on clamped beams ``4n x n x n``:

* ``pattern``: :func:`~voxflex.deform.models.voxel._kernels.grid_block_pattern` (the CSR pattern and
  the voxel block map), ns per voxel;
* ``scatter fresh``: :func:`~voxflex.deform.models.voxel._kernels.scatter_blocks` of one 24x24 matrix
  per voxel (chunks of 16384, as the model does) into a new ``np.zeros`` array: its pages are
  mapped on their first write;
* ``scatter touched``: the same into an array written once beforehand (pages mapped): the scatter's
  own cost, cache misses included;
* then the cost of touching fresh memory at all: ``np.zeros(n)`` followed by a sequential ``a[:] = 0``
  over 2.1 GB, twice (the first time in the process, and again after freeing it).

Measured here (2 cores, load average ~1; ns per voxel, fresh / touched): 16k voxels 1528 / 1128,
131k 4579 / 1081, 442k 4900 / 1322, 1M (3.26M DOF) 5525 / 1457; pattern 3100-3800 ns per voxel
from 131k to 1M.  Touching 2.1 GB of fresh memory sequentially: 4.7 s the first time, 0.24 s the
second.  So the scatter itself scales (1.1-1.5 us per voxel at every size); what grew was the first
touch of fresh pages (about 2.2 ns per byte the first time this virtual machine's process touches
them, sequential or scattered alike), which the lean path no longer pays above
``DIRECT_FALLBACK_MAX`` unknowns: it assembles no stiffness there (``FreeStiffness``).

    python benchmarks/bench_scatter_scaling.py [--sizes 16,32,48,64]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


def main():
    from voxflex.deform.materials.constitutive import material
    from voxflex.deform.models.voxel import _kernels as kern
    from voxflex.deform.models.voxel.model import VoxelModel
    from voxflex.image.label_image import LabelImage

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--sizes", default="16,32,48,64")
    a = p.parse_args()
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    print("| beam | voxels | DOF | pattern ns/voxel | scatter fresh ns/voxel | scatter touched ns/voxel |")
    print("|---|---|---|---|---|---|")
    hooke = material("hooke", young=1e4, poisson=0.3, strain="linear")
    kern.grid_block_pattern(np.arange(8).reshape(1, 8), 8)  # compile
    for n in map(int, a.sizes.split(",")):
        model = VoxelModel.from_image(LabelImage(np.ones((4 * n, n, n), dtype=np.uint8), spacing=(1 / n,) * 3),
                                      {1: hooke})
        conn = model.grid.element_nodes
        m = len(conn)
        t = time.perf_counter()
        _, indices, indptr_b, blockmap = kern.grid_block_pattern(conn, model.n_nodes)
        tp = time.perf_counter() - t
        Ke = np.repeat(model.unit_stiffness(1)[None], 16384, axis=0)
        out = {}
        for mode in ("fresh", "touched"):
            data = np.zeros(len(indices))
            if mode == "touched":
                data[:] = 1.0
                data[:] = 0.0
            t = time.perf_counter()
            for s in range(0, m, 16384):
                e = slice(s, min(m, s + 16384))
                kern.scatter_blocks(Ke[: e.stop - e.start], conn[e], blockmap[e], indptr_b, data)
            out[mode] = (time.perf_counter() - t) / m * 1e9
            del data
        print(f"| {4 * n}x{n}x{n} | {m} | {3 * model.n_nodes} | {tp / m * 1e9:.0f} | {out['fresh']:.0f} | "
              f"{out['touched']:.0f} |", flush=True)
    n = 262_000_000
    for k in ("first", "second"):
        a_ = np.zeros(n)
        t = time.perf_counter()
        a_[:] = 0.0
        print(f"sequential touch of {8 * n / 1e9:.1f} GB of fresh memory, {k} time: {time.perf_counter() - t:.2f} s")
        del a_
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
