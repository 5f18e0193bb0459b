"""Frame quadratures on the neo-Hooke cantilever: elastons, stabilised mid-point regions, Gauss-Legendre.

The documented large-deflection cantilever (beam [0,4]x[0,1]x[0,1], E = 1e3, nu = 0.3, rho g = 9.81,
clamp x = 0, 5 load steps) on the 32x8x8 image: voxel model tip u_z -2.687096 on this image, converged
-2.7087.  For 10, 20, 40, 80 frames (the default weights, or --shape-function) and each rule at its default count:
tip, error against the converged value and the voxel model, difference from Gauss-Legendre of the same
frames with the same weights (the builder gives named stabilised mid-point regions natural neighbours when the
scene names no weights: the weights column says which, and their exact twin is solved for that row), Newton
iterations, solve time (vf.simulate on the built model: min and median of --repeat runs,
alternated between the rules) and precompute time (one run, no disk cache); then the same rule with
twice the regions (how much the answer moves when the count doubles).

--locking: the same cantilever at nu = 0.3, 0.45, 0.49, 0.499, 0.4999 with the frames' default settings
(20 frames, default quadrature, volumetric "auto": the volume ratio projected onto the frames' weights for
nu >= 0.4) and elastons, against the voxel model with F-bar (volumetric "reduced") at every nu.

Usage: python benchmarks/bench_frames_quadrature.py [--counts 10,20,40,80] [--repeat 3] [--locking]
"""

from __future__ import annotations

import argparse
import os
import platform
import time
import warnings
from dataclasses import replace

import numpy as np

os.environ.setdefault("VOXFLEX_CACHE", "0")

import voxflex as vf  # noqa: E402
from voxflex.scene import ElasticitySpec, MaterialSpec, NodesSpec, Scene, SolverSpec  # noqa: E402

CONVERGED = -2.7087
VOXEL = -2.687096
RULES = ("elaston", "midpoint", "gauss-legendre")


def _scene(nu=0.3):
    scene = Scene.from_toml(os.path.join(os.path.dirname(__file__), "..", "examples", "cantilever.toml"))
    return replace(scene, object=replace(scene.object, voxel_size=0.125),
                   materials=(MaterialSpec(model="neo-hookean", young=1e3, poisson=nu, density=1.0),),
                   solver=SolverSpec(steps=5))


def _build(scene):
    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = vf.model(scene, cache=False)
    return model, time.perf_counter() - t


def _solve(scene, model):
    t = time.perf_counter()
    result = vf.simulate(scene, model=model, progress=False)
    return result, time.perf_counter() - t


def quadratures(counts, repeat, shape_function=None):
    base = _scene()
    print("| frames | rule | weights | regions | points | u_z (m) | vs converged | vs voxel | vs Gauss-Legendre, same weights "
          "| Newton it. | solve s (min / median) | precompute s | 2x regions: u_z | change |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for n in counts:
        runs = {}
        for rule in RULES:
            scene = replace(base, nodes=NodesSpec(kind="affine", count=n, shape_function=shape_function),
                            elasticity=ElasticitySpec(quadrature=rule))
            model, tp = _build(scene)
            runs[rule] = [scene, model, tp, []]
        for _ in range(repeat):  # alternated, so that a busy moment is shared
            for rule in RULES:
                scene, model = runs[rule][:2]
                result, ts = _solve(scene, model)
                runs[rule][3].append((ts, result))
        gl_weights = runs["gauss-legendre"][1].info.get("shape_function")
        gl = {gl_weights: runs["gauss-legendre"][3][0][1].probe_displacements()["tip"][2]}
        for rule in RULES:
            scene, model, tp, res = runs[rule]
            times = [t for t, _ in res]
            result = res[0][1]
            u = result.probe_displacements()["tip"][2]
            weights = model.info.get("shape_function")
            if weights not in gl:  # the builder fell back to other weights for this rule: its exact twin uses them
                twin = replace(scene, nodes=replace(scene.nodes, shape_function=weights),
                               elasticity=ElasticitySpec(quadrature="gauss-legendre"))
                gl[weights] = _solve(twin, _build(twin)[0])[0].probe_displacements()["tip"][2]
            its = int(result.newton_iterations.sum())
            regions = model.describe().get("regions", "")
            doubled = change = ""
            if rule != "gauss-legendre":
                s2 = replace(scene, elasticity=ElasticitySpec(quadrature=rule, samples=2 * int(regions)))
                m2, _ = _build(s2)
                u2 = _solve(s2, m2)[0].probe_displacements()["tip"][2]
                doubled = f"{u2:.5f} ({m2.describe()['regions']})"
                change = f"{100 * (u2 - u) / abs(u):+.2f} %"
            g = gl[weights]
            print(f"| {n} | {rule} | {weights} | {regions} | {model.n_samples} | {u:.5f} "
                  f"| {100 * (u - CONVERGED) / abs(CONVERGED):+.2f} % "
                  f"| {100 * (u - VOXEL) / abs(VOXEL):+.2f} % | {100 * (u - g) / abs(g):+.2f} % | {its} "
                  f"| {min(times):.2f} / {np.median(times):.2f} | {tp:.2f} | {doubled} | {change} |", flush=True)


def locking(nus, shape_function=None):
    print("\n| nu | voxel F-bar u_z | frames default u_z | vs voxel | frames elastons u_z | vs voxel | volumetric |")
    print("|---|---|---|---|---|---|---|")
    for nu in nus:
        base = _scene(nu)
        vox = replace(base, nodes=NodesSpec(kind="voxel"), elasticity=ElasticitySpec(volumetric="reduced"))
        uv = _solve(vox, _build(vox)[0])[0].probe_displacements()["tip"][2]
        fr = replace(base, nodes=NodesSpec(kind="affine", shape_function=shape_function),
                     elasticity=ElasticitySpec())  # the defaults (and the family asked for)
        mf = _build(fr)[0]
        uf = _solve(fr, mf)[0].probe_displacements()["tip"][2]
        el = replace(fr, elasticity=ElasticitySpec(quadrature="elaston"))
        ue = _solve(el, _build(el)[0])[0].probe_displacements()["tip"][2]
        print(f"| {nu} | {uv:.5f} | {uf:.5f} | {100 * (uf - uv) / abs(uv):+.2f} % | {ue:.5f} | "
              f"{100 * (ue - uv) / abs(uv):+.2f} % | {mf.describe()['volumetric']} |", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--counts", default="10,20,40,80")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--locking", action="store_true")
    ap.add_argument("--nus", default="0.3,0.45,0.49,0.499,0.4999")
    ap.add_argument("--shape-function", default=None, help="the frames' weight family (default: the scene's default)")
    args = ap.parse_args()
    load = os.getloadavg()
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, load {load[0]:.2f}, python "
          f"{platform.python_version()}, voxflex {vf.__version__}\n")
    if args.locking:
        locking([float(x) for x in args.nus.split(",")], args.shape_function)
    else:
        quadratures([int(c) for c in args.counts.split(",")], args.repeat, args.shape_function)


if __name__ == "__main__":
    main()
