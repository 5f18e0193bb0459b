"""Time voxelizing a ~100k-triangle mesh at 128^3 and 256^3 grids, with and without occupancy.

Uses ../shared/meshes/stanford-bunny.obj beside the repository (or $VOXFLEX_SHARED/meshes) (69,451 triangles, open at the
base) when present, else a pyvista sphere subdivided to ~100k triangles.  The
voxel size is the longest extent / N.  The first (compiling) call is excluded
by a warm-up on a small grid.

    python benchmarks/bench_voxelize.py [--mesh PATH] [--sizes 128 256] [--beta 1.5] [--profile]

The first line reports the first (small) call: numba compilation with
``VOXFLEX_NUMBA_CACHE=0``, else loading the cache.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import numpy as np

from voxflex.rasterize import load_mesh, voxelize

BUNNY = Path(os.environ.get("VOXFLEX_SHARED", Path(__file__).resolve().parents[2] / "shared")) / "meshes" / "stanford-bunny.obj"


def _mesh(path):
    if path is not None:
        return load_mesh(path), Path(path).name
    if BUNNY.exists():
        return load_mesh(BUNNY), BUNNY.name
    import pyvista as pv

    sphere = pv.Sphere(radius=1.0, theta_resolution=224, phi_resolution=224).triangulate()
    faces = np.asarray(sphere.faces).reshape(-1, 4)[:, 1:]
    from voxflex.rasterize import SurfaceMesh

    return SurfaceMesh(np.asarray(sphere.points), faces, name="pyvista sphere"), "pyvista sphere"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--mesh", default=None, help="surface mesh file (default: the bunny or a sphere)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[128, 256], help="cells along the longest extent")
    parser.add_argument("--beta", type=float, default=None, help="fast winding number accuracy (default: voxelize's)")
    parser.add_argument("--profile", action="store_true", help="cProfile the first size with occupancy (top 12)")
    args = parser.parse_args(argv)
    opts = {} if args.beta is None else {"beta": args.beta}
    mesh, name = _mesh(args.mesh)
    lo, hi = mesh.bounds()
    source = (mesh.vertices, mesh.faces)
    t0 = time.perf_counter()
    voxelize(source, float((hi - lo).max()) / 16, occupancy=True, progress=False, **opts)  # compile / load cache
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    voxelize(source, float((hi - lo).max()) / 16, occupancy=True, progress=False, **opts)
    second = time.perf_counter() - t0
    cores = os.cpu_count()
    threads = os.environ.get("NUMBA_NUM_THREADS", str(cores))
    print(f"mesh: {name}, {len(mesh.faces)} triangles; machine: {platform.processor() or platform.machine()}, "
          f"{cores} cores, numba threads {threads}")
    cache = os.environ.get("VOXFLEX_NUMBA_CACHE", "1")
    print(f"first call at 16^3: {first:.2f} s, second {second:.2f} s (VOXFLEX_NUMBA_CACHE={cache})")
    print(f"{'grid':>14} {'triangles':>10} {'occupancy':>9} {'seconds':>8} {'inside':>10} {'volume':>12}")
    for n in args.sizes:
        h = float((hi - lo).max()) / n
        for occ in (False, True):
            t0 = time.perf_counter()
            image = voxelize(source, h, occupancy=occ, progress=False, **opts)
            dt = time.perf_counter() - t0
            inside = int((image.labels > 0).sum())
            vol = (image.occupancy.sum() if occ else inside) * image.voxel_volume
            grid = "x".join(str(s) for s in image.shape)
            print(f"{grid:>14} {len(mesh.faces):>10} {str(occ):>9} {dt:>8.2f} {inside:>10} {vol:>12.6g}")
    if args.profile:
        import cProfile
        import pstats

        h = float((hi - lo).max()) / args.sizes[0]
        profiler = cProfile.Profile()
        profiler.runcall(voxelize, source, h, occupancy=True, progress=False, **opts)
        pstats.Stats(profiler).sort_stats("tottime").print_stats(12)


if __name__ == "__main__":
    main()
