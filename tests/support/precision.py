"""The patch test of linearly precise frame weights, shared by every such family's tests.

An affine motion of every frame gives F = its matrix at every sample (partition of unity); frames
carrying the quadratic field x(X) = X + G X + 1/2 [X^T Hq_i X]_i (frame a: A_a = I + G + 1/2 Hq X_a,
t_a = A_a X_a) give its exact gradient and positions at the samples (linear precision).
"""

from __future__ import annotations

import numpy as np

from voxflex.deform.chain.mappings import PointMapping


def check_linear_precision(m, *, x_tol: float) -> None:
    """Assert the patch tests on the frame model ``m`` (F to 1e-12 affine, 1e-11 quadratic; positions to
    ``x_tol``, which the families' tests state)."""
    X = m.frames
    rng = np.random.default_rng(0)
    A = np.eye(3) + 0.1 * rng.standard_normal((3, 3))
    b = rng.standard_normal(3)
    F = m.deformation_gradients(m.moved_state(np.concatenate([A, b[:, None]], axis=1)))
    assert np.abs(F - A).max() < 1e-12
    G = 0.05 * rng.standard_normal((3, 3))
    Hq = 0.05 * rng.standard_normal((3, 3, 3))
    Hq = 0.5 * (Hq + Hq.transpose(0, 2, 1))
    q = np.zeros((len(X), 12))
    for a in range(len(X)):
        Aa = np.eye(3) + G + 0.5 * np.einsum("ijk,k->ij", Hq, X[a])
        q[a, :9] = Aa.reshape(9)
        q[a, 9:] = Aa @ X[a]
    P = m.samples.points
    exact = np.eye(3) + G + np.einsum("ijk,mk->mij", Hq, P)
    assert np.abs(m.deformation_gradients(q) - exact).max() < 1e-11
    x = PointMapping(m.nodes, m.samples.values).apply(q)
    assert np.abs(x - (P + P @ G.T + 0.5 * np.einsum("mj,ijk,mk->mi", P, Hq, P))).max() < x_tol
