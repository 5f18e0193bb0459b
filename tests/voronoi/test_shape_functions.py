"""Shape-function container and Shepard weights: partition of unity, positivity, derivatives."""

from __future__ import annotations

import numpy as np
import pytest

from voxflex.errors import InputError
from voxflex.voronoi.shape_functions import ShapeValues, shepard


def _dense(sv, n, what):
    """Scatter (m, P, ...) per-parent values into (m, n, ...) so different parent orders compare."""
    vals = getattr(sv, what)
    out = np.zeros((sv.m, n) + vals.shape[2:])
    for c in range(sv.m):
        for p, a in enumerate(sv.index[c]):
            if a >= 0:
                out[c, a] = vals[c, p]
    return out


@pytest.mark.parametrize("power", [2.0, 3.0, 1.5])
def test_shepard_partition_of_unity_and_positivity(power):
    rng = np.random.default_rng(0)
    Xn = rng.random((8, 3))
    sv = shepard(rng.random((50, 3)), Xn, power=power)
    # sums of 8 terms of size ≤ |dw|·L: round-off ~1e-14 relative to those sizes
    assert sv.partition_of_unity_error() < 1e-12 * max(1.0, np.abs(sv.ddw).max())
    assert np.all(sv.w >= 0)
    np.testing.assert_allclose(sv.ddw, sv.ddw.transpose(0, 1, 3, 2), rtol=0, atol=1e-12 * np.abs(sv.ddw).max())
    knn = shepard(rng.random((50, 3)), Xn, power=power, n_parents=3)
    assert knn.n_parents == 3 and knn.partition_of_unity_error() < 1e-12 * max(1.0, np.abs(knn.ddw).max())


def test_shepard_interpolates_at_nodes():
    rng = np.random.default_rng(1)
    Xn = rng.random((6, 3))
    sv = shepard(Xn, Xn)
    np.testing.assert_array_equal(_dense(sv, 6, "w"), np.eye(6))
    assert not np.any(sv.dw)


@pytest.mark.parametrize("power", [2.0, 3.0])
def test_shepard_derivatives_match_finite_differences(power):
    """Central differences with h = 1e-5 on points ≥ 0.05 from any node: truncation ~h²·|w'''| ≲ 1e-6,
    round-off ~1e-16/h; compared relative to the largest derivative with 1e-6."""
    rng = np.random.default_rng(2)
    Xn = rng.random((6, 3))
    X = rng.random((40, 3))
    X = X[np.min(np.linalg.norm(X[:, None] - Xn[None], axis=2), axis=1) > 0.05]
    sv = shepard(X, Xn, power=power)
    h = 1e-5
    dw, ddw = _dense(sv, 6, "dw"), _dense(sv, 6, "ddw")
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        p, m = shepard(X + e, Xn, power=power), shepard(X - e, Xn, power=power)
        fd_w = (_dense(p, 6, "w") - _dense(m, 6, "w")) / (2 * h)
        fd_dw = (_dense(p, 6, "dw") - _dense(m, 6, "dw")) / (2 * h)
        assert np.abs(fd_w - dw[..., k]).max() < 1e-6 * np.abs(dw).max()
        assert np.abs(fd_dw - ddw[..., k]).max() < 1e-6 * np.abs(ddw).max()


def test_shepard_hessian_limit_at_a_node():
    """At a node (power 2) the Hessian is the limit ±2Σg I; compare with central differences of dw."""
    rng = np.random.default_rng(3)
    Xn = rng.random((5, 3))
    sv = shepard(Xn[:1], Xn)
    h = 1e-5
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        fd = (_dense(shepard(Xn[:1] + e, Xn), 5, "dw") - _dense(shepard(Xn[:1] - e, Xn), 5, "dw")) / (2 * h)
        # error O(h²)·|w''''| relative to |ddw| ~ 10: 1e-6 is generous and catches a wrong limit (O(1))
        np.testing.assert_allclose(fd, _dense(sv, 5, "ddw")[..., k], rtol=0, atol=1e-6 * np.abs(sv.ddw).max())


def test_container_validation():
    idx = np.array([[0, 1, -1]])
    w = np.array([[0.5, 0.5, 0.0]])
    dw = np.zeros((1, 3, 3))
    X = np.zeros((1, 3))
    sv = ShapeValues(idx, w, dw, None, X, n_nodes=2)
    assert (sv.m, sv.n_parents, sv.has_hessians) == (1, 3, False)
    assert sv.index.dtype == np.int64 and sv.partition_of_unity_error() == 0.0
    np.testing.assert_array_equal(sv.to_sparse().toarray(), [[0.5, 0.5]])
    with pytest.raises(InputError, match="only 1 nodes"):
        ShapeValues(idx, w, dw, None, X, n_nodes=1)
    with pytest.raises(InputError, match=r"w must have shape \(1, 3\)"):
        ShapeValues(idx, w[:, :2], dw, None, X)
    with pytest.raises(InputError, match="non-finite"):
        ShapeValues(idx, np.array([[np.nan, 0.5, 0.0]]), dw, None, X)
    with pytest.raises(InputError, match="padded slots"):
        ShapeValues(idx, np.array([[0.5, 0.4, 0.1]]), dw, None, X)
    with pytest.raises(InputError, match="repeats a parent"):
        ShapeValues(np.array([[1, 1, -1]]), w, dw, None, X)
    with pytest.raises(InputError, match=r"ddw must have shape"):
        ShapeValues(idx, w, dw, np.zeros((1, 3, 3)), X)
    # the compiled check names each problem wherever it sits (not only in the first row or slot)
    idx2 = np.array([[0, 1, -1], [2, 0, 1]])
    w2 = np.array([[0.5, 0.5, 0.0], [0.2, 0.3, 0.5]])
    dw2, ddw2, X2 = np.zeros((2, 3, 3)), np.zeros((2, 3, 3, 3)), np.zeros((2, 3))
    ShapeValues(idx2, w2, dw2, ddw2, X2, n_nodes=3)
    for name, arr in (("dw", dw2), ("ddw", ddw2), ("rest", X2)):
        a = arr.copy()
        a.reshape(-1)[-1] = np.inf
        args = {"dw": dw2, "ddw": ddw2, "rest": X2, name: a}
        with pytest.raises(InputError, match=f"ShapeValues.{name} has non-finite"):
            ShapeValues(idx2, w2, args["dw"], args["ddw"], args["rest"])
    with pytest.raises(InputError, match="below -1"):
        ShapeValues(np.array([[0, 1, -1], [2, 0, -2]]), w2 * [[1, 1, 1], [1, 1, 0]], dw2, None, X2)
    for arr in (dw2, ddw2):
        a = arr.copy()
        a[0, 2] = 1.0
        with pytest.raises(InputError, match="padded slots"):
            ShapeValues(idx2, w2, a if arr is dw2 else dw2, a if arr is ddw2 else ddw2, X2)
    with pytest.raises(InputError, match="repeats a parent"):
        ShapeValues(np.array([[0, 1, -1], [1, 0, 1]]), w2, dw2, None, X2)
    bad = ShapeValues(idx, np.array([[0.5, 0.6, 0.0]]), dw, None, X)
    assert abs(bad.partition_of_unity_error() - 0.1) < 1e-15
    with pytest.raises(InputError, match="power"):
        shepard(X, X, power=0.0)
    with pytest.raises(InputError, match="n_parents"):
        shepard(X, X, n_parents=2)
