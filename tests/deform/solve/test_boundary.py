"""Fixed regions, prescribed motions and force regions."""

from __future__ import annotations

import numpy as np
import pytest

from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.deform.solve.boundary import (
    FixedRegion,
    ForceRegion,
    fixed_dofs,
    prescribed_positions,
    region_forces,
)
from voxflex.errors import InputError
from voxflex.image.label_image import LabelImage


def _model():
    image = LabelImage(np.ones((4, 2, 2)), spacing=(0.5, 0.5, 0.5))
    return VoxelModel.from_image(image, {1: material("hooke", young=1e4, poisson=0.3, strain="linear")})


def test_fixed_dofs_components_and_prescribed_rotation():
    model = _model()
    regions = [FixedRegion([-1, -1, -1], [1e-9, 9, 9]),
               FixedRegion.rotation([2 - 1e-9, -1, -1], [9, 9, 9], [2, 0.5, 0.5], [1, 0, 0], np.pi / 2),
               FixedRegion([-1, -1, -1], [1.9, 1e-9, 9], components="y")]
    dofs, owner = fixed_dofs(model, regions)
    left = model.nodes_in_box([-1, -1, -1], [1e-9, 9, 9])
    assert set((3 * left[:, None] + np.arange(3)).ravel()) <= set(dofs.tolist())
    bottom_y = 3 * model.nodes_in_box([0.1, -1, -1], [1.9, 1e-9, 9]) + 1
    assert set(bottom_y.tolist()) <= set(dofs.tolist())
    assert not set((bottom_y - 1).tolist()) & set(dofs.tolist())  # x stays free on the sliding support
    end = prescribed_positions(model, regions, dofs, owner, 1.0)
    right = model.nodes_in_box([2 - 1e-9, -1, -1], [9, 9, 9])
    pos = dict(zip(dofs.tolist(), end.tolist()))
    X = model.rest[right]
    expected = np.stack([X[:, 0], 0.5 - (X[:, 2] - 0.5), 0.5 + (X[:, 1] - 0.5)], axis=1)  # 90 deg about x
    got = np.array([[pos[3 * i + c] for c in range(3)] for i in right])
    assert np.allclose(got, expected, atol=1e-14)
    # half-way the rotation is half the angle about the same axis (a screw motion, rigid throughout);
    # the held DOFs stay at rest
    half = dict(zip(dofs.tolist(), prescribed_positions(model, regions, dofs, owner, 0.5).tolist()))
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    y, z = X[:, 1] - 0.5, X[:, 2] - 0.5
    expected = np.stack([X[:, 0], 0.5 + c * y - s * z, 0.5 + s * y + c * z], axis=1)  # 45 deg about x
    got = np.array([[half[3 * i + k] for k in range(3)] for i in right])
    assert np.allclose(got, expected, atol=1e-14)
    assert all(half[d] == model.rest.ravel()[d] for d in (3 * left[:, None] + np.arange(3)).ravel())


def test_transform_at_rigid_screw_and_linear_otherwise():
    """Rigid maps move along their screw motion: rigid at every fraction, exact at the ends, a
    one-parameter group (T(a) T(b) = T(a + b), 1e-14); other maps interpolate linearly."""
    from voxflex.deform.chain.nodes import rotation_exp
    from voxflex.deform.models.motion import transform_at

    R = rotation_exp(np.array([[0.3, -0.2, 0.9]]))[0]
    T = np.hstack([R, np.array([[0.4], [-1.0], [2.0]])])
    assert np.abs(transform_at(T, 1.0) - T).max() < 1e-14
    assert np.abs(transform_at(T, 0.0) - np.eye(3, 4)).max() < 1e-15
    for s in (0.25, 0.5, 0.8):
        A = transform_at(T, s)[:, :3]
        assert np.abs(A.T @ A - np.eye(3)).max() < 1e-14 and abs(np.linalg.det(A) - 1) < 1e-14
    a, b = transform_at(T, 0.3), transform_at(T, 0.45)
    both = np.hstack([a[:, :3] @ b[:, :3], (a[:, :3] @ b[:, 3] + a[:, 3])[:, None]])
    assert np.abs(both - transform_at(T, 0.75)).max() < 1e-14
    stretch = np.hstack([np.diag([1.2, 1.0, 1.0]), np.ones((3, 1))])
    assert np.allclose(transform_at(stretch, 0.5), np.hstack([np.diag([1.1, 1.0, 1.0]), 0.5 * np.ones((3, 1))]),
                       atol=1e-15)


def test_force_regions_total_and_traction():
    model = _model()
    face = ForceRegion([2 - 1e-9, -1, -1], [9, 9, 9], [0, 0, -6.0])
    f = region_forces(model, [face])
    assert np.allclose(f.sum(axis=0), [0, 0, -6.0], atol=1e-14)
    nodes = model.nodes_in_box([2 - 1e-9, -1, -1], [9, 9, 9])
    # flat face of a regular grid: corner : edge : centre nodes = 1 : 2 : 4 (lumped area)
    assert sorted(set(np.round(f[nodes, 2] / f[nodes, 2].min(), 12))) == [0.25, 0.5, 1.0]
    trac = ForceRegion([-1, -1, 1 - 1e-9], [9, 9, 9], [0.0, 2.0, 0.0], kind="traction")  # top face z = 1, 2 x 1 m^2
    assert np.allclose(region_forces(model, [trac]).sum(axis=0), [0, 4.0, 0], atol=1e-14)
    with pytest.raises(InputError, match="no boundary face"):
        region_forces(model, [ForceRegion([0.6, 0.1, 0.1], [0.9, 0.4, 0.4], [1, 0, 0], kind="traction")])
    with pytest.raises(InputError, match="contains no material"):
        region_forces(model, [ForceRegion([5, 5, 5], [6, 6, 6], [1, 0, 0])])


def test_region_validation():
    with pytest.raises(InputError, match="subset of 'xyz'"):
        FixedRegion([0, 0, 0], [1, 1, 1], components="w")
    with pytest.raises(InputError, match="exceeds max"):
        FixedRegion([1, 0, 0], [0, 1, 1])
    with pytest.raises(InputError, match="3x4"):
        FixedRegion([0, 0, 0], [1, 1, 1], transform=np.eye(3))
    with pytest.raises(InputError, match="force kind"):
        ForceRegion([0, 0, 0], [1, 1, 1], [1, 0, 0], kind="suction")  # "pressure" is a kind now (membranes)


def test_a_box_ending_on_a_layer_of_corners_holds_it_in_every_unit():
    # corners at origin + i * h carry round-off (0.1 + 0.2 > 0.3); a box written to end on a layer of corners
    # holds that layer whatever the unit (to 1e-11 of a voxel edge)
    for scale in (1e-6, 1e-3, 0.1, 1.0, 3.7, 1e3):
        h = 0.1 * scale
        image = LabelImage(np.ones((5, 2, 2)), spacing=(h, h, h), origin=(0.1 * scale, 0.0, 0.0))
        model = VoxelModel.from_image(image, {1: material("hooke", young=1e4, poisson=0.3, strain="linear")})
        held = model.nodes_in_box([-1e9, -1e9, -1e9], [0.3 * scale, 1e9, 1e9])  # the corner layers at 0.1, 0.2, 0.3
        assert len(held) == 3 * 9, scale
        assert np.allclose(np.unique(model.rest[held, 0]) / scale, [0.1, 0.2, 0.3])
