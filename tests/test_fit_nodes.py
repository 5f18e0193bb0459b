"""The per-node quadratic fits of the natural-neighbour weights: compiled kernel against its numpy twin.

Oracle: the numpy twin (``fit_nodes(..., backend="numpy")``, the former Python loop) on an L-shaped
block whose node neighbourhoods include flat ones (the ridge then decides the free coefficients):
the same frames per node, and the same fitted weights at every node's samples to 1e-10 (the
coefficients themselves may differ by round-off times the ridge's condition number, ~1e-8, along
directions the samples do not see).
"""

from __future__ import annotations

import sys

import numpy as np

from voxflex.image import LabelImage
from voxflex.voronoi import place_frames, shape_function

SF = sys.modules["voxflex.voronoi.shape_function"]


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
