"""How deep the drawn surface's triangles go into curved obstacles (issue 27).

The collision points keep the drawn *vertices* out of every obstacle; a flat
triangle between them can still cross a sphere or a box's edge.  Each scene
below is run with the default contact settings and every recorded state's
drawn triangles are measured against the obstacle: the smallest signed
distance over each triangle, found by sampling it on a barycentric grid of
``--samples`` subdivisions (independent of the contact layer's own
arithmetic), reported as a fraction of the voxel size (negative: inside).

Scenes (box 1 x 1 x 0.5 m of 0.25 m voxels, neo-Hooke, dropped under gravity
with implicit Euler, or the pushed block of ``examples/pushed_block.toml``
with a smaller sphere):

* ``sphere-R``: dropped onto a sphere of radius R (m) below its centre;
* ``edge``: dropped onto the top face of a box obstacle whose edge runs
  under the body (the overhang drapes over the edge);
* ``press``: a clamped block (0.4 m, 0.05 m voxels) pushed down 10 mm by a
  sphere of radius 0.1 m (2 voxels).

Measured (deepest drawn-triangle point / deepest vertex, fractions of a voxel;
voxels, then 10 affine frames):

| scene | before: triangles | now: triangles | vertices |
|---|---|---|---|
| sphere-0.5 | -0.0826 / -0.0756 | +0.0022 / +0.0017 | +0.008 / +0.006 |
| sphere-1.0 | -0.0349 / -0.0500 | +0.0027 / +0.0023 | +0.008 / +0.008 |
| sphere-4.0 | -0.0014 / -0.0059 | +0.0052 / +0.0053 | +0.012 / +0.008 |
| edge | -0.2369 / -0.2455 | the same (named after the run) | +0.006 / +0.006 |
| press-0.1 | -0.0170 / +0.0004 | +0.0010 / +0.0010 | +0.001 / +0.001 |

("before": the collision points alone; "now": the drawn triangles also
collide with spheres at their deepest point, ``voxflex/deform/layers/drawn.py``.)

Run: ``python benchmarks/bench_contact_drawn.py`` (voxel and affine nodes,
about a minute on 2 cores).
"""

from __future__ import annotations

import argparse

import numpy as np

import voxflex as vf
from voxflex.deform.layers.obstacles import Box, Sphere
from voxflex.scene import Scene

DROP = """\
[object]
shape = "box"
size = [1.0, 1.0, 0.5]
voxel_size = 0.25
origin = [0.0, 0.0, 0.01]

[[material]]
model = "neo-hookean"
young = {young}
poisson = 0.3
density = 1000.0

[nodes]
kind = "{kind}"
{nodes}

[[load]]
kind = "gravity"
vector = [0.0, 0.0, -9.81]

{obstacle}

[solver]
kind = "implicit-euler"
dt = 0.02
steps = {steps}
"""

PRESS = """\
[object]
shape = "box"
size = [0.4, 0.4, 0.4]
voxel_size = 0.05

[[material]]
model = "hooke"
young = 1.0e4
poisson = 0.3
strain = "linear"

[nodes]
kind = "{kind}"
{nodes}

[[fixed]]
max = [1e9, 1e9, 1e-9]

[[obstacle]]
kind = "sphere"
center = [0.2, 0.2, {cz!r}]
radius = {radius!r}
motion = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, -0.01]]

[contact]
distance = 0.0001

[solver]
kind = "static"
steps = 5
"""


def triangle_depth(x, faces, obstacle, fraction=0.0, samples=24):
    """Smallest signed distance (m) of the triangles ``x[faces]`` to ``obstacle``, by barycentric sampling.

    Parameters
    ----------
    x : (V, 3) float, metres
    faces : (F, 3) int
    obstacle : Obstacle
    fraction : float
        Where the obstacle's motion stands.
    samples : int
        Subdivisions of each triangle edge (``(samples + 1)(samples + 2) / 2`` points per triangle).

    Returns
    -------
    triangles : float, metres (the smallest over every triangle's samples)
    vertices : float, metres (the smallest over the vertices)
    """
    dv = obstacle.signed_distance(x, fraction)[0]
    tri = x[faces]
    near = np.flatnonzero(dv[faces].min(axis=1) < 2.0 * np.max(np.linalg.norm(tri - tri[:, :1], axis=2)))
    i, j = np.meshgrid(np.arange(samples + 1), np.arange(samples + 1), indexing="ij")
    keep = i + j <= samples
    lam = np.stack([i[keep], j[keep], samples - i[keep] - j[keep]], axis=1) / samples  # (s, 3)
    best = float(dv.min())
    for a in range(0, len(near), 256):
        t = tri[near[a:a + 256]]
        p = np.einsum("sk,fkc->fsc", lam, t).reshape(-1, 3)
        best = min(best, float(obstacle.signed_distance(p, fraction)[0].min()))
    return best, float(dv.min())


def measure(result, obstacle, steps_fraction, samples):
    h = float(np.min(result.image_spacing))
    faces = np.asarray(result.surface_faces)
    T = result.surface_positions.shape[0]
    worst_t, worst_v = np.inf, np.inf
    for t in range(T):
        s = steps_fraction(t, T)
        dt, dv = triangle_depth(np.asarray(result.surface_positions[t]), faces, obstacle, s, samples)
        worst_t, worst_v = min(worst_t, dt), min(worst_v, dv)
    return worst_t / h, worst_v / h


def scenes():
    yield "sphere-0.5", 5e4, '[[obstacle]]\nkind = "sphere"\ncenter = [0.5, 0.5, -0.5]\nradius = 0.5', \
        Sphere(center=(0.5, 0.5, -0.5), radius=0.5)
    yield "sphere-1.0", 5e4, '[[obstacle]]\nkind = "sphere"\ncenter = [0.5, 0.5, -1.0]\nradius = 1.0', \
        Sphere(center=(0.5, 0.5, -1.0), radius=1.0)
    yield "sphere-4.0", 5e4, '[[obstacle]]\nkind = "sphere"\ncenter = [0.5, 0.5, -4.0]\nradius = 4.0', \
        Sphere(center=(0.5, 0.5, -4.0), radius=4.0)
    yield "edge", 2e4, '[[obstacle]]\nkind = "box"\nmin = [-1.0, -1.0, -1.0]\nmax = [0.6, 2.0, 0.0]', \
        Box(min=(-1.0, -1.0, -1.0), max=(0.6, 2.0, 0.0))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kinds", default="voxel,affine")
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--samples", type=int, default=24)
    args = ap.parse_args()
    print("| scene | nodes | deepest triangle point / voxel | deepest vertex / voxel |")
    print("|---|---|---|---|")
    for kind in args.kinds.split(","):
        nodes = "count = 10" if kind == "affine" else ""
        for name, young, table, ob in scenes():
            text = DROP.format(kind=kind, nodes=nodes, obstacle=table, steps=args.steps, young=young)
            r = vf.simulate(Scene.from_toml_text(text), progress=False)
            tri, ver = measure(r, ob, lambda t, T: 0.0, args.samples)
            print(f"| {name} | {kind} | {tri:+.4f} | {ver:+.4f} |", flush=True)
        radius = 0.1
        text = PRESS.format(kind=kind, nodes=nodes, cz=0.4 + radius + 5e-5, radius=radius)
        r = vf.simulate(Scene.from_toml_text(text), progress=False)
        ob = Sphere(center=(0.2, 0.2, 0.4 + radius + 5e-5), radius=radius,
                    motion=[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, -0.01]])
        tri, ver = measure(r, ob, lambda t, T: t / (T - 1), args.samples)
        print(f"| press-0.1 | {kind} | {tri:+.4f} | {ver:+.4f} |", flush=True)


if __name__ == "__main__":
    main()
