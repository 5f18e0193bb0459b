"""The examples of each object source (shape, mesh, image) run and give numbers known independently."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import paths
import pytest

import voxflex as vf
from voxflex.scene import Scene

ROOT = paths.ROOT
EXAMPLES = ROOT / "examples"


def test_shape_example_cylinder_cantilever():
    scene = Scene.from_toml(EXAMPLES / "object_shape.toml")
    assert scene.object.source_kind == "shape"
    result = vf.simulate(scene, progress=False)
    r, L, h = 0.05, 0.4, 0.02
    # voxel volume against the exact cylinder: a 5-voxel-wide staircase circle overestimates by ~7 %
    volume = result.n_voxels * h**3
    assert volume == pytest.approx(math.pi * r**2 * L, rel=0.10)
    # Euler-Bernoulli under its own weight: w = q L^4 / (8 E I), q = rho g A, I = pi r^4 / 4 -> 50.2 mm;
    # the staircase section (5 voxels across) and the short, thick rod (L/d = 4: shear adds a few %)
    # keep the voxel result within 15 % of it (measured 45.9 mm)
    E, rho, g = 1.0e6, 1000.0, 9.81
    w = rho * g * math.pi * r**2 * L**4 / (8 * E * math.pi * r**4 / 4)
    uz = result.probe_displacements()["tip"][2]
    assert uz < 0 and abs(uz) == pytest.approx(w, rel=0.15)


def test_mesh_example_capsule():
    scene = Scene.from_toml(EXAMPLES / "object_mesh.toml")
    assert scene.object.source_kind == "mesh" and Path(scene.object.mesh).name == "bar.stl"
    result = vf.simulate(scene, progress=False)
    # the capsule: a cylinder r = 5 mm between x = 5 and 45 mm and two hemispherical caps; at 2 mm voxels
    # (5 across) the voxel volume is within 15 % (measured +9 %)
    r, h = 0.005, 0.002
    exact = math.pi * r**2 * 0.040 + 4.0 / 3.0 * math.pi * r**3
    assert result.n_voxels * h**3 == pytest.approx(exact, rel=0.15)
    # symmetric about the x-z plane: the tip stays on it (to round-off) and goes down
    u = result.probe_displacements()["tip"]
    assert abs(u[1]) < 1e-9 and u[2] < -1e-4
    assert result.n_steps == 2 and np.all(result.newton_iterations[1:] > 0)


def test_image_example_phantom_at_a_small_size(tmp_path):
    """The example's scene on the phantom coarsened 4x (20 x 10 x 10 voxels of 2 mm), written to an
    image file: the run keeps every label's voxels as the image has them."""
    scene = Scene.from_toml(EXAMPLES / "object_image.toml")
    assert scene.object.source_kind == "image" and Path(scene.object.image).name == "phantom.nii.gz"
    full = vf.LabelImage.load(scene.object.image)
    small = vf.LabelImage(full.labels[2::4, 2::4, 2::4], spacing=full.spacing * 4, origin=full.origin)
    small.save(tmp_path / "small.npz")
    scene = replace(scene, object=replace(scene.object, image=str(tmp_path / "small.npz")))
    result = vf.simulate(scene, progress=False)
    for label in (1, 2, 3):
        assert np.count_nonzero(result.image_labels == label) == np.count_nonzero(small.labels == label)
    assert result.node_kind == scene.nodes.kind == "affine"
    assert result.probe_displacements()["tip"][2] < 0
