"""Mid-point regions without under-integration: each region's mean F plus its fluctuation energy.

A mid-point region r (a union of voxels) is integrated by one sample whose
deformation gradient is the exact volume mean of F over the region,
``F_r = sum_q v_q F_q / V_r`` over the region's 2x2x2 Gauss points q (F is
linear in the frames' DOFs, so F_r = Jbar_r q with the Gauss points' tables
averaged once), and the variation of F about that mean, which one sample
cannot see, is given its linearised energy:

    E_r = V_r W(F_r) + 1/2 sum_q v_q (G dF_q) : C0 : (G dF_q),     dF_q = F_q - F_r,

with ``C0`` the material's tangent at rest (its deviatoric part ``P C0 P``
where the volumetric term is projected) and ``G = I`` for materials with a
constant tangent or a small-strain (``linear``) strain measure (plastic ones
included: the fluctuation stays elastic), ``G = F_r^-1`` otherwise.

Why this form
-------------
* Linear materials (constant tangent): ``sum_q v_q W(F_r + dF_q) = V_r W(F_r)
  + 1/2 sum_q v_q dF_q : C0 : dF_q`` exactly (W is quadratic and the dF_q have
  zero mean), so mid-point regions give the Gauss-Legendre energy, gradient
  and Hessian of the same frames to round-off, at any state and any count.
  The second term is the frames' equivalent of the voxel model's
  Gauss-minus-mid-point stiffness: at rest its Hessian is
  ``K_r = sum_q v_q (J_q - Jbar_r)^T C0 (J_q - Jbar_r)`` (positive
  semi-definite, zero on every affine motion), so the rest stiffness of the
  regions is the Gauss-Legendre one and no region count leaves a soft mode.
* Other materials: the first term is the material's own energy of the mean F;
  the fluctuation's energy is the same quadratic form of the *pulled-back*
  fluctuation ``F_r^-1 dF_q``.  A rotation Q of the body (F -> Q F) leaves
  ``F_r^-1 dF_q`` unchanged, so the term is objective (a constant quadratic in
  the DOFs is not: it charges a bent, rotated cantilever for the rotation).
  It is exact at rest and for affine motions (dF_q = 0), and differs from the
  Taylor term ``1/2 dF : A(F_r) : dF`` by O(|F_r - I| |dF|^2): the strains of
  the region, not its rotations.  Measured on the neo-Hooke cantilever:
  ``benchmarks/bench_frames_quadrature.py``.

Its gradient and Hessian are exact.  With ``w = L(F_r) du`` (L applies G to
every parent's three DOF rows, du the DOFs minus rest: K_r annihilates affine
states) and ``E = 1/2 w^T K_r w``: the gradient is ``L^T K_r w + Jbar^T gamma``
with ``gamma = -G^T Phi G^T``, ``Phi[a, i] = sum_pc (K w)[p, a, c] du[p, i, c]``;
the Hessian ``T^T K T + Jbar^T C + C^T Jbar + Jbar^T D Jbar`` with
``T = L + B Jbar``, B, C, D the first and second derivatives of L (see
:meth:`Fluctuation.evaluate`).

Data: per region, its parents (the union of its Gauss points' parents), the
mean tables ``Gbar`` (the frame model's point tables, see ``_kernels``), the
mean weights and ``Gamma_r = sum_q v_q dG_q dG_q^T`` (12P x 12P), grouped by
parent count so that the dense per-region work is batched; and the weights' moments ``sum_q v_q dw_q
dw_q^T`` and ``sum_q v_q dw_q dG_q^T``, with which a projected volume ratio is integrated over the
regions as over their Gauss points (:mod:`~voxflex.deform.models.frames.volumetric`).  Built from the
Gauss points' shape values, which the precompute caches.
"""

from __future__ import annotations

import numpy as np

from ...._jit import njit, prange
from ._kernels import frame_tables

__all__ = ["RegionTables", "Fluctuation", "region_tables"]


class RegionTables:
    """Mean tables and fluctuation moments of mid-point regions (see the module docstring).

    Attributes
    ----------
    index : (R, P) int64, each region's parent frames, increasing, -1 padded
    G : (R, P, 4, 3) float, the mean tables (F_r = sum_pc d[a_p, :, c] G[p, c, :])
    w : (R, P) float, the mean weights (sum 1 per region)
    volume : (R,) float [m^3]
    buckets : list of (regions (Rb,) int64, P_b, Gamma (Rb, P_b, 4, 3, P_b, 4, 3)), regions grouped by
        parent count; ``Gamma[p, c, j, p', c', l] = sum_q v_q dG_q[p, c, j] dG_q[p', c', l]``
        over the first P_b parents of each region (the others are padding)
    weight_moments : list of (regions (Rb,) int64, P_b, Omega (Rb, P_b, P_b), C (Rb, P_b, P_b, 4, 3)), the same
        groups: the weights' fluctuation moments ``Omega[a, b] = sum_q v_q dw_q[a] dw_q[b]`` and their cross
        moments with the tables ``C[a, p, c, j] = sum_q v_q dw_q[a] dG_q[p, c, j]`` (``dw_q = w_q - wbar``,
        ``dG_q = G_q - Gbar``): what the volume ratio's projection needs to integrate the regions as their
        Gauss points do (:mod:`voxflex.deform.models.frames.volumetric`)
    """

    def __init__(self, index, G, w, volume, buckets, weight_moments=()):
        self.index = index
        self.G = G
        self.w = w
        self.weight_moments = list(weight_moments)
        self.volume = volume
        self.buckets = buckets

    @property
    def n_regions(self) -> int:
        return len(self.volume)


def region_tables(values, volume, region, n_regions, frames) -> RegionTables:
    """Build :class:`RegionTables` from the regions' Gauss points.

    Parameters
    ----------
    values : ShapeValues
        Shape values at the Gauss points (the Gauss-Legendre model's: pruned to its parents).
    volume : (K,) float
        The Gauss points' weights [m^3].
    region : (K,) int
        Region of each Gauss point, in ``[0, n_regions)``; every region needs one.
    n_regions : int
    frames : (n, 3) float
        The frames' rest positions [m].
    """
    n = len(frames)
    region = np.asarray(region, dtype=np.int64)
    volume = np.asarray(volume, dtype=np.float64)
    K, Pq = values.index.shape
    Gq = frame_tables(values, np.asarray(frames, dtype=np.float64))  # (K, Pq, 4, 3)
    ok = values.index >= 0
    # the union of parents per region, increasing
    key = region[:, None] * n + np.where(ok, values.index, 0)
    ukey = np.unique(key[ok])
    rk = ukey // n
    counts = np.bincount(rk, minlength=n_regions)
    P = max(int(counts.max(initial=1)), 1)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    index = np.full((n_regions, P), -1, dtype=np.int64)
    slot_of_key = np.arange(len(ukey)) - first[rk]
    index[rk, slot_of_key] = ukey % n
    slot = np.full((K, Pq), -1, dtype=np.int64)
    slot[ok] = slot_of_key[np.searchsorted(ukey, key[ok])]
    V = np.bincount(region, weights=volume, minlength=n_regions)
    # mean tables and weights: sums over (region, slot) in one compiled pass (numpy's temporaries of v G over the
    # bunny's 754k Gauss points with 6 parents held 0.9 GB)
    Gbar = np.zeros((n_regions, P, 12))
    wbar = np.zeros((n_regions, P))
    _region_sums(region, np.ascontiguousarray(slot), np.ascontiguousarray(Gq).reshape(K, Pq, 12),
                 np.ascontiguousarray(values.w, dtype=np.float64), volume, Gbar, wbar)
    Gbar = Gbar.reshape(n_regions, P, 4, 3) / V[:, None, None, None]
    wbar = wbar / V[:, None]
    # fluctuation moments sum_q v (G_q - Gbar)(G_q - Gbar)^T = sum_q v G_q G_q^T - V Gbar Gbar^T: the first
    # sum over each point's own parents only (compiled), in one ragged buffer of (12 P_r)^2 per region
    size = (12 * counts) ** 2
    offset = np.concatenate([[0], np.cumsum(size)[:-1]]).astype(np.int64)
    buf = np.zeros(int(size.sum()))
    _gauss_moments(region, np.ascontiguousarray(slot), np.ascontiguousarray(Gq), volume, offset,
                   (12 * counts).astype(np.int64), buf)
    buckets = []
    for Pb in np.unique(counts):
        Pb = int(Pb)
        regs = np.flatnonzero(counts == Pb)
        N = 12 * Pb
        idx = offset[regs][:, None] + np.arange(N * N)[None, :]
        Gam = buf[idx].reshape(len(regs), N, N)
        g = Gbar[regs, :Pb].reshape(len(regs), N)
        Gam -= V[regs, None, None] * g[:, :, None] * g[:, None, :]
        Gam = 0.5 * (Gam + Gam.transpose(0, 2, 1))
        buckets.append((regs, Pb, Gam.reshape(len(regs), Pb, 4, 3, Pb, 4, 3)))
    # the weights' moments: per region a (P_r, 13 P_r) block, row a: [sum v w_a w_b (b) | sum v w_a G_b (b, c, j)]
    wsize = 13 * counts ** 2
    woff = np.concatenate([[0], np.cumsum(wsize)[:-1]]).astype(np.int64)
    wbuf = np.zeros(int(wsize.sum()))
    _weight_moments(region, np.ascontiguousarray(slot), np.ascontiguousarray(Gq),
                    np.ascontiguousarray(values.w, dtype=np.float64), volume, woff, counts.astype(np.int64), wbuf)
    moments = []
    for regs, Pb, _ in buckets:
        idx = woff[regs][:, None] + np.arange(13 * Pb * Pb)[None, :]
        Wm = wbuf[idx].reshape(len(regs), Pb, 13 * Pb)
        wb = wbar[regs, :Pb]
        Om = Wm[:, :, :Pb] - V[regs, None, None] * wb[:, :, None] * wb[:, None, :]
        Om = 0.5 * (Om + Om.transpose(0, 2, 1))
        Cr = Wm[:, :, Pb:].reshape(len(regs), Pb, Pb, 4, 3) - V[regs, None, None, None, None] * \
            wb[:, :, None, None, None] * Gbar[regs, None, :Pb]
        moments.append((regs, Pb, Om, Cr))
    return RegionTables(index, Gbar, wbar, V, buckets, moments)


def _small_strain(material) -> bool:
    """Whether the fluctuation of ``material`` takes ``G = I``: a constant tangent, or a small-strain
    (``linear``) strain measure, e.g. under plasticity (the pull-back is for finite-strain measures)."""
    if bool(getattr(material, "constant_tangent", False)):
        return True
    strain = getattr(material, "strain", None)
    base = getattr(material, "base", None)
    if base is not None:
        strain = getattr(base, "strain", strain)
    return bool(getattr(strain, "constant_jacobian", False))


@njit
def _region_sums(region, slot, Gf, w, volume, Gsum, wsum):  # pragma: no cover - compiled
    """``Gsum[r, slot] += v_q G_q[parent]`` (12 entries) and ``wsum[r, slot] += v_q w_q[parent]`` over every Gauss
    point's own parents, in point order (numpy's bincount over the same entries: the same sums)."""
    K, Pq = slot.shape
    for q in range(K):
        r = region[q]
        v = volume[q]
        for a in range(Pq):
            sa = slot[q, a]
            if sa < 0:
                continue
            wsum[r, sa] += v * w[q, a]
            for e in range(12):
                Gsum[r, sa, e] += v * Gf[q, a, e]


@njit
def _by_region(region, n_regions):  # pragma: no cover - compiled
    """(order, start): the points of region r are ``order[start[r]:start[r + 1]]``, increasing (a counting sort:
    each region's sums then run in the serial loop's order, the same bits)."""
    start = np.zeros(n_regions + 1, dtype=np.int64)
    for q in range(region.shape[0]):
        start[region[q] + 1] += 1
    for r in range(n_regions):
        start[r + 1] += start[r]
    fill = start[:-1].copy()
    order = np.empty(region.shape[0], dtype=np.int64)
    for q in range(region.shape[0]):
        order[fill[region[q]]] = q
        fill[region[q]] += 1
    return order, start


REGION_CHUNK = 64
"""Regions per task of the moment kernels (each region's buffer is written by one thread)."""


@njit(parallel=True)
def _gauss_moments(region, slot, Gq, volume, offset, size, buf):  # pragma: no cover - compiled
    """``buf[offset[r] + a N + b] += v_q G_q[a] G_q[b]`` over each Gauss point's own parents (a, b the
    entries (slot, c, j) of its region's table, N = size[r] = 12 P_r); regions in chunks over the threads, each
    region's points in increasing order (the same bits for any thread count); numpy twin:
    :func:`_gauss_moments_numpy`."""
    R = offset.shape[0]
    order, start = _by_region(region, R)
    K, Pq = slot.shape
    Gf = Gq.reshape(K, Pq, 12)  # entry e = 3 c + j, contiguous: the inner loop vectorises
    for ch in prange((R + REGION_CHUNK - 1) // REGION_CHUNK):
        for r in range(ch * REGION_CHUNK, min(R, (ch + 1) * REGION_CHUNK)):
            off = offset[r]
            N = size[r]
            for t in range(start[r], start[r + 1]):
                q = order[t]
                v = volume[q]
                for a in range(Pq):
                    sa = slot[q, a]
                    if sa < 0:
                        continue
                    for c in range(4):
                        for j in range(3):
                            ga = v * Gq[q, a, c, j]
                            if ga == 0.0:
                                continue
                            row = off + ((sa * 4 + c) * 3 + j) * N
                            for b in range(Pq):
                                sb = slot[q, b]
                                if sb < 0:
                                    continue
                                base = row + sb * 12
                                for e in range(12):
                                    buf[base + e] += ga * Gf[q, b, e]


@njit(parallel=True)
def _weight_moments(region, slot, Gq, w, volume, offset, count, buf):  # pragma: no cover - compiled
    """``buf[offset[r] + a L + b] += v_q w_q[a] w_q[b]`` and ``buf[offset[r] + a L + P + 12 b + e] += v_q w_q[a]
    G_q[b, e]`` over each Gauss point's own parents (a, b their slots in region r, P = count[r], L = 13 P);
    regions over the threads as :func:`_gauss_moments`; numpy twin: :func:`_weight_moments_numpy`."""
    R = offset.shape[0]
    order, start = _by_region(region, R)
    K, Pq = slot.shape
    Gf = Gq.reshape(K, Pq, 12)
    for ch in prange((R + REGION_CHUNK - 1) // REGION_CHUNK):
        for r in range(ch * REGION_CHUNK, min(R, (ch + 1) * REGION_CHUNK)):
            P = count[r]
            L = 13 * P
            for t in range(start[r], start[r + 1]):
                q = order[t]
                v = volume[q]
                for a in range(Pq):
                    sa = slot[q, a]
                    if sa < 0:
                        continue
                    wa = v * w[q, a]
                    if wa == 0.0:
                        continue
                    row = offset[r] + sa * L
                    for b in range(Pq):
                        sb = slot[q, b]
                        if sb < 0:
                            continue
                        buf[row + sb] += wa * w[q, b]
                        base = row + P + 12 * sb
                        for e in range(12):
                            buf[base + e] += wa * Gf[q, b, e]


def _weight_moments_numpy(region, slot, Gq, w, volume, offset, count, buf):
    """The numpy twin of :func:`_weight_moments`."""
    K, Pq = slot.shape
    for q in range(K):
        r = region[q]
        P = int(count[r])
        ok = np.flatnonzero(slot[q] >= 0)
        sa = slot[q, ok]
        outer = volume[q] * np.outer(w[q, ok], np.concatenate([w[q, ok][:, None], Gq[q, ok].reshape(-1, 12)],
                                                              axis=1).reshape(-1))
        cols = np.concatenate([sa[:, None], P + 12 * sa[:, None] + np.arange(12)[None, :]], axis=1).reshape(-1)
        buf[offset[r] + (sa[:, None] * 13 * P + cols[None, :]).ravel()] += outer.ravel()


def _gauss_moments_numpy(region, slot, Gq, volume, offset, size, buf):
    """The numpy twin of :func:`_gauss_moments`."""
    K, Pq = slot.shape
    for q in range(K):
        N = size[region[q]]
        ok = np.flatnonzero(slot[q] >= 0)
        cols = (slot[q, ok][:, None] * 12 + np.arange(12)[None, :]).ravel()
        g = Gq[q, ok].reshape(-1)
        buf[offset[region[q]] + (cols[:, None] * N + cols[None, :]).ravel()] += volume[q] * np.outer(g, g).ravel()


def _dofs(index):
    """(R, P, 3, 4) global DOF of (parent p, row i, column c) (0 where padded)."""
    a = np.where(index >= 0, index, 0)[..., None, None]
    i = np.arange(3)[None, None, :, None]
    c = np.arange(4)[None, None, None, :]
    return np.where(c < 3, 12 * a + 3 * i + c, 12 * a + 9 + i)


def _rows(q):
    """(n, 3, 4): the frames' DOFs by row, ``d[a, i] = (A[i, 0], A[i, 1], A[i, 2], t[i])``."""
    return np.concatenate([q[:, :9].reshape(-1, 3, 3), q[:, 9:, None]], axis=2)


class Fluctuation:
    """The fluctuation energy of mid-point regions for given materials (see the module docstring).

    Parameters
    ----------
    tables : RegionTables
    label : (R,) int, each region's label
    materials : {label: Material}
    deviatoric : {label: bool}, labels whose volumetric term is projected (C0 -> P C0 P)
    rest : (n, 12) float, the frames' rest state
    """

    def __init__(self, tables: RegionTables, label, materials, deviatoric, rest):
        self.tables = tables
        self.rest_rows = _rows(np.asarray(rest, dtype=float))
        n = len(rest)
        self.n = n
        label = np.asarray(label, dtype=np.int64)
        I9 = np.eye(3).reshape(9)
        Pdev = np.eye(9) - np.outer(I9, I9) / 3.0
        C0 = {}
        for lab, mat in materials.items():
            C = mat.evaluate(np.eye(3)[None], tangent=True)[2][0].reshape(9, 9)
            C = 0.5 * (C + C.T)
            if deviatoric.get(lab, False):
                C = Pdev @ C @ Pdev
            C0[int(lab)] = C.reshape(3, 3, 3, 3)
        const = {int(lab): _small_strain(mat) for lab, mat in materials.items()}
        self.constant_matrix = np.zeros((12 * n, 12 * n))
        self.groups = []  # (regions, P, K (Rb, 3, 4P, 3, 4P), dofs (Rb, 12P)) of the nonlinear regions
        for regs, Pb, Gam in tables.buckets:
            Kb = np.empty((len(regs), 3, Pb, 4, 3, Pb, 4))  # rows (i, p, c), columns (k, q, d)
            for lab in np.unique(label[regs]):
                sel = label[regs] == lab
                Kb[sel] = np.einsum("ijkl,rpcjqdl->ripckqd", C0[int(lab)], Gam[sel], optimize=True)
            Kb = Kb.reshape(len(regs), 3, 4 * Pb, 3, 4 * Pb)
            Kb = 0.5 * (Kb + Kb.transpose(0, 3, 4, 1, 2))
            dofs = _dofs(tables.index[regs, :Pb]).transpose(0, 2, 1, 3).reshape(len(regs), 12 * Pb)
            lin = np.array([const[int(lab)] for lab in label[regs]], dtype=bool)
            if lin.any():  # constant tangent: one constant matrix for all of them
                Kl = Kb[lin].reshape(-1, 12 * Pb, 12 * Pb)
                dl = dofs[lin]
                flat = (dl[:, :, None] * (12 * n) + dl[:, None, :]).ravel()
                self.constant_matrix += np.bincount(flat, weights=Kl.ravel(),
                                                    minlength=(12 * n) ** 2).reshape(12 * n, 12 * n)
            if (~lin).any():
                self.groups.append((regs[~lin], Pb, np.ascontiguousarray(Kb[~lin]),
                                    np.ascontiguousarray(dofs[~lin])))
        self.constant_matrix = 0.5 * (self.constant_matrix + self.constant_matrix.T)
        self.nonlinear_regions = np.concatenate([g[0] for g in self.groups]) if self.groups else \
            np.zeros(0, dtype=np.int64)
        self.backend = "numba"  # "numpy": the twin (tests)
        self._block_cache = {}

    def evaluate(self, q, F, *, gradient=True, hessian=True, dq=None):
        """Fluctuation energy (J), its gradient (n, 12) and Hessian (12n, 12n) (dense, or None).

        ``F`` (R, 3, 3): the regions' mean deformation gradients at ``q``.  A region whose mean F
        is singular (det F_r = 0) has infinite energy (its material's energy is then infinite too,
        or undefined).  ``dq``: the displacement ``q - rest`` when the caller has it (its digits kept).
        """
        n = self.n
        dq = np.asarray(q, dtype=float) - self.rest_state() if dq is None else np.asarray(dq, dtype=float)
        dflat = dq.reshape(-1)
        Kc = self.constant_matrix
        g_c = Kc @ dflat
        energy = 0.5 * float(dflat @ g_c)
        grad = g_c.copy() if gradient else None
        H = Kc.copy() if hessian else None
        drows = np.ascontiguousarray(_rows(dq))
        if self.groups and not np.all(np.abs(np.linalg.det(F[self.nonlinear_regions])) > 0):
            return np.inf, (None if not gradient else np.full((n, 12), np.nan)), \
                (None if not hessian else np.full((12 * n, 12 * n), np.nan))
        out = np.zeros(1)
        g_out = grad if gradient else np.zeros(1)
        H_out = H if hessian else np.zeros((1, 1))
        for regs, Pb, Kb, dofs in self.groups:
            Gb = np.ascontiguousarray(self.tables.G[regs, :Pb].reshape(len(regs), 4 * Pb, 3))
            Fr = np.ascontiguousarray(F[regs])
            Kf = self._blocks(Kb)
            if self.backend == "numpy":
                e, g, h = _nonlinear(Kb, self.tables.index[regs, :Pb], self.tables.G[regs, :Pb], Fr, drows,
                                     gradient, hessian)
                out[0] += e
                if gradient:
                    np.add.at(g_out, dofs, g)
                if hessian:
                    for t in range(len(regs)):
                        H_out[np.ix_(dofs[t], dofs[t])] += h[t]
            else:
                _fluctuation_kernel(Kf, np.ascontiguousarray(self.tables.index[regs, :Pb]), Gb, Fr, drows, dofs,
                                    out, g_out, H_out, gradient, hessian)
        energy += float(out[0])
        if hessian:
            H = 0.5 * (H + H.T)
        return energy, (None if grad is None else grad.reshape(n, 12)), H

    def _blocks(self, Kb):
        """``Kb`` (Rb, 3, X, 3, X) as contiguous X x X blocks (Rb, 3, 3, X, X) (cached per bucket)."""
        key = id(Kb)
        if key not in self._block_cache:
            self._block_cache[key] = np.ascontiguousarray(Kb.transpose(0, 1, 3, 2, 4))
        return self._block_cache[key]

    def rest_state(self):
        rr = self.rest_rows
        return np.concatenate([rr[:, :, :3].reshape(-1, 9), rr[:, :, 3]], axis=1)

    def rest_matrix(self) -> np.ndarray:
        """The fluctuation's Hessian at rest (12n, 12n): ``sum_r K_r`` (G = I there)."""
        N = 12 * self.n
        H = self.constant_matrix.copy()
        for regs, Pb, Kb, dofs in self.groups:
            flat = (dofs[:, :, None] * N + dofs[:, None, :]).ravel()
            H += np.bincount(flat, weights=Kb.reshape(len(regs), 12 * Pb, 12 * Pb).ravel(),
                             minlength=N * N).reshape(N, N)
        return 0.5 * (H + H.T)


def _nonlinear(Kb, index, Gbar, F, drows, gradient, hessian):
    """Energy, gradient (Rb, 12P) and Hessian (Rb, 12P, 12P) of the pulled-back fluctuation of a bucket.

    Layout: a region's DOFs by row i of the frames, then parent p and column c (``x = (p, c)``, X = 4P
    of them per row).  ``Kb`` (Rb, 3, X, 3, X), ``index`` (Rb, P), ``Gbar`` (Rb, P, 4, 3), ``F``
    (Rb, 3, 3) the mean deformation gradients, ``drows`` (n, 3, 4) the DOFs minus rest by row.  Every
    product is a batched matmul on contiguous arrays.  None when a mean F is singular.
    """
    Rb, P = index.shape
    X = 4 * P
    N = 3 * X
    det = np.linalg.det(F)
    if not np.all(np.isfinite(det)) or np.any(det == 0.0):
        return None
    G = np.linalg.inv(F)
    GT = np.ascontiguousarray(G.transpose(0, 2, 1))
    du = np.where((index >= 0)[..., None, None], drows[np.where(index >= 0, index, 0)], 0.0)  # (Rb, P, 3, 4)
    du = np.ascontiguousarray(du.transpose(0, 2, 1, 3)).reshape(Rb, 3, X)  # [i, (p, c)]
    Gb = Gbar.reshape(Rb, X, 3)  # [(p, c), j]
    GbT = np.ascontiguousarray(Gb.transpose(0, 2, 1))  # [j, (p, c)]
    w = G @ du  # L du: rows mixed by G
    Km = Kb.reshape(Rb, N, N)
    g = (Km @ w.reshape(Rb, N, 1)).reshape(Rb, 3, X)  # K w
    energy = 0.5 * float(np.einsum("rax,rax->", w, g))
    if not (gradient or hessian):
        return energy, None, None
    Phi = g @ du.transpose(0, 2, 1)  # [a, i]
    Psi = GT @ Phi @ GT  # G^T Phi G^T
    grad_u = GT @ g - Psi @ GbT  # L^T K w + Jbar^T gamma, gamma = -Psi
    grad_u = grad_u.reshape(Rb, N)
    if not hessian:
        return energy, grad_u, None
    # L^T K L = (G^T (x) I) K (G (x) I): left product, transpose (K is symmetric), left product again
    A = (GT @ Km.reshape(Rb, 3, X * N)).reshape(Rb, N, N)
    LKL = (GT @ np.ascontiguousarray(A.transpose(0, 2, 1)).reshape(Rb, 3, X * N)).reshape(Rb, N, N)
    # B[(a, x), (m, n)] = (dL/dF_mn du)[a, x] = -G[a, m] (G du)[n, x]
    Gdu = G @ du  # [n, x]
    B = -(G[:, :, None, :, None] * Gdu.transpose(0, 2, 1)[:, None, :, None, :]).reshape(Rb, N, 9)
    KB = Km @ B  # (Rb, N, 9)
    XB = (GT @ KB.reshape(Rb, 3, X * 9)).reshape(Rb, N, 9)  # L^T K B
    # C^T[(i, x), (m, n)] = -sum_a g[a, x] G[a, m] G[n, i]
    gG = GT @ g  # [m, x] = sum_a G[a, m] g[a, x]
    Ct = -(G.transpose(0, 2, 1)[:, :, None, None, :] * gG.transpose(0, 2, 1)[:, None, :, :, None])
    Y = (XB.reshape(Rb, 3, X, 3, 3) + Ct).reshape(Rb, N, 3, 3)  # [(i, x), k, j]
    YJ = (Y @ GbT[:, None]).reshape(Rb, N, N)  # Y Jbar: [(i, x), (k, y)]
    # D[(m, n), (r, s)] = Psi[r, n] G[s, m] + Psi[m, s] G[n, r];  plus B^T K B
    D = (Psi.transpose(0, 2, 1)[:, None, :, :, None] * GT[:, :, None, None, :]
         + Psi[:, :, None, None, :] * G[:, None, :, :, None]).reshape(Rb, 9, 9)
    D = D + B.transpose(0, 2, 1) @ KB
    E1 = Gb[:, None] @ D.reshape(Rb, 3, 3, 9)  # [i, x, (k, l)] = sum_j Gbar[x, j] D[i, j, k, l]
    JDJ = (E1.reshape(Rb, N, 3, 3) @ GbT[:, None]).reshape(Rb, N, N)
    H = LKL + YJ + YJ.transpose(0, 2, 1) + JDJ
    return energy, grad_u, H


@njit
def _fluctuation_kernel(K, index, Gb, F, drows, dofs, energy, grad, H, with_grad, with_hess):  # pragma: no cover
    """Compiled :func:`_nonlinear` for a bucket, adding into ``energy`` (1,), ``grad`` (12n,) and the dense
    ``H`` (12n, 12n) (both triangles) directly.

    ``K`` (Rb, 3, 3, X, X): each region's matrix as X x X blocks between rows a and b of the frames
    (X = 4P, N = 3X).  Per region: ``g = K w`` (9 X^2), ``Z = K (G du)`` (27 X^2), then every Hessian
    entry ``sum_ab G[a, i] G[b, k] K_ab[x, y]`` plus the rank-9 terms ``Y Jbar``, ``(Y Jbar)^T`` and
    ``Jbar^T D Jbar`` (15 multiply-adds, contiguous in y): about 170 X^2 per region.  Mean F_r must be
    invertible (the caller checks).
    """
    Rb, P = index.shape
    X = 4 * P
    N = 3 * X
    G = np.empty((3, 3))
    C = np.empty((3, 3))
    du = np.empty((3, X))
    w = np.empty((3, X))
    g = np.empty((3, X))
    Gdu = np.empty((3, X))
    Phi = np.empty((3, 3))
    Psi = np.empty((3, 3))
    T = np.empty((3, 3))
    Z = np.empty((3, 3, 3))
    KB = np.empty((N, 3, 3))
    Y = np.empty((3, 3, X, 3))  # [i, k, x, j]: Y[(i, x), k, j]
    YT = np.empty((3, 3, X, 3))  # [i, k, y, j] = Y[(k, y), i, j]
    D = np.empty((3, 3, 3, 3))
    E1 = np.empty((3, 3, X, 3))  # [i, k, x, l]
    row = np.empty(X)
    for r in range(Rb):
        f = F[r]
        c00 = f[1, 1] * f[2, 2] - f[1, 2] * f[2, 1]
        c01 = f[1, 2] * f[2, 0] - f[1, 0] * f[2, 2]
        c02 = f[1, 0] * f[2, 1] - f[1, 1] * f[2, 0]
        det = f[0, 0] * c00 + f[0, 1] * c01 + f[0, 2] * c02
        G[0, 0] = c00 / det
        G[1, 0] = c01 / det
        G[2, 0] = c02 / det
        G[0, 1] = (f[0, 2] * f[2, 1] - f[0, 1] * f[2, 2]) / det
        G[1, 1] = (f[0, 0] * f[2, 2] - f[0, 2] * f[2, 0]) / det
        G[2, 1] = (f[0, 1] * f[2, 0] - f[0, 0] * f[2, 1]) / det
        G[0, 2] = (f[0, 1] * f[1, 2] - f[0, 2] * f[1, 1]) / det
        G[1, 2] = (f[0, 2] * f[1, 0] - f[0, 0] * f[1, 2]) / det
        G[2, 2] = (f[0, 0] * f[1, 1] - f[0, 1] * f[1, 0]) / det
        for i in range(3):
            for p in range(P):
                a = index[r, p]
                for c in range(4):
                    du[i, 4 * p + c] = drows[a, i, c] if a >= 0 else 0.0
        for a in range(3):
            for x in range(X):
                w[a, x] = G[a, 0] * du[0, x] + G[a, 1] * du[1, x] + G[a, 2] * du[2, x]
                Gdu[a, x] = 0.0
        Kr = K[r]
        e = 0.0
        for a in range(3):
            for x in range(X):
                acc = 0.0
                for b in range(3):
                    for y in range(X):
                        acc += Kr[a, b, x, y] * w[b, y]
                g[a, x] = acc
                e += 0.5 * acc * w[a, x]
        energy[0] += e
        if not (with_grad or with_hess):
            continue
        for a in range(3):
            for i in range(3):
                acc = 0.0
                for x in range(X):
                    acc += g[a, x] * du[i, x]
                Phi[a, i] = acc
        for m in range(3):  # Psi = G^T Phi G^T
            for i in range(3):
                T[m, i] = G[0, m] * Phi[0, i] + G[1, m] * Phi[1, i] + G[2, m] * Phi[2, i]
        for m in range(3):
            for n in range(3):
                Psi[m, n] = T[m, 0] * G[n, 0] + T[m, 1] * G[n, 1] + T[m, 2] * G[n, 2]
        if with_grad:
            for i in range(3):
                for x in range(X):
                    v = G[0, i] * g[0, x] + G[1, i] * g[1, x] + G[2, i] * g[2, x]
                    v -= Psi[i, 0] * Gb[r, x, 0] + Psi[i, 1] * Gb[r, x, 1] + Psi[i, 2] * Gb[r, x, 2]
                    grad[dofs[r, i * X + x]] += v
        if not with_hess:
            continue
        for n in range(3):
            for x in range(X):
                Gdu[n, x] = G[n, 0] * du[0, x] + G[n, 1] * du[1, x] + G[n, 2] * du[2, x]
        # KB[(i, x), m, n] = -sum_a G[a, m] sum_y K_ia[x, y] Gdu[n, y]
        for i in range(3):
            for x in range(X):
                for a in range(3):
                    for n in range(3):
                        acc = 0.0
                        for y in range(X):
                            acc += Kr[i, a, x, y] * Gdu[n, y]
                        Z[a, n, 0] = acc
                for m in range(3):
                    for n in range(3):
                        KB[i * X + x, m, n] = -(Z[0, n, 0] * G[0, m] + Z[1, n, 0] * G[1, m] + Z[2, n, 0] * G[2, m])
        # Y[(i, x), m, n] = sum_a G[a, i] KB[(a, x), m, n] - gG[m, x] G[n, i]
        for i in range(3):
            for x in range(X):
                for m in range(3):
                    gg = G[0, m] * g[0, x] + G[1, m] * g[1, x] + G[2, m] * g[2, x]
                    for n in range(3):
                        v = (G[0, i] * KB[x, m, n] + G[1, i] * KB[X + x, m, n]
                             + G[2, i] * KB[2 * X + x, m, n] - gg * G[n, i])
                        Y[i, m, x, n] = v
                        YT[m, i, x, n] = v
        # D[m, n, r', s'] = Psi[r', n] G[s', m] + Psi[m, s'] G[n, r'] + (B^T K B)[(m, n), (r', s')],
        # B[(a, x), (m, n)] = -G[a, m] Gdu[n, x]
        for m in range(3):
            for n in range(3):
                for rr in range(3):
                    for ss in range(3):
                        acc = Psi[rr, n] * G[ss, m] + Psi[m, ss] * G[n, rr]
                        for a in range(3):
                            ga = G[a, m]
                            for x in range(X):
                                acc -= ga * Gdu[n, x] * KB[a * X + x, rr, ss]
                        D[m, n, rr, ss] = acc
        # E1[i, k, x, l] = sum_j Gbar[x, j] D[i, j, k, l]
        for i in range(3):
            for k in range(3):
                for x in range(X):
                    for l in range(3):
                        E1[i, k, x, l] = (Gb[r, x, 0] * D[i, 0, k, l] + Gb[r, x, 1] * D[i, 1, k, l]
                                          + Gb[r, x, 2] * D[i, 2, k, l])
        Gbr = Gb[r]
        for i in range(3):
            for k in range(3):
                for a in range(3):
                    for b in range(3):
                        C[a, b] = G[a, i] * G[b, k]
                for x in range(X):
                    y0 = Y[i, k, x, 0] + E1[i, k, x, 0]
                    y1 = Y[i, k, x, 1] + E1[i, k, x, 1]
                    y2 = Y[i, k, x, 2] + E1[i, k, x, 2]
                    gx0 = Gbr[x, 0]
                    gx1 = Gbr[x, 1]
                    gx2 = Gbr[x, 2]
                    for y in range(X):
                        row[y] = (y0 * Gbr[y, 0] + y1 * Gbr[y, 1] + y2 * Gbr[y, 2]
                                  + YT[i, k, y, 0] * gx0 + YT[i, k, y, 1] * gx1 + YT[i, k, y, 2] * gx2)
                    for a in range(3):
                        for b in range(3):
                            cab = C[a, b]
                            Kab = Kr[a, b, x]
                            for y in range(X):
                                row[y] += cab * Kab[y]
                    ds = dofs[r, i * X + x]
                    for y in range(X):
                        H[ds, dofs[r, k * X + y]] += row[y]
