"""Memory per degree of freedom and time per Newton iteration of the voxel model (the constants of voxflex.resources).

Each case runs in a fresh subprocess (so the peak resident memory is its own):
build a clamped box of nx x ny x nz voxels, solve one static step under
gravity, and report the peak RSS above the baseline after imports and a warm-up
solve (kernels compiled), divided by the DOF count, and the solve time per
Newton iteration.  Repeated 3 times (min and median).

    python benchmarks/bench_resources.py            # the table used in voxflex/resources.py
    python benchmarks/bench_resources.py --quick    # two small sizes
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import subprocess
import sys

CHILD = r"""
import json, resource, sys, time
import numpy as np
from voxflex.deform.solve.boundary import FixedRegion
from voxflex.deform.materials.constitutive import material
from voxflex.deform.solve.stepping import SolverOptions, solve
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.image.label_image import LabelImage

nx, ny, nz, name, volumetric = sys.argv[1:6]
nx, ny, nz = int(nx), int(ny), int(nz)
kw = {"strain": "linear"} if name == "hooke" else {}

def run(shape):
    image = LabelImage(np.ones(shape), spacing=(0.01, 0.01, 0.01))
    model = VoxelModel.from_image(image, {1: material(name, young=1e6, poisson=0.3, **kw)}, volumetric=volumetric)
    t = time.perf_counter()
    rec = solve(model, fixed=[FixedRegion([-1, -1, -1], [1e-9, 1, 1])], gravity=[0, 0, -9.81], densities={1: 1e3},
                options=SolverOptions(tolerance=1e-8))
    return model, time.perf_counter() - t, sum(r.newton_iterations for r in rec)

run((4, 2, 2))  # compile and import everything
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
model, seconds, its = run((nx, ny, nz))
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(json.dumps({"dofs": 3 * model.n_nodes, "bytes": peak - base, "seconds": seconds, "iterations": its}))
"""


def measure(nx, ny, nz, name, volumetric="full", repeat=3):
    out = []
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    for _ in range(repeat):
        text = subprocess.run([sys.executable, "-c", CHILD, str(nx), str(ny), str(nz), name, volumetric],
                              check=True, capture_output=True, text=True, env=env).stdout
        out.append(json.loads(text.strip().splitlines()[-1]))
    return out


def main():
    quick = "--quick" in sys.argv
    sizes = [(16, 8, 8), (32, 16, 16)] if quick else [(16, 8, 8), (32, 16, 16), (48, 24, 24)]
    print(f"machine: {platform.platform()}, {os.cpu_count()} CPUs, python {platform.python_version()}")
    print(f"{'material':<12} {'volumetric':<10} {'voxels':>8} {'DOF':>8} {'bytes/DOF min':>14} {'median':>8} "
          f"{'s/iteration min':>16} {'median':>8} {'iterations':>10}")
    for name, vol in [("hooke", "full"), ("neo-hookean", "full"), ("neo-hookean", "reduced")]:
        for nx, ny, nz in sizes:
            runs = measure(nx, ny, nz, name, vol, repeat=1 if quick else 3)
            bpd = [r["bytes"] / r["dofs"] for r in runs]
            spi = [r["seconds"] / max(r["iterations"], 1) for r in runs]
            print(f"{name:<12} {vol:<10} {nx * ny * nz:>8} {runs[0]['dofs']:>8} {min(bpd):>14.0f} "
                  f"{statistics.median(bpd):>8.0f} {min(spi):>16.4f} {statistics.median(spi):>8.4f} "
                  f"{runs[0]['iterations']:>10}")


if __name__ == "__main__":
    main()
