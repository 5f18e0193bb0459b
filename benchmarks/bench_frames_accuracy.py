"""Frame models against the voxel model on the same image: error and time.

1. The SOFA frames-beam set-up: bar 0.4 x 0.4 x 2 (voxels 0.02, 40,000), clamped at
   z = 0, E = 1e5, nu = 0.3, linear elasticity, 1 N along x on the tip face; 40
   frames, 1000 samples; every shape function x sampler; tip deflection error
   against the voxel model, precompute and solve time.
2. The large-deflection neo-Hooke cantilever (beam [0,4]x[0,1]x[0,1], E = 1e3,
   nu = 0.3, rho g = 9.81, clamp x = 0, 5 load steps) on the 32x8x8 image
   (reference -2.687096, peers agree): tip u_z as the frames increase, time per
   Newton iteration and total time, the default stabilised mid-point regions
   (every quadrature at its default count: benchmarks/bench_frames_quadrature.py).

Timings are one run each (end to end: model building and solve), machine noted.
Usage: python benchmarks/bench_frames_accuracy.py [--part 1|2|all] [--counts 5,10,20,50,100]
"""

from __future__ import annotations

import argparse
import os
import platform
import time
import warnings
from dataclasses import replace


import voxflex as vf
from voxflex.scene import ElasticitySpec, FixedSpec, LoadSpec, MaterialSpec, NodesSpec, ObjectSpec, ProbeSpec, Scene, SolverSpec


def _run(scene):
    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = vf.model(scene)
    tp = time.perf_counter() - t
    t = time.perf_counter()
    result = vf.simulate(scene, model=model, progress=False)
    return result, model, tp, time.perf_counter() - t


def sofa(kinds, samplers):
    scene = Scene(object=ObjectSpec(shape="box", size=(0.4, 0.4, 2.0), voxel_size=0.02), nodes=NodesSpec(kind="voxel"),
                  materials=(MaterialSpec(model="hooke", young=1e5, poisson=0.3, strain="linear"),),
                  elasticity=ElasticitySpec(strain="linear"), fixed=(FixedSpec(max=(1e9, 1e9, 1e-6)),),
                  loads=(LoadSpec(kind="force", vector=(1.0, 0.0, 0.0), min=(-1e9, -1e9, 2.0 - 1e-6)),),
                  probes=(ProbeSpec("tip", (0.2, 0.2, 2.0)),))
    ref, _, tp, ts = _run(scene)
    uv = ref.probe_displacements()["tip"][0]
    print(f"\n### SOFA frames beam: voxel model {uv:.6e} m ({tp + ts:.1f} s, 40,000 voxels)\n")
    print("| shape function | sampler | samples | tip (m) | error | precompute s (one run) | solve s (one run) |")
    print("|---|---|---|---|---|---|---|")
    for kind in kinds:
        for q in samplers:
            s = replace(scene, nodes=NodesSpec(kind="affine", count=40, shape_function=kind),
                        elasticity=ElasticitySpec(strain="linear", quadrature=q,
                                                    samples=1000 if q != "gauss-legendre" else None))
            try:
                r, m, tp, ts = _run(s)
            except vf.VoxflexError as exc:
                print(f"| {kind} | {q} | | not available: {exc} | | | |")
                continue
            u = r.probe_displacements()["tip"][0]
            print(f"| {kind} | {q} | {m.n_samples} | {u:.6e} | {100 * (u - uv) / abs(uv):+.2f} % | {tp:.1f} | {ts:.1f} |",
                  flush=True)


def cantilever(counts):
    scene = Scene.from_toml(os.path.join(os.path.dirname(__file__), "..", "examples", "cantilever.toml"))
    scene = replace(scene, object=replace(scene.object, voxel_size=0.125), nodes=NodesSpec(kind="voxel"),
                    materials=(MaterialSpec(model="neo-hookean", young=1e3, poisson=0.3, density=1.0),),
                    elasticity=ElasticitySpec(), solver=SolverSpec(steps=5))
    ref, _, tp, ts = _run(scene)
    uv = ref.probe_displacements()["tip"][2]
    it = int(ref.newton_iterations.sum())
    print(f"\n### Neo-Hooke cantilever 32x8x8: voxel model u_z = {uv:.6f} m, {it} Newton iterations, "
          f"{tp + ts:.1f} s\n")
    print("| frames | samples | u_z (m) | error | Newton it. | s / iteration (one run) | precompute s (one run) | total s (one run) |")
    print("|---|---|---|---|---|---|---|---|")
    for n in counts:
        s = replace(scene, nodes=NodesSpec(kind="affine", count=n, shape_function="natural-neighbour"),
                    elasticity=ElasticitySpec(quadrature="midpoint"))
        r, m, tp, ts = _run(s)
        u = r.probe_displacements()["tip"][2]
        its = int(r.newton_iterations.sum())
        print(f"| {n} | {m.n_samples} | {u:.6f} | {100 * (u - uv) / abs(uv):+.2f} % | {its} | "
              f"{ts / max(its, 1):.4f} | {tp:.1f} | {tp + ts:.1f} |", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--part", default="all", choices=["1", "2", "all"])
    ap.add_argument("--counts", default="5,10,20,50,100")
    ap.add_argument("--kinds", default="natural-neighbour,laplace,distance-ratio,shepard")
    ap.add_argument("--samplers", default="midpoint,elaston,gauss-legendre")
    args = ap.parse_args()
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, python {platform.python_version()}, "
          f"voxflex {vf.__version__}")
    if args.part in ("1", "all"):
        sofa(args.kinds.split(","), args.samplers.split(","))
    if args.part in ("2", "all"):
        cantilever([int(c) for c in args.counts.split(",")])


if __name__ == "__main__":
    main()
