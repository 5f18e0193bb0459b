"""Compiled kernels against their plain-Python runs (``py_func``): the same answer, bitwise.

A compiled kernel and its plain-Python execution (what ``VOXFLEX_DISABLE_JIT=1``
runs) do the same IEEE operations in the same order (no fastmath), so their
outputs must be equal exactly, integers (owners) included; any tolerance would
hide a tie broken differently.  The case guarded here: the front propagation
(:func:`voxflex.voronoi._march._march`) sorted its seeds with numba's
quicksort, which orders equal distances differently from numpy's, so voxels
equidistant from two seeds changed owner between the two runs (a bar with 10
frames and a clamp: 8 voxels), and with them the shape functions, the
mid-point samples and the tip sag.
"""

from __future__ import annotations

import numpy as np
import pytest

from voxflex._jit import DISABLED
from voxflex.voronoi import _march as M

pytestmark = pytest.mark.skipif(DISABLED, reason="VOXFLEX_DISABLE_JIT=1: there is no compiled kernel to compare")


def _bar():
    """A 16 x 4 x 4 bar of 0.25 m voxels, padded (mask, cost, shape, spacing)."""
    labels = np.ones((16, 4, 4), dtype=np.uint8)
    mask, cost, shape = M.pad_grid(labels)
    return labels, mask, cost, shape, np.full(3, 0.25)


def _run(kernel, mask, cost, shape, spacing, si, sd, so, fmm):
    N = mask.shape[0]
    dist = np.full(N, np.inf)
    owner = np.full(N, -1, dtype=np.int64)
    state = M.state_of(mask)
    scratch = [np.empty(N, dtype=np.int32) for _ in range(3)]
    kernel(cost, shape, spacing, dist, owner, state, scratch[0], scratch[1], dist, False, si, sd, so, fmm,
           scratch[2], 0, float(cost.min()), float(cost.max()))
    return dist, owner


@pytest.mark.parametrize("fmm", [0, 2])
def test_march_ties_go_to_the_first_seed_compiled_and_plain(fmm):
    """Seeds at equal distances (here all at 0: voxels claimed twice, by two owners) are applied in the
    order given, compiled or not: each voxel belongs to the owner listed first (the oracle)."""
    labels, mask, cost, shape, spacing = _bar()
    rng = np.random.default_rng(3)
    vox = rng.choice(labels.size, size=60, replace=False)
    flat = M.inner_to_flat(np.argwhere(labels)[vox], shape)
    first, second = rng.integers(0, 5, size=60), rng.integers(5, 10, size=60)
    si = np.concatenate([flat, flat])
    sd = np.zeros(120)
    so = np.concatenate([first, second])
    d1, o1 = _run(M._march, mask, cost, shape, spacing, si, sd, so, fmm)
    d2, o2 = _run(M._march.py_func, mask, cost, shape, spacing, si, sd, so, fmm)
    np.testing.assert_array_equal(o1[flat], first)
    np.testing.assert_array_equal(o2[flat], first)
    np.testing.assert_array_equal(d1, d2)
    np.testing.assert_array_equal(o1, o2)


def test_frame_distances_with_a_clamp_compiled_equals_plain():
    """The input that showed the bug: 10 frames' balls of exact distances (many equal, by symmetry)
    and the clamped end's voxels owned outright, second-order fast marching as the shape functions
    use it.  Distances and owners equal exactly."""
    labels, mask, cost, shape, spacing = _bar()
    frames = np.array([[1, 1, 2], [3, 2, 1], [5, 1, 1], [6, 2, 2], [8, 1, 2],
                       [9, 2, 1], [11, 1, 1], [12, 2, 2], [14, 1, 2], [15, 2, 1]]) + 0.5
    clamp = np.argwhere(labels)[np.argwhere(labels)[:, 0] == 0]  # the face x = 0: 16 voxels, frame 0's
    pts = np.concatenate([frames, clamp + 0.5]) + M.PAD
    owners = np.concatenate([np.arange(10), np.zeros(len(clamp), dtype=np.int64)])
    args = (mask, cost, shape, spacing, np.ascontiguousarray(pts), owners, M.BALL)
    si, sd, so = M._seed_arrays(*args)
    for a, b in zip((si, sd, so), M._seed_arrays.py_func(*args)):
        np.testing.assert_array_equal(a, b)
    assert len(np.unique(sd)) < len(sd) // 10  # plenty of ties: the case that needs a stable order
    d1, o1 = _run(M._march, mask, cost, shape, spacing, si, sd, so, 2)
    d2, o2 = _run(M._march.py_func, mask, cost, shape, spacing, si, sd, so, 2)
    np.testing.assert_array_equal(d1, d2)
    np.testing.assert_array_equal(o1, o2)
    assert np.all(o1[M.inner_to_flat(clamp, shape)] == 0)


_SUBRULE_CASES = """
import sys
import numpy as np
from voxflex.image import LabelImage
from voxflex.sampling.subrule import gauss_points_in_voxels, moment_fitted_rule
rng = np.random.default_rng(5)
for labels in (np.ones((4, 3, 2), dtype=np.uint8), (rng.random((6, 5, 4)) < 0.7).astype(np.uint8)):
    pts, vol, vox = gauss_points_in_voxels(LabelImage(labels))
    sel, w = moment_fitted_rule(pts, vol, (vox * 7) % 3, 3, h=1.0)
    sys.stdout.write(" ".join(map(str, sel)) + "|" + " ".join(float(x).hex() for x in w) + "\\n")
"""


def test_subrule_fits_compiled_equal_plain():
    """The elastons' sub-rule fits (``sampling._subrule_kernel``: Lawson-Hanson NNLS per region) compiled and
    run as plain Python (``VOXFLEX_DISABLE_JIT=1``, every kernel of the module): the same points and the same
    weights, bitwise, on regions of a box (every Gauss point tied with its mirror images: the tie rule
    decides) and of a random blob."""
    import os
    import subprocess
    import sys

    runs = []
    for disable in ("0", "1"):
        env = dict(os.environ, VOXFLEX_DISABLE_JIT=disable)
        out = subprocess.run([sys.executable, "-c", _SUBRULE_CASES], env=env, capture_output=True, text=True,
                             timeout=600, check=True).stdout
        runs.append(out)
    assert runs[0] == runs[1]
    assert len(runs[0].splitlines()) == 2 and all(len(line.split("|")[0].split()) >= 3 for line in runs[0].splitlines())


def test_the_samplers_dijkstra_compiled_equals_plain():
    """The march's Dijkstra with groups and ties in a binary heap's order (the sampler's:
    :class:`voxflex.voronoi._march.VoxelGraph`) on the bar, two groups, 30 seeds: distances, owners and the
    voxels each distance came from equal exactly."""
    labels, mask, cost, shape, spacing = _bar()
    rng = np.random.default_rng(5)
    N = mask.shape[0]
    flat = M.inner_to_flat(np.argwhere(labels), shape)
    group = np.full(N, -1, dtype=np.int64)
    group[flat] = rng.integers(0, 2, len(flat))
    si = rng.choice(flat, 30, replace=False)
    out = []
    for kernel in (M._march, M._march.py_func):
        dist, owner, pred = np.full(N, np.inf), np.full(N, -1, dtype=np.int64), np.full(N, -7, dtype=np.int32)
        scratch = [np.empty(N, dtype=np.int32) for _ in range(3)]
        kernel(cost, shape, spacing, dist, owner, M.state_of(mask), scratch[0], scratch[1], dist, False, si,
               np.zeros(30), np.arange(30), 0, scratch[2], 0, 1.0, 1.0, group, pred)
        out.append((dist, owner, pred))
    for a, b in zip(*out):
        np.testing.assert_array_equal(a, b)
