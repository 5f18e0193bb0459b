"""Hertz contact under refinement: a rigid sphere pressed into an elastic block (voxel model + barrier).

Quarter model by symmetry: block [0, W]^2 x [0, H], faces x = 0 and y = 0 held
in their normal component, base clamped; sphere of radius R centred above the
corner (0, 0), moved down by ``delta`` over the load steps (the obstacle's
motion; ContactModel.begin_step carries the block along where the sphere's new
position would enclose collision points).  Hooke with linear strain (small
strain: delta / R = 1 %), E = 1, nu = 0.3.  Hertz for a rigid sphere on a
half-space:

    F = 4/3 E* sqrt(R) delta^(3/2),   E* = E / (1 - nu^2),   a = sqrt(R delta).

The block is finite (W = H = 5 a) and clamped at its base, so the limit of
refinement is a little stiffer than Hertz; the barrier keeps a gap below
``dhat`` (here 1 % of delta), which lowers the effective indentation by at
most 1 % (1.5 % in force).  Both are stated with the table.

Run: ``python benchmarks/bench_contact.py`` (a few minutes on 2 cores;
``--quick`` runs the two coarse levels only).
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from voxflex.deform import solvers as S
from voxflex.deform.contact import ContactModel
from voxflex.deform.materials import material
from voxflex.deform.obstacles import Sphere
from voxflex.deform.voxel_model import VoxelModel
from voxflex.image.label_image import LabelImage

E, NU, R, DELTA = 1.0, 0.3, 1.0, 0.01
A = np.sqrt(R * DELTA)
W = H = 5 * A  # the block's size; --block changes it (in contact radii)
DHAT = 0.01 * DELTA


def hertz_force(delta=DELTA):
    return 4.0 / 3.0 * E / (1 - NU**2) * np.sqrt(R) * delta**1.5


def run(per_a: int, steps: int = 4):
    """Quarter-model contact force (full sphere: x4) at ``per_a`` voxels per contact radius."""
    h = A / per_a
    n = int(round(W / h))
    image = LabelImage(np.ones((n, n, n), dtype=np.uint8), spacing=(h,) * 3)
    inner = VoxelModel.from_image(image, {1: material("hooke", young=E, poisson=NU, strain="linear")})
    gap0 = 0.5 * DHAT
    sphere = Sphere(center=(0.0, 0.0, H + R + gap0), radius=R,
                    motion=[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, -(DELTA + gap0)]])
    model = ContactModel(inner, [sphere], distance=DHAT, stiffness=E)
    big = 1e9
    fixed = np.unique(np.concatenate([
        inner.held_dofs((-big, -big, -big), (big, big, 1e-9 * h), "xyz"),
        inner.held_dofs((-big, -big, -big), (1e-9 * h, big, big), "x"),
        inner.held_dofs((-big, -big, -big), (big, 1e-9 * h, big), "y"),
    ]))
    X = np.asarray(inner.rest, dtype=float).ravel()
    N = X.size
    free = np.setdiff1d(np.arange(N), fixed)
    opt = S.SolverOptions(kind="static", steps=steps, tolerance=1e-8, linear_solver="auto")
    reduce = S._FreeBlock(free, N)
    x = X.copy()
    t0 = time.perf_counter()
    its = 0
    for k in range(1, steps + 1):
        start = model.begin_step(k / steps, x, x.copy())
        problem = S._Problem(model, np.zeros(N), start)
        delta, it, *_ = S._newton(problem, np.zeros(N), free, fixed, X[fixed] - start[fixed], opt, None,
                                  f"step {k}", reduce)
        its += it
        x = start + delta
    seconds = time.perf_counter() - t0
    q = x.reshape(-1, 3)
    force = -4.0 * model.contact_forces(q)[0, 2]
    gap = float(sphere.signed_distance(model.mapping.apply(q), 1.0)[0].min())
    return {"per_a": per_a, "voxels": n**3, "dofs": N, "force": force, "gap": gap, "newton": its, "seconds": seconds}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the two coarse levels only")
    parser.add_argument("--block", type=float, default=5.0, help="block size W = H in contact radii (default 5)")
    args = parser.parse_args()
    global W, H
    W = H = args.block * A
    levels = (2, 3) if args.quick else (2, 3, 4)
    F = hertz_force()
    print(f"machine: {platform.machine()} {platform.system()}, {os.cpu_count()} CPUs, Python {platform.python_version()}")
    print(f"sphere R = {R}, indentation delta = {DELTA} (a = {A:.3g}), block {W:.3g} x {W:.3g} x {H:.3g} (quarter), "
          f"E = {E}, nu = {NU}, dhat = {DHAT:g}; Hertz F = {F:.6g}")
    print(f"{'voxels/a':>8} {'voxels':>8} {'DOF':>7} {'F':>11} {'F/F_Hertz-1':>12} {'gap/delta':>10} {'Newton':>7} {'s':>7}")
    for per_a in levels:
        r = run(per_a)
        print(f"{r['per_a']:>8} {r['voxels']:>8} {r['dofs']:>7} {r['force']:>11.6g} {r['force'] / F - 1:>+12.4f} "
              f"{r['gap'] / DELTA:>10.4f} {r['newton']:>7} {r['seconds']:>7.2f}")


if __name__ == "__main__":
    main()
