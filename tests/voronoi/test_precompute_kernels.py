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
