"""Natural-neighbour coordinates on voxels by bounded propagation (private kernels).

Sibson's coordinate of frame i at a point x is the share of the volume that x
would steal from i's geodesic Voronoi cell if it were inserted as a new seed;
Laplace's is the area of the boundary between x's new cell and i's cell over
the distance between x and frame i, normalised.  A voxel v is stolen when
``d_x(v) < d(v)`` (d: the distance to the nearest frame); the stolen set is
reached from x by a propagation that stops wherever x no longer wins, so the
work per point is the size of its new cell (about one Voronoi cell), not the
image.  The naive twin, :func:`natural_naive`, re-propagates over the whole
image for each point (the tests compare the two).

For Laplace the distance between x and frame i is estimated locally as twice
the distance from x to the shared boundary (exact for the Euclidean bisector):
``h_i = min over boundary faces (d_x(v) + d(u) + step)`` for a stolen voxel v
and its face neighbour u in cell i (the face lies half a step from each).  Boundary areas are counted on voxel faces (a
staircase: a slanted face is over-counted by up to its |n|₁/|n|₂ <= √3).
"""

from __future__ import annotations

import numpy as np
from numba import get_num_threads

from .._jit import njit, prange
from . import _march as M


@njit
def _one_point(mask, cost, shape, spacing, d, own, p, nframes, laplace,
               dx, ox, state, nxt, prv, touched, acc, hmin, smin, smax, radius, ball_i, ball_d, ball_o):
    """Natural-neighbour weights of one point (padded index coords p); fills acc (n,), returns it unnormalised."""
    cnt = M._ball(mask, cost, shape, spacing, p, radius, ball_i, ball_d)
    for q in range(cnt):
        ball_o[q] = nframes
    nt = M._march(cost, shape, spacing, dx, ox, state, nxt, prv, d, True,
                  ball_i[:cnt], ball_d[:cnt], ball_o[:cnt], 2, touched, 0, smin, smax)
    s1 = shape[1] * shape[2]
    s2 = shape[2]
    if laplace == 0:
        for k in range(nt):
            acc[own[touched[k]]] += 1.0
    else:
        area0 = spacing[1] * spacing[2]
        area1 = spacing[0] * spacing[2]
        area2 = spacing[0] * spacing[1]
        for k in range(nt):
            v = touched[k]
            for a in range(3):
                st = s1 if a == 0 else (s2 if a == 1 else 1)
                ar = area0 if a == 0 else (area1 if a == 1 else area2)
                for sgn in (-1, 1):
                    u = v + sgn * st
                    if state[u] != 0:  # stolen (1, 2) or empty (3)
                        continue
                    f = own[u]
                    acc[f] += ar
                    h = dx[v] + d[u] + spacing[a] * 0.5 * (cost[u] + cost[v])
                    if h < hmin[f]:
                        hmin[f] = h
    for k in range(nt):
        v = touched[k]
        dx[v] = np.inf
        ox[v] = -1
        state[v] = 0
    return nt


@njit(parallel=True)
def _natural_kernel(mask, cost, shape, spacing, d, own, points, nframes, laplace, kmax, smin, smax, radius,
                    nthreads, out_f, out_w, out_n):
    """Weights of every point (q, 3) (padded index coords): top-kmax frames per point, normalised.

    The points are dealt round-robin to ``nthreads`` chunks, each with its own
    grid-sized scratch (allocated once per chunk, so keep ``nthreads`` a small
    multiple of the number of threads)."""
    N = mask.shape[0]
    per = (2 * radius + 1) ** 3
    for t in prange(nthreads):
        dx = np.full(N, np.inf)
        ox = np.full(N, -1, dtype=np.int64)
        state = np.empty(N, dtype=np.uint8)
        for v in range(N):
            state[v] = 0 if mask[v] != 0 else 3
        nxt = np.empty(N, dtype=np.int32)
        prv = np.empty(N, dtype=np.int32)
        touched = np.empty(N, dtype=np.int32)
        acc = np.zeros(nframes)
        hmin = np.full(nframes, np.inf)
        ball_i = np.empty(per, dtype=np.int64)
        ball_d = np.empty(per)
        ball_o = np.empty(per, dtype=np.int64)
        for q in range(t, points.shape[0], nthreads):
            _one_point(mask, cost, shape, spacing, d, own, points[q], nframes, laplace,
                       dx, ox, state, nxt, prv, touched, acc, hmin, smin, smax, radius, ball_i, ball_d, ball_o)
            if laplace == 1:
                for f in range(nframes):
                    if acc[f] > 0:
                        acc[f] = acc[f] / hmin[f]
            elif laplace == 2:  # distance ratio: inverse distance over the natural neighbours
                for f in range(nframes):
                    acc[f] = 1.0 / hmin[f] if hmin[f] < np.inf else 0.0
            tot = 0.0
            for f in range(nframes):
                tot += acc[f]
            # keep the kmax largest
            m = 0
            for f in range(nframes):
                a = acc[f]
                if a <= 0:
                    continue
                if m < kmax:
                    j = m
                    m += 1
                else:
                    if a <= out_w[q, kmax - 1]:
                        continue
                    j = kmax - 1
                while j > 0 and out_w[q, j - 1] < a:
                    out_w[q, j] = out_w[q, j - 1]
                    out_f[q, j] = out_f[q, j - 1]
                    j -= 1
                out_w[q, j] = a
                out_f[q, j] = f
            kept = 0.0
            for j in range(m):
                kept += out_w[q, j]
            for j in range(m):
                out_w[q, j] /= kept
            out_n[q] = m
            for f in range(nframes):
                acc[f] = 0.0
                hmin[f] = np.inf


def natural_weights(mask, cost, pshape, spacing, d, own, points, nframes, *, laplace, kmax=32):
    """Natural-neighbour weights of points (q, 3) in padded index coords.

    ``laplace``: False or 0 Sibson, True or 1 Laplace, 2 distance ratio (``1 / h_i``
    over the natural neighbours i, h_i the distance from the point to frame i through
    the shared boundary, as for Laplace).

    Returns frames (q, kmax) int64 (-1 padded), weights (q, kmax) (sum 1 per row) and counts (q,).
    """
    q = len(points)
    out_f = np.full((q, kmax), -1, dtype=np.int64)
    out_w = np.zeros((q, kmax))
    out_n = np.zeros(q, dtype=np.int64)
    if q:
        _natural_kernel(mask, cost, pshape, spacing, d, own, np.ascontiguousarray(points, dtype=np.float64),
                        int(nframes), int(laplace), int(kmax), float(cost.min()), float(cost.max()), M.BALL,
                        min(q, 2 * get_num_threads()), out_f, out_w, out_n)
    return out_f, out_w, out_n


def natural_naive(mask, cost, pshape, spacing, frame_points, point, *, laplace):
    """The naive twin: full, unbounded propagation from the point over the whole image (tests only).

    A voxel is stolen where the point's own distance field is below the frames'.
    Returns dense weights (n,) of one point (padded index coords).
    """
    n = len(frame_points)
    d, own = M.march(mask, cost, pshape, spacing, frame_points, np.arange(n), fmm=2)
    d2, _ = M.march(mask, cost, pshape, spacing, np.asarray(point, dtype=np.float64)[None], [n], fmm=2)
    stolen = (d2 < d) & (mask > 0)
    acc = np.zeros(n)
    if int(laplace) == 0:
        np.add.at(acc, own[stolen], 1.0)
    else:
        hmin = np.full(n, np.inf)
        s = [int(pshape[1] * pshape[2]), int(pshape[2]), 1]
        areas = [spacing[1] * spacing[2], spacing[0] * spacing[2], spacing[0] * spacing[1]]
        for v in np.flatnonzero(stolen):
            for a in range(3):
                for sgn in (-1, 1):
                    u = v + sgn * s[a]
                    if mask[u] and not stolen[u]:
                        acc[own[u]] += areas[a]
                        hmin[own[u]] = min(hmin[own[u]], d2[v] + d[u] + spacing[a] * 0.5 * (cost[u] + cost[v]))
        if int(laplace) == 2:
            acc = np.where(np.isfinite(hmin), 1.0 / hmin, 0.0)
        else:
            acc = np.where(acc > 0, acc / hmin, 0.0)
    return acc / acc.sum()
