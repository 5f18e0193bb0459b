"""Node types: rest states, increments, the rotation exponential against scipy."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from voxflex.deform.chain.nodes import (
    NODE_TYPES,
    AffineFrames,
    Points,
    RigidFrames,
    rotation_exp,
    skew,
)
from voxflex.errors import InputError


def test_sizes_and_rest_states():
    X = np.arange(12.0).reshape(4, 3)
    for cls, width, dofs in ((Points, 3, 3), (AffineFrames, 12, 12), (RigidFrames, 12, 6)):
        nodes = cls(X)
        assert (nodes.n, nodes.state_width, nodes.dofs_per_node, nodes.n_dofs) == (4, width, dofs, 4 * dofs)
        assert nodes.rest.shape == (4, width)
        np.testing.assert_array_equal(nodes.positions(nodes.rest), X)
        assert NODE_TYPES[nodes.kind] is cls
    rest = AffineFrames(X).rest
    np.testing.assert_array_equal(rest[:, :9], np.tile(np.eye(3).ravel(), (4, 1)))


def test_points_and_affine_integrate_additively():
    rng = np.random.default_rng(0)
    X = rng.random((3, 3))
    for cls in (Points, AffineFrames):
        nodes = cls(X)
        dq = rng.standard_normal((3, nodes.dofs_per_node))
        np.testing.assert_array_equal(nodes.integrate(nodes.rest, dq), nodes.rest + dq)
        np.testing.assert_array_equal(nodes.integrate(nodes.rest, dq.ravel()), nodes.rest + dq)
    fr = AffineFrames(X)
    np.testing.assert_array_equal(fr.matrices(fr.rest), np.broadcast_to(np.eye(3), (3, 3, 3)))


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-5, 0.99e-4, 1.01e-4, 0.3, 2.0, np.pi - 1e-6, 5.0])
def test_rotation_exp_matches_scipy(angle):
    """Rodrigues (with the small-angle series) equals scipy's rotation-vector conversion to 1e-15."""
    rng = np.random.default_rng(int(angle * 1000) % 97)
    axis = rng.standard_normal(3)
    w = angle * axis / np.linalg.norm(axis)
    R = rotation_exp(w[None])[0]
    np.testing.assert_allclose(R, Rotation.from_rotvec(w).as_matrix(), rtol=0, atol=2e-15)
    np.testing.assert_allclose(R.T @ R, np.eye(3), rtol=0, atol=2e-15)


def test_rigid_integrate_is_left_multiplication():
    rng = np.random.default_rng(1)
    nodes = RigidFrames(rng.random((5, 3)))
    s = nodes.integrate(nodes.rest, rng.standard_normal((5, 6)))
    dq = rng.standard_normal((5, 6))
    s2 = nodes.integrate(s, dq)
    np.testing.assert_allclose(nodes.positions(s2), nodes.positions(s) + dq[:, :3], rtol=0, atol=1e-15)
    expect = Rotation.from_rotvec(dq[:, 3:]).as_matrix() @ nodes.rotations(s)
    np.testing.assert_allclose(nodes.rotations(s2), expect, rtol=0, atol=1e-14)
    # the state stays a proper rotation after many steps (drift ~ steps × 1e-16)
    for _ in range(200):
        s = nodes.integrate(s, 0.1 * rng.standard_normal((5, 6)))
    R = nodes.rotations(s)
    assert np.abs(np.einsum("nki,nkj->nij", R, R) - np.eye(3)).max() < 1e-13
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-13)


def test_skew_is_cross_product():
    rng = np.random.default_rng(2)
    a, b = rng.standard_normal((2, 4, 3))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", skew(a), b), np.cross(a, b), rtol=0, atol=1e-15)


def test_state_validation():
    nodes = RigidFrames(np.zeros((2, 3)))
    with pytest.raises(InputError, match=r"state must have shape \(2, 12\)"):
        nodes.integrate(np.zeros((2, 7)), np.zeros((2, 6)))
    with pytest.raises(InputError, match=r"dq for RigidFrames must have shape \(2, 6\)"):
        nodes.integrate(nodes.rest, np.zeros((2, 12)))
    with pytest.raises(InputError, match="proper orthogonal"):
        nodes.state_from(np.tile(np.diag([1.0, 1.0, -1.0]), (2, 1, 1)), np.zeros((2, 3)))
    with pytest.raises(InputError, match="non-finite"):
        Points(np.full((2, 3), np.nan))
    with pytest.raises(InputError, match=r"\(n, 3\)"):
        AffineFrames(np.zeros((2, 2)))
    ok = nodes.state_from(Rotation.random(2, random_state=0).as_matrix(), np.ones((2, 3)))
    np.testing.assert_array_equal(nodes.positions(ok), np.ones((2, 3)))
