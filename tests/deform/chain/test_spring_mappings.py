"""Distance and extension mappings (voxflex.deform.chain.spring); derivatives are in the contract."""

from __future__ import annotations

import numpy as np
import pytest

from voxflex.deform.chain.spring import DistanceMapping, ExtensionMapping
from voxflex.errors import InputError


def test_values_and_cable_force_balance():
    X = np.array([[0.0, 0, 0], [3, 4, 0], [0, 0, 2]])
    edges = [[0, 1], [1, 2]]
    dist = DistanceMapping(edges, 3)
    np.testing.assert_allclose(dist.apply(X), [5.0, np.sqrt(29.0)], rtol=1e-15)
    ext = ExtensionMapping(edges, rest_points=X)
    np.testing.assert_allclose(ext.apply(X), 0.0, atol=1e-15)
    np.testing.assert_allclose(ext.apply(2 * X), 1.0, rtol=1e-14)  # every edge doubled
    # Jᵀ of an edge tension: equal and opposite forces along the edge (no net force, no net torque)
    x = 2 * X + 0.1
    f = ext.vjp(x, np.array([1.0, -2.0]))
    np.testing.assert_allclose(f.sum(axis=0), 0.0, atol=1e-14)
    np.testing.assert_allclose(np.cross(x, f).sum(axis=0), 0.0, atol=1e-13)
    # the geometric stiffness is symmetric and annihilates translations
    K = ext.geometric(x, np.array([1.0, -2.0])).toarray()
    np.testing.assert_allclose(K, K.T, atol=1e-15)
    np.testing.assert_allclose(K @ np.tile([1.0, 2, 3], 3), 0.0, atol=1e-14)


def test_targets():
    T = np.array([[1.0, 0, 0], [0, 0, 5]])
    d = DistanceMapping.to_targets([0, 0], T, n_points=1)
    np.testing.assert_allclose(d.apply([[0.0, 0, 1]]), [np.sqrt(2.0), 4.0], rtol=1e-15)


def test_bad_input():
    with pytest.raises(InputError, match="rest lengths must be > 0"):
        ExtensionMapping([[0, 1]], rest_points=np.zeros((2, 3)))
    with pytest.raises(InputError, match="outside"):
        DistanceMapping([[0, 3]], 2)
    with pytest.raises(InputError, match=r"\(2, 3\)"):
        DistanceMapping([[0, 1]], 2).apply(np.zeros((3, 3)))
