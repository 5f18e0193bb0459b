"""Weights stored at the voxel corners, evaluated by trilinear interpolation inside each material voxel.

The evaluation shared by the weight families that build their weights on the voxel grid's corners
(:class:`~voxflex.voronoi.reproducing_kernel.ReproducingKernel`,
:class:`~voxflex.voronoi.eigenmode.EigenmodeWeights`): a point's parents are the union of its voxel's eight
corners' frames, never truncated; values, gradients and (on request) Hessians are the trilinear blend of the
corner weights, by one compiled kernel over the threads (:func:`_interpolate`) with a numpy twin.
"""

from __future__ import annotations

import numpy as np

from .._jit import njit, prange
from ..errors import InputError
from ..image.grid import trilinear_weights
from .shape_functions import ShapeValues, world_points

__all__ = ["CornerWeights"]


@njit
def _union_sizes(element_nodes, indptr, fidx, n_frames):  # pragma: no cover
    """Number of distinct frames over the 8 corners of every element."""
    V = element_nodes.shape[0]
    stamp = np.full(n_frames, -1, dtype=np.int64)
    out = np.zeros(V, dtype=np.int64)
    for e in range(V):
        cnt = 0
        for c in range(8):
            node = element_nodes[e, c]
            for k in range(indptr[node], indptr[node + 1]):
                f = fidx[k]
                if stamp[f] != e:
                    stamp[f] = e
                    cnt += 1
        out[e] = cnt
    return out


@njit(parallel=True)
def _interpolate(elem, local, element_nodes, indptr, fidx, wdata, Dw, hess, index, w, dw, ddw):  # pragma: no cover
    """Trilinear interpolation of corner weights at points (element, local coords): fills index/w/dw
    (and ddw when ``hess``); ``Dw`` (3, 3) maps local derivatives to world ones (``direction / spacing``).
    Points in chunks of 4096 over the threads (:func:`_interpolate_range`)."""
    m = elem.shape[0]
    n_frames = 1
    for k in range(fidx.shape[0]):
        if fidx[k] + 1 > n_frames:
            n_frames = fidx[k] + 1
    step = 4096
    for c in prange((m + step - 1) // step):
        _interpolate_range(elem, local, element_nodes, indptr, fidx, wdata, Dw, hess, index, w, dw, ddw,
                           c * step, min(m, (c + 1) * step), n_frames)


@njit
def _interpolate_range(elem, local, element_nodes, indptr, fidx, wdata, Dw, hess, index, w, dw, ddw, lo, hi,
                       n_frames):  # pragma: no cover
    """:func:`_interpolate` for the points ``lo..hi``.  Local derivatives are summed per parent, then
    mapped once (the trilinear Hessian has only the three mixed terms)."""
    slot_of = np.full(n_frames, -1, dtype=np.int64)
    P = index.shape[1]
    N = np.empty(8)
    dN = np.empty((8, 3))
    hN = np.empty((8, 3))  # d2/dx0dx1, d2/dx0dx2, d2/dx1dx2
    gl = np.zeros((P, 3))
    hl = np.zeros((P, 3))
    for s in range(lo, hi):
        e = elem[s]
        x0 = local[s, 0]
        x1 = local[s, 1]
        x2 = local[s, 2]
        for c in range(8):
            o0 = (c >> 2) & 1
            o1 = (c >> 1) & 1
            o2 = c & 1
            f0 = x0 if o0 else 1.0 - x0
            f1 = x1 if o1 else 1.0 - x1
            f2 = x2 if o2 else 1.0 - x2
            d0 = 1.0 if o0 else -1.0
            d1 = 1.0 if o1 else -1.0
            d2 = 1.0 if o2 else -1.0
            N[c] = f0 * f1 * f2
            dN[c, 0] = d0 * f1 * f2
            dN[c, 1] = f0 * d1 * f2
            dN[c, 2] = f0 * f1 * d2
            hN[c, 0] = d0 * d1 * f2
            hN[c, 1] = d0 * f1 * d2
            hN[c, 2] = f0 * d1 * d2
        nf = 0
        for c in range(8):
            node = element_nodes[e, c]
            for k in range(indptr[node], indptr[node + 1]):
                f = fidx[k]
                t = slot_of[f]
                if t < 0:
                    t = nf
                    slot_of[f] = t
                    index[s, t] = f
                    for a in range(3):
                        gl[t, a] = 0.0
                        hl[t, a] = 0.0
                    nf += 1
                wk = wdata[k]
                w[s, t] += N[c] * wk
                for a in range(3):
                    gl[t, a] += dN[c, a] * wk
                    hl[t, a] += hN[c, a] * wk
        for t in range(nf):
            slot_of[index[s, t]] = -1
            for a in range(3):
                dw[s, t, a] = Dw[a, 0] * gl[t, 0] + Dw[a, 1] * gl[t, 1] + Dw[a, 2] * gl[t, 2]
            if hess:
                h01 = hl[t, 0]
                h02 = hl[t, 1]
                h12 = hl[t, 2]
                for a in range(3):
                    for b in range(a, 3):
                        v = (h01 * (Dw[a, 0] * Dw[b, 1] + Dw[a, 1] * Dw[b, 0])
                             + h02 * (Dw[a, 0] * Dw[b, 2] + Dw[a, 2] * Dw[b, 0])
                             + h12 * (Dw[a, 1] * Dw[b, 2] + Dw[a, 2] * Dw[b, 1]))
                        ddw[s, t, a, b] = v
                        ddw[s, t, b, a] = v


def _interpolate_numpy(elem, local, element_nodes, W, Dw, hess):
    """Plain numpy twin of :func:`_interpolate` with a dense (corners, n) weight table ``W``:
    returns dense ``w (m, n)``, ``dw (m, n, 3)`` and ``ddw (m, n, 3, 3)`` (or None)."""
    N, dN, HN = trilinear_weights(local, hessian=True)
    Wc = W[element_nodes[elem]]  # (m, 8, n)
    w = np.einsum("mc,mcf->mf", N, Wc)
    dwl = np.einsum("mca,mcf->mfa", dN, Wc)
    dw = dwl @ Dw.T
    ddw = None
    if hess:
        Hl = np.einsum("mcab,mcf->mfab", HN, Wc)
        ddw = np.einsum("ap,mfpr,br->mfab", Dw, Hl, Dw)
    return w, dw, ddw


# --------------------------------------------------------------------------- the shape function
class CornerWeights:
    """Weights stored at the voxel corners and interpolated trilinearly inside each material voxel
    (values, gradients and Hessians): the evaluation shared by the families that build their weights on
    the voxel grid (:class:`ReproducingKernel`, :class:`~voxflex.voronoi.eigenmode.EigenmodeWeights`).
    A subclass provides ``frames`` (n, 3), ``grid`` (:class:`~voxflex.image.grid.TrilinearGrid`),
    ``weights`` (corners x frames, CSR) and a ``_cache`` dict; its weights are never pruned.
    """

    @property
    def n_nodes(self) -> int:
        return len(self.frames)

    @property
    def parents(self) -> int:
        """The most parents a point has (the union over its voxel's corners; never truncated)."""
        if "sizes" not in self._cache:
            W = self.weights
            self._cache["sizes"] = _union_sizes(self.grid.element_nodes, W.indptr.astype(np.int64),
                                                W.indices.astype(np.int64), len(self.frames))
        return int(self._cache["sizes"].max(initial=1))

    def _Dw(self):
        return np.asarray(self.grid.direction, dtype=float) / np.asarray(self.grid.spacing, dtype=float)[None, :]

    def evaluate(self, elem, local, *, hessians=True) -> ShapeValues:
        """Values at points given by their element (material voxel, C order) and local coordinates."""
        elem = np.ascontiguousarray(elem, dtype=np.int64)
        local = np.ascontiguousarray(local, dtype=np.float64)
        self.parents  # noqa: B018 - fills the per-element union sizes
        sizes = self._cache["sizes"]
        m = len(elem)
        P = max(1, int(sizes[elem].max(initial=1)))
        index = np.full((m, P), -1, dtype=np.int64)
        w = np.zeros((m, P))
        dw = np.zeros((m, P, 3))
        ddw = np.zeros((m, P, 3, 3)) if hessians else np.zeros((1, 1, 3, 3))
        W = self.weights
        _interpolate(elem, local, self.grid.element_nodes, W.indptr.astype(np.int64), W.indices.astype(np.int64),
                     W.data, self._Dw(), bool(hessians), index, w, dw, ddw)
        X = self.grid.index_to_world(self.grid.element_ijk[elem] + local)
        return ShapeValues(index=index, w=w, dw=dw, ddw=ddw if hessians else None, rest=X, n_nodes=len(self.frames))

    def __call__(self, points, *, hessians=True) -> ShapeValues:
        X = world_points(points)
        elem, local = self.grid.locate(X, tolerance=1e-6)
        if np.any(elem < 0):
            b = int(np.flatnonzero(elem < 0)[0])
            raise InputError(f"point {b} at {X[b].tolist()} lies outside the material; evaluate shape functions "
                             "inside the object")
        sv = self.evaluate(elem, local, hessians=hessians)
        return ShapeValues(index=sv.index, w=sv.w, dw=sv.dw, ddw=sv.ddw, rest=X, n_nodes=sv.n_nodes)

    def voxel_values(self) -> ShapeValues:
        """Values at every material voxel centre, in ``np.flatnonzero(image.labels > 0)`` order (cached)."""
        if "voxels" not in self._cache:
            V = self.grid.n_elements
            self._cache["voxels"] = self.evaluate(np.arange(V), np.full((V, 3), 0.5))
        return self._cache["voxels"]

    centre_values = voxel_values

    def pruned_mass(self) -> float:
        """0: weights at the corners are never pruned."""
        return 0.0
