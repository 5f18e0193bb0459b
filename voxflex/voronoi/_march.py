"""Compiled front propagation on padded voxel grids (private).

One general kernel, :func:`_march`, serves every distance computation of the
Voronoi stage: the multi-source geodesic distance (Dijkstra on the
26-neighbourhood, or second-order fast marching), the incremental update when
a seed is added (farthest-point sampling), and the bounded propagation of a
point inserted as a new seed (natural-neighbour coordinates), where the front
stops wherever the new seed no longer wins (``candidate >= bound``).  Its
Dijkstra is the package's only one: the sampler's farthest points, Lloyd cells
and region splits run it too (:class:`VoxelGraph`, :func:`farthest_points`),
with groups (a front stays in its label or region) and ties broken in the
order of a binary heap.

Grids are flattened C-order arrays of the image padded by ``PAD`` empty voxels
on every side, so neighbour look-ups never leave the array.  ``mask`` is 1 on
material voxels; ``cost`` is the slowness per voxel (1 everywhere for plain
geodesic distance, ``E_ref / E_label`` for the compliance distance).

The plain-numpy twin of the Dijkstra kernel is ``scipy.sparse.csgraph``'s
Dijkstra on the same 26-neighbour graph (:func:`dijkstra_numpy`, used in the
tests); the fast-marching kernel is checked against exact Euclidean distances.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import njit, prange

PAD = 2
#: radius (in voxels) of the ball around a seed whose distances are set exactly
#: (straight line of sight inside uniform material) before marching; removes
#: most of the error fast marching makes near a point source.
BUCKET_TIE = 1e-7
"""Added to ``distance / bucket width`` before the bucket queue floors it: distances on an integer number
of widths (symmetric bodies have many) fall in the same bucket whatever the unit of length (in metres a
1 mm beam filed them one bucket off the 1 m beam's, the acceptance order changed and so did the frames
placed on it).  1e-7 of a width changes no distance."""
BALL = 3


def pad_grid(labels_mask, cost=None):
    """Padded flat ``mask`` (uint8) and ``cost`` (float64) arrays and the padded shape."""
    shape = tuple(int(s) + 2 * PAD for s in labels_mask.shape)
    mask = np.zeros(shape, dtype=np.uint8)
    inner = tuple(slice(PAD, PAD + s) for s in labels_mask.shape)
    mask[inner] = labels_mask
    c = np.ones(shape, dtype=np.float64)
    if cost is not None:
        c[inner] = cost
    return mask.ravel(), c.ravel(), np.array(shape, dtype=np.int64)


def unpad(flat, padded_shape):
    """Inner (unpadded) block of a flat padded array, as a C-contiguous 3-D copy."""
    a = flat.reshape(tuple(int(s) for s in padded_shape))
    return np.ascontiguousarray(a[PAD:-PAD, PAD:-PAD, PAD:-PAD])


def inner_to_flat(ijk, padded_shape):
    """Flat padded indices (n,) of unpadded voxel indices ``ijk`` (n, 3)."""
    ijk = np.asarray(ijk, dtype=np.int64) + PAD
    return (ijk[:, 0] * padded_shape[1] + ijk[:, 1]) * padded_shape[2] + ijk[:, 2]


# --------------------------------------------------------------------------- geometry
@njit
def _offsets(shape, spacing):
    """26 neighbour flat offsets, their world lengths, and a face flag (axis, or -1)."""
    off = np.empty(26, dtype=np.int64)
    length = np.empty(26, dtype=np.float64)
    face = np.empty(26, dtype=np.int64)
    s1 = shape[1] * shape[2]
    s2 = shape[2]
    k = 0
    for a in range(-1, 2):
        for b in range(-1, 2):
            for c in range(-1, 2):
                if a == 0 and b == 0 and c == 0:
                    continue
                off[k] = a * s1 + b * s2 + c
                length[k] = math.sqrt((a * spacing[0]) ** 2 + (b * spacing[1]) ** 2 + (c * spacing[2]) ** 2)
                nz = abs(a) + abs(b) + abs(c)
                if nz == 1:
                    face[k] = 0 if a != 0 else (1 if b != 0 else 2)
                else:
                    face[k] = -1
                k += 1
    return off, length, face


@njit
def _axis_term(v, st, dist, state, cost, h, second, uniform):
    """(alpha, beta) of the upwind term along one axis at voxel v; alpha 0 when unusable.

    ``state`` is 2 on voxels frozen in this run and 3 on empty voxels, so one
    read tells whether a neighbour is usable (the padding keeps ``v +- 2 st``
    inside the array for every material voxel v).
    """
    best = np.inf
    best2 = np.inf
    cv = cost[v] if not uniform else 1.0
    for sgn in (-1, 1):
        u = v + sgn * st
        if state[u] != 2:
            continue
        t1 = dist[u]
        if t1 < best:
            best = t1
            best2 = np.inf
            if second:
                u2 = u + sgn * st
                if state[u2] == 2 and dist[u2] <= t1 and (uniform or (cost[u2] == cv and cost[u] == cv)):
                    best2 = dist[u2]
    if best == np.inf:
        return 0.0, np.inf
    if best2 < np.inf:
        return 2.25 / (h * h), (4.0 * best - best2) / 3.0
    return 1.0 / (h * h), best


@njit
def _eikonal(v, dist, state, cost, stride, spacing, slowness, second, uniform):
    """Fast-marching update at voxel v from its usable face neighbours (inf if none).

    A neighbour is usable when it is frozen in this run (state 2): values left
    by an earlier run are never mixed in, so an added seed re-propagates only
    where it is nearer (a recomputed old value would differ by round-off and
    leak the front through the whole image).  Second
    order (Rickett & Fomel) along an axis when the next voxel beyond holds a
    usable value no larger than the first, all three in material of the same
    slowness (the one-sided stencil is wrong across a jump).  Solves sum_a alpha_a (T - beta_a)^2
    = slowness^2 adding the axes in increasing beta while T exceeds them.
    """
    a0, b0 = _axis_term(v, stride[0], dist, state, cost, spacing[0], second, uniform)
    a1, b1 = _axis_term(v, stride[1], dist, state, cost, spacing[1], second, uniform)
    a2, b2 = _axis_term(v, stride[2], dist, state, cost, spacing[2], second, uniform)
    # sort by beta (unusable terms have beta = inf and sort last)
    if b1 < b0:
        a0, b0, a1, b1 = a1, b1, a0, b0
    if b2 < b1:
        a1, b1, a2, b2 = a2, b2, a1, b1
        if b1 < b0:
            a0, b0, a1, b1 = a1, b1, a0, b0
    if b0 == np.inf:
        return np.inf
    c2 = slowness * slowness
    T = b0 + slowness / math.sqrt(a0)
    if T <= b1:
        return T
    A = a0 + a1
    B = a0 * b0 + a1 * b1
    C = a0 * b0 * b0 + a1 * b1 * b1
    disc = B * B - A * (C - c2)
    if disc < 0.0:
        return T
    T = (B + math.sqrt(disc)) / A
    if T <= b2:
        return T
    A += a2
    B += a2 * b2
    C += a2 * b2 * b2
    disc = B * B - A * (C - c2)
    if disc < 0.0:
        return T
    return (B + math.sqrt(disc)) / A


@njit
def _link(v, b, head, nxt, prv):
    h = head[b]
    nxt[v] = h
    prv[v] = -(b + 2)
    if h >= 0:
        prv[h] = v
    head[b] = v


@njit
def _unlink(v, head, nxt, prv):
    p = prv[v]
    n = nxt[v]
    if p < -1:
        head[-p - 2] = n
    else:
        nxt[p] = n
    if n >= 0:
        prv[n] = p


@njit
def _march(cost, shape, spacing, dist, owner, state, nxt, prv, bound, use_bound,
           seed_idx, seed_d, seed_own, fmm, touched, ntouched, smin, smax, group=None, pred=None):
    """Propagate distances from seeds; returns the new number of touched voxels.

    dist, owner: current values, improved in place (a voxel changes only when a
    candidate is below its current value and, with ``use_bound``, below
    ``bound``).  state: 3 on empty voxels (never entered; see
    :func:`state_of`), 0 untouched in this run, 1 tentative, 2 frozen; every
    voxel whose state becomes 1 is appended to ``touched`` (reset them with
    :func:`_reset`).  nxt, prv: int32 scratch of the grid's size (the bucket
    lists; no reset needed).  fmm: 0 Dijkstra on the 26-neighbourhood with
    exact step lengths, 1 fast marching of first order, 2 of second order (the
    26-neighbour steps are kept as candidates so that voxels joined only by an
    edge or a corner are reached, with the same connectivity as Dijkstra).
    smin, smax: the smallest and largest slowness of the grid; when they are
    equal the slowness is never read (plain geodesic distance).

    The sampler's Dijkstra (:class:`VoxelGraph`) passes two more arrays of the grid's size (numba
    compiles them out of the other calls): ``group`` (int64), the front moves only between voxels of
    equal group (a label, a region being split); ``pred`` (int32 scratch), the voxel each distance
    came from, so that a voxel reached at exactly its distance from two voxels takes the owner of the
    one nearer its seed, the lower index at equal distances (:func:`_earlier`): the owner a binary heap
    popping (distance, index) gives, whatever the order in which the bucket queue pops a bucket.

    The priority queue is a circular bucket queue with decrease-key (Dial; the
    "untidy" queue of Yatziv, Bartesaghi & Sapiro 2006): bucket width = the
    smallest step cost for Dijkstra, which keeps it exact (a voxel popped from
    the current bucket cannot improve another one in it), and a quarter of it
    for fast marching.
    """
    uniform = smin == smax
    stride = np.empty(3, dtype=np.int64)
    stride[0] = shape[1] * shape[2]
    stride[1] = shape[2]
    stride[2] = 1
    off, length, face = _offsets(shape, spacing)
    if uniform:
        length *= smin
    hmin = min(spacing[0], min(spacing[1], spacing[2]))
    width = hmin * smin
    if fmm != 0:
        width *= 0.25
    inv_width = 1.0 / width
    nb = int(math.ceil(length.max() * smax / width)) + 3
    head = np.full(nb, -1, dtype=np.int64)
    # stable: seeds at equal distances (the symmetric balls around point seeds, the voxels a frame
    # owns outright) are applied in the order given, so ties go to the first seed both compiled and
    # as plain Python (numba's quicksort and numpy's order equal keys differently)
    order = np.argsort(seed_d, kind="mergesort")
    ns = order.shape[0]
    pending = 0
    live = 0
    cur = 0
    second = fmm == 2
    while True:
        if live == 0:
            if pending >= ns:
                break
            cur = int(math.floor(seed_d[order[pending]] * inv_width + BUCKET_TIE))
        # apply the seeds whose bucket is reached
        while pending < ns:
            s = order[pending]
            d0 = seed_d[s]
            bb = int(math.floor(d0 * inv_width + BUCKET_TIE))
            if bb > cur:
                break
            pending += 1
            v = seed_idx[s]
            if state[v] < 2 and d0 < dist[v] and (not use_bound or d0 < bound[v]):
                dist[v] = d0
                owner[v] = seed_own[s]
                if state[v] == 1:
                    _unlink(v, head, nxt, prv)
                    live -= 1
                else:
                    touched[ntouched] = v
                    ntouched += 1
                state[v] = 1
                if pred is not None:
                    pred[v] = -1
                _link(v, cur % nb, head, nxt, prv)
                live += 1
        b = cur % nb
        u = head[b]
        if u < 0:
            cur += 1
            continue
        _unlink(u, head, nxt, prv)
        live -= 1
        state[u] = 2
        t = dist[u]
        ou = owner[u]
        cu = 1.0 if uniform else cost[u]
        if group is not None:
            gu = group[u]
        for k in range(26):
            v = u + off[k]
            sv = state[v]
            if sv >= 2:
                continue
            if group is not None and group[v] != gu:
                continue
            if uniform:
                cand = t + length[k]
            else:
                cand = t + length[k] * 0.5 * (cu + cost[v])
            if fmm != 0 and face[k] >= 0:
                te = _eikonal(v, dist, state, cost, stride, spacing, smin if uniform else cost[v], second, uniform)
                if te < cand:
                    cand = te
            if cand < dist[v] and (not use_bound or cand < bound[v]):
                dist[v] = cand
                owner[v] = ou
                if pred is not None:
                    pred[v] = u
                if sv == 1:
                    _unlink(v, head, nxt, prv)
                else:
                    touched[ntouched] = v
                    ntouched += 1
                    state[v] = 1
                    live += 1
                bb = int(math.floor(cand * inv_width + BUCKET_TIE))
                if bb < cur:
                    bb = cur
                _link(v, bb % nb, head, nxt, prv)
            elif pred is not None and sv == 1 and cand == dist[v] and _earlier(u, pred[v], dist):
                owner[v] = ou
                pred[v] = u
    return ntouched


@njit
def _earlier(u, p, dist):
    """Whether frozen voxel ``u`` comes before ``p`` (-1: a seed, which nothing precedes) in the order
    (distance, flat index): the order of C-order voxel indices, padded or not."""
    return p >= 0 and (dist[u] < dist[p] or (dist[u] == dist[p] and u < p))


def state_of(mask):
    """Fresh ``state`` array for :func:`_march`: 0 on material, 3 on empty voxels (uint8)."""
    return np.where(mask != 0, 0, 3).astype(np.uint8)


@njit
def _reset(state, touched, ntouched):
    for k in range(ntouched):
        state[touched[k]] = 0


@njit
def _ball(mask, cost, shape, spacing, p, radius, out_idx, out_d):
    """Exact distances from a point ``p`` (padded continuous index coords) to nearby voxel centres.

    Voxels within ``radius`` voxels (index box) whose centre is in straight
    line of sight of p through material of the same slowness as p's voxel get
    ``|p - centre| * slowness``.  Returns the count written to ``out_idx`` /
    ``out_d`` (capacity ``(2 radius + 1)^3``).
    """
    i0 = int(math.floor(p[0]))
    j0 = int(math.floor(p[1]))
    k0 = int(math.floor(p[2]))
    s1 = shape[1] * shape[2]
    s2 = shape[2]
    v0 = i0 * s1 + j0 * s2 + k0
    c0 = cost[v0]
    # a box of material of one slowness needs no line-of-sight test (every segment stays in it): the
    # usual case for a frame inside the object, 0.8 s of the bunny's placement at 2 mm with the tests
    full = True
    for a in range(-radius, radius + 1):
        i = i0 + a
        for b in range(-radius, radius + 1):
            j = j0 + b
            for c in range(-radius, radius + 1):
                k = k0 + c
                if i < 0 or i >= shape[0] or j < 0 or j >= shape[1] or k < 0 or k >= shape[2]:
                    full = False
                    break
                v = i * s1 + j * s2 + k
                if mask[v] == 0 or cost[v] != c0:
                    full = False
                    break
            if not full:
                break
        if not full:
            break
    cnt = 0
    for a in range(-radius, radius + 1):
        i = i0 + a
        if i < 0 or i >= shape[0]:
            continue
        for b in range(-radius, radius + 1):
            j = j0 + b
            if j < 0 or j >= shape[1]:
                continue
            for c in range(-radius, radius + 1):
                k = k0 + c
                if k < 0 or k >= shape[2]:
                    continue
                v = i * s1 + j * s2 + k
                if mask[v] == 0 or cost[v] != c0:
                    continue
                dx = (i + 0.5 - p[0])
                dy = (j + 0.5 - p[1])
                dz = (k + 0.5 - p[2])
                ok = True
                steps = 1 if full else int(4.0 * (abs(dx) + abs(dy) + abs(dz))) + 1
                for q in range(1, steps):
                    f = q / steps
                    ii = int(math.floor(p[0] + f * dx))
                    jj = int(math.floor(p[1] + f * dy))
                    kk = int(math.floor(p[2] + f * dz))
                    w = ii * s1 + jj * s2 + kk
                    if mask[w] == 0 or cost[w] != c0:
                        ok = False
                        break
                if ok:
                    out_idx[cnt] = v
                    out_d[cnt] = c0 * math.sqrt((dx * spacing[0]) ** 2 + (dy * spacing[1]) ** 2 + (dz * spacing[2]) ** 2)
                    cnt += 1
    return cnt


@njit
def _seed_arrays(mask, cost, shape, spacing, points, owners, radius):
    """Seeds (flat index, distance, owner) for point sources ``points`` (s, 3) in padded index coords.

    The balls are computed over the threads, each in its own slice, then packed in the points' order
    (the same arrays as one thread: a fixed region's thousands of voxel seeds took 0.37 s of the
    bunny's weights)."""
    per = (2 * radius + 1) ** 3
    ns = points.shape[0]
    idx = np.empty(ns * per, dtype=np.int64)
    d = np.empty(ns * per, dtype=np.float64)
    counts = _balls(mask, cost, shape, spacing, points, radius, idx, d)
    tot = int(counts.sum())
    oi = np.empty(tot, dtype=np.int64)
    od = np.empty(tot, dtype=np.float64)
    own = np.empty(tot, dtype=np.int64)
    k = 0
    for s in range(ns):
        for q in range(counts[s]):
            oi[k] = idx[s * per + q]
            od[k] = d[s * per + q]
            own[k] = owners[s]
            k += 1
    return oi, od, own


@njit(parallel=True)
def _balls(mask, cost, shape, spacing, points, radius, idx, d):
    """:func:`_ball` of every point into its slice ``[s * per, (s + 1) * per)``; returns the counts."""
    per = (2 * radius + 1) ** 3
    ns = points.shape[0]
    counts = np.zeros(ns, dtype=np.int64)
    for s in prange(ns):
        counts[s] = _ball(mask, cost, shape, spacing, points[s], radius, idx[s * per:(s + 1) * per],
                          d[s * per:(s + 1) * per])
    return counts


def march(mask, cost, shape, spacing, points, owners, *, fmm, dist=None, owner=None):
    """Multi-source propagation over the whole padded grid (fresh, or improving ``dist``/``owner``).

    ``points`` are seed positions in padded continuous index coordinates.
    Returns ``dist, owner`` (flat, padded).
    """
    N = mask.shape[0]
    if dist is None:
        dist = np.full(N, np.inf)
        owner = np.full(N, -1, dtype=np.int64)
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    owners = np.ascontiguousarray(owners, dtype=np.int64)
    radius = BALL if fmm else 0
    si, sd, so = _seed_arrays(mask, cost, shape, spacing, points, owners, radius)
    zero = sd == 0.0
    if np.count_nonzero(zero) > 1:
        # a region of voxels seeded at distance 0 (a fixed region a frame owns): the balls' entries on
        # voxels of the region can never win against their own 0 (the march applies seeds in order of
        # distance and keeps the smaller), so they are dropped; the result is the same, and the bunny's
        # base (thousands of voxels) no longer feeds millions of seeds to the queue
        seeded = np.zeros(N, dtype=bool)
        seeded[si[zero]] = True
        keep = zero | ~seeded[si]
        si, sd, so = si[keep], sd[keep], so[keep]
    state = state_of(mask)
    touched = np.empty(N, dtype=np.int32)
    nxt = np.empty(N, dtype=np.int32)
    prv = np.empty(N, dtype=np.int32)
    smin, smax = float(cost.min()), float(cost.max())
    _march(cost, shape, spacing, dist, owner, state, nxt, prv, dist, False, si, sd, so, fmm, touched, 0, smin, smax)
    return dist, owner


# --------------------------------------------------------------------------- the sampler's graph
class VoxelGraph:
    """The material voxels of a mask on the padded grid, for the Dijkstra of :func:`_march` (order 0) with
    groups and ordered ties: the sampler's farthest points, Lloyd cells and region splits.

    ``ijk`` (N, 3) voxel indices in C order (``np.flatnonzero(mask)``), ``flat`` (N,) their flat padded
    indices (increasing), ``index`` (size,) the compact index of each padded voxel or -1, ``shape`` (3,)
    the padded shape, ``spacing`` (3,) the step lengths' unit (the sampler's voxel units).  Fields
    (``dist``, ``owner``, ``group``) are flat padded arrays of ``size``; seeds are compact indices.
    """

    def __init__(self, mask, spacing):
        m, _, self.shape = pad_grid(np.asarray(mask, dtype=bool))
        self.flat = np.flatnonzero(m)
        self.ijk = np.stack(np.unravel_index(self.flat, tuple(self.shape)), axis=1) - PAD
        self.index = np.full(m.size, -1, dtype=np.int64)
        self.index[self.flat] = np.arange(len(self.flat))
        self.spacing = np.asarray(spacing, dtype=np.float64)
        self.state = state_of(m)
        self.nxt = np.empty(m.size, dtype=np.int32)
        self.prv = np.empty(m.size, dtype=np.int32)
        self.touched = np.empty(m.size, dtype=np.int32)
        self.pred = np.empty(m.size, dtype=np.int32)

    @property
    def n(self) -> int:
        return len(self.flat)

    @property
    def size(self) -> int:
        return len(self.index)

    @property
    def strides(self) -> np.ndarray:
        """Flat offsets (3,) of one step along each axis."""
        return np.array([self.shape[1] * self.shape[2], self.shape[2], 1], dtype=np.int64)

    def field(self, fill, voxels=None, values=None, dtype=np.float64) -> np.ndarray:
        """A padded field of ``fill``, with ``values`` at the compact ``voxels`` when given."""
        out = np.full(self.size, fill, dtype=dtype)
        if voxels is not None:
            out[self.flat[voxels]] = values
        return out

    def propagate(self, group, seeds, seed_owner, dist, owner, backend: str = "numba") -> None:
        """Lower ``dist``/``owner`` (padded) in place by shortest paths from the compact ``seeds`` (at
        distance 0, owners ``seed_owner``) inside equal ``group`` (padded); ``backend="numpy"``: the plain
        twin, :func:`dijkstra_numpy`."""
        seeds = self.flat[np.asarray(seeds, dtype=np.int64)]
        seed_owner = np.ascontiguousarray(seed_owner, dtype=np.int64)
        if backend == "numpy":
            dijkstra_numpy(self, group, seeds, seed_owner, dist, owner)
            return
        nt = _march(_UNIFORM, self.shape, self.spacing, dist, owner, self.state, self.nxt, self.prv, dist, False,
                    seeds, np.zeros(len(seeds)), seed_owner, 0, self.touched, 0, 1.0, 1.0, group, self.pred)
        _reset(self.state, self.touched, nt)

    def farthest_points(self, group, dist, owner, first, k, tie) -> np.ndarray:
        """:func:`farthest_points` from the compact voxel ``first``; returns the seeds (compact indices)."""
        seeds = farthest_points(self.shape, self.spacing, self.state, self.nxt, self.prv, self.touched, group,
                                self.pred, dist, owner, self.flat[first], k, tie)
        return self.index[seeds]


_UNIFORM = np.ones(1)
"""The slowness of :class:`VoxelGraph`'s marches: uniform, so never read."""

BLOCK_SHIFT = 8
"""Voxels per block of :func:`farthest_points`' maxima: 2^8."""


@njit
def _block_max(dist, b, top):  # pragma: no cover - compiled
    lo = b << BLOCK_SHIFT
    hi = min(lo + (1 << BLOCK_SHIFT), dist.shape[0])
    m = -np.inf
    for v in range(lo, hi):
        if dist[v] > m:
            m = dist[v]
    top[b] = m


@njit
def _dijkstra(shape, spacing, state, nxt, prv, touched, group, pred, dist, owner, v, o):  # pragma: no cover
    """:func:`_march`'s Dijkstra from the one voxel ``v`` (owner ``o``); returns the touched count (state reset)."""
    one = np.full(1, v, dtype=np.int64)
    nt = _march(_UNIFORM, shape, spacing, dist, owner, state, nxt, prv, dist, False, one, np.zeros(1),
                np.full(1, o, dtype=np.int64), 0, touched, 0, 1.0, 1.0, group, pred)
    _reset(state, touched, nt)
    return nt


@njit
def farthest_points(shape, spacing, state, nxt, prv, touched, group, pred, dist, owner, first, k, tie):  # pragma: no cover
    """Geodesic farthest-point seeds from ``first``: each next seed is the candidate farthest from the seeds so
    far, ties within ``tie`` of the largest distance going to the lowest index (as
    :func:`voxflex._ties.first_extreme` breaks them), until ``k`` seeds are placed and every candidate is
    reached, or every candidate is a seed.  Returns the seeds (int64, flat padded).

    Candidates are the voxels with ``dist`` >= 0 (inf: unreached; the others -1, never chosen nor crossed).
    ``dist`` and ``owner`` come out as the seeds' distance field and Voronoi owner.  The maxima of blocks of
    2^BLOCK_SHIFT voxels are kept (the blocks a seed's march touches are scanned again, the others not), so a
    seed costs its march and a pass over the blocks, not a pass over the image (the bunny's 9,430 seeds of
    94k voxels: 0.64 s as a Python loop of full-array maxima)."""
    n = dist.shape[0]
    nb = (n + (1 << BLOCK_SHIFT) - 1) >> BLOCK_SHIFT
    seeds = np.empty(n, dtype=np.int64)
    seeds[0] = first
    _dijkstra(shape, spacing, state, nxt, prv, touched, group, pred, dist, owner, first, 0)
    top = np.empty(nb)
    for b in range(nb):
        _block_max(dist, b, top)
    dirty = np.zeros(nb, dtype=np.uint8)
    ns = 1
    while True:
        best = -np.inf
        for b in range(nb):
            if top[b] > best:
                best = top[b]
        floor = best if best == np.inf else best - tie * best  # the first candidate at least this far wins
        v = -1
        for b in range(nb):
            if top[b] >= floor:
                lo = b << BLOCK_SHIFT
                for u in range(lo, min(lo + (1 << BLOCK_SHIFT), n)):
                    if dist[u] >= floor:
                        v = u
                        break
                break
        if v < 0 or dist[v] <= 0.0 or (ns >= k and dist[v] < np.inf):
            break
        seeds[ns] = v
        nt = _dijkstra(shape, spacing, state, nxt, prv, touched, group, pred, dist, owner, v, ns)
        ns += 1
        for q in range(nt):  # the blocks whose distances fell, once each
            b = touched[q] >> BLOCK_SHIFT
            if not dirty[b]:
                _block_max(dist, b, top)
                dirty[b] = 1
        for q in range(nt):
            dirty[touched[q] >> BLOCK_SHIFT] = 0
    return seeds[:ns].copy()


def _csgraph(graph: VoxelGraph, group):
    """The 26-neighbour graph between the compact voxels of equal ``group`` (padded) >= 0 (scipy CSR)."""
    import scipy.sparse as sp

    n = graph.n
    steps = np.indices((3, 3, 3)).reshape(3, -1).T - 1
    steps = steps[np.any(steps != 0, axis=1)]
    rows, cols, vals = [], [], []
    for step in steps:
        dst = graph.index[graph.flat + step @ graph.strides]
        src = np.flatnonzero(dst >= 0)
        dst = dst[src]
        keep = (group[graph.flat[src]] == group[graph.flat[dst]]) & (group[graph.flat[src]] >= 0)
        rows.append(src[keep])
        cols.append(dst[keep])
        vals.append(np.full(int(keep.sum()), np.sqrt(((step * graph.spacing) ** 2).sum())))
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))


def dijkstra_numpy(graph: VoxelGraph, group, seeds, seed_owner, dist, owner) -> None:
    """Plain twin of :meth:`VoxelGraph.propagate` (``seeds`` flat padded): scipy's Dijkstra on the explicit
    graph (:func:`_csgraph`), then the minimum with the given field; owners may differ at exact ties."""
    from scipy.sparse.csgraph import dijkstra

    if len(seeds) == 0:
        return
    at = graph.index[seeds]
    d, _, src = dijkstra(_csgraph(graph, np.asarray(group)), directed=False, indices=at, min_only=True,
                         return_predecessors=True)
    pos = {int(v): int(o) for v, o in zip(at, seed_owner)}
    new_owner = np.array([pos.get(int(s), -1) for s in src], dtype=np.int64)
    better = d < dist[graph.flat]
    dist[graph.flat[better]] = d[better]
    owner[graph.flat[better]] = new_owner[better]
    dist[seeds] = 0.0
    owner[seeds] = seed_owner
