"""Node -> child mappings: patch tests, consistency of F with the point map, numba vs numpy twins.

Derivatives (jvp, vjp, Jacobian, geometric stiffness) are checked against
finite differences by the shared contract (``contract_mappings.py``).
"""

from __future__ import annotations

import numpy as np
import pytest
from contract_mappings import padded_shepard  # noqa: E402
from scipy.spatial.transform import Rotation

from voxflex.deform.chain.mappings import (
    MAPPINGS,
    DeformationGradientMapping,
    DeformationGradientWithGradientMapping,
    PointMapping,
)
from voxflex.deform.chain.nodes import AffineFrames, Points, RigidFrames, skew  # noqa: E402
from voxflex.errors import InputError  # noqa: E402
from voxflex.voronoi.shape_functions import ShapeValues, shepard  # noqa: E402

NODE_TYPES = (Points, AffineFrames, RigidFrames)
MAPPING_TYPES = (PointMapping, DeformationGradientMapping, DeformationGradientWithGradientMapping)


def _random_state(nodes, rng, scale=0.3):
    if isinstance(nodes, RigidFrames):
        return nodes.integrate(nodes.rest, rng.standard_normal((nodes.n, 6)))
    return nodes.rest + scale * rng.standard_normal(nodes.rest.shape)


def _as_array(mapping, y):
    if isinstance(mapping, DeformationGradientWithGradientMapping):
        return mapping.pack(*y)
    return np.asarray(y)


# --- linear-precision weights built in the tests --------------------------------------


def trilinear_on_box(points, lo, hi):
    """Trilinear weights on the 8 corners of the box [lo, hi] (corner c = (i, j, k) bits)."""
    X = np.asarray(points, float)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    L = hi - lo
    u = (X - lo) / L  # (m, 3) local coordinates in [0, 1]
    corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], float)
    # per axis: value f = u (bit 1) or 1 - u (bit 0), derivative ±1/L
    f = np.where(corners[None] == 1, u[:, None, :], 1.0 - u[:, None, :])  # (m, 8, 3)
    df = np.where(corners[None] == 1, 1.0, -1.0) / L  # (1, 8, 3)
    df = np.broadcast_to(df, f.shape)
    w = f.prod(-1)
    dw = np.stack([df[..., 0] * f[..., 1] * f[..., 2], f[..., 0] * df[..., 1] * f[..., 2], f[..., 0] * f[..., 1] * df[..., 2]], -1)
    ddw = np.zeros(w.shape + (3, 3))
    for a in range(3):
        for b in range(3):
            if a != b:
                c = 3 - a - b
                ddw[..., a, b] = df[..., a] * df[..., b] * f[..., c]
    m = len(X)
    sv = ShapeValues(index=np.tile(np.arange(8), (m, 1)), w=w, dw=dw, ddw=ddw, rest=X, n_nodes=8)
    return sv, lo + corners * L


def barycentric_on_tet(points, verts):
    """Barycentric weights on a tetrahedron (linear: zero Hessians)."""
    V = np.asarray(verts, float)
    T = (V[1:] - V[0]).T  # columns: edges
    Tinv = np.linalg.inv(T)
    lam123 = (points - V[0]) @ Tinv.T
    w = np.concatenate([1.0 - lam123.sum(1, keepdims=True), lam123], axis=1)
    g = np.vstack([-Tinv.sum(0), Tinv])  # (4, 3): gradient of each barycentric coordinate
    m = len(points)
    return ShapeValues(
        index=np.tile(np.arange(4), (m, 1)),
        w=w,
        dw=np.broadcast_to(g, (m, 4, 3)).copy(),
        ddw=np.zeros((m, 4, 3, 3)),
        rest=points,
        n_nodes=4,
    )


def _affine_state(nodes, M, b):
    """Every node follows x -> M x + b."""
    Xn = nodes.rest_positions
    if isinstance(nodes, Points):
        return Xn @ M.T + b
    if isinstance(nodes, RigidFrames):
        return nodes.state_from(np.broadcast_to(M, (nodes.n, 3, 3)), Xn @ M.T + b)
    s = np.empty((nodes.n, 12))
    s[:, :9] = M.ravel()
    s[:, 9:] = Xn @ M.T + b
    return s


def _check_patch(nodes, sv, M, b):
    # Exact up to round-off: sums of P terms of size |M|·|X| and |dw|·|X|,
    # so a few 1e-15 relative; 1e-12 leaves margin and still catches any wrong term.
    x = PointMapping(nodes, sv).apply(_affine_state(nodes, M, b))
    np.testing.assert_allclose(x, sv.rest @ M.T + b, rtol=0, atol=1e-12)
    F = DeformationGradientMapping(nodes, sv).apply(_affine_state(nodes, M, b))
    np.testing.assert_allclose(F, np.broadcast_to(M, F.shape), rtol=0, atol=1e-12 * max(1.0, np.abs(sv.dw).max()))
    F2, dF = DeformationGradientWithGradientMapping(nodes, sv).apply(_affine_state(nodes, M, b))
    np.testing.assert_allclose(F2, F, rtol=0, atol=1e-13)
    np.testing.assert_allclose(dF, 0.0, rtol=0, atol=1e-12 * max(1.0, np.abs(sv.ddw).max()))


@pytest.mark.parametrize("seed", range(3))
def test_patch_points_trilinear_and_barycentric(seed):
    rng = np.random.default_rng(seed)
    M = np.eye(3) + 0.5 * rng.standard_normal((3, 3))
    b = rng.standard_normal(3)
    lo, hi = rng.random(3), 1.5 + rng.random(3)
    X = lo + (hi - lo) * rng.random((20, 3))
    sv, corners = trilinear_on_box(X, lo, hi)
    assert sv.linear_precision_error(corners) < 1e-13
    _check_patch(Points(corners), sv, M, b)
    verts = rng.random((4, 3)) + np.eye(4, 3)
    bary = rng.dirichlet(np.ones(4), size=15)
    sv = barycentric_on_tet(bary @ verts, verts)
    _check_patch(Points(verts), sv, M, b)


@pytest.mark.parametrize("node_type", [AffineFrames, RigidFrames])
@pytest.mark.parametrize("seed", range(3))
def test_patch_frames_shepard(node_type, seed):
    """Frames reproduce any affine (rigid: rigid) motion with mere partition-of-unity weights."""
    rng = np.random.default_rng(seed)
    Xn = rng.random((6, 3))
    sv = shepard(rng.random((25, 3)), Xn, n_parents=4)
    if node_type is RigidFrames:
        M = Rotation.random(random_state=seed).as_matrix()
    else:
        M = np.eye(3) + 0.5 * rng.standard_normal((3, 3))
    _check_patch(node_type(Xn), sv, M, rng.standard_normal(3))


def test_points_with_shepard_fail_the_patch_test():
    """Sanity of the patch test itself: Shepard has no linear precision, so points do not reproduce F = M."""
    rng = np.random.default_rng(5)
    Xn = rng.random((6, 3))
    sv = shepard(rng.random((10, 3)), Xn)
    F = DeformationGradientMapping(Points(Xn), sv).apply(Xn @ (2 * np.eye(3)).T)
    assert np.abs(F - 2 * np.eye(3)).max() > 0.1


@pytest.mark.parametrize("node_type", NODE_TYPES)
def test_F_is_the_gradient_of_the_point_map(node_type):
    """F (and ∇F) agree with central differences of the mapped points (of F) in the rest position X.

    Shepard on all nodes is smooth away from the nodes; step h = 1e-5 gives
    truncation ~h²·|x'''| ~ 1e-9 and round-off ~1e-16/h ~ 1e-11, so 1e-7 relative.
    """
    rng = np.random.default_rng(11)
    Xn = rng.random((5, 3))
    X = rng.random((6, 3))
    nodes = node_type(Xn)
    s = _random_state(nodes, rng)
    sv = shepard(X, Xn)
    F, dF = DeformationGradientWithGradientMapping(nodes, sv).apply(s)
    h = 1e-5
    fdF = np.empty_like(F)
    fddF = np.empty_like(dF)
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        xp = PointMapping(nodes, shepard(X + e, Xn)).apply(s)
        xm = PointMapping(nodes, shepard(X - e, Xn)).apply(s)
        fdF[:, :, k] = (xp - xm) / (2 * h)
        Fp = DeformationGradientMapping(nodes, shepard(X + e, Xn)).apply(s)
        Fm = DeformationGradientMapping(nodes, shepard(X - e, Xn)).apply(s)
        fddF[..., k] = (Fp - Fm) / (2 * h)
    assert np.linalg.norm(F - fdF) / np.linalg.norm(F) < 1e-7
    assert np.linalg.norm(dF - fddF) / np.linalg.norm(dF) < 1e-7
    np.testing.assert_array_equal(DeformationGradientMapping(nodes, sv).apply(s), F)


@pytest.mark.parametrize("mapping_type", MAPPING_TYPES)
@pytest.mark.parametrize("node_type", NODE_TYPES)
def test_numba_equals_numpy_twin(node_type, mapping_type):
    """Compiled kernels and numpy twins agree to 1e-12 relative (same sums, different order)."""
    rng = np.random.default_rng(3)
    Xn = rng.random((9, 3))
    sv = padded_shepard(rng.random((30, 3)), Xn, 5, rng)
    nodes = node_type(Xn)
    s = _random_state(nodes, rng)
    fast = mapping_type(nodes, sv, backend="numba")
    ref = mapping_type(nodes, sv, backend="numpy")

    def close(a, b):
        a, b = np.asarray(a), np.asarray(b)
        assert np.abs(a - b).max() <= 1e-12 * max(np.abs(b).max(), 1e-300)

    close(_as_array(fast, fast.apply(s)), _as_array(ref, ref.apply(s)))
    dq = rng.standard_normal((nodes.n, nodes.dofs_per_node))
    close(_as_array(fast, fast.jvp(s, dq)), _as_array(ref, ref.jvp(s, dq)))
    f = rng.standard_normal((sv.m, fast.child_size))
    close(fast.vjp(s, f), ref.vjp(s, f))
    Jf, Jr = fast.jacobian(s), ref.jacobian(s)
    assert Jf.shape == Jr.shape == fast.shape_out
    close(Jf.toarray(), Jr.toarray())
    assert Jf.has_canonical_format
    close(fast.geometric_vp(s, f, dq), ref.geometric_vp(s, f, dq))


@pytest.mark.parametrize("node_type", NODE_TYPES)
def test_geometric_stiffness(node_type):
    """Zero for constant Jacobians; for rigid frames the matrix equals its matrix-free product."""
    rng = np.random.default_rng(4)
    Xn = rng.random((5, 3))
    nodes = node_type(Xn)
    s = _random_state(nodes, rng)
    mp = DeformationGradientMapping(nodes, shepard(rng.random((8, 3)), Xn, n_parents=3))
    f = rng.standard_normal((8, 3, 3))
    v = rng.standard_normal((5, nodes.dofs_per_node))
    Kg = mp.geometric(s, f)
    assert Kg.shape == (nodes.n_dofs, nodes.n_dofs)
    assert mp.constant_jacobian == (node_type is not RigidFrames)
    if mp.constant_jacobian:
        assert Kg.nnz == 0 and not np.any(mp.geometric_vp(s, f, v))
    else:
        kv = mp.geometric_vp(s, f, v).ravel()
        assert np.linalg.norm(kv) > 0.1
        np.testing.assert_allclose(Kg @ v.ravel(), kv, rtol=0, atol=1e-13 * np.linalg.norm(kv))


def test_rigid_velocity_moves_points_rigidly():
    """A rigid-body velocity field u(x) = v + ω × x given to every rigid frame (v_a = u(t_a), ω_a = ω)
    moves every mapped point and rotates every F exactly by that field: J reproduces rigid velocities
    (world-frame ω, left multiplication).  Round-off only: 1e-13."""
    rng = np.random.default_rng(8)
    Xn = rng.random((4, 3))
    nodes = RigidFrames(Xn)
    s = _random_state(nodes, rng)
    X = rng.random((6, 3))
    sv = shepard(X, Xn)
    v, w = rng.standard_normal(3), rng.standard_normal(3)
    t = s[:, 9:]
    dq = np.concatenate([v + np.cross(w, t), np.tile(w, (4, 1))], axis=1)
    pm = PointMapping(nodes, sv)
    np.testing.assert_allclose(pm.jvp(s, dq), v + np.cross(w, pm.apply(s)), rtol=0, atol=1e-13)
    fm = DeformationGradientMapping(nodes, sv)
    F = fm.apply(s)
    np.testing.assert_allclose(fm.jvp(s, dq), skew(w) @ F, rtol=0, atol=1e-12)


def test_input_validation():
    rng = np.random.default_rng(0)
    Xn = rng.random((4, 3))
    sv = shepard(rng.random((3, 3)), Xn)
    mp = PointMapping(AffineFrames(Xn), sv)
    with pytest.raises(InputError, match="state must have shape"):
        mp.apply(np.zeros((4, 3)))
    with pytest.raises(InputError, match="valid: numba, numpy"):
        PointMapping(AffineFrames(Xn), sv, backend="cuda")
    with pytest.raises(InputError, match="built for 4 nodes but there are 3"):
        PointMapping(Points(Xn[:3]), sv)
    loose = ShapeValues(sv.index, sv.w, sv.dw, sv.ddw, sv.rest)  # n_nodes not recorded
    with pytest.raises(InputError, match="only 3 nodes"):
        PointMapping(Points(Xn[:3]), loose)
    nohess = ShapeValues(sv.index, sv.w, sv.dw, None, sv.rest)
    with pytest.raises(InputError, match="Hessians"):
        DeformationGradientWithGradientMapping(Points(Xn), nohess)
    with pytest.raises(InputError, match="f must have shape"):
        mp.vjp(AffineFrames(Xn).rest, np.zeros((3, 4)))
    assert set(MAPPINGS) == {"points", "deformation-gradient", "deformation-gradient-with-gradient"}


def test_threaded_split_equals_numpy_twin(monkeypatch):
    """The forward and Jacobian kernels split over threads by child ranges give the twin's result (1e-12)."""
    import numba

    import voxflex.deform.chain.mappings as mappings

    monkeypatch.setattr(mappings, "_MIN_CHILDREN_PER_THREAD", 4)
    monkeypatch.setattr(numba, "get_num_threads", lambda: 3)
    rng = np.random.default_rng(6)
    Xn = rng.random((7, 3))
    sv = padded_shepard(rng.random((25, 3)), Xn, 4, rng)
    nodes = AffineFrames(Xn)
    s = _random_state(nodes, rng)
    fast = DeformationGradientWithGradientMapping(nodes, sv)
    ref = DeformationGradientWithGradientMapping(nodes, sv, backend="numpy")
    a, b = fast.pack(*fast.apply(s)), ref.pack(*ref.apply(s))
    assert np.abs(a - b).max() <= 1e-12 * np.abs(b).max()
    Ja, Jb = fast.jacobian(s), ref.jacobian(s)
    assert Ja.has_canonical_format and abs(Ja - Jb).max() <= 1e-12 * abs(Jb).max()
