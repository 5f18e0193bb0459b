"""Compiled kernels of the frame model: F at the samples, forces and stiffness, with numpy twins.

An affine frame a moves a material point X to ``A_a (X - X_a) + t_a``; the
deformation gradient at a sample with parents p is

    F[i, j] = sum_p sum_c d[a_p, i, c] G[p, c, j],

with the frame's row-i DOFs ``d[a, i] = (A_a[i, 0], A_a[i, 1], A_a[i, 2], t_a[i])``
and the sample's constant table ``G[p, c, j] = w_p delta_cj + r_c dw_p[j]``
(c < 3, ``r = X - X_a``), ``G[p, 3, j] = dw_p[j]``.  The Jacobian is ``I_3 (x)
G``: row i of F sees only row-i DOFs, so the stiffness block between parents p
and q is ``K[(p, i, c), (q, k, d)] = sum_jl G[p, c, j] A[i, j, k, l] G[q, d, l]``
— per sample (P parents) 648 P flops for ``Y = G A`` and 864 flops per parent
pair q >= p for ``G Y``: 432 P^2 + 1080 P in all (22,000 at P = 6), instead of
(12 P)^2 * 81 for a generic J^T A J.

DOF of (frame a, row i, c): ``12 a + 3 i + c`` for c < 3, ``12 a + 9 + i`` for c = 3.

The stiffness is accumulated per coupled frame pair (a <= b) in a compact
array of 12x12 blocks (:func:`frame_pairs` sorts each sample's parents by
frame once, so a parent pair p < q is a frame pair a < b), then written into
both triangles of the dense matrix.  The inner update runs over 36 contiguous
numbers, which the compiler vectorises; 12-long loops (a frame's columns) it
does not (LLVM's minimum trip count).  The 36 numbers are padded to
:data:`PAD` = 40 (the padding stays zero): the compiler emits 256-bit
vectors here, and 40 is ten of them with no scalar remainder (1000
samples, P = 6, 50 frames, 638 pairs, one thread, min of 300: 1.24 against
1.33 ms unpadded).  Measured on this 2-core machine (1000 samples, P = 6, 50
frames, 643 pairs, one thread, min of 40), before the padding: the writes of
each pair straight into the dense matrix, row by row, 6.0 ms; this
pair-block pass 1.35 ms (0.39 ms of it for Y) plus 0.19 ms to write H and
0.1 ms to zero it.
"""

from __future__ import annotations

import numpy as np

from ...._jit import chunk_bounds, njit, prange

PAD = 40
"""Width of a pair block's rows in :func:`frame_stiffness_pairs` (36 numbers, zero-padded)."""

__all__ = ["PAD", "frame_tables", "frame_pairs", "frame_F", "frame_forces", "frame_F_points", "frame_forces_points",
           "points_F", "points_forces",
           "frame_stiffness_pairs", "frame_pairs_to_dense",
           "frame_stiffness_dense", "isotropic_moduli", "isotropic_worth_dense", "isotropic_stiffness_dense"]


def frame_tables(values, frames, order=None) -> np.ndarray:
    """The constant tables G (m, P, 4, 3) of the samples' shape values on the frames (0 where padded);
    with ``order`` (m, P), parent p of the tables is the values' parent ``order[s, p]``."""
    index = np.ascontiguousarray(values.index, dtype=np.int64)
    if order is None:
        order = np.broadcast_to(np.arange(index.shape[1], dtype=np.int64), index.shape)
    G = np.empty(index.shape + (4, 3))
    _fill_tables(index, order, np.ascontiguousarray(values.w, dtype=np.float64),
                 np.ascontiguousarray(values.dw, dtype=np.float64), np.ascontiguousarray(values.rest, dtype=np.float64),
                 np.ascontiguousarray(frames, dtype=np.float64), G)
    return G


@njit
def _fill_tables(index, order, w, dw, rest, frames, G):  # pragma: no cover - compiled
    """G[s, p, c, j] = w delta_cj + r_c dw_j (c < 3, r = X_s - X_a), G[s, p, 3, j] = dw_j of the values'
    parent o = order[s, p]; 0 where padded.  One pass without temporaries (the numpy form made four
    (m, P, 3, 3) arrays: 1.8 s for the bunny's 93k elaston points with 35 parents, 312 MB of G)."""
    m, P = index.shape
    for s in range(m):
        for p in range(P):
            o = order[s, p]
            a = index[s, o]
            if a < 0:
                for c in range(4):
                    for j in range(3):
                        G[s, p, c, j] = 0.0
                continue
            _parent_table(w[s, o], dw[s, o], rest[s], frames[a], G[s, p])


@njit
def _parent_table(wp, dwp, x, xa, out):  # pragma: no cover - compiled
    """out (4, 3) = one parent's table: ``w delta_cj + (x - x_a)_c dw_j`` (c < 3), ``dw_j`` (c = 3)."""
    for c in range(3):
        r = x[c] - xa[c]
        for j in range(3):
            out[c, j] = r * dwp[j] + (wp if c == j else 0.0)
    for j in range(3):
        out[3, j] = dwp[j]


@njit
def frame_F(index, G, q, F):  # pragma: no cover - compiled
    """F (m, 3, 3) from the state q (n, 12)."""
    m, P = index.shape
    for s in range(m):
        for i in range(3):
            for j in range(3):
                F[s, i, j] = 0.0
        for p in range(P):
            a = index[s, p]
            if a < 0:
                continue
            for i in range(3):
                for c in range(4):
                    d = q[a, 3 * i + c] if c < 3 else q[a, 9 + i]
                    for j in range(3):
                        F[s, i, j] += d * G[s, p, c, j]


@njit
def frame_forces(index, G, P_stress, weight, g):  # pragma: no cover - compiled
    """g (n, 12) += J^T (weight P) with P (m, 3, 3) the first Piola-Kirchhoff stresses, weight (m,)
    the sample volumes."""
    m, P = index.shape
    VP = np.empty((3, 3))
    for s in range(m):
        for i in range(3):
            for j in range(3):
                VP[i, j] = weight[s] * P_stress[s, i, j]
        for p in range(P):
            a = index[s, p]
            if a < 0:
                continue
            for i in range(3):
                for c in range(4):
                    acc = 0.0
                    for j in range(3):
                        acc += VP[i, j] * G[s, p, c, j]
                    if c < 3:
                        g[a, 3 * i + c] += acc
                    else:
                        g[a, 9 + i] += acc


POINT_CHUNKS = 8
"""Sample chunks of :func:`frame_F_points` and :func:`frame_forces_points` run in parallel (the forces of
each chunk summed in chunk order: the same bits for any thread count)."""

POINT_CHUNK_ENTRIES = 1 << 18
"""Parent entries (samples x parents) per chunk at least: below it the threads' wake-up costs more than it
saves.  Measured on the 3 mm bunny's 27,568 elaston points, implicit Euler, 2 threads against 1: 47
parents (1.3 M entries), F 6.9 -> 3.6 ms and a step 186 -> 133 ms; 6 parents (165 k), F 1.07 -> 0.55 ms
alone, but a step 45 -> 49 ms (the other kernels run serial between calls)."""


def point_chunks(m: int, parents: int) -> int:
    """How many chunks the point kernels cut ``m`` samples with ``parents`` parents each into."""
    return int(min(POINT_CHUNKS, max(1, (m * parents) // POINT_CHUNK_ENTRIES)))


def points_F(index, points, q, F) -> None:
    """F (m, 3, 3) of point samples ``points`` = (w, dw, rest, frames) at state q: :func:`frame_F_points`,
    in :func:`point_chunks` chunks on numba's threads when there are several (one runs serial)."""
    q = np.ascontiguousarray(q, dtype=np.float64)
    chunks = point_chunks(*index.shape)
    if chunks > 1:
        _F_points_chunks(index, *points, q, F, chunks)
    else:
        frame_F_points(index, *points, q, F)


def points_forces(index, points, P_stress, weight, g) -> None:
    """g (n, 12) += J^T (weight P) of point samples, as :func:`points_F` chunks them (the chunks' forces
    summed in chunk order)."""
    P_stress = np.ascontiguousarray(P_stress, dtype=np.float64)
    chunks = point_chunks(*index.shape)
    if chunks > 1:
        _forces_points_chunks(index, *points, P_stress, weight, g, chunks)
    else:
        frame_forces_points(index, *points, P_stress, weight, g)


@njit(parallel=True)
def _F_points_chunks(index, w, dw, rest, frames, q, F, chunks):  # pragma: no cover - compiled
    for c in prange(chunks):
        a, b = chunk_bounds(index.shape[0], chunks, c)
        frame_F_points(index[a:b], w[a:b], dw[a:b], rest[a:b], frames, q, F[a:b])


@njit(parallel=True)
def _forces_points_chunks(index, w, dw, rest, frames, P_stress, weight, g, chunks):  # pragma: no cover
    part = np.zeros((chunks,) + g.shape)
    for c in prange(chunks):
        a, b = chunk_bounds(index.shape[0], chunks, c)
        frame_forces_points(index[a:b], w[a:b], dw[a:b], rest[a:b], frames, P_stress[a:b], weight[a:b], part[c])
    for c in range(chunks):
        g += part[c]


@njit
def frame_F_points(index, w, dw, rest, frames, q, F):  # pragma: no cover - compiled
    """F (m, 3, 3) from the state q (n, 12) at point samples, from their weights w (m, P), weight
    gradients dw (m, P, 3) and rest positions (m, 3) instead of the tables G: ``F = sum_p y_a dw_p^T +
    w_p A_a`` with ``y_a = A_a (X_s - X_a) + t_a`` (frame a's map at the point).  The tables hold 12
    numbers per parent, this reads 4 (F streams the parents at memory bandwidth: 17 -> 7 ms for 27,568
    points with 47 parents; the same F to round-off)."""
    m, P = index.shape
    f = np.empty((3, 3))
    for s in range(m):
        for i in range(3):
            for j in range(3):
                f[i, j] = 0.0
        x0, x1, x2 = rest[s, 0], rest[s, 1], rest[s, 2]
        for p in range(P):
            a = index[s, p]
            if a < 0:
                continue
            r0, r1, r2 = x0 - frames[a, 0], x1 - frames[a, 1], x2 - frames[a, 2]
            wp = w[s, p]
            d0, d1, d2 = dw[s, p, 0], dw[s, p, 1], dw[s, p, 2]
            for i in range(3):
                A0, A1, A2 = q[a, 3 * i], q[a, 3 * i + 1], q[a, 3 * i + 2]
                y = A0 * r0 + A1 * r1 + A2 * r2 + q[a, 9 + i]
                f[i, 0] += y * d0 + wp * A0
                f[i, 1] += y * d1 + wp * A1
                f[i, 2] += y * d2 + wp * A2
        for i in range(3):
            for j in range(3):
                F[s, i, j] = f[i, j]


@njit
def frame_forces_points(index, w, dw, rest, frames, P_stress, weight, g):  # pragma: no cover - compiled
    """g (n, 12) += J^T (weight P) at point samples, from w, dw and the rest positions as
    :func:`frame_F_points` (``v = (weight P) dw_p``: row i of A_a gets ``v_i r + w_p (weight P)_i``,
    t_a gets v)."""
    m, P = index.shape
    VP = np.empty((3, 3))
    for s in range(m):
        ws = weight[s]
        for i in range(3):
            for j in range(3):
                VP[i, j] = ws * P_stress[s, i, j]
        x0, x1, x2 = rest[s, 0], rest[s, 1], rest[s, 2]
        for p in range(P):
            a = index[s, p]
            if a < 0:
                continue
            r0, r1, r2 = x0 - frames[a, 0], x1 - frames[a, 1], x2 - frames[a, 2]
            wp = w[s, p]
            d0, d1, d2 = dw[s, p, 0], dw[s, p, 1], dw[s, p, 2]
            for i in range(3):
                vi = VP[i, 0] * d0 + VP[i, 1] * d1 + VP[i, 2] * d2
                g[a, 3 * i] += vi * r0 + wp * VP[i, 0]
                g[a, 3 * i + 1] += vi * r1 + wp * VP[i, 1]
                g[a, 3 * i + 2] += vi * r2 + wp * VP[i, 2]
                g[a, 9 + i] += vi



@njit
def mass_blocks(index, w, rest, frames, mass, blocks):  # pragma: no cover - compiled
    """blocks (n, 4, 4) += per frame a, over the points s whose parent it is, ``mass_s w_sa [r; 1][r; 1]^T``
    with ``r = X_s - X_a`` (the lumped frame mass: the same sums as a bincount per entry pair, in the same
    order, without its (entries, 4) temporaries: 17 -> 2 ms for the 3 mm bunny's 28k voxel centres)."""
    m, P = index.shape
    r = np.empty(4)
    r[3] = 1.0
    for s in range(m):
        for p in range(P):
            a = index[s, p]
            if a < 0:
                continue
            c = w[s, p] * mass[s]
            r[0], r[1], r[2] = rest[s, 0] - frames[a, 0], rest[s, 1] - frames[a, 1], rest[s, 2] - frames[a, 2]
            for i in range(4):
                ci = c * r[i]
                for j in range(i, 4):
                    blocks[a, i, j] += ci * r[j]
    for a in range(blocks.shape[0]):
        for i in range(4):
            for j in range(i + 1, 4):
                blocks[a, j, i] = blocks[a, i, j]


@njit
def gauge_sums(index, w, dw, rest, frames, phi, S, T):  # pragma: no cover - compiled
    """Per sample s, over its parents a (index -1: padding): ``S[s, m, j] = sum w phi_a[m] r_j`` and
    ``T[s, m, j, l] = sum phi_a[m] (w delta_jl + r_j dw_l)`` with ``r = X_s - X_a`` -- the motion and the
    deformation gradient of the gauge candidates ``dA_a = sum_m C[k, m] phi_a[m]``
    (:func:`voxflex.deform.models.frames.modes.gauge_modes`; the einsums over (samples, parents, 4, 3, 3)
    took 0.9 s of 1.5 s on the bunny's 94k points with 35 parents)."""
    m, P = index.shape
    M = phi.shape[1]
    for s in range(m):
        for a in range(M):
            for j in range(3):
                S[s, a, j] = 0.0
                for l in range(3):
                    T[s, a, j, l] = 0.0
        for p in range(P):
            f = index[s, p]
            if f < 0:
                continue
            wp = w[s, p]
            r0, r1, r2 = rest[s, 0] - frames[f, 0], rest[s, 1] - frames[f, 1], rest[s, 2] - frames[f, 2]
            d0, d1, d2 = dw[s, p, 0], dw[s, p, 1], dw[s, p, 2]
            for a in range(M):
                ph = phi[f, a]
                pw = ph * wp
                S[s, a, 0] += pw * r0
                S[s, a, 1] += pw * r1
                S[s, a, 2] += pw * r2
                pr0, pr1, pr2 = ph * r0, ph * r1, ph * r2
                T[s, a, 0, 0] += pr0 * d0 + pw
                T[s, a, 0, 1] += pr0 * d1
                T[s, a, 0, 2] += pr0 * d2
                T[s, a, 1, 0] += pr1 * d0
                T[s, a, 1, 1] += pr1 * d1 + pw
                T[s, a, 1, 2] += pr1 * d2
                T[s, a, 2, 0] += pr2 * d0
                T[s, a, 2, 1] += pr2 * d1
                T[s, a, 2, 2] += pr2 * d2 + pw

def frame_pairs(index, G, n):
    """The tables of the pair-block stiffness: parents sorted by frame, and the coupled frame pairs.

    Parameters
    ----------
    index : (m, P) int, the samples' parent frames (-1 where padded)
    G : (m, P, 4, 3) float, their tables (:func:`frame_tables`)
    n : int, the number of frames

    Returns
    -------
    index : (m, P) int64, each sample's parents in increasing frame order, padding last
    G : (m, P, 4, 3) float, permuted alike
    pairs : (npairs, 2) int64, the frame pairs (a <= b) that share a sample, sorted
    pair_id : (n, n) int64, the row of ``pairs`` of (a, b) for a <= b, -1 elsewhere
    """
    index = np.asarray(index)
    key = np.where(index >= 0, index, np.iinfo(np.int64).max)
    if _rows_sorted(key):  # already in frame order (padding last): no permutation
        index = np.ascontiguousarray(index, dtype=np.int64)
        G = np.ascontiguousarray(G)
    else:
        order = np.ascontiguousarray(np.argsort(key, axis=1, kind="stable"), dtype=np.int64)
        index = np.ascontiguousarray(np.take_along_axis(index, order, axis=1), dtype=np.int64)
        Gs = np.empty_like(G, dtype=np.float64)
        _permute_tables(np.ascontiguousarray(G, dtype=np.float64), order, Gs)
        G = Gs
    return (index, G) + pair_list(index, n)


def sorted_parents(values):
    """(index, order): the samples' parents in increasing frame order (padding last) and the order (m, P)
    (parent p is the values' parent ``order[s, p]``), without tables: a stable sort of each row, compiled
    (numpy's argsort and gather took 0.35 s for the bunny's 93k points with 34 parents)."""
    index = np.ascontiguousarray(values.index, dtype=np.int64)
    order = np.empty(index.shape, dtype=np.int64)
    out = np.empty(index.shape, dtype=np.int64)
    _sort_rows(index, order, out)
    return out, order


@njit
def _sort_rows(index, order, out):  # pragma: no cover - compiled
    """Per row, ``order`` = the stable argsort of the frames (padding -1 last) and ``out`` = the sorted row
    (insertion sort: rows are short)."""
    m, P = index.shape
    big = np.iinfo(np.int64).max
    for s in range(m):
        for p in range(P):
            order[s, p] = p
        for p in range(1, P):
            o = order[s, p]
            k = index[s, o] if index[s, o] >= 0 else big
            r = p - 1
            while r >= 0:
                c = index[s, order[s, r]]
                if (c if c >= 0 else big) <= k:
                    break
                order[s, r + 1] = order[s, r]
                r -= 1
            order[s, r + 1] = o
        for p in range(P):
            out[s, p] = index[s, order[s, p]]


def point_arrays(values, frames, order):
    """(w, dw, rest, frames) of point samples in the parents' ``order`` (0 where padded): what the point
    kernels read instead of the tables (4 numbers per parent instead of 12)."""
    index = np.ascontiguousarray(values.index, dtype=np.int64)
    w = np.empty(index.shape)
    dw = np.empty(index.shape + (3,))
    _gather_points(index, np.ascontiguousarray(order, dtype=np.int64), np.ascontiguousarray(values.w, dtype=np.float64),
                   np.ascontiguousarray(values.dw, dtype=np.float64), w, dw)
    return w, dw, np.ascontiguousarray(values.rest, dtype=np.float64), np.ascontiguousarray(frames, dtype=np.float64)


@njit(parallel=True)
def _gather_points(index, order, w_in, dw_in, w, dw):  # pragma: no cover - compiled
    """w[s, p], dw[s, p] = the values' parent ``order[s, p]`` (0 where padded): one pass, no temporaries
    (numpy's take_along_axis and where took 1.0 s for the bunny's 93k points with 35 parents), the points
    over the threads (each writes its own rows)."""
    m, P = index.shape
    for s in prange(m):
        for p in range(P):
            o = order[s, p]
            if index[s, o] < 0:
                w[s, p] = 0.0
                for j in range(3):
                    dw[s, p, j] = 0.0
            else:
                w[s, p] = w_in[s, o]
                for j in range(3):
                    dw[s, p, j] = dw_in[s, o, j]


def tables_from_points(index, points):
    """The tables G (m, P, 4, 3) of point samples from their (w, dw, rest, frames), parents as given."""
    w, dw, rest, frames = points
    G = np.empty(index.shape + (4, 3))
    order = np.ascontiguousarray(np.broadcast_to(np.arange(index.shape[1], dtype=np.int64), index.shape))
    _fill_tables(np.ascontiguousarray(index, dtype=np.int64), order, w, dw, rest, frames, G)
    return G


def pair_list(index, n):
    """(pairs (npairs, 2) int64, the frame pairs a <= b that share a sample, sorted; pair_id (n, n), the row
    of ``pairs`` of (a, b) for a <= b, -1 elsewhere) of parents sorted by frame, padding last."""
    coupled = np.zeros((n, n), dtype=np.bool_)
    _couple(np.ascontiguousarray(index, dtype=np.int64), coupled)
    pairs = np.argwhere(coupled).astype(np.int64)  # row-major: sorted by a, then b
    pair_id = np.full((n, n), -1, dtype=np.int64)
    pair_id[pairs[:, 0], pairs[:, 1]] = np.arange(len(pairs))
    return pairs, pair_id


def _rows_sorted(key) -> bool:
    """Whether every row of ``key`` (m, P) is non-decreasing."""
    return bool(key.shape[1] < 2 or np.all(key[:, 1:] >= key[:, :-1]))


@njit
def _permute_tables(G, order, out):  # pragma: no cover - compiled
    """out[s, p] = G[s, order[s, p]] (a gather of 12 numbers per parent, no (m, P, 4, 3) index arrays)."""
    m, P = order.shape
    for s in range(m):
        for p in range(P):
            o = order[s, p]
            for c in range(4):
                for j in range(3):
                    out[s, p, c, j] = G[s, o, c, j]


@njit
def _couple(index, coupled):  # pragma: no cover - compiled
    """coupled[a, b] = True for every frame pair a <= b sharing a sample (parents sorted, padding last)."""
    m, P = index.shape
    for s in range(m):
        for p in range(P):
            a = index[s, p]
            if a < 0:
                break
            for q in range(p, P):
                b = index[s, q]
                if b < 0:
                    break
                coupled[a, b] = True


STIFFNESS_CHUNKS = 8
"""Sample chunks of :func:`frame_stiffness_pairs`, summed in chunk order: run on the threads numba has,
the same bits for any thread count (each chunk holds its own pair blocks: 8 x 2 MB for 60 frames with 47
parents; fewer chunks where the blocks exceed :data:`STIFFNESS_CHUNK_BYTES`)."""

STIFFNESS_CHUNK_BYTES = 64 << 20

STIFFNESS_CHUNK_SAMPLES = 512
"""Samples per chunk of :func:`frame_stiffness_pairs` at least (a smaller model runs in one)."""


def frame_stiffness_pairs(index, G, A, weight, pair_id, B, points=None):
    """B (npairs, 4, PAD) += the blocks of sum_s weight_s J_s^T A_s J_s of each coupled frame pair.

    ``index`` and ``G`` as :func:`frame_pairs` returns them (parents in increasing frame order, so
    parent p < q gives frames a < b); ``B[t, d, 9 c + 3 i + k]`` is the stiffness between DOF
    (a, row i, c) and (b, row k, d) of the pair t = pair_id[a, b].  Per sample: ``Y[p, l, (c, i, k)]
    = sum_j G[p, c, j] w A[i, j, k, l]`` (36 P * 9 multiply-adds), then per parent pair and d the
    36-long update ``B[t, d] += sum_l G[q, d, l] Y[p, l]`` (432 multiply-adds per pair, a
    contiguous loop the compiler vectorises).  Fused multiply-adds (``contract``) change results
    only at round-off (tested against the numpy twin to 1e-12).  The samples are cut into
    :data:`STIFFNESS_CHUNKS` chunks run in parallel, each into blocks of its own, summed in order.
    ``points`` = (w, dw, rest, frames) of point samples (as :func:`frame_F_points` reads them): each
    sample's tables are made on the fly from them (G may then be None: no (m, P, 4, 3) array at all).
    """
    m, P = index.shape
    if points is None:
        points = (np.zeros((0, P)), np.zeros((0, P, 3)), np.zeros((0, 3)), np.zeros((0, 3)))
    else:
        G = np.zeros((0, P, 4, 3))
    chunks = int(min(STIFFNESS_CHUNKS, max(1, m // STIFFNESS_CHUNK_SAMPLES),
                     max(1, STIFFNESS_CHUNK_BYTES // max(B.nbytes, 1))))
    if chunks == 1:
        _stiffness_range(index, G, *points, A, weight, pair_id, B, 0, m)
    else:
        _stiffness_chunks(index, G, *points, A, weight, pair_id, B, chunks)


@njit(parallel=True)
def _stiffness_chunks(index, G, pw, pdw, prest, pframes, A, weight, pair_id, B, chunks):  # pragma: no cover
    part = np.zeros((chunks,) + B.shape)
    for c in prange(chunks):
        s0, s1 = chunk_bounds(index.shape[0], chunks, c)
        _stiffness_range(index, G, pw, pdw, prest, pframes, A, weight, pair_id, part[c], s0, s1)
    for c in range(chunks):
        B += part[c]


@njit(fastmath={"contract"})
def _stiffness_range(index, G, pw, pdw, prest, pframes, A, weight, pair_id, B, s0, s1):  # pragma: no cover
    """The blocks of samples s0 <= s < s1 (see :func:`frame_stiffness_pairs`), from the tables G, or when G
    is empty from the point samples' (w, dw, rest) and the frames (each sample's tables made in a buffer,
    as :func:`_fill_tables` makes them)."""
    P = index.shape[1]
    points = G.shape[0] == 0
    AV = np.empty((3, 3, 9))  # l, j, (i, k)
    Y = np.zeros((P, 3, PAD))  # p, l, (c, i, k); entries 36 ... PAD - 1 stay zero (a constant trip count)
    Gp = np.zeros((P, 4, 3))
    for s in range(s0, s1):
        if points:
            for p in range(P):
                a = index[s, p]
                if a >= 0:
                    _parent_table(pw[s, p], pdw[s, p], prest[s], pframes[a], Gp[p])
            Gs = Gp
        else:
            Gs = G[s]
        w = weight[s]
        for i in range(3):
            for j in range(3):
                for k in range(3):
                    for l in range(3):
                        AV[l, j, 3 * i + k] = w * A[s, i, j, k, l]
        for p in range(P):
            if index[s, p] < 0:
                continue
            for l in range(3):
                for c in range(4):
                    g0 = Gs[p, c, 0]
                    g1 = Gs[p, c, 1]
                    g2 = Gs[p, c, 2]
                    for x in range(9):
                        Y[p, l, 9 * c + x] = g0 * AV[l, 0, x] + g1 * AV[l, 1, x] + g2 * AV[l, 2, x]
        for p in range(P):
            a = index[s, p]
            if a < 0:
                continue
            for q in range(p, P):
                b = index[s, q]
                if b < 0:
                    continue
                t = pair_id[a, b]
                for d in range(4):
                    h0 = Gs[q, d, 0]
                    h1 = Gs[q, d, 1]
                    h2 = Gs[q, d, 2]
                    for x in range(PAD):
                        B[t, d, x] += h0 * Y[p, 0, x] + h1 * Y[p, 1, x] + h2 * Y[p, 2, x]


@njit
def frame_pairs_to_dense(pairs, B, H):  # pragma: no cover - compiled
    """Write the pair blocks B (npairs, 4, PAD) into the dense H (12n, 12n), both triangles (H's
    other entries are left as they are: zeros for a fresh matrix).  H comes out exactly symmetric:
    a diagonal block (a == b) is read from its upper triangle only."""
    for t in range(pairs.shape[0]):
        a = 12 * pairs[t, 0]
        b = 12 * pairs[t, 1]
        for r in range(12):  # row (a, r): 12 contiguous columns of frame b
            c = r % 3 if r < 9 else 3
            i = r // 3 if r < 9 else r - 9
            o = 9 * c + 3 * i
            for k in range(3):
                for d in range(4):
                    col = 3 * k + d if d < 3 else 9 + k
                    if a != b:
                        H[a + r, b + col] = B[t, d, o + k]
                    elif col >= r:
                        H[a + r, a + col] = B[t, d, o + k]
                        H[a + col, a + r] = B[t, d, o + k]
        if a != b:  # the mirror block, row by row of frame b
            for k in range(3):
                for d in range(4):
                    row = b + (3 * k + d if d < 3 else 9 + k)
                    for c in range(4):
                        for i in range(3):
                            H[row, a + (3 * i + c if c < 3 else 9 + i)] = B[t, d, 9 * c + 3 * i + k]


def frame_stiffness_dense(index, G, A, n, weight=None, tables=None, points=None) -> np.ndarray:
    """The dense stiffness (12n, 12n) ``sum_s weight_s J_s^T A_s J_s``, with A of major symmetry.

    ``tables``: the result of :func:`frame_pairs` for these samples (computed when omitted; a
    model computes it once).  Each coupled frame pair's 12x12 block is accumulated once in a
    compact array (pairs with a <= b: about half the blocks of a 50-frame sphere, 0.8 MB, cache
    resident), then written into both triangles of H.  ``points``: see :func:`frame_stiffness_pairs`
    (``index`` then in frame order, padding last, and ``tables`` given).
    """
    if tables is None:
        tables = frame_pairs(index, G, n)
    index, G, pairs, pair_id = tables
    if weight is None:
        weight = np.ones(len(index))
    B = np.zeros((len(pairs), 4, PAD))
    frame_stiffness_pairs(index, G, A, weight, pair_id, B, points)
    H = np.zeros((12 * n, 12 * n))
    frame_pairs_to_dense(pairs, B, H)
    return H


DENSE_GAIN = 1.5
"""How many more multiply-adds per second the dense products of :func:`isotropic_stiffness_dense` do than the
pair-block kernel (:func:`frame_stiffness_pairs`): 27 against 16-21 G/s on the 2-core benchmark machine (unit
stiffness of the bunny's 93k elaston points, two threads: reproducing kernels, 34 parents, 0.34 against 0.71 s;
natural neighbours, 6 parents, 0.24 against 0.05 s).
The dense path wins by doing fewer multiply-adds where most frames are parents of every sample, not by a much
faster rate.  :func:`isotropic_worth_dense` compares the two paths' counts with it (both give the same
stiffness to round-off; only the time differs)."""

ISO_CHUNK = 2048
"""Samples per dense product of :func:`isotropic_stiffness_dense` (a chunk's rows: 2048 x 12 x its frames)."""


def isotropic_worth_dense(index, n) -> bool:
    """Whether :func:`isotropic_stiffness_dense` beats the pair-block kernel on these samples: the dense
    products' ``m (12 u)^2 / 2`` multiply-adds (u: the frames of a chunk of :data:`ISO_CHUNK` samples) against
    the pair blocks' ``432 P (P + 1) / 2`` per sample, weighed by :data:`DENSE_GAIN` (reproducing-kernel weights,
    most frames parents of every sample: dense; natural neighbours' 6 parents: pairs)."""
    index = np.asarray(index)
    m = len(index)
    if m == 0:
        return False
    dense = 0.0
    for s0 in range(0, m, ISO_CHUNK):
        idx = index[s0:s0 + ISO_CHUNK]
        u = int(np.count_nonzero(np.bincount(idx[idx >= 0], minlength=n)))
        dense += len(idx) * (12.0 * u) ** 2 / 2  # a symmetric product
    P = (index >= 0).sum(axis=1).astype(np.float64)
    pairs = float((432.0 * P * (P + 1) / 2).sum())
    return dense < DENSE_GAIN * pairs


def isotropic_moduli(A):
    """(mu, lambda) of a tangent A (3, 3, 3, 3) equal to ``mu (d_ik d_jl + d_il d_jk) + lambda d_ij d_kl`` to
    1e-12 of its largest entry, else None."""
    A = np.asarray(A, dtype=np.float64)
    mu, lam = float(A[0, 1, 0, 1]), float(A[0, 0, 1, 1])
    I = np.eye(3)
    iso = (mu * (np.einsum("ik,jl->ijkl", I, I) + np.einsum("il,jk->ijkl", I, I))
           + lam * np.einsum("ij,kl->ijkl", I, I))
    top = float(np.abs(A).max())
    return (mu, lam) if np.all(np.isfinite(A)) and np.abs(A - iso).max() <= 1e-12 * top else None


def isotropic_stiffness_dense(index, n, weight, mu, lam, G=None, points=None, H=None) -> np.ndarray:
    """H (12n, 12n) += ``sum_s weight_s J_s^T A J_s`` with the isotropic A = mu (d_ik d_jl + d_il d_jk) + lam d_ij d_kl,
    by dense matrix products.

    An isotropic tangent reads the samples' tables only through their products: with the moments
    ``M[(a, c, j), (b, d, l)] = sum_s weight_s G_s[a, c, j] G_s[b, d, l]`` (G_s[a]: sample s's table of parent
    frame a, zero where a is not a parent), the block of DOF (a, i, c) and (b, k, d) is
    ``mu delta_ik sum_j M[(a, c, j), (b, d, j)] + mu M[(a, c, k), (b, d, i)] + lam M[(a, c, i), (b, d, k)]``.  M is
    summed over chunks of :data:`ISO_CHUNK` samples as ``X^T (weight X)``, X the chunk's tables laid out on the
    columns of the frames the chunk touches (rows scaled by sqrt(weight) where no weight is negative: then
    ``Y^T Y``, a symmetric product of half the cost): ``72 u^2`` multiply-adds per sample against the pair
    kernel's ``216 P (P + 1)``, at a somewhat higher rate (:data:`DENSE_GAIN`).  Parents in any order, padding anywhere.  ``G`` the tables (m, P, 4, 3) or ``points`` =
    (w, dw, rest, frames) in the order of ``index``."""
    index = np.ascontiguousarray(index, dtype=np.int64)
    m, P = index.shape
    if points is None:
        points = (np.zeros((0, P)), np.zeros((0, P, 3)), np.zeros((0, 3)), np.zeros((0, 3)))
        G = np.ascontiguousarray(G, dtype=np.float64)
    else:
        points = tuple(np.ascontiguousarray(a, dtype=np.float64) for a in points)
        G = np.zeros((0, P, 4, 3))
    weight = np.ascontiguousarray(weight, dtype=np.float64)
    signed = bool(m and weight.min() < 0)  # else rows scaled by sqrt(weight): M = Y^T Y, half the products (syrk)
    scale = np.ones(m) if signed else np.sqrt(weight)
    M = np.zeros((12 * n, 12 * n))
    loc = np.full(n, -1, dtype=np.int64)
    for s0 in range(0, m, ISO_CHUNK):
        s1 = min(m, s0 + ISO_CHUNK)
        idx = index[s0:s1]
        U = np.flatnonzero(np.bincount(idx[idx >= 0], minlength=n))
        loc[U] = np.arange(len(U))
        X = np.zeros((s1 - s0, 12 * len(U)))
        _iso_rows(index, G, *points, scale, loc, s0, s1, X)
        cols = (12 * U[:, None] + np.arange(12)).ravel()
        Mc = X.T @ (weight[s0:s1, None] * X) if signed else X.T @ X
        if len(U) == n:
            M += Mc
        else:
            M[np.ix_(cols, cols)] += Mc
        loc[U] = -1
    M6 = M.reshape(n, 4, 3, n, 4, 3)  # a, c, j, b, d, l
    K6 = mu * np.einsum("ackbdi->aicbkd", M6) + lam * np.einsum("acibdk->aicbkd", M6)
    K6 += mu * np.einsum("ik,acbd->aicbkd", np.eye(3), np.einsum("acjbdj->acbd", M6))
    r = np.array([[3 * i + c if c < 3 else 9 + i for c in range(4)] for i in range(3)]).ravel()
    perm = np.empty(12, dtype=np.int64)
    perm[r] = np.arange(12)  # DOF 3 i + c (c < 3), 9 + i (c = 3) of the (i, c) order
    K = K6.reshape(n, 12, n, 12)[:, perm][:, :, :, perm].reshape(12 * n, 12 * n)
    if H is None:
        return K
    H += K
    return H


@njit
def _iso_rows(index, G, pw, pdw, prest, pframes, scale, loc, s0, s1, X):  # pragma: no cover - compiled
    """X[s - s0, 12 loc[a] + 3 c + j] = scale[s] times sample s's table of parent a
    (:func:`isotropic_stiffness_dense`)."""
    P = index.shape[1]
    points = G.shape[0] == 0
    T = np.zeros((4, 3))
    for s in range(s0, s1):
        for p in range(P):
            a = index[s, p]
            if a < 0:
                continue
            if points:
                _parent_table(pw[s, p], pdw[s, p], prest[s], pframes[a], T)
            else:
                T[:, :] = G[s, p]
            o = 12 * loc[a]
            for c in range(4):
                for j in range(3):
                    X[s - s0, o + 3 * c + j] = scale[s] * T[c, j]


# ----------------------------------------------------------------------------------------------
# numpy twins (reference for the tests)
# ----------------------------------------------------------------------------------------------
def _dofs(index):
    """(m, P, 3, 4) DOF numbers of (parent, row i, c)."""
    a = np.where(index >= 0, index, 0)[..., None, None]
    i = np.arange(3)[None, None, :, None]
    c = np.arange(4)[None, None, None, :]
    return np.where(c < 3, 12 * a + 3 * i + c, 12 * a + 9 + i)


def frame_F_numpy(index, G, q):
    ok = (index >= 0)[..., None, None]
    d = q[np.where(index >= 0, index, 0)]  # (m, P, 12)
    rows = np.concatenate([d[..., :9].reshape(d.shape[:2] + (3, 3)), d[..., 9:, None]], axis=-1)  # (m, P, 3, 4)
    return np.einsum("mpic,mpcj->mij", np.where(ok, rows, 0.0), G)


def frame_forces_numpy(index, G, P_stress, weight, n):
    contrib = np.einsum("mij,mpcj->mpic", weight[:, None, None] * P_stress, G)  # (m, P, 3, 4)
    ok = np.broadcast_to((index >= 0)[..., None, None], contrib.shape)
    g = np.bincount(_dofs(index)[ok], weights=contrib[ok], minlength=12 * n)
    return g.reshape(n, 12)


def frame_stiffness_numpy(index, G, A, weight, n):
    blocks = np.einsum("mpcj,mijkl,mqdl->mpicqkd", G, weight[:, None, None, None, None] * A, G)  # (m, P, 3, 4, P, 3, 4)
    D = _dofs(index)
    m, P = index.shape
    rows = np.broadcast_to(D[:, :, :, :, None, None, None], blocks.shape)
    cols = np.broadcast_to(D.transpose(0, 1, 2, 3)[:, None, None, None, :, :, :], blocks.shape)
    ok = (index >= 0)
    okb = np.broadcast_to(ok[:, :, None, None, None, None, None] & ok[:, None, None, None, :, None, None], blocks.shape)
    K = np.zeros((12 * n, 12 * n))
    np.add.at(K, (rows[okb], cols[okb]), blocks[okb])
    return K
