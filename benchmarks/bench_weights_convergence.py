"""Frame weights with exact integration: pure bending and the neo-Hooke cantilever, every family.

Every frame model here integrates with 2x2x2 Gauss points per voxel (``quadrature =
"gauss-legendre"``), so the figures measure the weights' kinematics, not the quadrature.  The
families are built as a scene builds them (``vf.model``): natural-neighbour (Sibson), laplace,
distance-ratio and shepard blended by the quadratic B-spline and pruned to the scene's
``parents = 6``; reproducing-kernel never pruned.

1. **Pure bending** (``--part bending``).  Beam [0,4]x[0,1]x[0,1] on the 32x8x8 image, linear
   isotropic material (E = 1e4, nu = 0.3, strain "linear"), free of supports, loaded on its end
   faces by the tractions of a constant bending moment about y: ``t = +-sigma_xx e_x`` with
   ``sigma_xx = -E kappa (z - 1/2)`` (kappa = 1e-3; 2x2 Gauss points per boundary voxel face).  The
   exact solution is Saint-Venant's pure bending (a quadratic field; ``sigma_xx`` the only stress),
   whose compliance is ``f . u = E I kappa^2 L`` (I = 1/12, L = 4).  The frame model solves
   ``K q = f`` orthogonal to its rigid modes (f is self-equilibrated); the **stiffness ratio** is
   ``E I kappa^2 L / (f . q)``: 1 when the weights can represent the quadratic field, above 1 when
   the kinematics lock (a conforming model with exact integration is never below 1).  The voxel
   model (trilinear, same image) is given for reference.
2. **Neo-Hooke cantilever** (``--part cantilever``): ``examples/cantilever.toml`` at 32x8x8
   (voxel 0.125), neo-Hooke E = 1e3, nu = 0.3, rho g = 9.81 along -z, clamp x = 0, 5 load steps;
   tip u_z at (4, 0.5, 0.5).  Voxel model on the same image: -2.687096 (solved and timed in the first
   row); converged: -2.7087.  ``--quadratures gauss-legendre,elaston`` adds the elaston rows (the default
   region count the builder chooses), ``--placements volume,strain`` the frames placed by the first
   solve's strain energy (``[nodes] placement = "strain"``; not for eigenmode weights, whose frames are
   their modes' Q-DEIM points).  ``frames`` is what the model got: eigenmode weights complete a
   degenerate cluster of modes (a square section's pair), so they may have one more than asked.
3. **Support** (``--part support``): the reproducing-kernel radius (in local frame spacings)
   against parents per point, bending ratio and cantilever tip.
5. **Cost** (``--part cost``): precompute and one assembly of the stiffness at rest (``model.hessian``)
   on the cantilever with Gauss points, per family and count: the assembly grows as parents^2 per
   sample, and eigenmode weights make every frame a parent of every point.
6. **Bunny** (``--part bunny``): ``../shared/meshes/stanford-bunny.obj`` (y-up) at ``--voxel`` (default
   3 mm), linear Hooke E = 3e4, nu = 0.3, density 100, the lowest 10 % of its height clamped, gravity
   along -z after turning up; frames (``--counts``, default 40) with reproducing-kernel weights and Gauss
   points, placement volume vs strain, against the voxel model of the same image: the RMS over the
   boundary voxels' centres of |u_frames - u_voxel|, relative to the RMS of |u_voxel| there.
7. **Parents** (``--part parents``): the pure-bending ratio of 20 frames per family as the weights are cut
   to ``--parents`` (default 4,6,8,12,20; 20 keeps every frame).  A conforming model with exact
   integration is never below 1: a ratio below 1 (or one that rises as parents are added) is the cut's
   own softness (the kept weights renormalised jump where the kept set changes), not accuracy.
4. **Conformity** (``--part conformity``): the same reproducing-kernel corner values, either
   interpolated trilinearly (the shipped construction: C0, linearly precise everywhere) or blended
   by the quadratic B-spline of :mod:`voxflex.voronoi.smoothing` from the voxel-centre values (C1,
   linearly precise only 1.5 voxels inside the material), bending ratio and cantilever tip.

Times: ``precompute`` = building the model (placement, weights, Gauss samples; the on-disk cache
off), ``solve`` = the static solve (bending: one sparse saddle-point solve; cantilever: 5 load
steps of Newton with the dense Cholesky of the frame model), min / median over ``--repeat`` runs
(kernels warmed by a first, untimed run of every configuration).  The load average is printed.

Usage: python benchmarks/bench_weights_convergence.py [--part bending|cantilever|support|conformity|cost|bunny|parents|all]
       [--counts 10,20,40] [--kinds natural-neighbour,...] [--repeat 3] [--quadratures gauss-legendre,elaston]
       [--placements volume,strain] [--voxel 0.003]
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
import scipy.sparse as sp
import scipy.sparse.linalg as spl

import voxflex as vf
from voxflex.scene import ElasticitySpec, MaterialSpec, NodesSpec, ObjectSpec, Scene, SolverSpec

KINDS = ("natural-neighbour", "laplace", "distance-ratio", "shepard", "reproducing-kernel", "eigenmode")
E_BEND, NU, KAPPA = 1e4, 0.3, 1e-3
VOXEL_TIP, CONVERGED_TIP = -2.687096, -2.7087
ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")


def _quiet(f, *a, **k):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return f(*a, **k)


def _times(ts):
    return f"{min(ts):.2f} / {statistics.median(ts):.2f}"


# ----------------------------------------------------------------------------- pure bending
def _face_points(x, h=0.125, ny=8, nz=8):
    g = 0.5 / np.sqrt(3.0)
    loc = np.array([0.5 - g, 0.5 + g])
    ys = ((np.arange(ny)[:, None] + loc[None]) * h).ravel()
    zs = ((np.arange(nz)[:, None] + loc[None]) * h).ravel()
    Y, Z = np.meshgrid(ys, zs, indexing="ij")
    return np.stack([np.full(Y.size, x), Y.ravel(), Z.ravel()], 1), np.full(Y.size, h * h / 4)


def bending_scene(nodes):
    return Scene(object=ObjectSpec(shape="box", size=(4.0, 1.0, 1.0), voxel_size=0.125),
                 materials=(MaterialSpec(model="hooke", young=E_BEND, poisson=NU, strain="linear"),),
                 nodes=nodes, elasticity=ElasticitySpec(quadrature="gauss-legendre", strain="linear"))


def bending_ratio(model):
    """(stiffness ratio, solve seconds) of a model of the bending beam (see the module docstring)."""
    q0 = model.rest
    t = time.perf_counter()
    K = sp.csr_matrix(model.hessian(q0))
    R = model.rigid_modes()
    f = np.zeros(q0.size)
    for x, sgn in ((0.0, -1.0), (4.0, 1.0)):
        pts, area = _face_points(x)
        F = np.zeros((len(pts), 3))
        F[:, 0] = sgn * (-E_BEND * KAPPA * (pts[:, 2] - 0.5)) * area
        f += np.asarray(model.point_mapping(pts).vjp(q0, F)).ravel()
    A = sp.bmat([[K, sp.csr_matrix(R)], [sp.csr_matrix(R.T), None]]).tocsc()
    sol = spl.spsolve(A, np.concatenate([f, np.zeros(R.shape[1])]))
    ts = time.perf_counter() - t
    return E_BEND * KAPPA ** 2 / 12.0 * 4.0 / float(f @ sol[:q0.size]), ts


def _build(scene):
    t = time.perf_counter()
    model = _quiet(vf.model, scene, cache=False)
    return model, time.perf_counter() - t


def bending(kinds, counts, repeat):
    print("\n### Pure bending, linear, 2x2x2 Gauss points: stiffness ratio (exact compliance / model's)\n")
    voxel, _ = _build(bending_scene(NodesSpec(kind="voxel")))
    rv, tv = bending_ratio(voxel)
    print(f"Voxel model (trilinear, 32x8x8, {voxel.rest.size} DOF): ratio {rv:.5f}\n")
    print("| weights | frames | parents | ratio | precompute s (min / median) | solve s (min / median) |")
    print("|---|---|---|---|---|---|")
    for kind in kinds:
        for n in counts:
            scene = bending_scene(NodesSpec(kind="affine", count=n, shape_function=kind))
            _build(scene)  # warm
            tp, tsl = [], []
            for _ in range(repeat):
                model, t = _build(scene)
                tp.append(t)
                ratio, ts = bending_ratio(model)
                tsl.append(ts)
            print(f"| {kind} | {n} | {model.info['parents']} | {ratio:.5f} | {_times(tp)} | {_times(tsl)} |", flush=True)


def parents_sweep(kinds, parents, n=20):
    print(f"\n### Pure bending, {n} frames, 2x2x2 Gauss points: stiffness ratio as the weights are cut to P parents\n")
    print("| weights | " + " | ".join(f"P = {p}" for p in parents) + " |")
    print("|---|" + "---|" * len(parents))
    for kind in kinds:
        if kind in ("reproducing-kernel", "eigenmode"):
            continue  # never cut (their partition of unity and linear precision need every parent)
        row = []
        for p in parents:
            model, _ = _build(bending_scene(NodesSpec(kind="affine", count=n, shape_function=kind, parents=p)))
            row.append(f"{bending_ratio(model)[0]:.4f}")
        print(f"| {kind} | " + " | ".join(row) + " |", flush=True)


# ----------------------------------------------------------------------------- cantilever
def cantilever_scene(nodes, quadrature="gauss-legendre"):
    base = Scene.from_toml(os.path.join(ROOT, "examples", "cantilever.toml"))
    return replace(base, object=replace(base.object, voxel_size=0.125), nodes=nodes,
                   materials=(MaterialSpec(model="neo-hookean", young=1e3, poisson=0.3, density=1.0),),
                   elasticity=ElasticitySpec(quadrature=quadrature if nodes.kind != "voxel" else None),
                   solver=SolverSpec(steps=5))


def _tip(scene, model):
    t = time.perf_counter()
    r = vf.simulate(scene, model=model, progress=False)
    return float(r.probe_displacements()["tip"][2]), int(r.newton_iterations.sum()), time.perf_counter() - t


def cantilever(kinds, counts, repeat, quadratures=("gauss-legendre",), placements=("volume",)):
    print("\n### Neo-Hooke cantilever 32x8x8: tip u_z\n")
    print(f"Voxel model on the image: {VOXEL_TIP}; converged: {CONVERGED_TIP}.\n")
    print("| quadrature | weights | placement | frames (asked / got) | parents | u_z (m) | error vs voxel model "
          "| error vs converged | Newton it. | precompute s (min / median) | solve s (min / median) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    scene = cantilever_scene(NodesSpec(kind="voxel"))
    tp, tsl = [], []
    for rep in range(repeat + 1):
        model, t = _build(scene)
        u, its, ts = _tip(scene, model)
        if rep:
            tp.append(t)
            tsl.append(ts)
    print(f"| 2x2x2 Gauss | voxel model (trilinear) | - | {model.rest.size} DOF | 8 | {u:.6f} | "
          f"{100 * (u - VOXEL_TIP) / abs(VOXEL_TIP):+.2f} % | {100 * (u - CONVERGED_TIP) / abs(CONVERGED_TIP):+.2f} % "
          f"| {its} | {_times(tp)} | {_times(tsl)} |", flush=True)
    for quadrature in quadratures:
        for kind in kinds:
            for placement in placements:
                if placement != "volume" and kind == "eigenmode":
                    continue  # its frames are the modes' points
                for n in counts:
                    scene = cantilever_scene(NodesSpec(kind="affine", count=n, shape_function=kind,
                                                       placement=placement), quadrature)
                    tp, tsl = [], []
                    for rep in range(repeat + (1 if n == counts[0] else 0)):  # the first count warms the kernels
                        model, t = _build(scene)
                        u, its, ts = _tip(scene, model)
                        if rep or n != counts[0]:
                            tp.append(t)
                            tsl.append(ts)
                    print(f"| {quadrature} | {kind} | {placement} | {n} / {len(model.frames)} | {model.info['parents']} "
                          f"| {u:.6f} | {100 * (u - VOXEL_TIP) / abs(VOXEL_TIP):+.2f} % "
                          f"| {100 * (u - CONVERGED_TIP) / abs(CONVERGED_TIP):+.2f} % | {its} | {_times(tp)} "
                          f"| {_times(tsl)} |", flush=True)


# ----------------------------------------------------------------------------- cost of the families
def cost(kinds, counts, repeat):
    print("\n### Cost: cantilever 32x8x8 (16384 Gauss points), precompute and one stiffness assembly at rest\n")
    print("| weights | frames | parents | precompute s (min / median) | stiffness assembly s (min / median) |")
    print("|---|---|---|---|---|")
    for kind in kinds:
        for n in counts:
            scene = cantilever_scene(NodesSpec(kind="affine", count=n, shape_function=kind))
            tp, ta = [], []
            for rep in range(repeat + (1 if n == counts[0] else 0)):
                model, t = _build(scene)
                t0 = time.perf_counter()
                model.hessian(model.rest)
                if rep or n != counts[0]:
                    tp.append(t)
                    ta.append(time.perf_counter() - t0)
            extra = ""
            if kind == "eigenmode":
                sec = model.shape_function.seconds
                extra = " (" + ", ".join(f"{k} {v:.2f}" for k, v in sec.items()) + " s in the last run)"
            print(f"| {kind} | {len(model.frames)} | {model.info['parents']} | {_times(tp)}{extra} | {_times(ta)} |",
                  flush=True)


# ----------------------------------------------------------------------------- the bunny
def bunny_scene(nodes, voxel):
    from voxflex.rasterize import load_mesh

    mesh = os.path.join(ROOT, "..", "shared", "meshes", "stanford-bunny.obj")
    lo, hi = load_mesh(mesh).bounds()
    base = Scene.from_toml_text(f"""
[object]
mesh = "{mesh}"
voxel_size = {voxel}
keep = "largest"
up = "y"
[[material]]
model = "hooke"
strain = "linear"
young = 3e4
poisson = 0.3
density = 100.0
[elasticity]
strain = "linear"
[[fixed]]
min = [-1e9, -1e9, -1e9]
max = [1e9, 1e9, {lo[1] + 0.1 * (hi[1] - lo[1])}]
[[load]]
kind = "gravity"
vector = [0.0, 0.0, -9.81]
""")
    quadrature = "gauss-legendre" if nodes.kind != "voxel" else None
    return replace(base, nodes=nodes, elasticity=replace(base.elasticity, quadrature=quadrature))


def _surface_u(scene, model, points):
    t = time.perf_counter()
    r = vf.simulate(scene, model=model, progress=False)
    ts = time.perf_counter() - t
    q = np.asarray(r.nodes_state[-1], dtype=float).ravel()
    return np.asarray(model.point_mapping(points).apply(q)).reshape(-1, 3) - points, ts


def bunny(counts, repeat, voxel, placements):
    from scipy import ndimage

    print(f"\n### Bunny at {1000 * voxel:g} mm, linear, base clamped, gravity: relative RMS surface error "
          "against the voxel model of the same image\n")
    scene = bunny_scene(NodesSpec(kind="voxel"), voxel)
    tp, tsl = [], []
    for _ in range(repeat):
        ref, t = _build(scene)
        tp.append(t)
        m = ref.image.labels > 0
        surf = m & ~ndimage.binary_erosion(m, border_value=0)
        pts = ref.image.index_to_world(np.argwhere(surf) + 0.5)
        u_ref, ts = _surface_u(scene, ref, pts)
        tsl.append(ts)
    scale = float(np.sqrt(np.mean(np.sum(u_ref ** 2, axis=1))))
    print(f"{int(m.sum())} voxels {ref.image.shape}, {len(pts)} boundary voxels; voxel model {ref.rest.size} DOF: "
          f"RMS |u| {scale:.4g} m, build {_times(tp)} s, solve {_times(tsl)} s (min / median)\n")
    print("| weights | placement | frames | parents | RMS surface error | max surface error | precompute s "
          "(min / median) | solve s (min / median) |")
    print("|---|---|---|---|---|---|---|---|")
    for placement in placements:
        for n in counts:
            sc = bunny_scene(NodesSpec(kind="affine", count=n, shape_function="reproducing-kernel",
                                       placement=placement), voxel)
            tp, tsl = [], []
            for _ in range(repeat):
                model, t = _build(sc)
                u, ts = _surface_u(sc, model, pts)
                tp.append(t)
                tsl.append(ts)
            err = np.sqrt(np.sum((u - u_ref) ** 2, axis=1))
            print(f"| reproducing-kernel | {placement} | {len(model.frames)} | {model.info['parents']} | "
                  f"{100 * np.sqrt(np.mean(err ** 2)) / scale:.2f} % | {100 * err.max() / scale:.1f} % | "
                  f"{_times(tp)} | {_times(tsl)} |", flush=True)


# ----------------------------------------------------------------------------- support and conformity
def support(counts, supports):
    print("\n### Reproducing-kernel support (kernel radius in local frame spacings)\n")
    print("| support | frames | parents | grown frames | fallback corners | bending ratio | cantilever u_z | "
          "error vs voxel model | precompute s | solve s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for s in supports:
        for n in counts:
            nodes = NodesSpec(kind="affine", count=n, shape_function="reproducing-kernel", support=s)
            m, _ = _build(bending_scene(nodes))
            ratio, _ = bending_ratio(m)
            scene = cantilever_scene(nodes)
            model, tp = _build(scene)
            u, _, ts = _tip(scene, model)
            print(f"| {s} | {n} | {model.info['parents']} | {model.info['kernel_grown_frames']} | "
                  f"{model.info['kernel_fallback_corners']} | {ratio:.5f} | {u:.6f} | "
                  f"{100 * (u - VOXEL_TIP) / abs(VOXEL_TIP):+.2f} % | {tp:.2f} | {ts:.2f} |", flush=True)


class _Blended:
    """The reproducing-kernel voxel-centre values blended by the quadratic B-spline (smoothing.py)."""

    def __init__(self, rk):
        from voxflex.voronoi.smoothing import SmoothWeights

        vv = rk.voxel_values()
        self.frames = rk.frames
        self._s = SmoothWeights(rk.image, vv.index, vv.w, len(rk.frames))

    def __call__(self, points):
        return self._s(points)


def conformity(counts):
    from voxflex.build import build_image
    from voxflex.deform.materials.constitutive import material
    from voxflex.deform.models.frames.build import _clamp_owners
    from voxflex.deform.models.frames.model import FrameModel
    from voxflex.voronoi import place_frames, shape_function

    print("\n### Reproducing kernels: trilinear interpolation of the corner values against the B-spline blend\n")
    print("| construction | frames | linear precision error (max over Gauss points) | bending ratio | cantilever u_z | "
          "error vs voxel model |")
    print("|---|---|---|---|---|---|")
    for n in counts:
        for blend in (False, True):
            rows = []
            for which in ("bending", "cantilever"):
                scene = (bending_scene if which == "bending" else cantilever_scene)(
                    NodesSpec(kind="affine", count=n, shape_function="reproducing-kernel"))
                image = build_image(scene)
                fixed = [(np.asarray(f.min, float), np.asarray(f.max, float)) for f in scene.fixed]
                frames = place_frames(image, n, fixed=fixed, seed=0)
                rk = _quiet(shape_function, image, frames, kind="reproducing-kernel",
                            seed_owner=_clamp_owners(image, frames, fixed))
                sf = _Blended(rk) if blend else rk
                m = scene.materials[0]
                mat = material(m.model, young=m.young, poisson=m.poisson,
                               **({"strain": m.strain} if m.strain else {}))
                model = FrameModel.from_image(image, frames, sf, {1: mat}, quadrature="gauss-legendre")
                if which == "bending":
                    lp = model.samples.values.linear_precision_error(frames)
                    rows.append(lp)
                    rows.append(bending_ratio(model)[0])
                else:
                    rows.append(_tip(scene, model)[0])
            name = "B-spline blend of the centre values (C1)" if blend else "trilinear corners (C0, shipped)"
            print(f"| {name} | {n} | {rows[0]:.1e} | {rows[1]:.5f} | {rows[2]:.6f} | "
                  f"{100 * (rows[2] - VOXEL_TIP) / abs(VOXEL_TIP):+.2f} % |", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--part", default="all",
                    choices=["bending", "cantilever", "support", "conformity", "cost", "bunny", "parents", "all"])
    ap.add_argument("--parents", default="4,6,8,12,20", help="parents: the cuts to compare")
    ap.add_argument("--quadratures", default="gauss-legendre", help="cantilever: gauss-legendre,elaston,midpoint")
    ap.add_argument("--placements", default="volume", help="cantilever and bunny: volume,strain")
    ap.add_argument("--voxel", type=float, default=0.003, help="bunny voxel size (m)")
    ap.add_argument("--counts", default=None, help="frame counts (default 10,20,40 bending; 5,...,80 cantilever)")
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--supports", default="1.5,2.0,2.5,3.0")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, python {platform.python_version()}, "
          f"voxflex {vf.__version__}, load average {os.getloadavg()[0]:.2f}")
    kinds = args.kinds.split(",")
    pick = (lambda d: [int(c) for c in (args.counts or d).split(",")])
    if args.part in ("bending", "all"):
        bending(kinds, pick("10,20,40"), args.repeat)
    if args.part in ("cantilever", "all"):
        cantilever(kinds, pick("5,10,20,40,80"), args.repeat, args.quadratures.split(","),
                   args.placements.split(","))
    if args.part in ("support", "all"):
        support(pick("10,20,40"), [float(s) for s in args.supports.split(",")])
    if args.part in ("parents", "all"):
        parents_sweep(kinds, [int(p) for p in args.parents.split(",")])
    if args.part in ("conformity", "all"):
        conformity(pick("10,20,40"))
    if args.part in ("cost", "all"):
        cost(kinds, pick("10,20,40,80"), args.repeat)
    if args.part == "bunny":  # minutes: only when asked
        bunny(pick("40"), args.repeat, args.voxel, args.placements.split(","))
    print(f"\nload average at the end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
