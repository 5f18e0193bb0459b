"""Smooth shape functions from weights known at the voxel centres.

Weights computed voxel by voxel (natural neighbours, distance ratio) are
values on the lattice of voxel centres.  A Newton solver and any quadrature
need them as a smooth function of the position, with exact gradients and
Hessians.  This module blends the centre values with the quadratic B-spline
``b`` (support three voxels per axis, C1) normalised over the material:

    w_f(x) = sum_v b(x - x_v) w_f(x_v) / sum_v b(x - x_v),      v material voxels.

Properties (tested in tests/test_smoothing.py):

* partition of unity exactly (the centre weights sum to one, so the
  numerators of all frames sum to the denominator), with ∇ and ∇² summing to
  zero to round-off;
* non-negative where the centre weights are;
* continuous with continuous gradients everywhere in the material (each term
  is a C1 B-spline; the material set does not depend on x), Hessians
  piecewise continuous — what Newton's quadratic convergence and any
  quadrature rule need;
* no leak across a one-voxel slit: a point of one part is at least 1.5 voxels
  from the centres across the slit, where ``b`` vanishes;
* linear fields are reproduced at least 1.5 voxels inside the material (the
  B-spline's linear precision), not closer to the boundary, where the
  normalisation is one-sided;
* the Kronecker property at the frames is smoothed: a frame's own weight is
  below 1 at its position (by the weight its neighbouring voxels give it).

Cost: 27 stencil voxels per point, one sparse product per derivative order.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .._jit import njit, prange
from ..errors import InputError
from .shape_functions import ShapeValues

__all__ = ["SmoothWeights"]


def _bspline2(t):
    """Quadratic B-spline (centred, support [-1.5, 1.5]) with first and second derivatives."""
    a = np.abs(t)
    inner = a <= 0.5
    outer = (a > 0.5) & (a < 1.5)
    b = np.where(inner, 0.75 - t * t, np.where(outer, 0.5 * (1.5 - a) ** 2, 0.0))
    db = np.where(inner, -2.0 * t, np.where(outer, -(1.5 - a) * np.sign(t), 0.0))
    ddb = np.where(inner, -2.0, np.where(outer, 1.0, 0.0))
    return b, db, ddb


def _finish(idx, w, dw, ddw, prune):
    """Drop parents below ``prune`` (renormalising with exact derivatives) and symmetrise the Hessians
    (``ddw`` None: values and gradients only)."""
    hess = ddw is not None
    if prune > 0:
        keep = (idx >= 0) & (w >= prune)
        w = np.where(keep, w, 0.0)
        dw = np.where(keep[..., None], dw, 0.0)
        idx = np.where(keep, idx, -1)
        s = w.sum(1)
        ds = dw.sum(1)
        wn = w / s[:, None]
        dn = (dw - wn[..., None] * ds[:, None, :]) / s[:, None, None]
        if hess:
            ddw = np.where(keep[..., None, None], ddw, 0.0)
            hs = ddw.sum(1)
            hn = (ddw - dn[..., :, None] * ds[:, None, None, :] - ds[:, None, :, None] * dn[..., None, :]
                  - wn[..., None, None] * hs[:, None]) / s[:, None, None, None]
            ddw = np.where(keep[..., None, None], hn, 0.0)
        w, dw = wn, np.where(keep[..., None], dn, 0.0)
    return idx, w, dw, (0.5 * (ddw + ddw.transpose(0, 1, 3, 2)) if hess else None)


@njit
def _b2(t):  # pragma: no cover - compiled
    a = abs(t)
    if a <= 0.5:
        return 0.75 - t * t, -2.0 * t, -2.0
    if a < 1.5:
        sg = 1.0 if t > 0 else -1.0
        return 0.5 * (1.5 - a) ** 2, -(1.5 - a) * sg, 1.0
    return 0.0, 0.0, 0.0


@njit
def _blend_range(u, vid, indptr, indices, data, P, idx, w, dw, ddw, counts, J, lo, hi, n_frames,
                 hess):  # pragma: no cover
    """:func:`_blend_kernel` for the points ``lo..hi``, with its own scratch (a frame's slot found by a
    table, not a search; no allocation per point).  Without ``hess`` no Hessian is summed or written (the
    parents, values and gradients are the same bits)."""
    nx, ny, nz = vid.shape
    fr = np.empty(n_frames, np.int64)
    slot_of = np.full(n_frames, -1, np.int64)
    N = np.empty(n_frames)
    dN = np.empty((n_frames, 3))
    HN = np.empty((n_frames, 3, 3))
    order = np.empty(n_frames, np.int64)
    bv = np.empty(3)
    dv = np.empty(3)
    hv = np.empty(3)
    gl = np.empty(3)
    Hl = np.empty((3, 3))
    H = np.empty((3, 3))
    dS = np.empty(3)
    HS = np.empty((3, 3))
    for s in range(lo, hi):
        nf = 0
        S = 0.0
        for p in range(3):
            dS[p] = 0.0
            for q in range(3):
                HS[p, q] = 0.0
        base0 = int(np.floor(u[s, 0] + 0.5)) - 1
        base1 = int(np.floor(u[s, 1] + 0.5)) - 1
        base2 = int(np.floor(u[s, 2] + 0.5)) - 1
        for a in range(3):
            i = base0 + a
            if i < 0 or i >= nx:
                continue
            bx, dx, hx = _b2(u[s, 0] - i)
            for b in range(3):
                j = base1 + b
                if j < 0 or j >= ny:
                    continue
                by, dy, hy = _b2(u[s, 1] - j)
                for c in range(3):
                    k = base2 + c
                    if k < 0 or k >= nz:
                        continue
                    v = vid[i, j, k]
                    if v < 0:
                        continue
                    bz, dz, hz = _b2(u[s, 2] - k)
                    bv[0], bv[1], bv[2] = bx, by, bz
                    dv[0], dv[1], dv[2] = dx, dy, dz
                    hv[0], hv[1], hv[2] = hx, hy, hz
                    val = bx * by * bz
                    g0 = dx * by * bz
                    g1 = bx * dy * bz
                    g2 = bx * by * dz
                    if val == 0.0 and g0 == 0.0 and g1 == 0.0 and g2 == 0.0 and hx * by * bz == 0.0 \
                            and bx * hy * bz == 0.0 and bx * by * hz == 0.0 and dx * dy * bz == 0.0 \
                            and dx * by * dz == 0.0 and bx * dy * dz == 0.0:
                        continue
                    if hess:
                        for p in range(3):
                            for q in range(3):
                                f = 1.0
                                for r in range(3):
                                    o = (1 if p == r else 0) + (1 if q == r else 0)
                                    f *= bv[r] if o == 0 else (dv[r] if o == 1 else hv[r])
                                H[p, q] = f
                                HS[p, q] += f
                    S += val
                    dS[0] += g0
                    dS[1] += g1
                    dS[2] += g2
                    for e in range(indptr[v], indptr[v + 1]):
                        f_id = indices[e]
                        wv = data[e]
                        slot = slot_of[f_id]
                        if slot < 0:
                            slot = nf
                            slot_of[f_id] = slot
                            fr[slot] = f_id
                            N[slot] = 0.0
                            for p in range(3):
                                dN[slot, p] = 0.0
                                for q in range(3):
                                    HN[slot, p, q] = 0.0
                            nf += 1
                        N[slot] += val * wv
                        dN[slot, 0] += g0 * wv
                        dN[slot, 1] += g1 * wv
                        dN[slot, 2] += g2 * wv
                        if hess:
                            for p in range(3):
                                for q in range(3):
                                    HN[slot, p, q] += H[p, q] * wv
        for t in range(nf):
            slot_of[fr[t]] = -1
        if S <= 0.0:
            counts[s] = -1
            continue
        if P == 0:
            counts[s] = nf
            continue
        # sort the parents by decreasing weight (insertion sort, nf is small)
        for t in range(nf):
            order[t] = t
        for t in range(1, nf):
            key = order[t]
            r = t - 1
            while r >= 0 and N[order[r]] < N[key]:
                order[r + 1] = order[r]
                r -= 1
            order[r + 1] = key
        for t in range(min(nf, P)):
            o = order[t]
            wv = N[o] / S
            idx[s, t] = fr[o]
            w[s, t] = wv
            for p in range(3):
                gl[p] = (dN[o, p] - wv * dS[p]) / S
            for a in range(3):
                dw[s, t, a] = J[a, 0] * gl[0] + J[a, 1] * gl[1] + J[a, 2] * gl[2]
            if not hess:
                continue
            for p in range(3):
                for q in range(3):
                    Hl[p, q] = (HN[o, p, q] - gl[p] * dS[q] - dS[p] * gl[q] - wv * HS[p, q]) / S
            for a in range(3):
                for b in range(a, 3):
                    acc = 0.0
                    for p in range(3):
                        for q in range(3):
                            acc += J[a, p] * (Hl[p, q] + Hl[q, p]) * J[b, q]
                    ddw[s, t, a, b] = 0.5 * acc
                    ddw[s, t, b, a] = 0.5 * acc


@njit(parallel=True)
def _blend_kernel(u, vid, indptr, indices, data, P, idx, w, dw, ddw, counts, J, n_frames, hess):  # pragma: no cover
    """Blend of the voxel-centre weights (CSR rows per material voxel) at lattice points u (m, 3).

    With ``P == 0`` it only counts the parents of each point into ``counts`` (-1: no material in the
    stencil); otherwise it fills idx/w/dw/ddw, the derivatives mapped to world ones by ``J`` (3, 3)
    (``d/dx = J d/du``, ``J = direction / spacing``): in the kernel, because the einsum doing it
    afterwards took 1.8 s of the bunny's precompute (94k points, 2 mm, 40 frames).  Points in
    chunks of 4096 over the threads (each point's result does not depend on the chunking).  ``hess``: sum
    and write the Hessians (else ``ddw`` is not touched).
    """
    m = u.shape[0]
    step = 4096
    nchunk = (m + step - 1) // step
    for c in prange(nchunk):
        _blend_range(u, vid, indptr, indices, data, P, idx, w, dw, ddw, counts, J, c * step,
                     min(m, (c + 1) * step), n_frames, hess)


class SmoothWeights:
    """Quadratic B-spline blend of per-voxel weights over the material (see the module docstring).

    Parameters
    ----------
    image : LabelImage
    index, w : (V, K) arrays
        Frame indices (-1 padded) and weights at every material voxel centre, in
        ``np.flatnonzero(image.labels > 0)`` order; rows sum to one.
    n_frames : int
    """

    def __init__(self, image, index, w, n_frames: int, *, backend: str = "numba"):
        self.backend = backend
        self.image = image
        self.n_frames = int(n_frames)
        mask = image.labels > 0
        V = int(mask.sum())
        index = np.asarray(index, dtype=np.int64)
        w = np.asarray(w, dtype=float)
        if index.shape != w.shape or index.shape[0] != V:
            raise InputError(f"voxel weights must be (V, K) with V = {V} material voxels, got {index.shape}")
        rows = np.repeat(np.arange(V), index.shape[1])
        ok = index.ravel() >= 0
        self._W = sp.csr_matrix((w.ravel()[ok], (rows[ok], index.ravel()[ok])), shape=(V, self.n_frames))
        self._vid = -np.ones(image.shape, dtype=np.int64)
        self._vid[mask] = np.arange(V)
        self._step = np.asarray(image.spacing, dtype=float)
        self._dir = np.asarray(image.direction, dtype=float)

    @classmethod
    def from_csr(cls, image, W, *, backend: str = "numba") -> "SmoothWeights":
        """From the (V, n) CSR matrix of the voxel-centre weights (as stored by the precompute cache)."""
        self = cls.__new__(cls)
        self.backend = backend
        self.image = image
        self.n_frames = int(W.shape[1])
        self._W = sp.csr_matrix(W)
        mask = image.labels > 0
        self._vid = -np.ones(image.shape, dtype=np.int64)
        self._vid[mask] = np.arange(int(mask.sum()))
        self._step = np.asarray(image.spacing, dtype=float)
        self._dir = np.asarray(image.direction, dtype=float)
        return self

    def __call__(self, points, *, prune: float = 0.0, chunk: int = 20000, hessians: bool = True) -> ShapeValues:
        """Values, gradients and Hessians at world points (m, 3) inside (or on) the material.

        ``prune``: weights below it are dropped and the rest renormalised (0 keeps every
        non-zero weight; pruning makes the functions discontinuous where the set changes).
        ``hessians=False``: no Hessians (``ddw`` None; values and gradients the same bits).
        """
        X = np.asarray(points, dtype=float)
        if self.backend != "numpy" and len(X):
            return self._compiled(X, prune, bool(hessians))
        sv = self._numpy_values(X, prune, chunk)
        return sv if hessians else sv.without_hessians()

    def _numpy_values(self, X, prune, chunk):
        out = [self._chunk(X[a:a + chunk], prune) for a in range(0, len(X), chunk)]
        if not out:
            z = np.zeros((0, 1))
            return ShapeValues(np.zeros((0, 1), np.int64), z, np.zeros((0, 1, 3)), np.zeros((0, 1, 3, 3)), X.reshape(0, 3),
                               n_nodes=self.n_frames)
        P = max(o[0].shape[1] for o in out)

        def pad(a, fill):
            width = [(0, 0), (0, P - a.shape[1])] + [(0, 0)] * (a.ndim - 2)
            return np.pad(a, width, constant_values=fill)

        index = np.concatenate([pad(o[0], -1) for o in out])
        w = np.concatenate([pad(o[1], 0.0) for o in out])
        dw = np.concatenate([pad(o[2], 0.0) for o in out])
        ddw = np.concatenate([pad(o[3], 0.0) for o in out])
        return ShapeValues(index=index, w=w, dw=dw, ddw=ddw, rest=X, n_nodes=self.n_frames)

    def _compiled(self, X, prune, hess=True):
        """All points at once: one kernel pass counting the parents, one filling the output in place
        (the chunks' padding and concatenation took 1.2 s of the bunny's precompute)."""
        u = np.ascontiguousarray(self.image.world_to_index(X) - 0.5)
        counts = np.zeros(len(X), dtype=np.int64)
        W = self._W
        J = np.ascontiguousarray(self._dir / self._step[None, :])
        ip, ix = W.indptr.astype(np.int64), W.indices.astype(np.int64)
        _blend_kernel(u, self._vid, ip, ix, W.data, 0, np.zeros((0, 1), np.int64), np.zeros((0, 1)),
                      np.zeros((0, 1, 3)), np.zeros((0, 1, 3, 3)), counts, J, max(self.n_frames, 1), False)
        if np.any(counts < 0):
            bad = int(np.flatnonzero(counts < 0)[0])
            raise InputError(f"point {X[bad].tolist()} lies outside the material; evaluate shape functions inside the object")
        P = max(1, int(counts.max()))
        idx = np.full((len(X), P), -1, dtype=np.int64)
        w = np.zeros((len(X), P))
        dw = np.zeros((len(X), P, 3))
        ddw = np.zeros((len(X), P, 3, 3)) if hess else np.zeros((1, 1, 3, 3))
        _blend_kernel(u, self._vid, ip, ix, W.data, P, idx, w, dw, ddw, counts, J, max(self.n_frames, 1), hess)
        if not hess:
            ddw = None
        if prune > 0:
            idx, w, dw, ddw = _finish(idx, w, dw, ddw, prune)
        return ShapeValues(index=idx, w=w, dw=dw, ddw=ddw, rest=X, n_nodes=self.n_frames)

    def _chunk(self, X, prune):
        return self._chunk_numpy(X, prune)

    def _chunk_numpy(self, X, prune):
        m = len(X)
        img = self.image
        u = img.world_to_index(X) - 0.5  # lattice coordinates of the voxel centres
        base = np.floor(u + 0.5).astype(np.int64) - 1  # the 3 centres per axis within 1.5 of u
        offs = np.array([[a, b, c] for a in range(3) for b in range(3) for c in range(3)], dtype=np.int64)
        cells = base[:, None, :] + offs[None, :, :]  # (m, 27, 3)
        t = u[:, None, :] - cells  # (m, 27, 3)
        b1, d1, dd1 = _bspline2(t)
        shape = np.asarray(img.shape)
        inside = np.all((cells >= 0) & (cells < shape), axis=2)
        cc = np.clip(cells, 0, shape - 1)
        vid = np.where(inside, self._vid[cc[..., 0], cc[..., 1], cc[..., 2]], -1)
        use = vid >= 0
        # tensor-product values and derivatives in lattice coordinates
        b = b1[..., 0] * b1[..., 1] * b1[..., 2] * use
        g = np.stack([d1[..., 0] * b1[..., 1] * b1[..., 2], b1[..., 0] * d1[..., 1] * b1[..., 2],
                      b1[..., 0] * b1[..., 1] * d1[..., 2]], axis=-1) * use[..., None]
        H = np.empty(b.shape + (3, 3))
        f = (b1, d1, dd1)
        for i in range(3):
            for j in range(3):
                terms = []
                for k in range(3):
                    order = (i == k) + (j == k)
                    terms.append(f[order][..., k])
                H[..., i, j] = terms[0] * terms[1] * terms[2]
        H *= use[..., None, None]
        S, dS, HS = b.sum(1), g.sum(1), H.sum(1)
        if np.any(S <= 0):
            bad = int(np.flatnonzero(S <= 0)[0])
            raise InputError(f"point {X[bad].tolist()} lies outside the material; evaluate shape functions inside the object")
        rows = np.repeat(np.arange(m), 27)
        cols = np.where(use, vid, 0).ravel()

        def blend(vals):
            B = sp.csr_matrix((vals.ravel(), (rows, cols)), shape=(m, self._W.shape[0]))
            return np.asarray((B @ self._W).todense())

        N = blend(b)  # (m, n)
        dN = np.stack([blend(g[..., k]) for k in range(3)], axis=-1)  # (m, n, 3)
        HN = np.empty(N.shape + (3, 3))
        for i in range(3):
            for j in range(i, 3):
                HN[..., i, j] = blend(H[..., i, j])
                HN[..., j, i] = HN[..., i, j]
        wv = N / S[:, None]
        dwv = (dN - wv[..., None] * dS[:, None, :]) / S[:, None, None]
        Hw = (HN - dwv[..., :, None] * dS[:, None, None, :] - dS[:, None, :, None] * dwv[..., None, :]
              - wv[..., None, None] * HS[:, None]) / S[:, None, None, None]
        # lattice coordinates -> world: d/dx = direction @ diag(1/spacing) d/du
        J = self._dir / self._step[None, :]  # columns scaled: du_k/dx = direction[:, k] / spacing[k]
        dwv = dwv @ J.T
        Hw = np.einsum("ak,mfkl,bl->mfab", J, Hw, J)
        # a frame is a parent wherever its value or a derivative is non-zero (at a B-spline knot a
        # stencil voxel can give b ~ 1e-31 with a finite second derivative: dropping it would break
        # the zero sum of the Hessians)
        touched = (wv != 0) | np.any(dwv != 0, axis=-1) | np.any(Hw != 0, axis=(-2, -1))
        P = max(1, int(touched.sum(1).max()))
        order = np.argsort(-np.where(touched, wv, -1.0), axis=1, kind="stable")[:, :P]
        r = np.arange(m)[:, None]
        k = touched[r, order]
        idx = np.where(k, order, -1)
        return _finish(idx, np.where(k, wv[r, order], 0.0), np.where(k[..., None], dwv[r, order], 0.0),
                       np.where(k[..., None, None], Hw[r, order], 0.0), prune)
