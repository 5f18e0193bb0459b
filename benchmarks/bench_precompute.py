"""Frame-model precompute at a real size: the Stanford bunny at 2 mm (about 94k voxels), 40 frames.

The scene: ``../shared/meshes/stanford-bunny.obj`` (y-up, ``[object] up = "y"``, ``keep =
"largest"``) at 2 mm, linear Hooke E = 3e4, nu = 0.3, density 100, base (lowest 10 % of its
height) clamped, gravity; ``[nodes] count = 40``, the scene's default quadrature for the weights
(stabilised mid-point regions, 5 per frame, for natural neighbours; elastons, 10 per frame, for reproducing
kernels).  The precompute is what ``vf.model`` spends building the frame model with the on-disk cache off:
placement, weights, samples and the checks of their modes (``precompute_seconds``).

Printed: min / median over ``--repeat`` runs (after one warm-up run that compiles the kernels),
the cost per material voxel and per frame, and the profile of one further run (cumulative seconds
of the stages, the top functions by own time).  ``--kinds``: the weight families timed.

Usage: python benchmarks/bench_precompute.py [--repeat 3] [--kinds natural-neighbour,reproducing-kernel]
"""

from __future__ import annotations

import argparse
import cProfile
import os
import platform
import pstats
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np

SHARED = Path(os.environ.get("VOXFLEX_SHARED", Path(__file__).resolve().parents[2] / "shared"))
BUNNY = SHARED / "meshes" / "stanford-bunny.obj"

STAGES = [
    ("placement", "placement.py", "place_frames"),
    ("weights", "weights.py", "shape_function"),
    ("  of which reproducing kernels", "reproducing_kernel.py", "reproducing_kernel"),
    ("samples (regions and their values)", "build.py", "_samples"),
    ("  of which mid-point regions", "sampler.py", "sample"),
    ("  of which elaston sub-rules", "quadrature.py", "elaston_samples"),
    ("checks (modes, soft modes)", "build.py", "_check"),
    ("  of which the soft-mode check", "build.py", "_softest"),
]


def bunny_scene(kind, count=40):
    from voxflex.rasterize import load_mesh
    from voxflex.scene import Scene

    lo, hi = load_mesh(BUNNY).bounds()
    return Scene.from_toml_text(f"""
[object]
mesh = "{BUNNY}"
voxel_size = 0.002
keep = "largest"
up = "y"
[[material]]
model = "hooke"
strain = "linear"
young = 3e4
poisson = 0.3
density = 100.0
[nodes]
count = {count}
shape_function = "{kind}"
[[fixed]]
min = [-1e9, -1e9, -1e9]
max = [1e9, 1e9, {lo[1] + 0.1 * (hi[1] - lo[1])}]
[[load]]
kind = "gravity"
vector = [0.0, 0.0, -9.81]
""")


def _precompute(scene, image, materials):
    from voxflex.deform.models.frames.build import build as _frame_model

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t = time.perf_counter()
        model = _frame_model(scene, image, materials, cache=False)
        return time.perf_counter() - t, model


def _stage_table(stats, total):
    rows = []
    for name, fname, func in STAGES:
        for (f, _, fn), v in stats.stats.items():
            if fn == func and f.endswith(fname):
                rows.append((name, v[3]))
                break
    print("| stage | cumulative s (profiled run) | share |")
    print("|---|---|---|")
    for name, t in rows:
        print(f"| {name} | {t:.2f} | {100 * t / total:.0f} % |")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--kinds", default="natural-neighbour,reproducing-kernel")
    ap.add_argument("--count", type=int, default=40)
    ap.add_argument("--top", type=int, default=15, help="functions listed by own time in the profile")
    args = ap.parse_args()
    if not BUNNY.is_file():
        sys.exit(f"{BUNNY} is absent (the shared test meshes); set VOXFLEX_SHARED")
    import voxflex as vf
    from voxflex.build import build_image, build_materials

    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, python {platform.python_version()}, "
          f"voxflex {vf.__version__}, load average {os.getloadavg()[0]:.2f}")
    for kind in args.kinds.split(","):
        scene = bunny_scene(kind, args.count)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            image = build_image(scene)
        nvox = int((image.labels > 0).sum())
        materials = build_materials(scene, np.unique(image.labels[image.labels > 0]))
        run = (lambda: _precompute(scene, image, materials))
        print(f"\n### {kind} + {scene.elasticity.quadrature}: bunny 2 mm, {nvox} voxels {image.shape}, {args.count} "
              "frames (the whole precompute)\n")
        run()  # warm-up: compiles
        times = [run()[0] for _ in range(args.repeat)]
        tmin, tmed = min(times), statistics.median(times)
        print(f"precompute: min {tmin:.2f} s, median {tmed:.2f} s over {args.repeat} runs "
              f"(load average {os.getloadavg()[0]:.2f}); per voxel {1e6 * tmin / nvox:.1f} us (min), "
              f"per frame {tmin / args.count:.3f} s (min)\n")
        pr = cProfile.Profile()
        pr.enable()
        t, _ = run()
        pr.disable()
        stats = pstats.Stats(pr)
        _stage_table(stats, t)
        print(f"\nTop {args.top} functions by own time (profiled run, {t:.2f} s):\n")
        print("| function | own s | cumulative s |")
        print("|---|---|---|")
        items = sorted(stats.stats.items(), key=lambda kv: -kv[1][2])[:args.top]
        for (f, line, fn), v in items:
            print(f"| {Path(f).name}:{line}({fn}) | {v[2]:.3f} | {v[3]:.3f} |")


if __name__ == "__main__":
    main()
