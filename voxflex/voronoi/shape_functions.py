"""Shape functions: the padded container and Shepard (inverse-distance) weights.

A shape function spreads the motion of ``n`` nodes over ``m`` children (mass,
collision or visual points, quadrature samples).  Child ``c`` depends on at most
``P`` parent nodes; :class:`ShapeValues` stores, for every child, the parent
indices (padded with ``-1``), the values ``w``, the gradients ``dw`` with
respect to the child's rest position ``X`` and optionally the Hessians ``ddw``.
Any shape function (Shepard, natural neighbours, trilinear voxel weights)
produces one; the mappings of :mod:`voxflex.deform.chain.mappings` consume it.

Example
-------
>>> import numpy as np
>>> nodes = np.array([[0.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0]])
>>> sv = shepard(np.array([[0.25, 0.25, 0.0]]), nodes)
>>> float(sv.w.sum())
1.0
>>> sv.partition_of_unity_error() < 1e-12
True
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._jit import njit
from ..errors import InputError

__all__ = ["ShapeValues", "shepard", "keep_largest", "world_points"]


_VALUE_ERRORS = {
    1: "ShapeValues.w has non-finite values; compute the shape functions away from singular points",
    2: "ShapeValues.dw has non-finite values; compute the shape functions away from singular points",
    3: "ShapeValues.ddw has non-finite values; compute the shape functions away from singular points",
    4: "ShapeValues.rest has non-finite values; compute the shape functions away from singular points",
    5: "ShapeValues.index has entries below -1; pad with -1 only",
    6: "ShapeValues: padded slots (index -1) must hold zero values, gradients and Hessians",
    7: "ShapeValues.index repeats a parent within a child; merge the repeated entries",
}


@njit
def _check_values(index, w, dw, rest, ddw):  # pragma: no cover - compiled
    """0 when the values are sound, else the key of :data:`_VALUE_ERRORS` of the first problem found in the
    order the messages list them (every array is read once; a repeated parent is found by the last row that
    named each frame: 35 parents per row, 0.05 s a call on the bunny's 94k points compared pairwise)."""
    m, P = index.shape
    H = ddw.shape[1]
    for s in range(m):
        for p in range(P):
            if not np.isfinite(w[s, p]):
                return 1
        for k in range(3 * P):
            if not np.isfinite(dw[s, k]):
                return 2
        for k in range(H):
            if not np.isfinite(ddw[s, k]):
                return 3
        for j in range(3):
            if not np.isfinite(rest[s, j]):
                return 4
    for s in range(m):
        for p in range(P):
            if index[s, p] < -1:
                return 5
    for s in range(m):
        for p in range(P):
            if index[s, p] >= 0:
                continue
            if w[s, p] != 0.0:
                return 6
            for j in range(3):
                if dw[s, 3 * p + j] != 0.0:
                    return 6
            if H:
                for j in range(9):
                    if ddw[s, 9 * p + j] != 0.0:
                        return 6
    top = -1
    for s in range(m):
        for p in range(P):
            if index[s, p] > top:
                top = index[s, p]
    seen = np.full(top + 1, -1, dtype=np.int64)  # the last row that named each parent: P per row, not P^2 / 2
    for s in range(m):
        for p in range(P):
            a = index[s, p]
            if a < 0:
                continue
            if seen[a] == s:
                return 7
            seen[a] = s
    return 0

@dataclass(frozen=True)
class ShapeValues:
    """Shape functions of ``m`` children (points or samples) on their parent nodes.

    Parameters
    ----------
    index : (m, P) int array
        Parent node indices of each child, padded with ``-1``.  A parent may
        appear at most once per child.
    w : (m, P) float array
        Shape-function values (dimensionless), 0 where padded.
    dw : (m, P, 3) float array
        Gradients with respect to the child's rest position X (1/m), 0 where padded.
    ddw : (m, P, 3, 3) float array or None
        Hessians with respect to X (1/m²), symmetric, 0 where padded; optional
        (needed only for the mapping to F and its gradient).
    rest : (m, 3) float array
        Rest positions X of the children (m).
    n_nodes : int, optional
        Number of nodes; when given, every index must be below it.

    Raises
    ------
    InputError
        On wrong shapes, non-finite values, indices out of range, repeated
        parents, or non-zero values in padded slots.

    Notes
    -----
    Arrays are stored as C-contiguous ``int64`` / ``float64`` (copied only when
    needed).  Treat them as read-only.
    """

    index: np.ndarray
    w: np.ndarray
    dw: np.ndarray
    ddw: np.ndarray | None
    rest: np.ndarray
    n_nodes: int | None = None

    def __post_init__(self):
        def _float(name, a):
            try:
                return np.ascontiguousarray(a, dtype=np.float64)
            except (TypeError, ValueError) as exc:
                raise InputError(f"ShapeValues.{name} must be a float array ({exc})") from None

        index = np.asarray(self.index)
        if index.ndim != 2 or not (np.issubdtype(index.dtype, np.integer) or index.size == 0):
            raise InputError(f"ShapeValues.index must be an (m, P) integer array, got shape {index.shape} dtype {index.dtype}")
        index = np.ascontiguousarray(index, dtype=np.int64)
        m, P = index.shape
        w = _float("w", self.w)
        dw = _float("dw", self.dw)
        rest = _float("rest", self.rest)
        if w.shape != (m, P):
            raise InputError(f"ShapeValues.w must have shape {(m, P)} like index, got {w.shape}")
        if dw.shape != (m, P, 3):
            raise InputError(f"ShapeValues.dw must have shape {(m, P, 3)}, got {dw.shape}")
        if rest.shape != (m, 3):
            raise InputError(f"ShapeValues.rest must have shape {(m, 3)} (one rest position per child), got {rest.shape}")
        ddw = None
        if self.ddw is not None:
            ddw = _float("ddw", self.ddw)
            if ddw.shape != (m, P, 3, 3):
                raise InputError(f"ShapeValues.ddw must have shape {(m, P, 3, 3)} or be None, got {ddw.shape}")
        # one compiled pass: finiteness, padding, zero padded slots, repeated parents (numpy's isfinite, masks
        # and a row sort took 0.64 s over the five ShapeValues of the bunny's 40-frame precompute)
        bad = _check_values(index, w, dw.reshape(m, P * 3), rest,
                            ddw.reshape(m, P * 9) if ddw is not None else np.zeros((m, 0)))
        if bad:
            raise InputError(_VALUE_ERRORS[bad])
        n_nodes = self.n_nodes
        if n_nodes is not None:
            n_nodes = int(n_nodes)
            if n_nodes < 0:
                raise InputError(f"ShapeValues.n_nodes must be >= 0, got {n_nodes}")
            if index.size and index.max() >= n_nodes:
                raise InputError(f"ShapeValues.index refers to node {int(index.max())} but there are only {n_nodes} nodes")
        object.__setattr__(self, "index", index)
        object.__setattr__(self, "w", w)
        object.__setattr__(self, "dw", dw)
        object.__setattr__(self, "ddw", ddw)
        object.__setattr__(self, "rest", rest)
        object.__setattr__(self, "n_nodes", n_nodes)

    @property
    def m(self) -> int:
        """Number of children."""
        return self.index.shape[0]

    @property
    def n_parents(self) -> int:
        """Padded number of parents per child, P."""
        return self.index.shape[1]

    @property
    def has_hessians(self) -> bool:
        return self.ddw is not None

    def without_hessians(self) -> "ShapeValues":
        """The same values and gradients, ``ddw`` None (the arrays shared, not copied)."""
        return self if self.ddw is None else ShapeValues(index=self.index, w=self.w, dw=self.dw, ddw=None,
                                                         rest=self.rest, n_nodes=self.n_nodes)

    def partition_of_unity_error(self) -> float:
        """Largest deviation from a partition of unity over all children.

        Returns ``max_c max(|Σ_a w_a - 1|, |Σ_a ∇w_a| * L, |Σ_a ∇∇w_a| * L²)``
        where ``L`` is the extent of the children's rest positions (so that
        every term is dimensionless); Hessian terms only when stored.
        """
        if self.m == 0:
            return 0.0
        ext = float(np.ptp(self.rest, axis=0).max()) if self.m > 1 else 1.0
        L = ext if ext > 0 else 1.0
        err = float(np.max(np.abs(self.w.sum(axis=1) - 1.0)))
        err = max(err, float(np.max(np.abs(self.dw.sum(axis=1)))) * L)
        if self.ddw is not None:
            err = max(err, float(np.max(np.abs(self.ddw.sum(axis=1)))) * L * L)
        return err

    def linear_precision_error(self, node_positions) -> float:
        """Largest deviation from reproducing linear fields, relative to the extent.

        Linear precision means ``Σ_a w_a X_a = X``, ``Σ_a X_a ⊗ ∇w_a = I`` and
        ``Σ_a X_a ⊗ ∇∇w_a = 0``; returns the max of these residuals made
        dimensionless with the extent ``L`` of the children.
        """
        Xn = np.asarray(node_positions, dtype=np.float64)
        if Xn.ndim != 2 or Xn.shape[1] != 3 or (self.m and self.index.max() >= len(Xn)):
            raise InputError("node_positions must be an (n, 3) array covering every parent index")
        if self.m == 0:
            return 0.0
        ext = float(np.ptp(self.rest, axis=0).max()) if self.m > 1 else 1.0
        L = ext if ext > 0 else 1.0
        Xa = np.where(self.index[..., None] >= 0, Xn[np.maximum(self.index, 0)], 0.0)
        err = float(np.max(np.abs(np.einsum("mp,mpi->mi", self.w, Xa) - self.rest))) / L
        G = np.einsum("mpi,mpj->mij", Xa, self.dw)
        err = max(err, float(np.max(np.abs(G - np.eye(3)))))
        if self.ddw is not None:
            H = np.einsum("mpi,mpjk->mijk", Xa, self.ddw)
            err = max(err, float(np.max(np.abs(H))) * L)
        return err

    def to_sparse(self, n_nodes: int | None = None):
        """The values as a ``scipy.sparse.csr_matrix`` of shape (m, n_nodes)."""
        import scipy.sparse as sp

        n = self.n_nodes if n_nodes is None else int(n_nodes)
        if n is None:
            n = int(self.index.max()) + 1 if self.index.size else 0
        mask = self.index >= 0
        rows = np.broadcast_to(np.arange(self.m)[:, None], self.index.shape)[mask]
        return sp.csr_matrix((self.w[mask], (rows, self.index[mask])), shape=(self.m, n))


def world_points(points) -> np.ndarray:
    """``points`` as a finite (m, 3) float array of world positions, or an InputError saying what they are (the
    check every weight family makes before evaluating)."""
    try:
        X = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("points must be an (m, 3) array of world positions") from None
    if X.ndim != 2 or X.shape[1] != 3 or not np.all(np.isfinite(X)):
        raise InputError(f"points must be a finite (m, 3) array of world positions, got shape {X.shape}")
    return X


def keep_largest(values: ShapeValues, parents: int, *, backend: str = "numba") -> ShapeValues:
    """The ``parents`` largest weights of every child, cut conformingly and renormalised to a partition of unity.

    Where a child has more than ``P = parents`` weights, the first one dropped (the (P+1)-th largest,
    ``w_c``) is subtracted from the kept ones before they are renormalised:
    ``w'_i = (w_i - w_c) / S`` with ``S = sum_kept (w_i - w_c)``.  A weight then reaches zero exactly
    where it leaves the kept set (it is the (P+1)-th there), so the cut functions are as continuous as
    the weights they cut: the model stays conforming, and with exact integration it cannot come out
    softer than the weights give uncut.  Keeping the P largest and renormalising them as they are (what
    this did before) jumps where the kept set changes, and the jumps soften the model (pure bending, 20
    natural-neighbour frames with Gauss points: 1.283 at 6 parents against 1.376 uncut;
    ``benchmarks/bench_weights_convergence.py --part parents``).  ``w_c`` is taken with its gradient and
    Hessian, and with ``w~ = w - w_c``: ``w' = w~ / S``, ``dw' = (dw~ - w' dS) / S`` and
    ``ddw' = (ddw~ - dw' dS^T - dS dw'^T - w' ddS) / S`` (``S``, ``dS``, ``ddS`` the sums over the kept
    ones), the exact derivatives wherever the order of the P+1 largest does not change.  Where the P+1
    largest are all equal (``S = 0``: a point of exact symmetry) the plain cut is used there.  Ties keep
    the lowest frame index (not the first slot: slot order comes from sorts on rounded values and differs
    between units).  ``backend="numba"``: :func:`_keep_largest_kernel` (0.55 s of numpy on the bunny's
    94k voxel centres at 2 mm); ``"numpy"``: its twin.
    """
    parents = int(parents)
    if parents < 1:
        raise InputError(f"parents must be >= 1, got {parents}")
    if values.n_parents <= parents:
        return values
    # weights equal to 1e-12 tie (the lowest frame wins): the same scene in other units rounds its weights
    # differently, and must keep the same parents (a 1 cm beam kept others than the 1 m beam: 0.05 % off)
    key = np.round(values.w, 12)
    hess = values.ddw is not None
    if backend != "numpy":
        m = values.m
        idx = np.full((m, parents), -1, dtype=np.int64)
        w = np.zeros((m, parents))
        dw = np.zeros((m, parents, 3))
        ddw = np.zeros((m, parents, 3, 3)) if hess else np.zeros((1, 1, 3, 3))
        _keep_largest_kernel(values.index, key, values.w, values.dw,
                             values.ddw if hess else np.zeros((1, 1, 3, 3)), hess, idx, w, dw, ddw)
        return ShapeValues(index=idx, w=w, dw=dw, ddw=ddw if hess else None, rest=values.rest, n_nodes=values.n_nodes)
    big = np.iinfo(np.int64).max
    order = np.lexsort((np.where(values.index >= 0, values.index, big),
                        -np.where(values.index >= 0, key, -np.inf)), axis=1)[:, :parents + 1]
    r = np.arange(values.m)[:, None]
    idx_all = values.index[r, order]
    valid = idx_all >= 0
    w_all = np.where(valid, values.w[r, order], 0.0)
    dw_all = np.where(valid[..., None], values.dw[r, order], 0.0)
    ddw_all = np.where(valid[..., None, None], values.ddw[r, order], 0.0) if hess else None
    idx = idx_all[:, :parents]
    keep = idx >= 0
    cut = np.zeros(values.m) if order.shape[1] <= parents else w_all[:, parents]
    S0 = np.where(keep, w_all[:, :parents] - cut[:, None], 0.0).sum(1)
    ok = S0 > 0.0  # the P+1 largest not all equal (elsewhere: the plain cut)
    c = np.where(ok, cut, 0.0)
    w = np.where(keep, w_all[:, :parents] - c[:, None], 0.0)
    dw = dw_all[:, :parents]
    if order.shape[1] > parents:
        dw = dw - np.where(ok[:, None, None], dw_all[:, parents:parents + 1], 0.0)
    dw = np.where(keep[..., None], dw, 0.0)
    S = w.sum(1)
    dS = dw.sum(1)
    wn = w / S[:, None]
    dn = np.where(keep[..., None], (dw - wn[..., None] * dS[:, None, :]) / S[:, None, None], 0.0)
    ddn = None
    if hess:
        ddw = ddw_all[:, :parents]
        if order.shape[1] > parents:
            ddw = ddw - np.where(ok[:, None, None, None], ddw_all[:, parents:parents + 1], 0.0)
        ddw = np.where(keep[..., None, None], ddw, 0.0)
        hS = ddw.sum(1)
        ddn = (ddw - dn[..., :, None] * dS[:, None, None, :] - dS[:, None, :, None] * dn[..., None, :]
               - wn[..., None, None] * hS[:, None]) / S[:, None, None, None]
        ddn = np.where(keep[..., None, None], 0.5 * (ddn + ddn.transpose(0, 1, 3, 2)), 0.0)
    return ShapeValues(index=np.where(keep, idx, -1), w=wn, dw=dn, ddw=ddn, rest=values.rest, n_nodes=values.n_nodes)


@njit
def _keep_largest_kernel(index, key, w, dw, ddw, hess, out_idx, out_w, out_dw, out_ddw):  # pragma: no cover
    """Compiled :func:`keep_largest` (the numpy path is its twin): per child, the slots sorted by
    decreasing ``key`` (the weights rounded to 12 digits; ties by increasing frame index), the first
    ``out_idx.shape[1]`` kept, the first dropped one subtracted and the rest renormalised."""
    m, P = index.shape
    K = out_idx.shape[1]
    order = np.empty(P, np.int64)
    dS = np.empty(3)
    dc = np.zeros(3)
    hS = np.empty((3, 3))
    hc = np.zeros((3, 3))
    H = np.empty((3, 3))
    for s in range(m):
        nv = 0
        for t in range(P):  # valid slots, insertion by decreasing weight, then increasing frame index
            if index[s, t] < 0:
                continue
            r = nv - 1
            while r >= 0 and (key[s, order[r]] < key[s, t]
                              or (key[s, order[r]] == key[s, t] and index[s, order[r]] > index[s, t])):
                order[r + 1] = order[r]
                r -= 1
            order[r + 1] = t
            nv += 1
        k = min(K, nv)
        # the first dropped weight (and its derivatives), subtracted from the kept ones: the conforming cut
        c = 0.0
        for a in range(3):
            dc[a] = 0.0
            for b in range(3):
                hc[a, b] = 0.0
        if nv > K:
            o = order[K]
            c = w[s, o]
            S0 = 0.0
            for j in range(k):
                S0 += w[s, order[j]] - c
            if S0 > 0.0:
                for a in range(3):
                    dc[a] = dw[s, o, a]
                    if hess:
                        for b in range(3):
                            hc[a, b] = ddw[s, o, a, b]
            else:
                c = 0.0  # the P+1 largest all equal: the plain cut at this point
        S = 0.0
        for a in range(3):
            dS[a] = 0.0
            for b in range(3):
                hS[a, b] = 0.0
        for j in range(k):
            o = order[j]
            S += w[s, o] - c
            for a in range(3):
                dS[a] += dw[s, o, a] - dc[a]
                if hess:
                    for b in range(3):
                        hS[a, b] += ddw[s, o, a, b] - hc[a, b]
        for j in range(k):
            o = order[j]
            out_idx[s, j] = index[s, o]
            wn = (w[s, o] - c) / S
            out_w[s, j] = wn
            for a in range(3):
                out_dw[s, j, a] = (dw[s, o, a] - dc[a] - wn * dS[a]) / S
            if hess:
                for a in range(3):
                    for b in range(3):
                        H[a, b] = (ddw[s, o, a, b] - hc[a, b] - out_dw[s, j, a] * dS[b] - dS[a] * out_dw[s, j, b]
                                   - wn * hS[a, b]) / S
                for a in range(3):
                    for b in range(3):
                        out_ddw[s, j, a, b] = 0.5 * (H[a, b] + H[b, a])


def shepard(points, nodes, *, power: float = 2.0, n_parents: int | None = None, hessians: bool = True) -> ShapeValues:
    """Shepard (inverse-distance) weights of ``points`` on ``nodes``.

    ``w_a(X) = g_a / Σ_b g_b`` with ``g_a = |X - X_a|^(-power)``, a partition of
    unity, non-negative, interpolating (``w_a(X_b) = δ_ab``) but without linear
    precision.

    Parameters
    ----------
    points : (m, 3) float array
        Rest positions X of the children (m).
    nodes : (n, 3) float array
        Rest positions X_a of the nodes (m).
    power : float, keyword-only
        Exponent, > 0 (default 2).  At a point coinciding with a node the
        derivatives are the limits for ``power >= 2`` (gradients 0; Hessians
        ``∓2 Σ g`` I for power 2, 0 above); for smaller powers they are
        unbounded and set to 0 there.
    n_parents : int, optional
        Keep only the ``n_parents`` nearest nodes (renormalized Shepard, still
        a partition of unity; the weights jump where the set of nearest nodes
        changes).  Default: all nodes.
    hessians : bool
        Also compute the Hessians ``ddw``.

    Returns
    -------
    ShapeValues
        With ``P = n_parents`` (or ``n``), parents sorted by distance.

    References
    ----------
    D. Shepard, "A two-dimensional interpolation function for irregularly-spaced
    data", Proc. ACM National Conference, 1968.
    """
    X = np.asarray(points, dtype=np.float64)
    Xn = np.asarray(nodes, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3:
        raise InputError(f"points must be an (m, 3) array, got shape {X.shape}")
    if Xn.ndim != 2 or Xn.shape[1] != 3 or len(Xn) == 0:
        raise InputError(f"nodes must be a non-empty (n, 3) array, got shape {Xn.shape}")
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(Xn))):
        raise InputError("points and nodes must be finite")
    power = float(power)
    if not power > 0:
        raise InputError(f"power must be > 0, got {power}")
    n = len(Xn)
    k = n if n_parents is None else int(n_parents)
    if not 1 <= k <= n:
        raise InputError(f"n_parents must be between 1 and the number of nodes ({n}), got {n_parents}")
    if k < n:
        from scipy.spatial import cKDTree

        _, idx = cKDTree(Xn).query(X, k=k)
        idx = np.asarray(idx, dtype=np.int64).reshape(len(X), k)
    else:
        d2all = ((X[:, None, :] - Xn[None, :, :]) ** 2).sum(-1)
        idx = np.argsort(d2all, axis=1, kind="stable").astype(np.int64)
    w, dw, ddw = _shepard_impl(X, Xn[idx], power, hessians)
    return ShapeValues(index=idx, w=w, dw=dw, ddw=ddw, rest=X, n_nodes=n)


def _shepard_impl(X, Xa, p, hessians):
    """Shepard values, gradients and Hessians; X (m,3), Xa (m,P,3) parent positions."""
    r = X[:, None, :] - Xa  # (m, P, 3)
    d2 = (r * r).sum(-1)  # (m, P)
    hit = d2 == 0.0
    rows_hit = hit.any(axis=1)
    d2s = np.where(hit, 1.0, d2)
    g = d2s ** (-0.5 * p)  # |r|^-p
    gp = -p * d2s ** (-0.5 * p - 1.0)  # coefficient of r in grad g
    dg = gp[..., None] * r
    S = g.sum(1)
    w = g / S[:, None]
    dS = dg.sum(1)
    dw = (dg - w[..., None] * dS[:, None, :]) / S[:, None, None]
    ddw = None
    if hessians:
        I = np.eye(3)
        gpp = p * (p + 2.0) * d2s ** (-0.5 * p - 2.0)
        ddg = gp[..., None, None] * I + gpp[..., None, None] * r[..., :, None] * r[..., None, :]
        ddS = ddg.sum(1)
        ddw = (
            ddg
            - dw[..., :, None] * dS[:, None, None, :]
            - dS[:, None, :, None] * dw[..., None, :]
            - w[..., None, None] * ddS[:, None]
        ) / S[:, None, None, None]
    if np.any(rows_hit):
        # the child sits on a node: w = delta, and the limits of the derivatives
        hw = hit[rows_hit]
        w[rows_hit] = hw.astype(np.float64)
        dw[rows_hit] = 0.0
        if ddw is not None:
            if p == 2.0:
                # w_a ≈ 1 - |r|² G, w_b ≈ |r|² g_b near node a, with G = Σ_{b≠a} g_b
                gother = np.where(hw, 0.0, ((Xa[rows_hit] - X[rows_hit][:, None, :]) ** 2).sum(-1))
                gother = np.where(hw, 0.0, 1.0 / np.where(hw, 1.0, gother))
                G = gother.sum(1)
                coef = np.where(hw, -2.0 * G[:, None], 2.0 * gother)
                ddw[rows_hit] = coef[..., None, None] * np.eye(3)
            else:
                ddw[rows_hit] = 0.0
    return w, dw, ddw
