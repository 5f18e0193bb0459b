"""Natural-neighbour coordinates on voxels by bounded propagation (private kernels).

Sibson's coordinate of frame i at a point x is the share of the volume that x
would steal from i's geodesic Voronoi cell if it were inserted as a new seed;
Laplace's is the area of the boundary between x's new cell and i's cell over
the distance between x and frame i, normalised.  A voxel v is stolen when
``d_x(v) < d(v)`` (d: the distance to the nearest frame, second-order fast
marching); the stolen set is reached from x by a propagation that stops
wherever x no longer wins, so the work per point is the size of its new cell
(about one Voronoi cell), not the image.  The naive twin, :func:`natural_naive`,
re-propagates over the whole image for each point (the tests compare the two).

``d_x`` is measured in line of sight (:mod:`._sight`) when the material has one
slowness: where x sees every voxel it steals (a convex part), ``d_x`` is the
straight-line distance and the stolen set is found by a span fill along the
contiguous z rows with no priority queue (:func:`_span_steal`: a few ns per
voxel, against ~1.3 µs per voxel for the bounded fast marching it replaces);
where it does not, by the bounded line-of-sight march.  With a compliance
distance (several slownesses) it is bounded second-order fast marching.

For Laplace the distance between x and frame i is estimated locally as twice
the distance from x to the shared boundary (exact for the Euclidean bisector):
``h_i = min over boundary faces (d_x(v) + d(u) + step)`` for a stolen voxel v
and its face neighbour u in cell i (the face lies half a step from each).  Boundary areas are counted on voxel faces (a
staircase: a slanted face is over-counted by up to its |n|₁/|n|₂ <= √3).
"""

from __future__ import annotations

import math

import numpy as np
from numba import get_num_threads

from .._jit import njit, prange
from . import _march as M
from . import _sight as S

STEAL = 1.0 - 1e-9
"""A point steals a voxel when it is nearer than ``STEAL`` times the voxel's distance to its frame: a voxel
at the same distance (symmetric bodies have many) is not stolen, whatever the unit of length rounds."""


@njit
def _stolen_sight(mask, table, shape, spacing, slow, d, p, nframes, dx, ox, src, state, nxt, prv, touched, spans):
    """Stolen voxels of a point (padded index coords p) in line-of-sight distances (one slowness):
    by the span fill when the point sees all of them, else by the bounded line-of-sight march.
    Writes them to ``touched`` with their ``dx``, marks them in ``state``; returns their count."""
    r = _span_steal(mask, table, shape, spacing, slow, d, p, state, spans, spans.shape[0])
    nr = r if r >= 0 else -r - 1
    nt = 0
    s1 = shape[1] * shape[2]
    s2 = shape[2]
    for q in range(nr):
        a = spans[q, 0]
        i = a // s1
        j = (a - i * s1) // s2
        k0 = a - i * s1 - j * s2
        ryz = ((i + 0.5 - p[0]) * spacing[0]) ** 2 + ((j + 0.5 - p[1]) * spacing[1]) ** 2
        for t in range(spans[q, 1]):
            v = a + t
            touched[nt] = v
            nt += 1
            dx[v] = slow * math.sqrt(ryz + ((k0 + t + 0.5 - p[2]) * spacing[2]) ** 2)
    if r < 0:  # not all in sight: clear and march
        for q in range(nt):
            v = touched[q]
            state[v] = 0
            dx[v] = np.inf
        pts = np.empty((1, 3))
        pts[0, 0], pts[0, 1], pts[0, 2] = p[0], p[1], p[2]
        ownp = np.full(1, nframes, dtype=np.int64)
        nt = S._sight_march(mask, table, shape, spacing, slow, dx, ox, src, state, nxt, prv, d, True,
                            pts, ownp, touched, 0, False)
    return nt


@njit
def _stolen_fmm(mask, cost, shape, spacing, d, p, nframes, dx, ox, state, nxt, prv, touched, smin, smax, radius,
                ball_i, ball_d, ball_o):
    """Stolen voxels of a point by bounded second-order fast marching (several slownesses)."""
    cnt = M._ball(mask, cost, shape, spacing, p, radius, ball_i, ball_d)
    for q in range(cnt):
        ball_o[q] = nframes
    return M._march(cost, shape, spacing, dx, ox, state, nxt, prv, d, True,
                    ball_i[:cnt], ball_d[:cnt], ball_o[:cnt], 2, touched, 0, smin, smax)


@njit
def _accumulate(cost, shape, spacing, d, own, laplace, dx, ox, state, touched, nt, acc, hmin):
    """Unnormalised weights of one point from its stolen voxels (acc (n,), and hmin for Laplace);
    resets the scratch of the stolen voxels."""
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


@njit
def keep_largest_insert(values, index, count, k, v, f):
    """Insert value v of item f into the descending ``values[:count]`` (with ``index``), keeping at most
    k entries (the first one stays on ties); returns the new count."""
    if count < k:
        j = count
        count += 1
    elif v > values[k - 1]:
        j = k - 1
    else:
        return count
    while j > 0 and values[j - 1] < v:
        values[j] = values[j - 1]
        index[j] = index[j - 1]
        j -= 1
    values[j] = v
    index[j] = f
    return count


@njit
def normalise_first(values, count):
    """Divide ``values[:count]`` by their sum."""
    total = 0.0
    for j in range(count):
        total += values[j]
    for j in range(count):
        values[j] /= total


@njit
def _finish(acc, hmin, nframes, laplace, kmax, q, out_f, out_w, out_n):
    """Row q of the outputs from acc: Laplace / distance-ratio weights, the kmax largest, normalised;
    resets acc and hmin."""
    if laplace == 1:
        for f in range(nframes):
            if acc[f] > 0:
                acc[f] = acc[f] / hmin[f]
    elif laplace == 2:  # distance ratio: inverse distance over the natural neighbours
        for f in range(nframes):
            acc[f] = 1.0 / hmin[f] if hmin[f] < np.inf else 0.0
    m = 0
    for f in range(nframes):
        if acc[f] > 0:
            m = keep_largest_insert(out_w[q], out_f[q], m, kmax, acc[f], f)
    normalise_first(out_w[q], m)
    out_n[q] = m
    for f in range(nframes):
        acc[f] = 0.0
        hmin[f] = np.inf


@njit
def _span_steal(mask, table, shape, spacing, slow, d, p, state, spans, nspan_max):
    """The voxels a point steals, when all of them are in straight line of sight of it.

    Stolen voxels are the material voxels v with ``|p - c_v| < d(v)`` in the
    26-connected component of p's voxel: with p seeing all of them (checked
    row by row), the straight-line distance is p's geodesic distance there, so
    this is exactly the stolen set, and because d is a distance the set is
    closed under "the path to p": nothing stolen lies beyond it.  Found by a
    span fill along the contiguous z rows (stack of maximal runs, each run
    scanning the 8 neighbouring rows one voxel wider): no priority queue.

    Marks the stolen voxels ``state = 1`` and writes the runs to ``spans``
    (first flat index, length); returns the number of runs, or -1 when some
    stolen voxel is not visible from p (the caller marches instead; the marks
    of the runs written so far must be reset either way).
    """
    s1 = shape[1] * shape[2]
    s2 = shape[2]
    sx, sy, sz = spacing[0] * slow, spacing[1] * slow, spacing[2] * slow
    px, py, pz = p[0], p[1], p[2]
    fi, fj, fk = int(math.floor(px)), int(math.floor(py)), int(math.floor(pz))
    v0 = fi * s1 + fj * s2 + fk
    if mask[v0] == 0:
        return -1
    ns = 0
    top = 0  # runs [0, top) are done; runs [top, ns) wait (the stack is the tail of ``spans``)
    # the run through p's voxel
    ryz = ((fi + 0.5 - px) * sx) ** 2 + ((fj + 0.5 - py) * sy) ** 2
    if not math.sqrt(ryz + ((fk + 0.5 - pz) * sz) ** 2) < d[v0] * STEAL:
        return 0
    a = v0
    while state[a - 1] == 0 and math.sqrt(ryz + ((a - 1 - fi * s1 - fj * s2 + 0.5 - pz) * sz) ** 2) < d[a - 1] * STEAL:
        a -= 1
    b = v0
    while state[b + 1] == 0 and math.sqrt(ryz + ((b + 1 - fi * s1 - fj * s2 + 0.5 - pz) * sz) ** 2) < d[b + 1] * STEAL:
        b += 1
    for v in range(a, b + 1):
        state[v] = 1
    spans[ns, 0] = a
    spans[ns, 1] = b - a + 1
    ns += 1
    while top < ns:
        a = spans[top, 0]
        ln = spans[top, 1]
        top += 1
        i = a // s1
        j = (a - i * s1) // s2
        ka = a - i * s1 - j * s2
        kb = ka + ln - 1
        # the run must be visible from p: its box with p's voxel all material, else each centre by samples
        if S._box_empty(table, shape, min(fi, i), min(fj, j), min(fk, ka), max(fi, i), max(fj, j), max(fk, kb)) != 0:
            for k in range(ka, kb + 1):
                if not S._segment_in_material(mask, shape, px, py, pz, i + 0.5, j + 0.5, k + 0.5):
                    return -(ns + 1)
        for di in range(-1, 2):
            for dj in range(-1, 2):
                if di == 0 and dj == 0:
                    continue
                ii, jj = i + di, j + dj
                base = ii * s1 + jj * s2
                ryz = ((ii + 0.5 - px) * sx) ** 2 + ((jj + 0.5 - py) * sy) ** 2
                k = ka - 1
                while k <= kb + 1:
                    v = base + k
                    if state[v] != 0 or not math.sqrt(ryz + ((k + 0.5 - pz) * sz) ** 2) < d[v] * STEAL:
                        k += 1
                        continue
                    # a new run through v: extend both ways
                    lo = k
                    while state[base + lo - 1] == 0 and math.sqrt(ryz + ((lo - 1 + 0.5 - pz) * sz) ** 2) < d[base + lo - 1] * STEAL:
                        lo -= 1
                    hi = k
                    while state[base + hi + 1] == 0 and math.sqrt(ryz + ((hi + 1 + 0.5 - pz) * sz) ** 2) < d[base + hi + 1] * STEAL:
                        hi += 1
                    if ns >= nspan_max:
                        return -(ns + 1)
                    for w in range(base + lo, base + hi + 1):
                        state[w] = 1
                    spans[ns, 0] = base + lo
                    spans[ns, 1] = hi - lo + 1
                    ns += 1
                    k = hi + 2
    return ns


@njit(parallel=True)
def _natural_kernel_sight(mask, cost, shape, spacing, d, own, points, nframes, laplace, kmax, slow,
                          nthreads, table, out_f, out_w, out_n):
    """Weights of every point (q, 3) (padded index coords), line-of-sight stolen sets (one slowness):
    top-kmax frames per point, normalised.

    The points are dealt round-robin to ``nthreads`` chunks, each with its own
    grid-sized scratch (allocated once per chunk, so keep ``nthreads`` a small
    multiple of the number of threads).  Two kernels (this one and
    :func:`_natural_kernel_fmm`) rather than one with a branch: each compiles
    only its own propagation."""
    N = mask.shape[0]
    for t in prange(nthreads):
        dx = np.full(N, np.inf)
        ox = np.full(N, -1, dtype=np.int64)
        state = np.empty(N, dtype=np.uint8)
        for v in range(N):
            state[v] = 0 if mask[v] != 0 else 3
        nxt = np.empty(N, dtype=np.int32)
        prv = np.empty(N, dtype=np.int32)
        touched = np.empty(N, dtype=np.int32)
        src = np.empty(N, dtype=np.int64)
        spans = np.empty((N // 4 + 16, 2), dtype=np.int64)
        acc = np.zeros(nframes)
        hmin = np.full(nframes, np.inf)
        for q in range(t, points.shape[0], nthreads):
            nt = _stolen_sight(mask, table, shape, spacing, slow, d, points[q], nframes, dx, ox, src, state,
                               nxt, prv, touched, spans)
            _accumulate(cost, shape, spacing, d, own, laplace, dx, ox, state, touched, nt, acc, hmin)
            _finish(acc, hmin, nframes, laplace, kmax, q, out_f, out_w, out_n)


@njit(parallel=True)
def _natural_kernel_fmm(mask, cost, shape, spacing, d, own, points, nframes, laplace, kmax, smin, smax, radius,
                        nthreads, out_f, out_w, out_n):
    """As :func:`_natural_kernel_sight`, with stolen sets by bounded second-order fast marching
    (the compliance distance: several slownesses)."""
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
            nt = _stolen_fmm(mask, cost, shape, spacing, d, points[q], nframes, dx, ox, state, nxt, prv, touched,
                             smin, smax, radius, ball_i, ball_d, ball_o)
            _accumulate(cost, shape, spacing, d, own, laplace, dx, ox, state, touched, nt, acc, hmin)
            _finish(acc, hmin, nframes, laplace, kmax, q, out_f, out_w, out_n)


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
        pts = np.ascontiguousarray(points, dtype=np.float64)
        nth = min(q, 2 * get_num_threads())
        slow = S.uniform_slowness(cost)
        if slow is not None:
            _natural_kernel_sight(mask, cost, pshape, spacing, d, own, pts, int(nframes), int(laplace), int(kmax),
                                  slow, nth, S.empty_table(mask, pshape), out_f, out_w, out_n)
        else:
            _natural_kernel_fmm(mask, cost, pshape, spacing, d, own, pts, int(nframes), int(laplace), int(kmax),
                                float(cost.min()), float(cost.max()), M.BALL, nth, out_f, out_w, out_n)
    return out_f, out_w, out_n


def natural_naive(mask, cost, pshape, spacing, frame_points, point, *, laplace):
    """The naive twin: full, unbounded propagation from the point over the whole image (tests only).

    A voxel is stolen where the point's own distance field is below the frames'.
    Returns dense weights (n,) of one point (padded index coords).
    """
    n = len(frame_points)
    d, own = S.frame_distances(mask, cost, pshape, spacing, frame_points, np.arange(n))
    d2, _ = S.point_distances(mask, cost, pshape, spacing, np.asarray(point, dtype=np.float64)[None], [n])
    stolen = (d2 < d * STEAL) & (mask > 0)
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
