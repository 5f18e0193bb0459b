"""voxflex's natural-neighbour weights side by side with libigl's bounded biharmonic weights.

One object, one set of frames, two weight schemes, measured at the same points:

* **voxflex**: :func:`voxflex.voronoi.weights` (natural neighbours, Sibson; the default
  ``parents=4`` and ``parents=8``, blended as models use them) on the label image;
* **BBW**: ``igl.bbw`` (A. Jacobson et al., "Bounded biharmonic weights for real-time
  deformation", SIGGRAPH 2011) on a tet mesh of the same object: the vertices are the material
  voxel centres, every 2x2x2 group of material centres is a hexahedron split into 6 tets along
  its main diagonal (a conforming mesh of the object shrunk by half a voxel), each frame is a
  point handle at its voxel centre (b = that vertex, bc = the identity), the rows normalised
  afterwards as libigl advises.

Measured at the mesh vertices (the voxel centres): time (each scheme warmed, then min and median of
``--repeat`` runs), partition of unity (max |sum w - 1|,
BBW before normalising), the smallest weight, locality (frames with w > 1e-3 per point: mean and
max), linear precision (max |sum_i w_i x_i - x| in voxels, everywhere and inside the frames' hull),
and w_i at frame i (the Kronecker property; the blended voxflex weights smooth it).
Linear precision (sum_i w_i x_i = x) is a property of Sibson coordinates inside the frames'
convex hull only; BBW does not have it.

libigl is an optional, test-free dependency (``pip install libigl``, wheels for CPython on
Linux, macOS and Windows); without it the script says so and stops.

    python benchmarks/bench_weights_vs_libigl.py                 # bar 24 x 12 x 12 voxels, 16 frames
    python benchmarks/bench_weights_vs_libigl.py --shape 30,10,10 --frames 12
"""

from __future__ import annotations

import argparse
import itertools
import os
import platform
import time

import numpy as np


def tet_mesh_of_centres(labels):
    """Vertices (index coords of material voxel centres, (V, 3)) and tets (T, 4) of the voxel-centre
    lattice: each 2x2x2 group of material centres is a cube split into 6 tets around its diagonal."""
    mat = labels > 0
    ijk = np.argwhere(mat)
    vid = -np.ones(labels.shape, dtype=np.int64)
    vid[mat] = np.arange(len(ijk))
    full = mat[:-1, :-1, :-1].copy()
    for o in itertools.product((0, 1), repeat=3):
        full &= mat[o[0]:labels.shape[0] - 1 + o[0], o[1]:labels.shape[1] - 1 + o[1], o[2]:labels.shape[2] - 1 + o[2]]
    base = np.argwhere(full)
    tets = []
    for perm in itertools.permutations(range(3)):
        corners = [np.zeros(3, int)]
        for a in perm:
            c = corners[-1].copy()
            c[a] = 1
            corners.append(c)
        tets.append(np.stack([vid[tuple((base + c).T)] for c in corners], axis=1))
    return ijk + 0.5, np.concatenate(tets).astype(np.int64)


def properties(W, X, frames, interior, frame_rows):
    """Dict of the measured properties of dense weights W (m, n) at points X (m, 3) (voxel units)."""
    s = W.sum(1)
    support = (W > 1e-3).sum(1)
    rec = W @ frames
    err = np.linalg.norm(rec - X, axis=1)
    return {
        "pu": float(np.abs(s - 1).max()),
        "min": float(W.min()),
        "supp_mean": float(support.mean()),
        "supp_max": int(support.max()),
        "lin_all": float(err.max()),
        "lin_in": float(err[interior].max()) if interior.any() else float("nan"),
        "kron": float(W[frame_rows, np.arange(len(frames))].min()),
    }


def dense(sv, n):
    W = np.zeros((sv.m, n))
    for j in range(sv.n_parents):
        ok = sv.index[:, j] >= 0
        np.add.at(W, (np.flatnonzero(ok), sv.index[ok, j]), sv.w[ok, j])
    return W


class BBWShapeFunction:
    """Piecewise-linear interpolation of vertex weights W (V, n) on the 6-tet split of the
    voxel-centre lattice of a full box (unit direction): ``f(points) -> ShapeValues`` with all n
    frames as parents, exact gradients, zero Hessians; points within half a voxel of the box's
    faces (outside the centre lattice) extend the linear function of the nearest cell."""

    def __init__(self, image, W):
        self.image, self.W = image, W
        self.shape = np.array(image.shape)
        self.vid = np.arange(int(np.prod(self.shape))).reshape(image.shape)

    def __call__(self, points):
        from voxflex.voronoi.shape_functions import ShapeValues

        img, W = self.image, self.W
        c = img.world_to_index(np.asarray(points, dtype=float)) - 0.5
        base = np.clip(np.floor(c).astype(int), 0, self.shape - 2)
        u = c - base
        perm = np.argsort(-u, axis=1, kind="stable")
        m, n = len(c), W.shape[1]
        corner = np.zeros((m, 3), int)
        verts = [self.vid[tuple(base.T)]]
        for k in range(3):
            corner[np.arange(m), perm[:, k]] = 1
            verts.append(self.vid[tuple((base + corner).T)])
        Wv = [W[v] for v in verts]  # 4 x (m, n)
        up = np.take_along_axis(u, perm, axis=1)
        w = Wv[0] + up[:, :1] * (Wv[1] - Wv[0]) + up[:, 1:2] * (Wv[2] - Wv[1]) + up[:, 2:] * (Wv[3] - Wv[2])
        dw = np.zeros((m, n, 3))
        sp = np.asarray(img.spacing, dtype=float)
        for k in range(3):
            dw[np.arange(m), :, perm[:, k]] = (Wv[k + 1] - Wv[k]) / sp[perm[:, k]][:, None]
        idx = np.broadcast_to(np.arange(n), (m, n)).copy()
        return ShapeValues(index=idx, w=w, dw=dw, ddw=np.zeros((m, n, 3, 3)), rest=np.asarray(points, float), n_nodes=n)


def cantilever(n_frames, igl):
    """Tip deflection of the linear cantilever (SOFA-beam-like, 10 x 10 x 30 voxels) with both weight
    sets on the same frames and the same per-voxel Gauss-Legendre quadrature, against the voxel model."""
    import warnings
    from dataclasses import replace

    import voxflex as vf
    from voxflex.deform.models.frames.model import FrameModel
    from voxflex.scene import ElasticitySpec, FixedSpec, LoadSpec, MaterialSpec, NodesSpec, ObjectSpec, ProbeSpec, Scene

    scene = Scene(object=ObjectSpec(shape="box", size=(0.2, 0.2, 0.6), voxel_size=0.02), nodes=NodesSpec(kind="voxel"),
                  materials=(MaterialSpec(model="hooke", young=1e5, poisson=0.3, strain="linear"),),
                  elasticity=ElasticitySpec(strain="linear"), fixed=(FixedSpec(max=(1e9, 1e9, 1e-6)),),
                  loads=(LoadSpec(kind="force", vector=(1.0, 0.0, 0.0), min=(-1e9, -1e9, 0.6 - 1e-6)),),
                  probes=(ProbeSpec("tip", (0.1, 0.1, 0.6)),))
    out = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = vf.simulate(scene, progress=False, cache=False).probe_displacements()["tip"][0]
        fs = replace(scene, nodes=NodesSpec(kind="affine", count=n_frames, shape_function="natural-neighbour"),
                     elasticity=ElasticitySpec(strain="linear", quadrature="gauss-legendre"))
        model = vf.model(fs, cache=False)
        u = vf.simulate(fs, model=model, progress=False, cache=False).probe_displacements()["tip"][0]
        out.append(("voxflex sibson, parents=4", u))
        img, frames = model.image, model.frames
        labels = np.asarray(img.labels)
        V, T = tet_mesh_of_centres(labels)
        fr = np.floor(img.world_to_index(frames)).astype(int)
        vid = -np.ones(labels.shape, int)
        vid[labels > 0] = np.arange(len(V))
        handles = vid[tuple(fr.T)]
        n = len(frames)
        # the clamp: like voxflex's seed_owner, the clamped layer belongs to the frame in it
        clamp = np.flatnonzero((V[:, 2] < 1.0) & ~np.isin(np.arange(len(V)), handles))
        owner = np.argmin(np.where(fr[:, 2] == 0, 0, 1))
        b = np.concatenate([handles, clamp]).astype(np.int64)
        bc = np.concatenate([np.eye(n), np.tile(np.eye(n)[owner], (len(clamp), 1))])
        Wb = igl.bbw(V, T, b, bc, partition_unity=False, max_iter=100)
        Wb = np.clip(Wb, 0.0, None)
        Wb /= Wb.sum(1, keepdims=True)
        sf = BBWShapeFunction(img, Wb)
        bm = FrameModel.from_image(img, frames, sf, model.materials, quadrature="gauss-legendre")
        ub = vf.simulate(fs, model=bm, progress=False, cache=False).probe_displacements()["tip"][0]
        out.append(("libigl bbw (clamp layer bound to its frame)", ub))
    return ref, out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shape", default="24,12,12", help="bar size in voxels nx,ny,nz")
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--repeat", type=int, default=3, help="timed runs of each weight scheme (min and median)")
    ap.add_argument("--cantilever", type=int, default=0, metavar="N",
                    help="also the cantilever tip error with N frames and each weight set (slow)")
    a = ap.parse_args(argv)
    try:
        import igl
    except ImportError:
        print("libigl is not installed (pip install libigl): nothing to compare; skipped")
        return
    from voxflex.image import LabelImage
    from voxflex.voronoi import place_frames, shape_function

    shape = tuple(int(s) for s in a.shape.split(","))
    labels = np.ones(shape, np.uint8)
    img = LabelImage(labels)  # unit voxels: positions are in voxels
    frames = place_frames(img, a.frames)
    shape_function(LabelImage(np.ones((6, 6, 6), np.uint8)), place_frames(LabelImage(np.ones((6, 6, 6), np.uint8)), 3))(
        np.array([[1.0, 1.0, 1.0]]))  # compile the kernels before timing
    V, T = tet_mesh_of_centres(labels)
    rows = {tuple(np.round(v, 6)): r for r, v in enumerate(V)}
    frame_rows = np.array([rows[tuple(np.round(f, 6))] for f in frames])
    inside = np.zeros(len(V), bool)  # the frames' convex hull, where Sibson coordinates are linearly precise
    try:
        from scipy.spatial import Delaunay

        inside = Delaunay(frames).find_simplex(V) >= 0
    except Exception:  # frames in a plane: no hull
        pass
    n = len(frames)
    print(f"# {platform.platform()}, os.cpu_count() = {os.cpu_count()}, load {os.getloadavg()[0]:.1f}; "
          f"bar {shape} voxels, {n} frames (place_frames), {len(V)} points (voxel centres), {len(T)} tets for BBW")
    def timed(fn):
        """(result, min s, median s) of --repeat runs."""
        ts = []
        for _ in range(max(a.repeat, 1)):
            t = time.perf_counter()
            out = fn()
            ts.append(time.perf_counter() - t)
        return out, min(ts), float(np.median(ts))

    # warm libigl too (its first solve allocates and sets up), on a small bar with the same call
    Vw, Tw = tet_mesh_of_centres(np.ones((4, 2, 2), np.uint8))
    igl.bbw(Vw, Tw, np.array([0, len(Vw) - 1], dtype=np.int64), np.eye(2), partition_unity=False, max_iter=5)
    results = []
    for parents in (4, 8):
        sv, tmin, tmed = timed(lambda: shape_function(img, frames, parents=parents)(V))
        results.append((f"voxflex sibson, parents={parents}", (tmin, tmed),
                        properties(dense(sv, n), V, frames, inside, frame_rows)))
    Wb, tmin, tmed = timed(lambda: igl.bbw(V, T, frame_rows.astype(np.int64), np.eye(n), partition_unity=False,
                                           max_iter=100))
    raw = properties(Wb, V, frames, inside, frame_rows)
    Wn = Wb / Wb.sum(1, keepdims=True)
    pn = properties(Wn, V, frames, inside, frame_rows)
    pn["pu_raw"] = raw["pu"]
    results.append(("libigl bbw (rows normalised)", (tmin, tmed), pn))
    print()
    print(f"time: min / median of {max(a.repeat, 1)} warm runs")
    print("| weights | time s (min / median) | max abs(sum w - 1) | min w | frames w > 1e-3 per point (mean / max) "
          "| linear precision, voxels (all / in the frames' hull) | min w_i at frame i |")
    print("|---|---|---|---|---|---|---|")
    for name, dt, p in results:
        pu = f"{p['pu']:.1e}" + (f" ({p['pu_raw']:.1e} before)" if "pu_raw" in p else "")
        print(f"| {name} | {dt[0]:.2f} / {dt[1]:.2f} | {pu} | {p['min']:.1e} | {p['supp_mean']:.2f} / {p['supp_max']} | "
              f"{p['lin_all']:.2f} / {p['lin_in']:.2f} | {p['kron']:.3f} |")
    if a.cantilever:
        ref, rows = cantilever(a.cantilever, igl)
        print(f"\nLinear cantilever 10 x 10 x 30 voxels, {a.cantilever} frames, Gauss-Legendre per voxel: voxel model "
              f"tip u_x = {ref:.6e} m\n")
        print("| weights | tip u_x (m) | error |")
        print("|---|---|---|")
        for name, u in rows:
            print(f"| {name} | {u:.6e} | {100 * (u - ref) / abs(ref):+.2f} % |")


if __name__ == "__main__":
    main()
