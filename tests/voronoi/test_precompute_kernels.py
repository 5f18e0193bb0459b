"""Compiled precompute kernels against their numpy twins.

The per-node quadratic fits of the natural-neighbour weights.  Oracle: the numpy twin (``fit_nodes(..., backend="numpy")``, the former Python loop) on an L-shaped
block whose node neighbourhoods include flat ones (the ridge then decides the free coefficients):
the same frames per node, and the same fitted weights at every node's samples to 1e-10 (the
coefficients themselves may differ by round-off times the ridge's condition number, ~1e-8, along
directions the samples do not see).

Pruning to the largest parents (``keep_largest``): the numpy twin, bit for bit (same order of
operations), on blended values with Hessians and without.
"""

from __future__ import annotations

import sys

import numpy as np

from voxflex.image import LabelImage
from voxflex.voronoi import place_frames, shape_function

SF = sys.modules["voxflex.voronoi.weights"]


def test_compiled_fit_matches_numpy_twin(monkeypatch):
    lab = np.ones((24, 16, 10), np.uint8)
    lab[12:, 8:, :5] = 0
    image = LabelImage(lab, spacing=(0.1, 0.1, 0.1))
    frames = place_frames(image, 12, seed=0)
    captured = {}
    real = SF.fit_nodes

    def spy(*args, **kwargs):
        captured["args"] = args
        return real(*args, **kwargs)

    monkeypatch.setattr(SF, "fit_nodes", spy)
    shape_function(image, frames)
    node_pos, nf, nw, pa, pb, h, n = captured["args"]
    F1, C1 = real(*captured["args"])
    F2, C2 = real(*captured["args"], backend="numpy")
    np.testing.assert_array_equal(F1, F2)
    # fitted values at each node's neighbours (and the node itself: interpolated exactly)
    indptr, indices = SF._adjacency(pa, pb, len(node_pos))
    for q in range(0, len(node_pos), 5):
        nb = indices[indptr[q]:indptr[q + 1]]
        x = (node_pos[np.concatenate([[q], nb])] - node_pos[q]) / h
        phi, _, _ = SF._basis(x)
        v1 = C1[q, :, :1].T + phi @ C1[q, :, 1:].T
        v2 = C2[q, :, :1].T + phi @ C2[q, :, 1:].T
        np.testing.assert_allclose(v1, v2, rtol=0, atol=1e-10)


def test_keep_largest_matches_numpy_twin():
    from voxflex.voronoi.shape_functions import ShapeValues, keep_largest

    image = LabelImage(np.ones((14, 10, 8), np.uint8), spacing=(0.1, 0.1, 0.1))
    frames = place_frames(image, 12, seed=2)
    vv = shape_function(image, frames).voxel_values()
    assert vv.n_parents > 6
    for values in (vv, ShapeValues(vv.index, vv.w, vv.dw, None, vv.rest, n_nodes=vv.n_nodes)):
        for parents in (2, 4, 6):
            a, b = keep_largest(values, parents), keep_largest(values, parents, backend="numpy")
            np.testing.assert_array_equal(a.index, b.index)
            np.testing.assert_array_equal(a.w, b.w)
            np.testing.assert_array_equal(a.dw, b.dw)
            assert (a.ddw is None) == (b.ddw is None)
            if a.ddw is not None:
                np.testing.assert_array_equal(a.ddw, b.ddw)
            assert np.abs(a.w.sum(1) - 1).max() < 1e-14


def _bumps(x):
    """A smooth partition of unity of 7 frames on the x axis (normalised Gaussians), with exact derivatives."""
    centres = np.linspace(0.0, 1.0, 7)
    g = np.exp(-((x[:, None] - centres[None]) ** 2) / 0.08)
    dg = -2.0 * (x[:, None] - centres[None]) / 0.08 * g
    ddg = (4.0 * (x[:, None] - centres[None]) ** 2 / 0.08**2 - 2.0 / 0.08) * g
    s, ds, dds = g.sum(1, keepdims=True), dg.sum(1, keepdims=True), ddg.sum(1, keepdims=True)
    w = g / s
    dw = (dg - w * ds) / s
    ddw = (ddg - 2.0 * dw * ds - w * dds) / s
    m = len(x)
    D = np.zeros((m, 7, 3))
    D[..., 0] = dw
    H = np.zeros((m, 7, 3, 3))
    H[..., 0, 0] = ddw
    return w, D, H


def test_the_parents_cut_is_conforming():
    """Cut to 3 of 7 smooth weights along a line, the kept weights reach zero where they leave the set: the
    cut functions are continuous (no step larger than their slope allows between points 1e-5 apart), while
    renormalising the kept weights as they are jumps by ~0.2 where the set changes.  Partition of unity
    everywhere; value, gradient and Hessian consistent with central differences away from the changes of
    order; where the largest four are exactly equal the plain cut is kept (no division by zero)."""
    from voxflex.voronoi.shape_functions import ShapeValues, keep_largest

    h = 1e-5
    x = np.arange(0.0, 1.0, h)
    w, dw, ddw = _bumps(x)
    m = len(x)
    rest = np.zeros((m, 3))
    rest[:, 0] = x
    index = np.broadcast_to(np.arange(7), (m, 7)).copy()
    cut = keep_largest(ShapeValues(index, w, dw, ddw, rest, n_nodes=7), 3)
    full = np.zeros((m, 7))
    np.put_along_axis(full, np.maximum(cut.index, 0), np.where(cut.index >= 0, cut.w, 0.0), axis=1)
    assert np.abs(full.sum(1) - 1.0).max() < 1e-13
    step = np.abs(np.diff(full, axis=0)).max()
    slope = np.abs(np.where(cut.index >= 0, cut.dw[..., 0], 0.0)).max()
    assert step <= 1.01 * slope * h
    plain = w * (np.argsort(np.argsort(-w, axis=1), axis=1) < 3)
    plain /= plain.sum(1, keepdims=True)
    assert np.abs(np.diff(plain, axis=0)).max() > 0.1  # what the conforming cut removes
    # derivatives: central differences where the order of the 4 largest is the same at x - h, x, x + h
    rank = np.argsort(-w, axis=1)[:, :4]
    same = np.all(rank[:-2] == rank[1:-1], axis=1) & np.all(rank[2:] == rank[1:-1], axis=1)
    i = 1 + np.flatnonzero(same)[::97]
    fd = (full[i + 1] - full[i - 1]) / (2 * h)
    fdd = (full[i + 1] - 2 * full[i] + full[i - 1]) / h**2
    g = np.zeros((m, 7))
    np.put_along_axis(g, np.maximum(cut.index, 0), np.where(cut.index >= 0, cut.dw[..., 0], 0.0), axis=1)
    hh = np.zeros((m, 7))
    np.put_along_axis(hh, np.maximum(cut.index, 0), np.where(cut.index >= 0, cut.ddw[..., 0, 0], 0.0), axis=1)
    assert np.abs(fd - g[i]).max() < 1e-6 * np.abs(g[i]).max()
    assert np.abs(fdd - hh[i]).max() < 1e-3 * np.abs(hh[i]).max()
    # exact symmetry: four equal largest weights keep the plain cut there
    tie = ShapeValues(np.array([[0, 1, 2, 3, 4]]), np.array([[0.2, 0.2, 0.2, 0.2, 0.2]]), np.zeros((1, 5, 3)),
                      None, np.zeros((1, 3)), n_nodes=5)
    for backend in ("numba", "numpy"):
        t = keep_largest(tie, 3, backend=backend)
        assert np.allclose(t.w, 1.0 / 3.0) and np.all(np.isfinite(t.dw))
