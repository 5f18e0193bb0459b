"""Dual-quaternion skinning (voxflex.deform.chain.skinning).

The shared derivative contract (tests/contract_skinning.py) checks all its
derivatives, the geometric stiffness included; here apply / jvp / vjp / jacobian
are also checked with the contract's own checks of J: central differences along the rigid-frame manifold
(x = a (v, ω) increment applied through RigidFrames.integrate, as in
contract_mappings.py; step 1e-6, relative tolerance 1e-6: truncation and
round-off both stay ~1e-9), the adjoint identity to 1e-10 and the assembled J
against jvp to 1e-12.
"""

from __future__ import annotations

import numpy as np
import pytest

from voxflex.deform.chain.mappings import PointMapping
from voxflex.deform.chain.nodes import RigidFrames
from voxflex.deform.chain.skinning import DualQuaternionSkinning
from voxflex.voronoi.shape_functions import shepard


def _setup(seed=0):
    rng = np.random.default_rng(seed)
    frames = RigidFrames(rng.random((4, 3)))
    sv = shepard(rng.random((6, 3)), frames.rest_positions, n_parents=3)
    s0 = frames.integrate(frames.rest, np.concatenate([0.3 * rng.standard_normal((4, 3)),
                                                       1.2 * rng.standard_normal((4, 3))], axis=1))
    return rng, frames, sv, s0


def test_jvp_vjp_jacobian_against_finite_differences():
    rng, frames, sv, s0 = _setup()
    dqs = DualQuaternionSkinning(frames, sv)
    h = 1e-6
    for _ in range(3):
        v = rng.standard_normal((4, 6))
        u = rng.standard_normal((6, 3))
        fd = (dqs.apply(frames.integrate(s0, h * v)) - dqs.apply(frames.integrate(s0, -h * v))) / (2 * h)
        jv = dqs.jvp(s0, v)
        assert np.linalg.norm(jv - fd) < 1e-6 * np.linalg.norm(fd)
        lhs, rhs = np.vdot(jv, u), np.vdot(v, dqs.vjp(s0, u))
        assert abs(lhs - rhs) < 1e-10 * np.linalg.norm(jv) * np.linalg.norm(u)
        Jv = dqs.jacobian(s0) @ v.ravel()
        assert np.linalg.norm(Jv - jv.ravel()) < 1e-12 * np.linalg.norm(jv)


def test_rest_and_common_rigid_motion_and_single_parent():
    rng, frames, sv, _ = _setup(1)
    dqs = DualQuaternionSkinning(frames, sv)
    np.testing.assert_allclose(dqs.apply(frames.rest), sv.rest, atol=1e-14)
    # every frame moved by the same rigid motion x -> R x + c: the points follow it exactly
    from voxflex.deform.chain.nodes import rotation_exp

    R = rotation_exp(np.array([[0.4, -1.1, 0.7]]))[0]
    c = np.array([0.3, -2.0, 1.0])
    X = frames.rest_positions
    s = frames.state_from(np.tile(R, (4, 1, 1)), X @ R.T + c)
    np.testing.assert_allclose(dqs.apply(s), sv.rest @ R.T + c, atol=1e-13)
    # one parent with weight 1: the rigid point mapping of that frame
    one = shepard(sv.rest, X, n_parents=1)
    s1 = frames.integrate(frames.rest, rng.standard_normal((4, 6)))
    np.testing.assert_allclose(DualQuaternionSkinning(frames, one).apply(s1),
                               PointMapping(frames, one).apply(s1), atol=1e-13)


def test_geometric_stiffness_is_the_second_derivative_of_a_potential():
    """For a constant point load c (6, 3), phi(h) = c . x(integrate(s, h v)) has phi'(h) = <v, J(s(h))^T c>
    (the increment path exp(h w) R is a one-parameter group), so phi''(0) = <v, K_geo v>: central second
    differences as the oracle, at a rotated state.  (K_geo is not symmetric: rotation increments do not
    commute.)"""
    rng, frames, sv, s = _setup(2)
    dqs = DualQuaternionSkinning(frames, sv)
    c = rng.standard_normal((6, 3))
    for _ in range(3):
        v = rng.standard_normal((4, 6))

        def phi(x):
            return float(np.sum(c * dqs.apply(frames.integrate(s, x))))

        h = 1e-4  # second differences: truncation ~h^2 = 1e-8, round-off ~1e-16 / h^2 = 1e-8 (relative)
        second = (phi(h * v) - 2 * phi(np.zeros((4, 6))) + phi(-h * v)) / h**2
        assert np.vdot(v, dqs.geometric_vp(s, c, v)) == pytest.approx(second, rel=1e-5)
