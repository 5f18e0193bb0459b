"""Frames with the default weights and quadrature on real meshes, against the voxel model (issue 24's "must show").

"The defaults" here are what the bundled default scene names (the library default stays natural-neighbour
weights with stabilised mid-point regions, see the README): reproducing-kernel weights (``[nodes]
shape_function = "reproducing-kernel"``, linearly precise, never truncated) integrated with elastons
(``[elasticity] quadrature = "elaston"``, moment-fitted sub-rules of the Gauss points), named explicitly
in every scene this script builds.  This script measures, on the
shared real meshes (``../shared/meshes``), whether they win the trade they exist for: frames within 5 %
RMS surface error at >= 5x less total time than the voxel grid of equal error.

Parts (``--part``):

``bunny``
    ``stanford-bunny.obj`` (y-up, turned z-up) at ``--voxel`` (default 2 mm), the largest component,
    neo-Hookean E = 3e4 Pa, nu = 0.3, density 100 kg/m^3, the lowest 10 % of its height clamped, gravity
    along -z, one static load step (Newton to the scene's tolerance).  Rows: the full voxel model (the
    reference: trilinear, 2x2x2 Gauss points, 1 run), the voxel model on grids 2x and 4x coarser (the
    image's 2x2x2 blocks merged, as ``voxflex tradeoff --voxel-levels`` does), ``--counts`` frames with
    the defaults (RK + elastons), the same frames with Gauss-Legendre points (2x2x2 per voxel: exact
    integration) at ``--exact-counts``, and natural-neighbour weights with elastons at
    ``--nn-counts`` (for comparison: the old weights) and the same with Gauss-Legendre at
    ``--nn-exact-counts``; ``--strain-counts`` adds RK + elastons with the frames
    placed by a first cheap solve's strain energy (``[nodes] placement = "strain"``).
``second``
    A second real mesh, ``--mesh2`` (default ``rocker-arm.obj``: watertight, a mechanical lever with
    holes and a slender arm, so bending and geodesic weights matter, unlike the compact bunny) at
    ``--voxel2`` (mesh units; default 0.01, ~42k voxels), neo-Hookean, nu = 0.3, the lowest 10 % along its
    longest axis clamped, gravity along the shortest axis, E chosen so that rho g L / E is the bunny's
    (the same dimensionless sag).  Same rows at ``--counts2``.
``dynamics``
    The bunny at ``--dyn-voxel`` (default 3 mm), same material and clamp, released from rest under
    gravity, implicit Euler with dt = ``--dt`` (default 5 ms, about 1/25 of the first period), ``--steps``
    (default 20) steps; ``--dyn-count`` (default 60) frames with the defaults against the voxel model:
    milliseconds per step (a 20-step run divided by its steps; warm: after an untimed run) and the
    trajectory error (max over the steps of the RMS surface error, relative to the largest reference
    surface displacement over all steps).  ``--dyn-placement strain`` places the frames by a first cheap
    solve's strain energy, ``--dyn-samples N`` sets the elaston regions (the default is the frames' own count:
    at least one region per 10 voxels), ``--dyn-exact`` adds each row's exact-integration twin (the same
    frames with Gauss-Legendre points: an elaston row whose error is below its twin's is under-integrated,
    the difference is a cancellation, not accuracy).
``profile``
    The bunny at ``--voxel`` with 40 frames and the defaults: wall time of the precompute (``vf.model``,
    the on-disk cache off; warm: numba compiled by an untimed run first), min / median of ``--repeat``,
    and the cProfile top entries (cumulative and own time) of one more run.

Errors.  The surface is the voxelized boundary (the result's ``surface_rest`` vertices).  ``RMS/max`` is
``voxflex tradeoff``'s ``surface_error``: the RMS over the surface vertices of |u - u_ref|, divided by the
largest reference surface displacement (max over states for dynamics).  ``RMS/RMS`` divides by the RMS of
|u_ref| instead (stricter: the bunny's base barely moves).  Coarser voxel grids are compared at the
vertices their surface shares with the reference's (the fraction is printed).

Memory.  The last column is the process's peak resident set so far (it only grows: a jump names the row).
At 2 mm the bunny's rows with many parents per point reach 8.4 GB together (Gauss-Legendre points carry
parents^2 pair tables: 754k points x 35^2 at 40 frames; 160 RK frames have 89 parents): run those in a
process of their own (``--counts "" --exact-counts 40 --nn-counts ""`` etc.) under a memory limit.

Times.  Every model is solved by the same Newton solver at the scene's tolerance, each with its own
``linear_solver = "auto"`` (a best-solver comparison: multigrid-CG or sparse direct for the voxel grids,
dense Cholesky for the frames).  BLAS, OpenMP and numba pinned to one thread (as ``voxflex tradeoff`` does: figures of one core,
comparable on a shared machine).  Every kernel is warmed by an untimed run of each configuration's family
on the 4x coarser grid first.  ``precompute`` = ``vf.model(scene, cache=False)`` (placement, weights,
samples, checks; voxel: element tables), ``solve`` = ``vf.simulate``; min / median over ``--repeat``
runs for the cheap rows (``runs`` column says how many), one run for the slow ones (the reference voxel
model, Gauss-Legendre frames).  ``total`` = median precompute + median solve.  The load average is
printed before and after every table: the machine is shared.

Examples::

    python benchmarks/bench_real_frames.py --part bunny                     # 2 mm, 20/40/80 frames
    python benchmarks/bench_real_frames.py --part bunny --voxel 0.003 --counts 20,40,80,160
    python benchmarks/bench_real_frames.py --part second --mesh2 fandisk.obj --voxel2 0.05
    python benchmarks/bench_real_frames.py --part dynamics --dyn-counts 60 --steps 20
    python benchmarks/bench_real_frames.py --part dynamics --dyn-weights natural-neighbour --dyn-placement strain \
        --dyn-samples 1400 --dyn-exact
    python benchmarks/bench_real_frames.py --part profile --voxel 0.002
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import io
import os
import platform
import pstats
import statistics
import time
import warnings
from dataclasses import replace

import numpy as np

import voxflex as vf
from voxflex.build import build_image
from voxflex.scene import NodesSpec, Scene
from voxflex.sweep import _image_at_level, _surface_error
from voxflex.sweep_runs import _pinned

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
MESHES = os.path.join(ROOT, "..", "shared", "meshes")
SAG = 100.0 * 9.81 * 0.155699 / 3e4  # the bunny's rho g L / E: the same dimensionless load on every mesh


def _machine() -> str:
    return (f"{platform.machine()}, {os.cpu_count()} cores, python {platform.python_version()}, voxflex "
            f"{vf.__version__}, timings on 1 thread (BLAS, OpenMP, numba pinned)")


def _load() -> str:
    return "load average " + " / ".join(f"{x:.2f}" for x in os.getloadavg()) + " (1 / 5 / 15 min)"


def _rss_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


# ----------------------------------------------------------------------------- scenes
def mesh_scene(mesh, voxel, *, young, up=None, dynamics=None):
    """A real mesh clamped over the lowest 10 % of its longest axis (the height for the bunny), gravity
    across.  ``dynamics`` = (dt, steps) for implicit Euler."""
    from voxflex.rasterize import load_mesh

    path = os.path.join(MESHES, mesh)
    up_line = f'up = "{up}"' if up else ""
    probe = Scene.from_toml_text(f'[object]\nmesh = "{path}"\nvoxel_size = {voxel}\nkeep = "largest"\n{up_line}\n'
                                 '[[material]]\nmodel = "neo-hookean"\n[nodes]\nkind = "voxel"\n')
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lo, hi = _bounds(probe) if up else load_mesh(path).bounds()
    ext = hi - lo
    axis = 2 if up else int(np.argmax(ext))  # clamp along z (the height) after turning up, else the longest axis
    across = 2 if up else int(np.argmin(ext))
    if axis == across:
        across = int(np.argsort(ext)[1])
    cmin, cmax = [-1e9] * 3, [1e9] * 3
    cmax[axis] = lo[axis] + 0.1 * ext[axis]
    g = [0.0, 0.0, 0.0]
    g[across] = -9.81
    solver = ""
    if dynamics:
        solver = f'[solver]\nkind = "implicit-euler"\ndt = {dynamics[0]}\nsteps = {dynamics[1]}\n'
    return Scene.from_toml_text(f"""
[object]
mesh = "{path}"
voxel_size = {voxel}
keep = "largest"
{up_line}
[[material]]
model = "neo-hookean"
young = {young}
poisson = 0.3
density = 100.0
[[fixed]]
min = [{', '.join(f'{float(x):.9g}' for x in cmin)}]
max = [{', '.join(f'{float(x):.9g}' for x in cmax)}]
[[load]]
kind = "gravity"
vector = [{', '.join(f'{float(x):g}' for x in g)}]
{solver}""")


def _bounds(scene):
    img = build_image(scene)
    idx = np.argwhere(img.labels > 0)
    lo = img.index_to_world(idx.min(0).astype(float))
    hi = img.index_to_world(idx.max(0).astype(float) + 1.0)
    return np.minimum(lo, hi), np.maximum(lo, hi)


PARENTS = None  # --parents: [nodes] parents of every frame row (the scene's default when not given)


def configure(scene, *, kind="affine", count=None, sf=None, q=None, placement=None):
    """``scene`` with these nodes: sf / q None give RK + elastons, named explicitly (a scene that names no
    shape_function gets the frame builder's own fallback, natural-neighbour, whatever the kind declares)."""
    if kind == "voxel":
        return replace(scene, nodes=NodesSpec(kind="voxel"), elasticity=replace(scene.elasticity,
                                                                                 quadrature="gauss-legendre"))
    nodes = NodesSpec(kind="affine", count=count, shape_function=sf or "reproducing-kernel", placement=placement,
                      parents=PARENTS or NodesSpec.parents)
    return replace(scene, nodes=nodes, elasticity=replace(scene.elasticity, quadrature=q or "elaston"))


# ----------------------------------------------------------------------------- measuring
def run(scene, image, runs):
    """(runs of (precompute s, solve s), model, result of the first run)."""
    times, first = [], None
    with warnings.catch_warnings(), _pinned():
        warnings.simplefilter("ignore")
        for _ in range(runs):
            t0 = time.perf_counter()
            m = vf.model(scene, image=image, cache=False)
            t1 = time.perf_counter()
            r = vf.simulate(scene, model=m, progress=False)
            times.append((t1 - t0, time.perf_counter() - t1))
            if first is None:
                first = (m, r)
    return times, first[0], first[1]


def _record(model, result):
    return {"surface_rest": np.asarray(result.surface_rest), "surface_positions": np.asarray(result.surface_positions),
            "voxel_size": float(np.max(model.image.spacing)) if hasattr(model, "image") else np.nan}


def errors(rec, ref):
    """(RMS / max |u_ref|, RMS / RMS |u_ref|, max / max |u_ref|, fraction of this model's vertices compared): each
    the largest over the states of the error, over the largest over the states of the reference's scale; RMS |u_ref|
    over the compared vertices."""
    from scipy.spatial import cKDTree

    rms_max, _, frac = _surface_error(rec, ref)
    Vr, Xr, Vm, Xm = ref["surface_rest"], ref["surface_positions"], rec["surface_rest"], rec["surface_positions"]
    if Vm.shape == Vr.shape and np.allclose(Vm, Vr):
        im = ir = np.arange(len(Vr))
    else:
        d, idx = cKDTree(Vr).query(Vm, distance_upper_bound=1e-6 * min(ref["voxel_size"], rec["voxel_size"]))
        im = np.flatnonzero(np.isfinite(d))
        ir = idx[im]
    ur = Xr[:, ir] - Vr[None, ir]
    diff = (Xm[:, im] - Vm[None, im]) - ur
    e = np.linalg.norm(diff, axis=2)
    scale_max = float(np.max(np.linalg.norm(Xr - Vr[None], axis=2)))
    rms_ref = float(np.max(np.sqrt(np.mean(np.sum(ur ** 2, axis=2), axis=1))))  # largest over the states
    rms_rms = float(np.max(np.sqrt(np.mean(e ** 2, axis=1)))) / rms_ref if rms_ref > 0 else float("nan")
    return rms_max, rms_rms, float(e.max()) / scale_max, frac


def _largest(image, what):
    """``image`` with only its largest face-connected material component (merging 2x2x2 blocks can leave
    islands held by an edge or a corner, which a static solve refuses); says how many voxels it dropped."""
    from scipy import ndimage

    from voxflex.image import LabelImage

    comp, n = ndimage.label(image.labels > 0)
    if n <= 1:
        return image
    sizes = np.bincount(comp.ravel())[1:]
    keep = comp == 1 + int(np.argmax(sizes))
    print(f"{what}: kept the largest of {n} face-connected components, dropped {int(sizes.sum() - sizes.max())} "
          "voxel(s)")
    occ = None if image.occupancy is None else np.where(keep, np.asarray(image.occupancy), 0.0)
    return LabelImage(np.where(keep, image.labels, 0).astype(image.labels.dtype), spacing=image.spacing,
                      origin=image.origin, direction=image.direction, occupancy=occ)


def _t(ts):
    return f"{min(ts):.2f} / {statistics.median(ts):.2f}"


def static_table(title, base, *, counts, exact_counts, nn_counts, repeat, levels=(1, 2), extra_counts=(),
                 strain_counts=(), nn_exact_counts=()):
    """The table of one mesh: the voxel model (reference), coarser grids, frames (defaults, exact, NN)."""
    print(f"\n### {title}\n")
    print(_load())
    image = build_image(base)
    coarse = {lv: _largest(_image_at_level(image, -lv), f"{2 ** lv}x coarser grid") for lv in levels}
    warm_image = coarse[max(levels)]
    # warm every family's kernels untimed on the coarsest grid
    t0 = time.perf_counter()
    for sc in (configure(base, kind="voxel"), configure(base, count=10), configure(base, count=10, q="gauss-legendre"),
               configure(base, count=10, sf="natural-neighbour")):
        run(sc, warm_image, 1)
    print(f"warm-up (untimed, {time.perf_counter() - t0:.1f} s on the {max(levels)}x coarser grid)")
    nvox = int((image.labels > 0).sum())
    rows = []
    (times, model, result) = run(configure(base, kind="voxel"), image, repeat)  # timed like the rows it is compared with
    ref = _record(model, result)
    ref["voxel_size"] = float(np.max(image.spacing))
    u = np.linalg.norm(ref["surface_positions"][-1] - ref["surface_rest"], axis=1)
    print(f"image {image.shape}, voxel {float(np.max(image.spacing)):.4g}, {nvox} material voxels, "
          f"{len(ref['surface_rest'])} surface vertices; reference max |u| {u.max():.4g}, RMS |u| "
          f"{np.sqrt(np.mean(u ** 2)):.4g} (Newton {int(np.sum(result.newton_iterations))}); "
          f"max RSS {_rss_mb():.0f} MB",
          flush=True)
    rows.append(("voxel model (reference)", model.describe()["dofs"], times, (0.0, 0.0, 0.0, 1.0),
                 int(np.sum(result.newton_iterations))))

    def add(label, scene, img, runs):
        times, m, r = run(scene, img, runs)
        rec = _record(m, r)
        rec["voxel_size"] = float(np.max(img.spacing))
        d = m.describe()
        extra = f", {d.get('parents', '')} parents" if "parents" in d else ""
        rows.append((label + extra, d["dofs"], times, errors(rec, ref), int(np.sum(r.newton_iterations))))
        _print_row(rows[-1], header=False)

    _print_row(None, header=True)
    _print_row(rows[0], header=False)
    for lv in levels:
        add(f"voxel grid {2 ** lv}x coarser ({float(np.max(coarse[lv].spacing)):.4g})",
            configure(base, kind="voxel"), coarse[lv], repeat)
    for n in counts:
        add(f"{n} frames RK + elastons (default)", configure(base, count=n), image, repeat)
    for n in extra_counts:
        add(f"{n} frames RK + elastons (default)", configure(base, count=n), image, 1)
    for n in exact_counts:
        add(f"{n} frames RK + Gauss-Legendre (exact)", configure(base, count=n, q="gauss-legendre"), image, 1)
    for n in strain_counts:
        add(f"{n} frames RK + elastons, placement = strain", configure(base, count=n, placement="strain"), image, 1)
    for n in nn_counts:
        add(f"{n} frames natural-neighbour + elastons", configure(base, count=n, sf="natural-neighbour"), image,
            repeat)
    for n in nn_exact_counts:
        add(f"{n} frames natural-neighbour + Gauss-Legendre (exact)",
            configure(base, count=n, sf="natural-neighbour", q="gauss-legendre"), image, 1)
    print(f"\n{_load()}; max RSS {_rss_mb():.0f} MB")
    return rows


def _print_row(row, header):
    if header:
        print("| model | DOF | RMS/max | RMS/RMS | max/max | compared | Newton | runs | precompute s (min / median) "
              "| solve s (min / median) | total s | peak RSS so far MB |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|")
        return
    label, dofs, times, (rm, rr, mx, frac), its = row
    pre, sol = [t[0] for t in times], [t[1] for t in times]
    print(f"| {label} | {dofs:,} | {100 * rm:.2f} % | {100 * rr:.2f} % | {100 * mx:.1f} % | {100 * frac:.0f} % | {its} "
          f"| {len(times)} | {_t(pre)} | {_t(sol)} | {statistics.median(pre) + statistics.median(sol):.2f} "
          f"| {_rss_mb():.0f} |",
          flush=True)


# ----------------------------------------------------------------------------- parts
def part_bunny(args):
    base = mesh_scene("stanford-bunny.obj", args.voxel, young=3e4, up="y")
    static_table(f"Bunny at {1000 * args.voxel:g} mm, neo-Hookean, base clamped, gravity", base,
                 counts=args.counts, exact_counts=args.exact_counts, nn_counts=args.nn_counts, repeat=args.repeat,
                 extra_counts=args.slow_counts, strain_counts=args.strain_counts, nn_exact_counts=args.nn_exact_counts)


def part_second(args):
    from voxflex.rasterize import load_mesh

    lo, hi = load_mesh(os.path.join(MESHES, args.mesh2)).bounds()
    L = float(np.max(hi - lo))
    young = 100.0 * 9.81 * L / SAG
    base = mesh_scene(args.mesh2, args.voxel2, young=f"{young:.6g}")
    static_table(f"{args.mesh2} at voxel {args.voxel2:g} (length {L:.4g}), neo-Hookean E = {young:.4g}, "
                 "lowest 10 % of the longest axis clamped, gravity along the shortest", base,
                 counts=args.counts2, exact_counts=args.exact_counts2, nn_counts=args.nn_counts2, repeat=args.repeat)


def part_dynamics(args):
    base = mesh_scene("stanford-bunny.obj", args.dyn_voxel, young=3e4, up="y", dynamics=(args.dt, args.steps))
    print(f"\n### Dynamics: bunny at {1000 * args.dyn_voxel:g} mm, implicit Euler dt = {args.dt:g} s, {args.steps} "
          f"steps from rest under gravity\n")
    print(_load())
    image = build_image(base)
    warm_image = _largest(_image_at_level(image, -2), "warm-up grid")
    for sc in (configure(base, kind="voxel"), *(configure(base, count=10, sf=None if f == "default" else f)
                                               for f in args.dyn_weights)):
        run(sc, warm_image, 1)
    tv, mv, rv = run(configure(base, kind="voxel"), image, args.repeat)  # min and median of --repeat runs
    ref = _record(mv, rv)
    ref["voxel_size"] = float(np.max(image.spacing))
    n = args.steps
    print("| model | DOF | trajectory error RMS/max | RMS/RMS | Newton (all steps) | runs | precompute s "
          "| ms per step (min / median) |")
    print("|---|---|---|---|---|---|---|---|")
    sv = [1000 * t[1] / n for t in tv]
    print(f"| voxel model (reference) | {mv.describe()['dofs']:,} | 0 | 0 | {int(np.sum(rv.newton_iterations))} "
          f"| {len(tv)} | {min(t[0] for t in tv):.2f} | {min(sv):.1f} / {statistics.median(sv):.1f} |", flush=True)
    rows = [(c, f, q) for f in args.dyn_weights for c in args.dyn_counts
            for q in (("elaston", "gauss-legendre") if args.dyn_exact else ("elaston",))]
    for count, sf, quad in rows:
        sc = configure(base, count=count, sf=None if sf == "default" else sf, q=quad, placement=args.dyn_placement)
        if args.dyn_samples and quad == "elaston":
            sc = replace(sc, elasticity=replace(sc.elasticity, samples=args.dyn_samples))
        times, m, r = run(sc, image, 1)
        with warnings.catch_warnings(), _pinned():  # the model is built; time the stepping alone, warm
            warnings.simplefilter("ignore")
            steps = []
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                vf.simulate(sc, model=m, progress=False)
                steps.append(1000 * (time.perf_counter() - t0) / n)
        rec = _record(m, r)
        rec["voxel_size"] = ref["voxel_size"]
        rm, rr, _, _ = errors(rec, ref)
        d = m.describe()
        integ = (f"{d.get('regions')} elaston regions" if quad == "elaston"
                 else "Gauss-Legendre 2x2x2 per voxel (exact)")
        name = f"{'RK' if sf == 'default' else sf}, {integ}, {d.get('placement')} placement"
        print(f"| {count} frames {name}, {d.get('parents')} parents | "
              f"{m.describe()['dofs']:,} | {100 * rm:.2f} % | {100 * rr:.2f} % | {int(np.sum(r.newton_iterations))} "
              f"| {args.repeat} | {times[0][0]:.2f} | {min(steps):.1f} / {statistics.median(steps):.1f} |", flush=True)
    print(f"\n{_load()}; max RSS {_rss_mb():.0f} MB")


def part_profile(args):
    base = mesh_scene("stanford-bunny.obj", args.voxel, young=3e4, up="y")
    sc = configure(base, count=40)
    print(f"\n### Precompute profile: bunny at {1000 * args.voxel:g} mm, 40 frames, defaults "
          f"({sc.nodes.shape_function} + {sc.elasticity.quadrature})\n")
    print(_load())
    image = build_image(base)
    run(configure(base, count=10), _largest(_image_at_level(image, -2), "warm-up grid"), 1)  # compile the kernels
    import numba

    ts = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for threads, ctx in ((f"{numba.get_num_threads()} threads (default)", contextlib.nullcontext),
                             ("1 thread (pinned)", _pinned)):
            ts[threads] = []
            with ctx():
                for _ in range(args.repeat):
                    t0 = time.perf_counter()
                    m = vf.model(sc, image=image, cache=False)
                    ts[threads].append(time.perf_counter() - t0)
    d = m.describe()
    for threads, t in ts.items():
        print(f"precompute (vf.model, image given, cache off), {threads}, min / median of {args.repeat}: {_t(t)} s")
    print(f"{d['samples']} samples, {d.get('regions')} regions, {d.get('parents')} parents, "
          f"{int((image.labels > 0).sum())} voxels; {_load()}")
    with warnings.catch_warnings(), _pinned():
        warnings.simplefilter("ignore")
        prof = cProfile.Profile()
        prof.enable()
        vf.model(sc, image=image, cache=False)
        prof.disable()
    for key in ("cumulative", "tottime"):
        s = io.StringIO()
        pstats.Stats(prof, stream=s).strip_dirs().sort_stats(key).print_stats(args.top)
        print(f"\ncProfile, sorted by {key} (top {args.top}):\n```")
        print("\n".join(line for line in s.getvalue().splitlines() if line.strip())[-6000:])
        print("```")
    print(f"\n{_load()}")


def main():
    ints = (lambda s: [int(c) for c in s.split(",") if c])
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--part", default="bunny", choices=["bunny", "second", "dynamics", "profile", "all"],
                    help="which table (default bunny; all = the four, tens of minutes)")
    ap.add_argument("--voxel", type=float, default=0.002, help="bunny voxel size in m (default 0.002)")
    ap.add_argument("--counts", type=ints, default=[20, 40, 80], help="bunny frame counts, defaults (RK + elastons)")
    ap.add_argument("--slow-counts", type=ints, default=[], help="bunny counts run once (e.g. 160)")
    ap.add_argument("--exact-counts", type=ints, default=[40], help="bunny counts with Gauss-Legendre (1 run each)")
    ap.add_argument("--nn-counts", type=ints, default=[40], help="bunny counts with natural-neighbour + elastons")
    ap.add_argument("--nn-exact-counts", type=ints, default=[40],
                    help="bunny counts with natural-neighbour + Gauss-Legendre (1 run each)")
    ap.add_argument("--strain-counts", type=ints, default=[], help="bunny counts with [nodes] placement = \"strain\" "
                    "(frames placed by a first cheap solve's strain energy; 1 run each)")
    ap.add_argument("--mesh2", default="rocker-arm.obj", help="second mesh in ../shared/meshes")
    ap.add_argument("--voxel2", type=float, default=0.01, help="its voxel size in mesh units")
    ap.add_argument("--counts2", type=ints, default=[40, 80])
    ap.add_argument("--exact-counts2", type=ints, default=[40])
    ap.add_argument("--nn-counts2", type=ints, default=[40])
    ap.add_argument("--parents", type=int, default=None,
                    help="[nodes] parents of the frame rows (default: the scene's, 6; reproducing-kernel ignores it)")
    ap.add_argument("--dyn-voxel", type=float, default=0.003, help="dynamics: bunny voxel size (m)")
    ap.add_argument("--dyn-counts", type=ints, default=[60], help="dynamics: frame counts")
    ap.add_argument("--dyn-weights", default=["default"], type=lambda s: s.split(","),
                    help="dynamics: shape functions, 'default' (RK) and e.g. natural-neighbour, with elastons")
    ap.add_argument("--dyn-placement", default=None, choices=["volume", "strain"],
                    help="dynamics: [nodes] placement (default: the scene's, volume)")
    ap.add_argument("--dyn-samples", type=int, default=None,
                    help="dynamics: [elasticity] samples, the elaston regions (default: the frames' own count)")
    ap.add_argument("--dyn-exact", action="store_true",
                    help="dynamics: each row also with Gauss-Legendre points (the exact integration twin; slow)")
    ap.add_argument("--dt", type=float, default=0.005, help="dynamics: time step (s)")
    ap.add_argument("--steps", type=int, default=20, help="dynamics: steps")
    ap.add_argument("--repeat", type=int, default=3, help="runs of the cheap rows (min / median)")
    ap.add_argument("--top", type=int, default=25, help="profile: entries printed")
    args = ap.parse_args()
    global PARENTS
    PARENTS = args.parents
    print(f"machine: {_machine()}\n{_load()}")
    parts = ["bunny", "second", "dynamics", "profile"] if args.part == "all" else [args.part]
    for p in parts:
        {"bunny": part_bunny, "second": part_second, "dynamics": part_dynamics, "profile": part_profile}[p](args)
    print(f"\nat the end: {_load()}; max RSS {_rss_mb():.0f} MB")


if __name__ == "__main__":
    with contextlib.suppress(KeyboardInterrupt):
        main()
