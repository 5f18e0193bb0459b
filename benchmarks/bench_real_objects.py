"""Benchmark: the voxel reference on the real objects of issue 26 (cow, standing Homer, Stanford bunny).

Scenes in ``benchmarks/scenes/`` (meshes from the shared test collection, ``../shared/meshes``
beside the repository): the cow at 0.2 (6.7k voxels, 26k DOF, neo-Hooke E = 1e6, hooves clamped,
gravity, 3 steps), standing Homer at 10 mm (21k voxels, 79k DOF, E = 5e4, soles clamped, gravity
along -y, 3 steps), the bunny at 2 mm (94k voxels, 315k DOF, E = 2e4, base clamped, gravity, 3
steps); nu = 0.3, density 1000 kg/m^3, ``linear_solver = "auto"`` (multigrid-CG at these sizes).

Each scene runs in a fresh process (its kernels warmed on a small beam first) through
``voxflex.deform.solve.stepping.solve``: Newton iterations per load step, the linear solves
(count, mean and largest seconds, the methods used), the total, the peak resident memory and the
largest displacement (and the bunny's ``ear`` probe).  ``--before PATH`` runs the same scenes
with the voxflex package found at PATH (a checkout of the code before, e.g. ``git worktree add
/tmp/before b706a7e``) in the same way, each under ``--timeout`` seconds (the code before factorised
the tangents directly: a run that does not finish is reported as such, with what it did until then).

    python benchmarks/bench_real_objects.py [--scenes cow,homer,bunny] [--before PATH] [--timeout 900]
        [--memory-cap GB]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
SCENES = ("cow", "homer", "bunny")

CHILD = r'''
import json, sys, time, dataclasses, resource
import numpy as np
out = {"iterations": [], "solves": [], "done": False}
path, dest = sys.argv[1], sys.argv[2]
def dump():
    out["peak_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    with open(dest, "w") as fh:
        json.dump(out, fh)
import voxflex.deform.solve.newton as newton
from voxflex.scene import Scene
from voxflex.build import build_image, model as build_model
from voxflex.deform.solve.boundary import FORCE_KINDS, FixedRegion, ForceRegion
from voxflex.deform.solve.options import SolverOptions
from voxflex.deform.solve.stepping import solve
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.image.label_image import LabelImage
import voxflex as vf
# warm the kernels on a small beam
warm = VoxelModel.from_image(LabelImage(np.ones((8, 2, 2)), spacing=(0.25,) * 3), {1: vf.material("neo-hookean", young=1e3, poisson=0.3)})
solve(warm, fixed=[FixedRegion([-1, -1, -1], [1e-9, 9, 9])], gravity=[0, 0, -9.81], densities={1: 1.0},
      options=SolverOptions(linear_solver="multigrid"))
inner = newton.solve_linear
def timed(A, b, **kw):
    t = time.perf_counter()
    x, info = inner(A, b, **kw)
    out["solves"].append((time.perf_counter() - t, info.method, int(info.iterations)))
    dump()
    return x, info
newton.solve_linear = timed
scene = Scene.from_toml(path)
model = build_model(scene, image=build_image(scene), cache=False)
out["voxels"], out["dofs"] = int(model.n_elements), int(3 * model.n_nodes)
fixed = [FixedRegion(np.array(f.min), np.array(f.max), components=f.components) for f in scene.fixed]
forces = [ForceRegion(np.array(l.min), np.array(l.max), np.array(l.vector), kind=l.kind)
          for l in scene.loads if l.kind in FORCE_KINDS]
opts = SolverOptions(**dataclasses.asdict(scene.solver))
def cb(info):
    out["iterations"].append((info["label"].split(" (")[0], info["iteration"], info["residual"], info["step_length"]))
t0 = time.perf_counter()
recs = solve(model, fixed=fixed, forces=forces, gravity=np.array(scene.gravity),
             densities={m.label: m.density for m in scene.materials}, options=opts, newton_callback=cb)
out["seconds"] = time.perf_counter() - t0
out["steps"] = [int(r.newton_iterations) for r in recs[1:]]
u = recs[-1].q - model.rest
out["max_u"] = float(np.abs(u).max())
if scene.probes:
    pts = np.array([p.point for p in scene.probes])
    out["probes"] = (model.point_mapping(pts).apply(recs[-1].q) - pts).tolist()
out["done"] = True
dump()
'''


def run(scene: str, package: Path, timeout: float, cap_gb: float = 0.0) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        dest = Path(tmp) / "out.json"
        child = Path(tmp) / "child.py"
        child.write_text(CHILD)
        env = dict(os.environ, PYTHONPATH=str(package), VOXFLEX_PROGRESS="0")
        def limit():  # an address-space cap: a factorisation that outgrows it fails instead of swamping the host
            import resource

            if cap_gb > 0:
                cap = int(cap_gb * 2**30)
                resource.setrlimit(resource.RLIMIT_AS, (cap, cap))

        error = ""
        try:
            proc = subprocess.run([sys.executable, str(child), str(HERE / "scenes" / f"{scene}.toml"), str(dest)],
                                  env=env, timeout=timeout, check=False, capture_output=True, text=True,
                                  preexec_fn=limit)
            timed_out = False
            lines = [ln for ln in proc.stderr.strip().splitlines() if ln.strip()]
            error = lines[-1][:160] if proc.returncode != 0 and lines else ""
        except subprocess.TimeoutExpired:
            timed_out = True
        out = json.loads(dest.read_text()) if dest.exists() else {"iterations": [], "solves": [], "done": False}
        out["timed_out"], out["error"] = timed_out, error
        return out


def row(name, code, r, timeout):
    solves = r.get("solves", [])
    secs = [s[0] for s in solves]
    methods = sorted({s[1] for s in solves})
    lin = f"{len(secs)}, mean {sum(secs) / len(secs):.2f} s, max {max(secs):.1f} s ({', '.join(methods)})" if secs else "-"
    if r.get("done"):
        steps = " / ".join(map(str, r["steps"]))
        total = f"{r['seconds']:.0f} s"
        extra = f"max |u| {r['max_u']:.4g} m" + (f"; probe {r['probes'][0]}" if r.get("probes") else "")
    else:
        steps = f"unfinished: {len(r.get('iterations', []))} Newton iterates"
        total = f"> {timeout:.0f} s (stopped)" if r.get("timed_out") else "failed"
        extra = r.get("error", "")
    dofs = r.get("dofs", "?")
    print(f"| {name} | {code} | {dofs} | {steps} | {lin} | {total} | {r.get('peak_mb', 0):.0f} | {extra} |", flush=True)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenes", default=",".join(SCENES))
    p.add_argument("--before", default=None, help="path of a checkout of the code before (its repository root)")
    p.add_argument("--timeout", type=float, default=900.0)
    p.add_argument("--memory-cap", type=float, default=0.0, metavar="GB",
                   help="address-space limit of each run (the code before factorised at 9-14 GB)")
    a = p.parse_args()
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    print("| scene | code | DOF | Newton iterations per step | linear solves | total | peak MB | answer |")
    print("|---|---|---|---|---|---|---|---|")
    for name in filter(None, a.scenes.split(",")):
        row(name, "now", run(name, HERE.parent, a.timeout, a.memory_cap), a.timeout)
        if a.before:
            row(name, "before", run(name, Path(a.before), a.timeout, a.memory_cap), a.timeout)
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
