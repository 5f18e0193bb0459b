"""Compiled rank-n products of the frames' projected volumetric term (:mod:`.volumetric`).

The projection's Hessian needs, per projected label, ``Z = N^T V B`` (active frames x DOFs: the weights
times the rows ``dJ_s/dq``) and ``X = sum_s v_s J_s^T HFJ_s N_s`` (DOFs x active frames).  Both are sums over
samples of the outer product of a sample's weights (its P parents) with one DOF row ``J_s^T vec(c_s)``
(``c_s`` a 3x3 matrix per sample), built here in one pass instead of two sparse matrices and their products
(the bundled capsule's 3,916 elastons with about 34 parents: 0.11 s of sparse work per Hessian).  Samples are
cut into a fixed number of chunks, each summed into its own array, then added in order: the same bits on any
number of threads.
"""

from __future__ import annotations

import numpy as np

from ...._jit import chunk_bounds, njit, prange

__all__ = ["weighted_rows"]

CHUNKS = 8
"""Chunks of samples summed apart (each holds an (active frames x DOFs) array)."""


@njit
def _rows_into(index, col, w, v, G, c, dofs, out):  # pragma: no cover - compiled
    P = index.shape[1]
    r = np.empty((P, 3, 4))
    for s in range(index.shape[0]):
        for p in range(P):
            if index[s, p] < 0:
                continue
            for i in range(3):
                for cc in range(4):
                    acc = 0.0
                    for j in range(3):
                        acc += c[s, i, j] * G[s, p, cc, j]
                    r[p, i, cc] = acc
        for a in range(P):
            fa = index[s, a]
            if fa < 0:
                continue
            ca = col[fa]
            wa = v[s] * w[s, a]
            if ca < 0 or wa == 0.0:
                continue
            for p in range(P):
                if index[s, p] < 0:
                    continue
                for i in range(3):
                    for cc in range(4):
                        out[ca, dofs[s, p, i, cc]] += wa * r[p, i, cc]


@njit(parallel=True)
def _rows_chunks(index, col, w, v, G, c, dofs, na, ndof, chunks):  # pragma: no cover - compiled
    part = np.zeros((chunks, na, ndof))
    for k in prange(chunks):
        a, b = chunk_bounds(index.shape[0], chunks, k)
        _rows_into(index[a:b], col, w[a:b], v[a:b], G[a:b], c[a:b], dofs[a:b], part[k])
    out = np.zeros((na, ndof))
    for k in range(chunks):
        out += part[k]
    return out


def weighted_rows(index, col, w, v, G, c, dofs, na: int, ndof: int) -> np.ndarray:
    """``sum_s v_s N_s (x) (J_s^T vec(c_s))`` as a dense (na, ndof) array.

    index (k, P) int: the samples' parent frames (-1 padding); col (n,) int: each frame's active column (-1:
    none); w (k, P): the weights N; v (k,): the samples' volumes; G (k, P, 4, 3): dF_s/d(frame DOF rows) as the
    model keeps them; c (k, 3, 3): the matrix of each sample's row; dofs (k, P, 3, 4): the DOF of (parent, row
    i, column c)."""
    k = index.shape[0]
    chunks = max(1, min(CHUNKS, k))
    return _rows_chunks(np.ascontiguousarray(index, dtype=np.int64), np.ascontiguousarray(col, dtype=np.int64),
                        np.ascontiguousarray(w, dtype=np.float64), np.ascontiguousarray(v, dtype=np.float64),
                        np.ascontiguousarray(G, dtype=np.float64), np.ascontiguousarray(c, dtype=np.float64),
                        np.ascontiguousarray(dofs, dtype=np.int64), int(na), int(ndof), chunks)
