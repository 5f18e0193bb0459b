"""Log-rigid and relative-rigid mappings (voxflex.deform.chain.rigid); derivatives are in the contract."""

from __future__ import annotations

import numpy as np
import pytest

from voxflex.deform.chain.nodes import RigidFrames, rotation_exp
from voxflex.deform.chain.rigid import (
    LogRigidMapping,
    RelativeRigidMapping,
    rotation_log,
)
from voxflex.errors import InputError


def test_log_inverts_exp_from_tiny_to_near_pi():
    rng = np.random.default_rng(0)
    axes = rng.standard_normal((7, 3))
    axes /= np.linalg.norm(axes, axis=1)[:, None]
    angles = np.array([0.0, 1e-12, 1e-5, 0.3, 2.0, 3.0, np.pi - 1e-6])
    th = axes * angles[:, None]
    # exp∘log is the identity on rotation vectors with |θ| < π, to round-off (1e-12 relative to π)
    np.testing.assert_allclose(rotation_log(rotation_exp(th)), th, atol=1e-12 * np.pi)


def test_relative_frame_of_a_known_pair():
    frames = RigidFrames(np.array([[0.0, 0, 0], [1.0, 0, 0]]))
    Ra = rotation_exp(np.array([[0, 0, np.pi / 2]]))[0]
    s = frames.state_from(np.stack([Ra, np.eye(3)]), np.array([[1.0, 2, 3], [1.0, 5, 3]]))
    rel = RelativeRigidMapping(frames, [[0, 1]]).apply(s)[0]
    # b sits 3 m along world y from a; in a's frame (rotated +90° about z) that is +3 along a's x
    np.testing.assert_allclose(rel[9:], [3.0, 0, 0], atol=1e-15)
    np.testing.assert_allclose(rel[:9].reshape(3, 3), Ra.T, atol=1e-15)
    log = LogRigidMapping(RelativeRigidMapping(frames, [[0, 1]]).children).apply(rel[None])[0]
    np.testing.assert_allclose(log, [3.0, 0, 0, 0, 0, -np.pi / 2], atol=1e-14)


def test_rigid_motion_of_both_frames_leaves_the_relative_frame_unchanged():
    rng = np.random.default_rng(2)
    frames = RigidFrames(rng.random((3, 3)))
    s = frames.integrate(frames.rest, rng.standard_normal((3, 6)))
    rel = RelativeRigidMapping(frames, [[0, 1], [2, 1]])
    # a common world velocity (v + ω × (p - t)) at each frame: J maps it to zero
    w, v0 = rng.standard_normal(3), rng.standard_normal(3)
    t = frames.positions(s)
    common = np.concatenate([v0 + np.cross(w, t), np.tile(w, (3, 1))], axis=1)
    assert np.abs(rel.jvp(s, common)).max() < 1e-14 * np.abs(common).max()


def test_bad_input():
    frames = RigidFrames(np.zeros((2, 3)))
    with pytest.raises(InputError, match="different frames"):
        RelativeRigidMapping(frames, [[0, 0]])
    with pytest.raises(InputError, match="RigidFrames"):
        LogRigidMapping(np.zeros((2, 3)))
    with pytest.raises(InputError, match=r"\(2, 6\)"):
        LogRigidMapping(frames).vjp(frames.rest, np.zeros((2, 3)))
