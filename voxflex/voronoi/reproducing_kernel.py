"""Reproducing-kernel frame weights: geodesic kernels, linearly corrected at the voxel corners.

Natural-neighbour (Sibson, Laplace) weights reproduce linear fields only
inside the frames' convex hull; frames sit inside the surface, so over much of
the material the blended affine frames cannot represent a quadratic field and
a bent part carries a parasitic strain (it locks, like linear tetrahedra).
Weights that reproduce linear fields *everywhere* (``sum_i w_i = 1`` and
``sum_i w_i X_i = X``) let affine frames represent every quadratic field
exactly: with ``A_i = G + H X_i / 2`` and ``t_i = A_i X_i + c`` the blend is
``sum_i w_i (A_i X + c) = c + G X + X^T H X / 2`` — pure bending is exact.

Construction
------------
1. **Kernels.**  Frame ``i`` has the Wendland C2 kernel
   ``phi_i(X) = (1 - r)^4 (1 + 4 r)``, ``r = d_i(X) / rho_i`` (0 for r >= 1), with
   ``d_i`` the geodesic distance from the frame through the material (second-order
   fast marching bounded at ``rho_i``, so the work is the kernel's ball, not the
   image) and the radius ``rho_i = support * h_i``; ``h_i``, the *local frame
   spacing*, is the median distance from frame ``i`` to the frames whose geodesic
   Voronoi cells touch its own (measured through the shared border).  A radius is
   never below the cell's own radius plus two voxel diagonals, so every material
   point lies in its own frame's kernel.  A frame that owns a fixed region
   (``seed_owner``) measures its distance from that region.
2. **Values at the voxel corners.**  At every corner ``c`` of a material voxel
   (distance: the mean of the adjacent material voxels' centre distances) the
   Shepard weights ``s_i = phi_i / sum_j phi_j`` are corrected with a linear basis,
   in the centred form

       w_i(c) = s_i [1 + (X_i - Xbar)^T C^-1 (c - Xbar)],
       Xbar = sum_i s_i X_i,   C = sum_i s_i (X_i - Xbar)(X_i - Xbar)^T,

   so that ``sum_i w_i = 1`` and ``sum_i w_i X_i = c`` to round-off (it is the
   moment-matrix form ``p(X_i - c)^T M^-1 p(0) phi_i`` of the reproducing-kernel
   method, solved by a 3x3 eigen-decomposition instead of a 4x4 inverse).
3. **Inside a voxel** the weights are the trilinear interpolation of the corner
   values.  The trilinear corner functions sum to one and reproduce linear
   fields, so partition of unity and linear precision hold *at every point* to
   round-off; the weights are continuous (conforming: no jump anywhere, so exact
   quadrature gives an upper bound on the stiffness of the linear problem) and
   ``w``, ``grad w`` and the (mixed) Hessian are exact derivatives of the one
   interpolated function.  No parent is ever dropped: a point's parents are the
   union of its voxel's corners' frames.

Regularity guard
----------------
A corner's moment matrix is judged by the dimensionless ``lambda_min(C) / l^2``
(``l^2 = sum_i s_i rho_i^2``, the kernels' squared radius seen there): below
:data:`CONDITION` (or with no kernel at all) the corner is *bad*; the kernels of
its frame's cell and of the neighbouring cells grow by :data:`GROWTH`, at most
:data:`MAX_GROWTH_ROUNDS` times, and the corners are recomputed.  A corner still
bad after that (frames all on a line or a plane, e.g. one layer of frames in a
thin plate) gets a lower-order correction: the directions of ``C`` whose
eigenvalue is below the threshold are not corrected (partition of unity stays
exact, linear precision holds along the other directions); those corners are
counted (:attr:`ReproducingKernel.fallback_corners`) and a
:class:`ReproducingKernelWarning` says so.  A near-singular matrix is never inverted.

Negative weights
----------------
The corrected weights are negative near the edge of a kernel and where a point
lies outside its frames' hull (near the surface).  That is harmless for the
stiffness (the frame model's energy is a Galerkin restriction) but a mass lumped
in proportion to the weights can be zero or negative: the frame model lumps with
the positive part (``voxflex.deform.models.frames.model``).

Fixed regions (``seed_owner``): a corner all of whose material voxels belong to a
frame outright carries that frame alone (weight 1), so a clamp holds exactly the
corners inside it, as the voxel model's does; linear precision is given up there
(the corners' motion is prescribed).

References
----------
W. K. Liu, S. Jun, Y. F. Zhang, "Reproducing kernel particle methods", IJNMF 20,
1995.  H. Wendland, "Piecewise polynomial, positive definite and compactly
supported radial functions of minimal degree", Adv. Comput. Math. 4, 1995.
B. Gilles et al., "Frame-based elastic models", ACM TOG 30(2), 2011.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from .._jit import njit, prange
from .._ties import TIE
from ..errors import InputError
from ..image.grid import TrilinearGrid
from . import _march as M
from .corner_weights import CornerWeights
from .geodesic import voxel_coordinates

__all__ = ["CornerWeights", "ReproducingKernel", "ReproducingKernelWarning", "reproducing_kernel", "DEFAULT_SUPPORT", "CONDITION",
           "LEBESGUE_MAX", "GROWTH", "MAX_GROWTH_ROUNDS"]

DEFAULT_SUPPORT = 2.5
"""Kernel radius in local frame spacings (``[nodes] support``)."""

CONDITION = 1e-6
"""Smallest admissible ``lambda_min / lambda_max`` of a corner's centred moment matrix C (dimensionless):
below it a direction is numerically singular and never inverted."""

LEBESGUE_MAX = 20.0
"""Largest admissible ``sum_i |w_i|`` at a corner (1 for non-negative weights): how much the
corrected weights amplify the frames' motion.  Above it the weakest corrected direction is dropped
(after growing the kernels): nearly coplanar or collinear frames would otherwise give weights of
order 1 / spread."""

GROWTH = 1.25
"""Factor by which the kernels around a bad corner grow per round."""

MAX_GROWTH_ROUNDS = 6
"""Growth rounds before the lower-order fallback (kernels at most ``1.25^6 = 3.8`` times larger)."""


class ReproducingKernelWarning(UserWarning):
    """Some voxel corners got a lower-order (not linearly precise) correction."""


# --------------------------------------------------------------------------- kernels
def wendland(r):
    """Wendland C2 kernel ``(1 - r)^4 (1 + 4 r)`` for ``0 <= r < 1``, 0 beyond (array in, array out)."""
    r = np.asarray(r, dtype=float)
    t = np.clip(1.0 - r, 0.0, None)
    return t ** 4 * (1.0 + 4.0 * r)


@njit
def _frame_corners(touched, nt, dist, elem_of, element_nodes, acc, cnt, mark, out_nodes):  # pragma: no cover
    """Mean distance at the corners of the voxels a march reached: returns the count k of corners
    written to ``out_nodes[:k]``, their means left in ``acc`` (``mark`` is reset, acc/cnt are scratch)."""
    k = 0
    for t in range(nt):
        v = touched[t]
        e = elem_of[v]
        if e < 0:
            continue
        dv = dist[v]
        for c in range(8):
            node = element_nodes[e, c]
            if mark[node] == 0:
                mark[node] = 1
                out_nodes[k] = node
                k += 1
                acc[node] = 0.0
                cnt[node] = 0
            acc[node] += dv
            cnt[node] += 1
    for q in range(k):
        node = out_nodes[q]
        mark[node] = 0
        acc[node] = acc[node] / cnt[node]
    return k


@njit
def _eigh3(a, ev, V):  # pragma: no cover
    """Eigen-decomposition of the symmetric 3x3 ``a`` (overwritten) by cyclic Jacobi rotations:
    eigenvalues ascending in ``ev``, eigenvectors in the columns of ``V`` (no allocation; numba's
    ``np.linalg.eigh`` spent 3.7 us per corner, most of it allocating)."""
    for i in range(3):
        for j in range(3):
            V[i, j] = 1.0 if i == j else 0.0
    for _ in range(32):
        off = a[0, 1] * a[0, 1] + a[0, 2] * a[0, 2] + a[1, 2] * a[1, 2]
        scale = a[0, 0] * a[0, 0] + a[1, 1] * a[1, 1] + a[2, 2] * a[2, 2]
        if off <= 1e-34 * scale or off == 0.0:
            break
        for r in range(3):
            p = 0 if r < 2 else 1
            q = 1 if r == 0 else 2
            apq = a[p, q]
            if apq == 0.0:
                continue
            theta = (a[q, q] - a[p, p]) / (2.0 * apq)
            t = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + np.sqrt(theta * theta + 1.0))
            c = 1.0 / np.sqrt(t * t + 1.0)
            s = t * c
            for k in range(3):
                akp = a[k, p]
                akq = a[k, q]
                a[k, p] = c * akp - s * akq
                a[k, q] = s * akp + c * akq
            for k in range(3):
                apk = a[p, k]
                aqk = a[q, k]
                a[p, k] = c * apk - s * aqk
                a[q, k] = s * apk + c * aqk
            for k in range(3):
                vkp = V[k, p]
                vkq = V[k, q]
                V[k, p] = c * vkp - s * vkq
                V[k, q] = s * vkp + c * vkq
    for i in range(3):
        ev[i] = a[i, i]
    for i in range(1, 3):  # insertion sort, columns along
        j = i
        while j > 0 and ev[j - 1] > ev[j]:
            tmp = ev[j - 1]
            ev[j - 1] = ev[j]
            ev[j] = tmp
            for k in range(3):
                tmp = V[k, j - 1]
                V[k, j - 1] = V[k, j]
                V[k, j] = tmp
            j -= 1


@njit
def _copy_rows(old_indptr, old_w, new_indptr, todo, new_w):  # pragma: no cover
    """Copy the corner rows not in ``todo`` (same entries, new offsets) from the last round."""
    for q in range(todo.shape[0]):
        if todo[q]:
            continue
        a = old_indptr[q]
        b = new_indptr[q]
        for k in range(new_indptr[q + 1] - b):
            new_w[b + k] = old_w[a + k]


@njit(parallel=True)
def _rk_corners(indptr, fidx, phi, frames, rho, corners, eps, lebesgue_max, todo, w, lam, delta2, dropped,
                lebesgue):  # pragma: no cover
    """:func:`_rk_corners_range` over every corner, in chunks of 4096 over the threads (each corner's row is
    its own: the same bits for any thread count)."""
    nc = corners.shape[0]
    step = 4096
    for c in prange((nc + step - 1) // step):
        _rk_corners_range(indptr, fidx, phi, frames, rho, corners, eps, lebesgue_max, todo, w, lam, delta2, dropped,
                          lebesgue, c * step, min(nc, (c + 1) * step))


@njit
def _rk_corners_range(indptr, fidx, phi, frames, rho, corners, eps, lebesgue_max, todo, w, lam, delta2, dropped,
                      lebesgue, lo, hi):  # pragma: no cover
    """Linearly corrected weights at the corners ``lo..hi`` (CSR rows of kernel values; see the module docstring).

    Only the rows where ``todo`` is true.  Writes ``w`` (like ``phi``), ``lam`` = lambda_min / lambda_max
    of C (-1 where no kernel reaches), ``delta2`` = (c - Xbar)^T C^-1 (c - Xbar) over the corrected
    directions, ``lebesgue`` = sum |w| and ``dropped`` = the number of directions left uncorrected (3
    where no kernel reaches): those with eigenvalue below ``eps`` times the largest (numerically
    singular), then the weakest while ``sum |w| > lebesgue_max``.
    """
    C = np.empty((3, 3))
    ev = np.empty(3)
    V = np.empty((3, 3))
    u = np.empty(3)
    keep = np.empty(3, dtype=np.bool_)
    for q in range(lo, hi):
        if not todo[q]:
            continue
        a, b = indptr[q], indptr[q + 1]
        S = 0.0
        for k in range(a, b):
            S += phi[k]
        if not S > 0.0:
            lam[q] = -1.0
            delta2[q] = 0.0
            dropped[q] = 3
            continue
        xb0 = 0.0
        xb1 = 0.0
        xb2 = 0.0
        l2 = 0.0
        for k in range(a, b):
            s = phi[k] / S
            f = fidx[k]
            xb0 += s * (frames[f, 0] - corners[q, 0])
            xb1 += s * (frames[f, 1] - corners[q, 1])
            xb2 += s * (frames[f, 2] - corners[q, 2])
            l2 += s * rho[f] * rho[f]
        for i in range(3):
            for j in range(3):
                C[i, j] = 0.0
        for k in range(a, b):
            s = phi[k] / S
            f = fidx[k]
            r0 = frames[f, 0] - corners[q, 0] - xb0
            r1 = frames[f, 1] - corners[q, 1] - xb1
            r2 = frames[f, 2] - corners[q, 2] - xb2
            C[0, 0] += s * r0 * r0 / l2
            C[0, 1] += s * r0 * r1 / l2
            C[0, 2] += s * r0 * r2 / l2
            C[1, 1] += s * r1 * r1 / l2
            C[1, 2] += s * r1 * r2 / l2
            C[2, 2] += s * r2 * r2 / l2
        C[1, 0] = C[0, 1]
        C[2, 0] = C[0, 2]
        C[2, 1] = C[1, 2]
        _eigh3(C, ev, V)  # ascending
        top = ev[2]
        lam[q] = ev[0] / top if top > 0.0 else 0.0
        nd = 0
        for e in range(3):
            u[e] = -(V[0, e] * xb0 + V[1, e] * xb1 + V[2, e] * xb2)
            keep[e] = top > 0.0 and ev[e] >= eps * top
            if not keep[e]:
                nd += 1
        # weights with the kept directions corrected; the weakest dropped while sum |w| > lebesgue_max
        for e0 in range(4):
            g0 = 0.0
            g1 = 0.0
            g2 = 0.0
            d2 = 0.0
            for e in range(3):
                if keep[e]:
                    coef = u[e] / ev[e] / l2
                    d2 += u[e] * coef
                    g0 += V[0, e] * coef
                    g1 += V[1, e] * coef
                    g2 += V[2, e] * coef
            L1 = 0.0
            for k in range(a, b):
                s = phi[k] / S
                f = fidx[k]
                r0 = frames[f, 0] - corners[q, 0] - xb0
                r1 = frames[f, 1] - corners[q, 1] - xb1
                r2 = frames[f, 2] - corners[q, 2] - xb2
                w[k] = s * (1.0 + r0 * g0 + r1 * g1 + r2 * g2)
                L1 += abs(w[k])
            if L1 <= lebesgue_max or e0 == 3:
                break
            for e in range(3):  # drop the weakest kept direction
                if keep[e]:
                    keep[e] = False
                    nd += 1
                    break
        # one step of iterative refinement on the moment residuals (1 - sum w, -sum w (X - c)) over the
        # kept directions: near-singular corners (condition ~1e-6) otherwise keep residuals ~1e-11
        r0 = 1.0
        t0 = 0.0
        t1 = 0.0
        t2 = 0.0
        for k in range(a, b):
            f = fidx[k]
            r0 -= w[k]
            t0 -= w[k] * (frames[f, 0] - corners[q, 0])
            t1 -= w[k] * (frames[f, 1] - corners[q, 1])
            t2 -= w[k] * (frames[f, 2] - corners[q, 2])
        t0 -= r0 * xb0
        t1 -= r0 * xb1
        t2 -= r0 * xb2
        g0 = 0.0
        g1 = 0.0
        g2 = 0.0
        for e in range(3):
            if keep[e]:
                coef = (V[0, e] * t0 + V[1, e] * t1 + V[2, e] * t2) / ev[e] / l2
                g0 += V[0, e] * coef
                g1 += V[1, e] * coef
                g2 += V[2, e] * coef
        for k in range(a, b):
            s = phi[k] / S
            f = fidx[k]
            w[k] += s * (r0 + (frames[f, 0] - corners[q, 0] - xb0) * g0 + (frames[f, 1] - corners[q, 1] - xb1) * g1
                         + (frames[f, 2] - corners[q, 2] - xb2) * g2)
        dropped[q] = nd
        delta2[q] = max(d2, 0.0)
        lebesgue[q] = L1


def _rk_corners_numpy(indptr, fidx, phi, frames, rho, corners, eps, lebesgue_max):
    """Plain numpy twin of :func:`_rk_corners` (every row, padded); returns ``w, lam, delta2, dropped, lebesgue``."""
    nc = len(corners)
    counts = np.diff(indptr)
    K = max(int(counts.max(initial=0)), 1)
    row = np.repeat(np.arange(nc), counts)
    pos = np.arange(len(fidx)) - indptr[row]
    F = np.zeros((nc, K), dtype=np.int64)
    Phi = np.zeros((nc, K))
    F[row, pos] = fidx
    Phi[row, pos] = phi
    S = Phi.sum(1)
    ok = S > 0
    s = np.where(ok[:, None], Phi / np.where(ok, S, 1.0)[:, None], 0.0)
    R = frames[F] - corners[:, None, :]  # (nc, K, 3)
    xb = np.einsum("qk,qki->qi", s, R)
    l2 = np.where(ok, np.einsum("qk,qk->q", s, rho[F] ** 2), 1.0)
    Rc = R - xb[:, None, :]
    C = np.einsum("qk,qki,qkj->qij", s, Rc, Rc) / l2[:, None, None]
    ev, V = np.linalg.eigh(C)
    top = ev[:, 2:3]
    keep = (top > 0) & (ev >= eps * top)
    u = -np.einsum("qie,qi->qe", V, xb)

    def weights(keep):
        coef = np.where(keep, u / np.where(keep, ev, 1.0), 0.0) / l2[:, None]
        g = np.einsum("qie,qe->qi", V, coef)
        Wp = s * (1.0 + np.einsum("qki,qi->qk", Rc, g))
        return Wp, (u * coef).sum(1)

    Wp, d2 = weights(keep)
    for _ in range(3):
        over = np.abs(Wp).sum(1) > lebesgue_max
        if not over.any():
            break
        first = np.argmax(keep, axis=1)  # the weakest kept direction
        drop = over & keep.any(1)
        keep[np.flatnonzero(drop), first[drop]] = False
        W2, d22 = weights(keep)
        Wp = np.where(drop[:, None], W2, Wp)
        d2 = np.where(drop, d22, d2)
    r0 = 1.0 - Wp.sum(1)
    t = -np.einsum("qk,qki->qi", Wp, R) - r0[:, None] * xb
    coef = np.where(keep, np.einsum("qie,qi->qe", V, t) / np.where(keep, ev, 1.0), 0.0) / l2[:, None]
    g = np.einsum("qie,qe->qi", V, coef)
    Wp = Wp + s * (r0[:, None] + np.einsum("qki,qi->qk", Rc, g))
    w = Wp[row, pos]
    lam = np.where(ok, np.where(top[:, 0] > 0, ev[:, 0] / np.where(top[:, 0] > 0, top[:, 0], 1.0), 0.0), -1.0)
    delta2 = np.where(ok, np.maximum(d2, 0.0), 0.0)
    dropped = np.where(ok, (~keep).sum(1), 3)
    return w, lam, delta2, dropped, np.abs(Wp).sum(1)


@dataclass(frozen=True, eq=False)
class ReproducingKernel(CornerWeights):
    """Reproducing-kernel weights of frames over the material of an image (see the module docstring).

    Attributes
    ----------
    frames : (n, 3) float, metres
    kind : str, ``"reproducing-kernel"``
    support : float, kernel radius in local frame spacings
    image : LabelImage
    rho : (n,) float, the kernel radii (metres, or metres of the stiffest material with a compliance distance)
    spacing : (n,) float, the local frame spacings h_i
    grown_frames : int, frames whose kernel the regularity guard grew
    fallback_corners : int, corners left with a lower-order correction
    min_condition : float, smallest lambda_min(C) / l^2 over the corners that kept the full correction
    max_delta : float, largest (c - Xbar)^T C^-1 (c - Xbar) over the corners, square-rooted (how far a
        corner lies from its frames' centroid, in their kernel-weighted spread)
    max_lebesgue : float, largest sum_i |w_i| over the corners (1 for non-negative weights)

    Calling it with points (m, 3) (world, metres) inside (or on) the material returns
    :class:`~voxflex.voronoi.shape_functions.ShapeValues` with every parent (no truncation) and
    Hessians unless ``hessians=False``.
    """

    linearly_precise = True
    """Sums of w_a and of w_a X_a reproduce 1 and x at every point (frames' volumetric "auto" reads it)."""

    frames: np.ndarray
    image: object
    support: float
    rho: np.ndarray
    spacing: np.ndarray
    grid: TrilinearGrid = field(repr=False)
    weights: sp.csr_matrix = field(repr=False)  # (corners, n)
    grown_frames: int = 0
    fallback_corners: int = 0
    min_condition: float = float("nan")
    max_delta: float = float("nan")
    max_lebesgue: float = float("nan")
    kind: str = "reproducing-kernel"
    _cache: dict = field(repr=False, default_factory=dict)

    # -- storage (the precompute cache) ----------------------------------------
    def to_store(self) -> dict:
        W = self.weights
        return {"rk_indptr": W.indptr, "rk_indices": W.indices, "rk_data": W.data, "rk_rho": self.rho,
                "rk_spacing": self.spacing, "rk_support": np.float64(self.support),
                # statistics not measured (no fully corrected corner) are NaN; stored as -1 (a cache entry's
                # floats must be finite: voxflex.cache checks them)
                "rk_stats": np.nan_to_num(np.array([self.grown_frames, self.fallback_corners, self.min_condition,
                                                    self.max_delta, self.max_lebesgue], dtype=float), nan=-1.0)}

    @classmethod
    def from_store(cls, image, frames, d) -> "ReproducingKernel":
        grid = TrilinearGrid.from_image(image)
        W = sp.csr_matrix((d["rk_data"], d["rk_indices"], d["rk_indptr"]), shape=(grid.n_nodes, len(frames)))
        st = np.asarray(d["rk_stats"], dtype=float)
        st = np.where(st < 0, np.nan, st)  # -1: not measured (to_store)
        return cls(frames=np.asarray(frames, dtype=float), image=image, support=float(d["rk_support"]),
                   rho=np.asarray(d["rk_rho"]), spacing=np.asarray(d["rk_spacing"]), grid=grid, weights=W,
                   grown_frames=int(st[0]), fallback_corners=int(st[1]), min_condition=float(st[2]),
                   max_delta=float(st[3]), max_lebesgue=float(st[4]))


# --------------------------------------------------------------------------- construction
def _neighbour_distances(D, O, material, cost, spacing, n):
    """Geodesic distance between frames whose Voronoi cells share a voxel face, through that face:
    ``min (d(u) + d(v) + step)`` over the face pairs (u in cell i, v in cell j).  Returns (pairs (p, 2),
    distance (p,))."""
    keys, vals = [], []
    for axis in range(3):
        a = [slice(None)] * 3
        b = [slice(None)] * 3
        a[axis] = slice(0, -1)
        b[axis] = slice(1, None)
        a, b = tuple(a), tuple(b)
        sel = material[a] & material[b] & (O[a] != O[b]) & (O[a] >= 0) & (O[b] >= 0)
        if not sel.any():
            continue
        oa, ob = O[a][sel], O[b][sel]
        step = spacing[axis] * 0.5 * (cost[a][sel] + cost[b][sel])
        keys.append(np.minimum(oa, ob) * n + np.maximum(oa, ob))
        vals.append(D[a][sel] + D[b][sel] + step)
    if not keys:
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0)
    keys = np.concatenate(keys)
    vals = np.concatenate(vals)
    order = np.lexsort((vals, keys))
    keys, vals = keys[order], vals[order]
    first = np.ones(len(keys), dtype=bool)
    first[1:] = keys[1:] != keys[:-1]
    k, v = keys[first], vals[first]
    return np.stack([k // n, k % n], axis=1), v


class _Marcher:
    """Bounded distance propagations from frames, their kernel values at the voxel corners.

    Second-order fast marching (:mod:`._march`), bounded at the kernel radius plus a voxel diagonal.
    Line of sight (:mod:`._sight`) was tried and rejected: over kernel balls ~40 voxels wide in a
    non-convex object most visibility tests fail the box test and walk the segment, and the bunny's
    40 kernels took 9.2 s against 3.0 s here (Dijkstra: 2.8 s, but 13 % anisotropic).  The frames
    are shared among ``numba.get_num_threads()`` Python threads (the kernels release the GIL), each
    with its own scratch arrays; the result of a frame does not depend on the thread.
    """

    def __init__(self, mask, cost, pshape, spacing, grid, margin):
        # the marches run in units of the smallest voxel edge: the bucket queue files distances by
        # floor(d / width), and the same scene in other units must file them the same (in metres, 1 mm and
        # 1 um beams gave kernels 0.26 apart: another acceptance order, other second-order updates)
        spacing = np.asarray(spacing, dtype=np.float64)
        self.unit = float(spacing.min())
        self.mask, self.cost, self.pshape, self.spacing = mask, cost, pshape, spacing / self.unit
        self.grid, self.margin = grid, margin / self.unit
        self.smin, self.smax = float(cost.min()), float(cost.max())
        N = mask.shape[0]
        self.elem_of = np.full(N, -1, dtype=np.int64)
        self.elem_of[M.inner_to_flat(grid.element_ijk, pshape)] = np.arange(grid.n_elements)
        self.state0 = M.state_of(mask)
        self._scratch = []

    def _new_scratch(self):
        N, nn = self.mask.shape[0], self.grid.n_nodes
        return {"dist": np.full(N, np.inf), "owner": np.full(N, -1, dtype=np.int64), "state": self.state0.copy(),
                "nxt": np.empty(N, dtype=np.int32), "prv": np.empty(N, dtype=np.int32),
                "touched": np.empty(N, dtype=np.int32), "bound": np.empty(N),
                "acc": np.zeros(nn), "cnt": np.zeros(nn, dtype=np.int64), "mark": np.zeros(nn, dtype=np.uint8),
                "out": np.empty(nn, dtype=np.int64)}

    def seeds(self, pts):
        """March seeds of one frame at ``pts`` (padded index coords: the frame, with the exact ball around
        it, then the centres of the voxels it owns outright, at distance 0).  Called on the main thread:
        the ball kernel is parallel, and numba's default threading layer must not be entered from two
        threads at once."""
        own = np.zeros(len(pts), dtype=np.int64)
        si, sd, so = M._seed_arrays(self.mask, self.cost, self.pshape, self.spacing, pts[:1], own[:1], M.BALL)
        if len(pts) > 1:
            s2 = M._seed_arrays(self.mask, self.cost, self.pshape, self.spacing, pts[1:], own[1:], 0)
            si, sd, so = np.concatenate([si, s2[0]]), np.concatenate([sd, s2[1]]), np.concatenate([so, s2[2]])
        return si, sd, so

    def one(self, seeds, rho, sc):
        """(corner indices, kernel values) of one frame from its seeds (:meth:`seeds`)."""
        si, sd, so = seeds
        rho = rho / self.unit  # voxel units, as the march
        sc["bound"].fill(rho + self.margin)
        nt = M._march(self.cost, self.pshape, self.spacing, sc["dist"], sc["owner"], sc["state"], sc["nxt"],
                      sc["prv"], sc["bound"], True, si, sd, so, 2, sc["touched"], 0, self.smin, self.smax)
        k = _frame_corners(sc["touched"], nt, sc["dist"], self.elem_of, self.grid.element_nodes, sc["acc"], sc["cnt"],
                           sc["mark"], sc["out"])
        nodes = sc["out"][:k].copy()
        dc = sc["acc"][nodes]
        touched = sc["touched"][:nt]
        M._reset(sc["state"], sc["touched"], nt)
        sc["dist"][touched] = np.inf
        # corners within 1e-9 of the radius are out (their kernel value is ~1e-36): corners at exactly the
        # radius (symmetric bodies) fall on either side by round-off, which differs between units
        keep = dc < rho * (1.0 - TIE)
        return nodes[keep], wendland(dc[keep] / rho)

    def kernels(self, jobs):
        """``[(nodes, values)]`` of the frames ``jobs = [(seed points, radius)]``, in order."""
        from concurrent.futures import ThreadPoolExecutor

        import numba

        jobs = [(self.seeds(p), r) for p, r in jobs]
        workers = max(1, min(int(numba.get_num_threads()), len(jobs)))
        while len(self._scratch) < workers:
            self._scratch.append(self._new_scratch())
        if workers == 1:
            return [self.one(p, r, self._scratch[0]) for p, r in jobs]
        out = [None] * len(jobs)

        def run(t):
            for j in range(t, len(jobs), workers):
                out[j] = self.one(jobs[j][0], jobs[j][1], self._scratch[t])

        with ThreadPoolExecutor(max_workers=workers) as ex:
            list(ex.map(run, range(workers)))
        return out


def reproducing_kernel(image, frames, d, own, mask, cost, pshape, *, support=DEFAULT_SUPPORT, anchored=None,
                       seed_owner=None, condition=None, lebesgue_max=None) -> ReproducingKernel:
    """Build :class:`ReproducingKernel` weights (called by :func:`voxflex.voronoi.shape_function`).

    Parameters
    ----------
    image : LabelImage
    frames : (n, 3) float, validated world positions (one per material voxel)
    d, own : flat padded arrays, the frames' multi-source distance and Voronoi owner
        (seeded with the fixed regions' voxels when ``seed_owner`` is given)
    mask, cost, pshape : the padded grid (:func:`voxflex.voronoi.geodesic._prepare`)
    support : float > 0, kernel radius in local frame spacings
    anchored : (nx, ny, nz) bool, voxels a frame owns outright, or None
    seed_owner : (nx, ny, nz) int, the owning frame of each anchored voxel
    condition : float, :data:`CONDITION`
    lebesgue_max : float, :data:`LEBESGUE_MAX`
    """
    condition = CONDITION if condition is None else float(condition)
    lebesgue_max = LEBESGUE_MAX if lebesgue_max is None else float(lebesgue_max)
    support = float(support)
    if not (np.isfinite(support) and support > 0):
        raise InputError(f"support must be a positive number of frame spacings, got {support}")
    F = np.asarray(frames, dtype=float)
    n = len(F)
    spacing = np.asarray(image.spacing, dtype=np.float64)
    material = image.labels > 0
    grid = TrilinearGrid.from_image(image)
    nn = grid.n_nodes
    D = M.unpad(d, pshape)
    O = M.unpad(own, pshape)
    Cst = M.unpad(cost, pshape)
    smax = float(cost.max())
    diag = float(np.sqrt((spacing ** 2).sum())) * smax

    # local frame spacing: median distance to the frames of touching cells
    pairs, pd = _neighbour_distances(D, O, material, Cst, spacing, n)
    h = np.zeros(n)
    cell_radius = np.zeros(n)
    np.maximum.at(cell_radius, O[material], D[material])
    for i in range(n):
        di = pd[(pairs[:, 0] == i) | (pairs[:, 1] == i)]
        h[i] = float(np.median(di)) if len(di) else 2.0 * cell_radius[i] + diag
    nbrs = [[] for _ in range(n)]
    for a_, b_ in pairs.tolist():
        nbrs[a_].append(b_)
        nbrs[b_].append(a_)
    floor = cell_radius + 2.0 * diag
    rho = np.maximum(support * h, floor)
    if n and np.all(support * h < floor):
        # every kernel at its floor: the asked support changes nothing (0.01, 1.0 and 1.2 gave the same weights)
        warnings.warn(
            f"reproducing-kernel support = {support:g} frame spacings is below every kernel's floor (its frame's "
            f"cell and two voxel diagonals); the kernels run at the floor, {float(np.median(rho / h)):.2g} frame "
            f"spacings on the median: raise support (default {DEFAULT_SUPPORT:g}) for a setting that acts",
            ReproducingKernelWarning,
            stacklevel=3)

    # seeds of each frame's march: its own point, and the voxels it owns outright (their centres)
    fc = voxel_coordinates(image, F) + M.PAD  # without the unit's round-off (geodesic.voxel_coordinates)
    owned = [np.zeros((0, 3))] * n
    if anchored is not None and np.any(anchored):
        aijk = np.argwhere(anchored)
        aown = seed_owner[anchored]
        for i in np.unique(aown):
            owned[int(i)] = aijk[aown == i] + 0.5 + M.PAD
    marcher = _Marcher(mask, cost, pshape, spacing, grid, diag)

    def seeds(i):
        return np.concatenate([fc[i][None], owned[i]])

    kern = marcher.kernels([(seeds(i), rho[i]) for i in range(n)])
    Xc = grid.node_positions

    # anchored corners: every adjacent material voxel owned outright by a frame
    anchor_of = None
    if anchored is not None and np.any(anchored):
        en = grid.element_nodes
        ea = anchored[tuple(grid.element_ijk.T)]
        adj = np.bincount(en.ravel(), minlength=nn)
        adj_a = np.bincount(en[ea].ravel(), minlength=nn)
        anchor_of = np.full(nn, np.iinfo(np.int64).max, dtype=np.int64)
        eo = seed_owner[tuple(grid.element_ijk[ea].T)].astype(np.int64)
        np.minimum.at(anchor_of, en[ea].ravel(), np.repeat(eo, 8))
        anchor_of = np.where((adj_a == adj) & (adj > 0), anchor_of, -1)

    node_owner = np.full(nn, -1, dtype=np.int64)
    node_owner[grid.element_nodes.ravel()] = np.repeat(O[tuple(grid.element_ijk.T)], 8)

    grown = np.zeros(n, dtype=bool)
    todo = np.ones(nn, dtype=bool)
    old = None
    nbad_last = None
    stalled = 0
    lam = np.zeros(nn)
    delta2 = np.zeros(nn)
    dropped = np.zeros(nn, dtype=np.int64)
    lebesgue = np.zeros(nn)
    for rnd in range(MAX_GROWTH_ROUNDS + 1):
        rows = np.concatenate([k[0] for k in kern])
        cols = np.concatenate([np.full(len(k[0]), i, dtype=np.int64) for i, k in enumerate(kern)])
        vals = np.concatenate([k[1] for k in kern])
        K = sp.csr_matrix((vals, (rows, cols)), shape=(nn, n))
        K.sort_indices()
        indptr, fidx = K.indptr.astype(np.int64), K.indices.astype(np.int64)
        w = np.zeros(len(K.data))
        if old is not None:  # the rows no grown kernel reaches are those of the last round
            _copy_rows(old[0], old[1], indptr, todo, w)
        _rk_corners(indptr, fidx, K.data, F, rho, Xc, condition, lebesgue_max, todo, w, lam, delta2, dropped,
                    lebesgue)
        bad = dropped > 0
        if anchor_of is not None:
            bad &= anchor_of < 0
        nbad = int(bad.sum())
        # stop when nothing is bad, at the last round, or when two rounds in a row did not help (frames
        # on a plane across a thin part: larger kernels see the same plane)
        stalled = stalled + 1 if (nbad_last is not None and nbad > 0.9 * nbad_last) else 0
        if nbad == 0 or rnd == MAX_GROWTH_ROUNDS or stalled >= 2:
            break
        nbad_last = nbad
        # grow the kernels of the bad corners' cells and of the cells within ``rnd + 1`` Voronoi
        # neighbours: the frames a corner lacks may be further than the next cell
        grow = set(np.unique(node_owner[bad]).tolist())
        ring = set(grow)
        for _ in range(rnd + 1):
            ring = {b_ for a_ in ring for b_ in nbrs[a_]} - grow
            grow |= ring
        grow = np.array(sorted(grow), dtype=np.int64)
        grown[grow] = True
        rho[grow] *= GROWTH
        new = marcher.kernels([(seeds(i), rho[i]) for i in grow.tolist()])
        for i, kv in zip(grow.tolist(), new):
            kern[i] = kv
        old = (indptr, w)
        todo = np.zeros(nn, dtype=bool)
        for i in grow.tolist():
            todo[kern[i][0]] = True

    W = sp.csr_matrix((w, fidx, indptr), shape=(nn, n))
    if anchor_of is not None and np.any(anchor_of >= 0):
        a = np.flatnonzero(anchor_of >= 0)
        W = (sp.diags((anchor_of < 0).astype(float)) @ W + sp.csr_matrix(
            (np.ones(len(a)), (a, anchor_of[a])), shape=(nn, n))).tocsr()
        W.eliminate_zeros()
        bad &= anchor_of < 0
    W.sort_indices()
    full = ~bad
    if anchor_of is not None:
        full &= anchor_of < 0
    nfall = int(bad.sum())
    if nfall:
        warnings.warn(
            f"reproducing-kernel weights: {nfall} of {nn} voxel corners have frames on a line or a plane within "
            f"their (grown) kernels; they are linearly precise only along the frames' spread (partition of unity "
            f"kept); place frames across thin parts or raise support", ReproducingKernelWarning, stacklevel=3)
    return ReproducingKernel(
        frames=F, image=image, support=support, rho=rho, spacing=h, grid=grid, weights=W,
        grown_frames=int(grown.sum()), fallback_corners=nfall,
        min_condition=float(lam[full].min()) if full.any() else float("nan"),
        max_delta=float(np.sqrt(max(delta2[full].max(), 0.0))) if full.any() else float("nan"),
        max_lebesgue=float(lebesgue[anchor_of < 0].max(initial=1.0)) if anchor_of is not None
        else float(lebesgue.max(initial=1.0)))  # every corner anchored (all clamped): the clamp's weights are 1
