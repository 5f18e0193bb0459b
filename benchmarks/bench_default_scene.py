"""The bundled default scene (data/default.toml: a neo-Hookean capsule, nu = 0.45, bending under its own
weight) as frames and as voxel grids: tip sag, error against the converged answer, and time.

Two references: the scene's own voxel model (``[nodes] kind = "voxel"`` on the same 1 mm image), and
the voxel model on that image with every voxel split into 2x2x2 (the same voxelized shape, so the
converged answer on the image the frames see: ``voxflex tradeoff --reference finer``).  The mesh
voxelized at 2, 1 and 0.5 mm is printed with its observed order of convergence (each size is another
staircase; no extrapolation is made from it).  Every model is solved by the same
Newton solver at the scene's tolerance (1e-8) with the scene's linear solver setting ("auto": a
best-solver comparison -- sparse direct or multigrid-CG for the voxel grids, dense Cholesky for the
frames).  Timings: the precompute (frames: weights, samples, checks; voxel: element tables), and the
solve with the model built, warmed once, then ``--repeat`` times (min and median; the slow rows,
Gauss-Legendre frames and the split image, once: the ``runs`` column).  Every frame figure stands
beside the same frames with exact integration (2x2x2 Gauss-Legendre points per voxel) and beside the
library's default settings (natural-neighbour weights, stabilised mid-point regions, the volume ratio
projected).

Usage: python benchmarks/bench_default_scene.py [--repeat 3] [--quick]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
import warnings
from dataclasses import replace

import numpy as np

import voxflex as vf
from voxflex.scene import Scene, default_scene_path


def _scene(base, *, kind="affine", h=None, sf=None, q=None, count=None, volumetric=None):
    if kind == "voxel":  # the default scene's frame keys (count, shape_function) do not apply to voxels
        nodes = replace(base.nodes, kind=kind, shape_function=None, count=None)
    else:
        nodes = replace(base.nodes, kind=kind, **({"shape_function": sf} if sf else {}),
                        **({"count": count} if count else {}))
    el = replace(base.elasticity, quadrature=q or ("gauss-legendre" if kind == "voxel" else "elaston"),
                 **({"volumetric": volumetric} if volumetric else {}))
    obj = replace(base.object, voxel_size=h) if h else base.object
    return replace(base, object=obj, nodes=nodes, elasticity=el)  # the same clamp box at every voxel size


def _measure(scene, repeat, image=None):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t = time.perf_counter()
        model = vf.model(scene, image=image, cache=False)
        pre = time.perf_counter() - t
        times = []
        for k in range(repeat + 1):  # the first run warms the kernels
            t = time.perf_counter()
            r = vf.simulate(scene, model=model, progress=False)
            if k:
                times.append(time.perf_counter() - t)
    p = r.probes["tip"]
    return float((p[-1] - p[0])[2]), model.describe()["dofs"], pre, times


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="skip the 0.5 mm voxel model and Gauss-Legendre frames")
    args = ap.parse_args()
    base = Scene.from_toml(default_scene_path())
    rows = [("voxel 1 mm, F-bar (auto)", _scene(base, kind="voxel")),
            ("voxel 1 mm, full", _scene(base, kind="voxel", volumetric="full")),
            ("voxel 2 mm, F-bar (auto)", _scene(base, kind="voxel", h=0.002))]
    if not args.quick:
        rows.append(("voxel 0.5 mm, F-bar (auto)", _scene(base, kind="voxel", h=0.0005)))
        rows.append(("voxel 1 mm image split 2x2x2, F-bar (auto)", _scene(base, kind="voxel")))
    for n in (20, 40, 80):
        rows.append((f"{n} frames, RK + elastons" + (" (the default scene)" if n == 40 else ""), _scene(base, sf="reproducing-kernel", count=n)))
    if not args.quick:
        rows.append(("40 frames, RK + Gauss-Legendre (exact)", _scene(base, sf="reproducing-kernel",
                                                                      q="gauss-legendre", count=40)))
    rows.append(("40 frames, NN + stabilised mid-point (the library defaults before 2026-12-05)",
                 _scene(base, sf="natural-neighbour", q="midpoint", count=40)))
    if not args.quick:  # the exact-integration twin of the library defaults (the same volume-ratio projection)
        rows.append(("40 frames, NN + Gauss-Legendre (exact)", _scene(base, sf="natural-neighbour",
                                                                      q="gauss-legendre", count=40)))
    rows.append(("40 frames, NN + Gauss-Legendre, full", _scene(base, sf="natural-neighbour", q="gauss-legendre",
                                                                 count=40, volumetric="full")))
    out = {}
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}")
    from voxflex.build import build_image
    from voxflex.image.levels import image_at_level as _image_at_level

    split = _image_at_level(build_image(base), 1)
    for label, scene in rows:
        out[label] = _measure(scene, 1 if ("Gauss" in label or "split" in label) else args.repeat,
                              image=split if "split" in label else None)
        tip, dofs, pre, times = out[label]
        print(f"  {label}: {tip * 1e3:.3f} mm", flush=True)
    u2, u1 = out["voxel 2 mm, F-bar (auto)"][0], out["voxel 1 mm, F-bar (auto)"][0]
    u05 = out.get("voxel 0.5 mm, F-bar (auto)", (None,))[0]
    same = out.get("voxel 1 mm image split 2x2x2, F-bar (auto)", (None,))[0]
    print()
    if u05 is None:
        print("references: not measured (--quick)")
    else:
        # the mesh voxelized at 2, 1, 0.5 mm is a different staircase at each size: its observed order says how
        # far an extrapolation could be trusted (none is made)
        ratio = (u1 - u2) / (u05 - u1) if u05 != u1 else float("inf")
        order = f"{np.log2(ratio):.2f}" if np.isfinite(ratio) and ratio > 0 else "none (not monotone)"
        print(f"the mesh voxelized at 2 / 1 / 0.5 mm (F-bar): {-u2 * 1e3:.3f} / {-u1 * 1e3:.3f} / {-u05 * 1e3:.3f} mm, "
              f"observed order {order}; the 1 mm image, converged (split 2x2x2): {-same * 1e3:.3f} mm")
    print()
    print("| model | DOF | tip sag [mm] | vs the 1 mm voxel model | vs the 1 mm image split | precompute [s] | "
          "solve min / median [s] | runs |")
    print("|---|---|---|---|---|---|---|---|")
    for label, (tip, dofs, pre, times) in out.items():
        e0 = f"{(tip / u1 - 1) * 100:+.1f} %"
        e1 = f"{(tip / same - 1) * 100:+.1f} %" if same is not None else "-"
        print(f"| {label} | {dofs:,} | {-tip * 1e3:.3f} | {e0} | {e1} | {pre:.2f} | "
              f"{min(times):.2f} / {statistics.median(times):.2f} | {len(times)} |")

if __name__ == "__main__":
    main()
