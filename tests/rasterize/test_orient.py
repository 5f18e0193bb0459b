"""Turning objects so that a chosen axis points up: meshes, primitives, label images, voxelize(up=)."""

from __future__ import annotations

import numpy as np
import pytest

from voxflex.errors import InputError
from voxflex.image import LabelImage
from voxflex.rasterize import (
    Box,
    Cylinder,
    Sphere,
    SurfaceMesh,
    turn_up,
    up_rotation,
    voxelize,
)


@pytest.mark.parametrize("up", ["x", "y", "z"])
def test_rotation_is_proper_and_takes_up_to_z(up):
    R = up_rotation(up)
    e = np.eye(3)["xyz".index(up)]
    # integer matrices: exact
    np.testing.assert_array_equal(R @ e, [0.0, 0.0, 1.0])
    np.testing.assert_array_equal(R.T @ R, np.eye(3))
    assert np.linalg.det(R) == pytest.approx(1.0, abs=0)


def test_y_up_front_faces_the_front_camera():
    # a y-up model's front (+z) must face -y: voxflex's front view looks along +y
    np.testing.assert_array_equal(up_rotation("y") @ [0.0, 0.0, 1.0], [0.0, -1.0, 0.0])


def test_unknown_axis_is_refused():
    with pytest.raises(InputError, match="valid: x, y, z"):
        up_rotation("w")
    with pytest.raises(InputError, match="up axis"):
        voxelize("box:1,1,1", 0.5, up="Y", progress=False)


def _tetra():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3]]) + [0.5, -1.0, 2.0]
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return SurfaceMesh(v, f, name="tet")


@pytest.mark.parametrize("up", ["x", "y"])
def test_mesh_turns_rigidly_keeping_its_orientation(up):
    mesh = _tetra()
    turned = turn_up(mesh, up)
    np.testing.assert_array_equal(turned.vertices, mesh.vertices @ up_rotation(up).T)
    np.testing.assert_array_equal(turned.faces, mesh.faces)
    # a proper rotation keeps the enclosed volume and its sign (1 * 2 * 3 / 6 = 1)
    assert turned.signed_volume == pytest.approx(mesh.signed_volume, rel=1e-14)
    assert mesh.signed_volume == pytest.approx(1.0, rel=1e-14)


@pytest.mark.parametrize("up", ["x", "y"])
@pytest.mark.parametrize(
    "prim",
    [Box((1.0, 2.0, 3.0), origin=(0.1, 0.2, 0.3)), Cylinder(0.5, 2.0, origin=(1.0, 0.0, -1.0), axis="x"),
     Cylinder(0.4, 1.5, axis="z"), Sphere(0.7, origin=(0.3, -0.2, 0.1))],
)
def test_primitive_turns_exactly(prim, up):
    """Oracle: the turned primitive's signed distance at R p equals the original's at p."""
    R = up_rotation(up)
    turned = turn_up(prim, up)
    assert type(turned) is type(prim)
    rng = np.random.default_rng(0)
    lo, hi = prim.bounds()
    p = rng.uniform(lo - 0.5, hi + 0.5, size=(500, 3))
    # exact distances of the same geometry: only round-off of the coordinates differs
    np.testing.assert_allclose(turned.signed_distance(p @ R.T), prim.signed_distance(p), atol=1e-12)


def _voxel_set(image):
    """Sorted rows (x, y, z, label) of the world centres of every material voxel."""
    idx = np.argwhere(image.labels > 0)
    centres = image.index_to_world(idx + 0.5)
    rows = np.column_stack([np.round(centres, 9), image.labels[tuple(idx.T)]])
    return rows[np.lexsort(rows.T[::-1])]


@pytest.mark.parametrize("up", ["x", "y"])
def test_image_turns_without_resampling(up):
    rng = np.random.default_rng(1)
    labels = rng.integers(0, 3, size=(4, 5, 6)).astype(np.uint8)
    occupancy = rng.uniform(0.1, 1.0, size=labels.shape).astype(np.float32) * (labels > 0)
    image = LabelImage(labels, spacing=(0.1, 0.2, 0.3), origin=(1.0, -2.0, 0.5), occupancy=occupancy)
    turned = turn_up(image, up)
    R = up_rotation(up)
    np.testing.assert_array_equal(turned.direction, np.eye(3))
    # every voxel keeps its label and lands at the rotated world position (voxel centres, 1e-9 m rounding)
    moved = _voxel_set(image)
    moved[:, :3] = np.round(moved[:, :3] @ R.T, 9)
    moved = moved[np.lexsort(moved.T[::-1])]
    np.testing.assert_allclose(_voxel_set(turned), moved, atol=1e-9)
    assert turned.voxel_volume == pytest.approx(image.voxel_volume, rel=1e-15)
    assert np.sort(turned.occupancy.ravel()).tolist() == np.sort(image.occupancy.ravel()).tolist()
    # the occupancy follows its voxel: the sums per label are unchanged
    for lab in (1, 2):
        assert turned.occupancy[turned.labels == lab].sum() == pytest.approx(
            image.occupancy[image.labels == lab].sum(), rel=1e-6
        )


def test_oblique_image_turns_its_direction():
    c, s = np.cos(0.3), np.sin(0.3)
    direction = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    image = LabelImage(np.ones((2, 3, 4), np.uint8), spacing=(1.0, 1.0, 1.0), origin=(1.0, 2.0, 3.0),
                       direction=direction)
    turned = turn_up(image, "y")
    R = up_rotation("y")
    np.testing.assert_allclose(turned.direction, R @ direction, atol=1e-15)
    idx = np.array([[0.5, 0.5, 0.5], [1.5, 2.5, 3.5]])
    np.testing.assert_allclose(turned.index_to_world(idx), image.index_to_world(idx) @ R.T, atol=1e-12)


def test_voxelize_up_places_the_grid_around_the_turned_object():
    image = voxelize("box:1,2,3", 0.5, up="y", progress=False)
    # y (2 m) now points up: the grid is 1 x 3 x 2 m, all filled, lower corner at the turned box's corner
    assert image.shape == (2, 6, 4)
    assert int(image.labels.sum()) == 48
    np.testing.assert_allclose(image.origin, [0.0, -3.0, 0.0], atol=1e-15)
    same = voxelize(turn_up(_tetra(), "x"), 0.25, progress=False)
    np.testing.assert_array_equal(voxelize(_tetra(), 0.25, up="x", progress=False).labels, same.labels)


def test_cli_voxelize_up(tmp_path, capsys):
    from voxflex.cli import main

    out = tmp_path / "box.npz"
    assert main(["voxelize", "box:1,2,3", "-o", str(out), "--voxel-size", "0.5", "--up", "x"]) == 0
    image = LabelImage.load(out)
    # x (1 m) points up: the grid is 3 x 2 x 1 m
    assert image.shape == (6, 4, 2)
    assert "wrote" in capsys.readouterr().out
