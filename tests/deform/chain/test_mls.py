"""The moving-least-squares mapping (voxflex.deform.chain.mls): exact reproduction of affine and rigid
motions, its limits, its input checks, and a comparison with linear blend skinning on a bent bar.

The derivatives (J against finite differences, the adjoint identity, the geometric stiffness) are
in the shared contract: tests/contract_mls.py.
"""

from __future__ import annotations

import doctest

import numpy as np
import pytest

from voxflex.deform.chain import mls as mls_module
from voxflex.deform.chain.mappings import PointMapping
from voxflex.deform.chain.mls import MovingLeastSquaresMapping
from voxflex.deform.chain.nodes import AffineFrames, Points, RigidFrames, rotation_exp
from voxflex.errors import InputError
from voxflex.voronoi.shape_functions import ShapeValues, shepard

# Affine and rigid reproduction: the mapping is a sum of ~P terms of size ~1 m computed by a 3x3
# solve of condition < 1e3 here, so round-off stays ~1e-14; 1e-12 m leaves margin and catches any
# wrong coefficient (which gives errors of order the motion, 0.1-1 m).
EXACT = 1e-12


def _rng_affine(rng):
    B = np.eye(3) + 0.4 * rng.standard_normal((3, 3))
    return B, rng.standard_normal(3)


def _rigid(rng):
    return rotation_exp(rng.standard_normal((1, 3)))[0], rng.standard_normal(3)


def test_docstring_example_runs():
    assert doctest.testmod(mls_module, raise_on_error=False).failed == 0


@pytest.mark.parametrize("parents", [4, 6, 10])
def test_point_nodes_reproduce_affine_motions(parents):
    """Schaefer's affine MLS (radius 0): linear precision, for any weights and parent count >= 4."""
    rng = np.random.default_rng(parents)
    nodes = Points(rng.random((10, 3)))
    sv = shepard(rng.random((50, 3)), nodes.rest_positions, n_parents=parents, power=3.0)
    B, b = _rng_affine(rng)
    x = MovingLeastSquaresMapping(nodes, sv).apply(nodes.rest @ B.T + b)
    np.testing.assert_allclose(x, sv.rest @ B.T + b, rtol=0, atol=EXACT)


@pytest.mark.parametrize("radius", [0.0, 0.05, 0.3, 2.0])
def test_affine_frames_reproduce_affine_motions(radius):
    rng = np.random.default_rng(1)
    frames = AffineFrames(rng.random((8, 3)))
    sv = shepard(rng.random((40, 3)), frames.rest_positions, n_parents=5)
    B, b = _rng_affine(rng)
    state = np.concatenate([np.broadcast_to(B.ravel(), (8, 9)), frames.rest_positions @ B.T + b], axis=1)
    x = MovingLeastSquaresMapping(frames, sv, radius=radius).apply(state)
    np.testing.assert_allclose(x, sv.rest @ B.T + b, rtol=0, atol=EXACT)


@pytest.mark.parametrize("radius", [None, 0.0, 0.3])
def test_rigid_frames_reproduce_rigid_motions(radius):
    rng = np.random.default_rng(2)
    frames = RigidFrames(rng.random((6, 3)))
    sv = shepard(rng.random((40, 3)), frames.rest_positions, n_parents=4)
    R, b = _rigid(rng)
    state = frames.state_from(np.broadcast_to(R, (6, 3, 3)), frames.rest_positions @ R.T + b)
    x = MovingLeastSquaresMapping(frames, sv, radius=radius).apply(state)
    np.testing.assert_allclose(x, sv.rest @ R.T + b, rtol=0, atol=EXACT)


def test_one_parent_gives_the_frames_own_motion_and_a_node_its_own_position():
    rng = np.random.default_rng(3)
    frames = AffineFrames(rng.random((3, 3)))
    X = rng.random((5, 3))
    sv = ShapeValues(np.zeros((5, 1), dtype=int), np.ones((5, 1)), np.zeros((5, 1, 3)), None, X)
    state = frames.rest + 0.3 * rng.standard_normal((3, 12))
    A, t = state[0, :9].reshape(3, 3), state[0, 9:]
    x = MovingLeastSquaresMapping(frames, sv, radius=0.1).apply(state)
    np.testing.assert_allclose(x, (X - frames.rest_positions[0]) @ A.T + t, rtol=0, atol=EXACT)
    # point nodes: a point on a node (Shepard: weight 1 there) takes that node's position
    nodes = Points(rng.random((6, 3)))
    q = rng.random((6, 3))
    x = MovingLeastSquaresMapping(nodes, shepard(nodes.rest_positions[:2], nodes.rest_positions)).apply(q)
    np.testing.assert_allclose(x, q[:2], rtol=0, atol=EXACT)


def test_weights_may_be_scaled_per_point():
    """The fit is invariant to a positive scale of each point's weights (Schaefer's raw 1/d^2a weights
    give the same map as Shepard's normalised ones)."""
    rng = np.random.default_rng(4)
    frames = RigidFrames(rng.random((6, 3)))
    sv = shepard(rng.random((20, 3)), frames.rest_positions, n_parents=5)
    scaled = ShapeValues(sv.index, sv.w * rng.uniform(0.1, 10.0, (20, 1)), sv.dw, None, sv.rest)
    a, b = MovingLeastSquaresMapping(frames, sv), MovingLeastSquaresMapping(frames, scaled)
    np.testing.assert_allclose(b.phi, a.phi, rtol=0, atol=1e-13)
    np.testing.assert_allclose(b.c, a.c, rtol=0, atol=1e-13)


def test_assembled_geometric_stiffness_matches_its_product():
    rng = np.random.default_rng(5)
    frames = RigidFrames(rng.random((5, 3)))
    mls = MovingLeastSquaresMapping(frames, shepard(rng.random((12, 3)), frames.rest_positions, n_parents=4), radius=0.2)
    state = frames.integrate(frames.rest, rng.standard_normal((5, 6)))
    f, v = rng.standard_normal((12, 3)), rng.standard_normal((5, 6))
    K = mls.geometric(state, f)
    # both are the same sums in a different order: round-off only
    np.testing.assert_allclose(K @ v.ravel(), mls.geometric_vp(state, f, v).ravel(), rtol=1e-12, atol=1e-12)
    assert not mls.constant_jacobian
    assert MovingLeastSquaresMapping(frames, mls.shape, radius=0.0).constant_jacobian
    affine = MovingLeastSquaresMapping(AffineFrames(frames.rest_positions), mls.shape)
    assert affine.constant_jacobian and affine.geometric(state, f).nnz == 0


def test_bad_input_is_refused_with_the_fix():
    rng = np.random.default_rng(6)
    X = rng.random((5, 3))
    with pytest.raises(InputError, match="do not span 3-D"):  # three parents: a plane
        MovingLeastSquaresMapping(Points(X), shepard(rng.random((4, 3)), X, n_parents=3))
    with pytest.raises(InputError, match="no linear part"):
        MovingLeastSquaresMapping(Points(X), shepard(rng.random((4, 3)), X), radius=0.1)
    with pytest.raises(InputError, match="radius must be finite"):
        MovingLeastSquaresMapping(AffineFrames(X), shepard(rng.random((4, 3)), X), radius=-1.0)
    with pytest.raises(InputError, match="nodes must be"):
        MovingLeastSquaresMapping(X, shepard(rng.random((4, 3)), X))
    zero = ShapeValues(np.zeros((1, 1), dtype=int), np.zeros((1, 1)), np.zeros((1, 1, 3)), None, np.zeros((1, 3)))
    with pytest.raises(InputError, match="all weights zero"):
        MovingLeastSquaresMapping(AffineFrames(X), zero)


# -- the bent bar --------------------------------------------------------------------------------------
L, H, KAPPA = 1.0, 0.1, np.pi / 2  # a 1 x 0.1 x 0.1 m bar bent into a quarter circle about y


def _bend(P):
    """The exact pure bending: the axis onto an arc of radius 1/KAPPA, sections stay plane and normal."""
    rho = 1 / KAPPA
    s, y, z = np.asarray(P).T
    return np.stack([(rho - z) * np.sin(KAPPA * s), y, rho - (rho - z) * np.cos(KAPPA * s)], axis=1)


def _grid(nx=41, ny=5):
    g = np.meshgrid(np.linspace(0, L, nx), *2 * [np.linspace(-H / 2, H / 2, ny)], indexing="ij")
    return np.stack(g, -1).reshape(-1, 3), (nx, ny, ny)


def _cell_volumes(P, shape):
    """Volumes of the hexahedral cells of a mapped grid, 6 tetrahedra each (exact for the mapped corners)."""
    P = P.reshape(*shape, 3)
    c = [P[:-1, :-1, :-1], P[1:, :-1, :-1], P[1:, 1:, :-1], P[:-1, 1:, :-1],
         P[:-1, :-1, 1:], P[1:, :-1, 1:], P[1:, 1:, 1:], P[:-1, 1:, 1:]]
    tets = [(0, 1, 2, 6), (0, 2, 3, 6), (0, 3, 7, 6), (0, 7, 4, 6), (0, 4, 5, 6), (0, 5, 1, 6)]
    return sum(np.einsum("...i,...i->...", np.cross(c[b] - c[a], c[k] - c[a]), c[d] - c[a]) / 6 for a, b, k, d in tets)


def test_bent_bar_against_linear_blend_skinning():
    """Two settings, both checked on properties and printed with their volume change.

    Point nodes (the bar's 20 corner points of 5 sections, moved by the exact bending): linear
    blend skinning of points is Shepard interpolation, whose gradient vanishes at every node (a
    property of inverse-distance weights with power >= 2), so the mapped bar collapses around the
    nodes; MLS has linear precision.  Rigid frames on the axis (5, rotated with the sections): both
    interpolate the frames' origins and reproduce the rigid motion of each frame at its origin.
    Measured (printed): point nodes, 8 parents: volume change LBS -84 %, MLS -2.6 %; rigid frames,
    2 parents: LBS +0.08 %, MLS -2.5 % (MLS fits straight chords through the origins, which
    shortens the arc).
    """
    G, shape = _grid()
    V0 = _cell_volumes(G, shape)
    Xp = np.stack(np.meshgrid(np.linspace(0, L, 5), [-H / 2, H / 2], [-H / 2, H / 2], indexing="ij"), -1).reshape(-1, 3)
    nodes = Points(Xp)
    sv = shepard(G, Xp, n_parents=8)
    lbs = PointMapping(nodes, sv, backend="numpy").apply(_bend(Xp))
    mls = MovingLeastSquaresMapping(nodes, sv).apply(_bend(Xp))
    exact = _bend(G)
    ratios = {name: _cell_volumes(P, shape) / V0 for name, P in (("lbs", lbs), ("mls", mls), ("exact", exact))}
    for name, r in ratios.items():
        print(f"point nodes, {name}: volume change {r.mean() - 1:+.4f}, cell volume ratio [{r.min():.3f}, {r.max():.3f}], "
              f"max position error {np.abs({'lbs': lbs, 'mls': mls, 'exact': exact}[name] - exact).max():.4f} m")
    # both interpolate the nodes (grid points on nodes take the node's position)
    on = np.flatnonzero(np.min(np.linalg.norm(G[:, None] - Xp[None], axis=2), axis=1) < 1e-12)
    assert len(on) == 20
    np.testing.assert_allclose(lbs[on], exact[on], rtol=0, atol=EXACT)
    np.testing.assert_allclose(mls[on], exact[on], rtol=0, atol=EXACT)
    # the gradient of Shepard LBS at a node is zero: a central difference of step e around the
    # node gives |dx/dX| = O(e) (here e = 1e-6 m: ~1e-5 against ~1 for the bending)
    e = 1e-6
    X0 = Xp[5]
    stencil = X0 + e * np.concatenate([np.eye(3), -np.eye(3)])
    svs = shepard(stencil, Xp, n_parents=8)
    for mapping, bound in ((PointMapping(nodes, svs, backend="numpy"), 1e-4), (MovingLeastSquaresMapping(nodes, svs), None)):
        x = mapping.apply(_bend(Xp))
        D = ((x[:3] - x[3:]) / (2 * e)).T
        if bound is not None:
            assert np.abs(D).max() < bound
        else:
            # MLS: the local map is the fit through the 8 parents, a near-rotation here; the exact
            # bending has det = 1 - KAPPA z = 1 -+ 0.079 on the faces, MLS within 20 % of it
            assert abs(np.linalg.det(D) - (1 - KAPPA * X0[2])) < 0.2
    # rigid frames on the axis: both reproduce each frame's rigid motion at its origin
    Xa = np.stack([np.linspace(0, L, 5), np.zeros(5), np.zeros(5)], 1)
    frames = RigidFrames(Xa)
    R = rotation_exp(np.stack([np.zeros(5), -KAPPA * Xa[:, 0], np.zeros(5)], 1))
    state = frames.state_from(R, _bend(Xa))
    sv = shepard(G, Xa, n_parents=2)
    lbs = PointMapping(frames, sv, backend="numpy").apply(state)
    mls = MovingLeastSquaresMapping(frames, sv).apply(state)
    on = np.flatnonzero(np.min(np.linalg.norm(G[:, None] - Xa[None], axis=2), axis=1) < 1e-12)
    np.testing.assert_allclose(lbs[on], _bend(Xa), rtol=0, atol=EXACT)
    np.testing.assert_allclose(mls[on], _bend(Xa), rtol=0, atol=EXACT)
    for name, P in (("lbs", lbs), ("mls", mls)):
        r = _cell_volumes(P, shape) / V0
        print(f"rigid frames, {name}: volume change {r.mean() - 1:+.4f}, cell volume ratio [{r.min():.3f}, {r.max():.3f}], "
              f"max position error {np.abs(P - exact).max():.4f} m")
