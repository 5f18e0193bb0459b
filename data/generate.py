"""Make the small bundled data files of ``voxflex.data`` (deterministic; run from anywhere).

``phantom.nii.gz``
    A multi-label phantom voxelized by :func:`voxflex.voxelize` at 0.5 mm
    voxels (80 x 40 x 40, origin 0): a box 40 x 20 x 20 mm of label 1 with a
    ball inclusion of radius 5 mm (label 2, centred at (10, 10, 10) mm) and a
    cylinder of radius 3 mm (label 3) crossing the box along y at
    x = 28 mm, z = 10 mm.  Later labels overwrite earlier ones.
``bar.stl``
    A closed, outward-oriented triangle surface of a capsule (rounded bar):
    a cylinder of radius 5 mm between x = 5 mm and x = 45 mm with
    hemispherical caps, so it spans [0, 50] x [-5, 5] x [-5, 5] mm; 32
    segments around, 12 rings per cap, 8 along the body (1,984 triangles,
    binary STL).  Built from its parametrization (no randomness).

    python data/generate.py            # writes both files next to this script
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def phantom():
    """The phantom :class:`voxflex.LabelImage`."""
    from voxflex.rasterize import Box, Cylinder, Sphere, voxelizer as voxelize

    box = Box((0.04, 0.02, 0.02))
    ball = Sphere(0.005, origin=(0.005, 0.005, 0.005))
    rod = Cylinder(0.003, 0.02, origin=(0.025, 0.0, 0.007), axis="y")
    return voxelize([(box, 1), (ball, 2), (rod, 3)], 0.0005, progress=False)


def capsule(radius=0.005, body=0.04, around=32, cap_rings=12, body_rings=8):
    """Vertices (V, 3) and outward triangles (F, 3) of a capsule along x starting at x = 0."""
    profile = []  # (x, rho) from the left pole (excluded) to the right pole (excluded)
    for i in range(1, cap_rings + 1):
        phi = -0.5 * math.pi + 0.5 * math.pi * i / cap_rings
        profile.append((radius + radius * math.sin(phi), radius * math.cos(phi)))
    for i in range(1, body_rings):
        profile.append((radius + body * i / body_rings, radius))
    for i in range(cap_rings):
        phi = 0.5 * math.pi * i / cap_rings
        profile.append((radius + body + radius * math.sin(phi), radius * math.cos(phi)))
    theta = 2 * math.pi * np.arange(around) / around
    rings = [np.stack([np.full(around, x), rho * np.cos(theta), rho * np.sin(theta)], axis=1) for x, rho in profile]
    left, right = np.array([[0.0, 0.0, 0.0]]), np.array([[2 * radius + body, 0.0, 0.0]])
    vertices = np.concatenate([left, *rings, right])
    faces = []
    nxt = (np.arange(around) + 1) % around
    ring0 = 1 + np.arange(around)
    faces += [np.stack([np.zeros(around, int), ring0[nxt], ring0], axis=1)]
    for r in range(len(rings) - 1):
        a = 1 + r * around + np.arange(around)
        b = a + around
        faces += [np.stack([a, a[nxt], b[nxt]], axis=1), np.stack([a, b[nxt], b], axis=1)]
    last = 1 + (len(rings) - 1) * around + np.arange(around)
    faces += [np.stack([np.full(around, len(vertices) - 1), last, last[nxt]], axis=1)]
    faces = np.concatenate(faces)
    tri = vertices[faces]
    if np.einsum("ti,ti->t", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() < 0:
        faces = faces[:, ::-1]
    return vertices, np.ascontiguousarray(faces)


def write_stl(path, vertices, faces):
    """Binary STL through an atomic write."""
    from voxflex._atomic import atomic_path

    tri = vertices[faces].astype(np.float32)
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
    record = np.zeros(len(faces), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    record["n"], record["v"] = normals, tri
    header = b"voxflex bundled data: capsule bar (data/generate.py)".ljust(80, b" ")
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(header)
            fh.write(np.uint32(len(faces)).tobytes())
            fh.write(record.tobytes())


def main():
    image = phantom()
    image.save(HERE / "phantom.nii.gz")
    v, f = capsule()
    write_stl(HERE / "bar.stl", v, f)
    counts = np.bincount(image.labels.ravel())
    print(f"phantom.nii.gz: {image.shape}, voxels per label {counts.tolist()}")
    print(f"bar.stl: {len(f)} triangles")


if __name__ == "__main__":
    main()
