"""Singular value decomposition of 3x3 matrices without LAPACK (compiled, and its numpy twin).

``F = U diag(sig) V^T`` by one-sided (Hestenes) Jacobi rotations on the columns
of F: rotate pairs of columns of ``B = F V`` until every pair is orthogonal to
a relative tolerance, ``|b_p . b_q| <= TOL |b_p| |b_q|``; the singular values
are then the column norms and U the normalized columns.  Working on F (not on
``C = F^T F``) keeps the small singular values accurate relative to the
largest one (forming C would square the condition number), and the relative
stopping test keeps U orthogonal even for tiny or zero columns.

Post-processing, shared by both twins:

* the columns are sorted by decreasing norm, and the last columns of V and B
  are negated when the sorting permutation is odd, so ``det V = +1``;
* ``u1 = b1 / |b1|``; ``u2`` is b2 Gram-Schmidt-orthogonalized against u1
  (any unit vector orthogonal to u1 when that is zero, i.e. rank F <= 1);
  ``u3 = u1 x u2`` so ``det U = +1``, and ``sig3 = u3 . b3``;
* ``signed=True``: the *rotation-signed* SVD (Irving et al. 2004): U and V are
  rotations and ``sig3`` carries the sign of ``det F`` (``sig1 >= sig2 >= |sig3|``);
  ``signed=False``: the ordinary SVD, ``u3`` and ``sig3`` negated when
  ``sig3 < 0`` (``sig1 >= sig2 >= sig3 >= 0``).

F is scaled by ``1 / max|F_ij|`` first, so the thresholds are scale-free.
Accuracy (float64, tests/test_svd3.py): ``|U diag(sig) V^T - F| <= ~1e-15 |F|``,
``|U^T U - I|, |V^T V - I| <= ~1e-15``, singular values to ~1e-15 |F|, for
random, near-repeated, flat (rank 2 and rank 1), inverted and orthogonal F.
Typical cost: 2 to 4 sweeps of 3 rotations.

References
----------
Hestenes, "Inversion of matrices by biorthogonalization and related results",
J. SIAM 6 (1958).  Demmel, Veselic, "Jacobi's method is more accurate than
QR", SIAM J. Matrix Anal. Appl. 13 (1992).
"""

from __future__ import annotations

import math

import numpy as np

from voxflex._jit import njit

TOL = 1e-15
"""Relative orthogonality of the columns of F V at which a pair is not rotated (~4.5 ulp)."""
MAX_SWEEPS = 12
"""Cap on the Jacobi sweeps (quadratic convergence: 2 to 5 are used in practice)."""

_TINY = 1e-150  # |b2 - (u1.b2) u1| below this (F scaled to max|F_ij| = 1) means rank F <= 1


@njit(error_model="numpy")
def _svd3(F, signed, U, sig, V):
    """SVD of one 3x3 matrix into U (3, 3), sig (3,), V (3, 3); see the module docstring.

    ``F`` is read only; U, sig and V are overwritten (U is the workspace B).
    """
    scale = 0.0
    for a in range(3):
        for b in range(3):
            x = abs(F[a, b])
            if x > scale:
                scale = x
            V[a, b] = 1.0 if a == b else 0.0
    if not scale > 0.0:  # zero matrix (or NaN): U = V = I, sig = 0 (NaN propagates)
        for a in range(3):
            sig[a] = scale
            for b in range(3):
                U[a, b] = 1.0 if a == b else 0.0
        return
    inv = 1.0 / scale
    for a in range(3):
        for b in range(3):
            U[a, b] = F[a, b] * inv
    tol2 = TOL * TOL
    for _sweep in range(MAX_SWEEPS):
        rotated = False
        for pair in range(3):
            p = 0 if pair < 2 else 1
            q = 1 if pair == 0 else 2
            al = U[0, p] * U[0, p] + U[1, p] * U[1, p] + U[2, p] * U[2, p]
            be = U[0, q] * U[0, q] + U[1, q] * U[1, q] + U[2, q] * U[2, q]
            ga = U[0, p] * U[0, q] + U[1, p] * U[1, q] + U[2, p] * U[2, q]
            if ga * ga <= tol2 * al * be:
                continue
            rotated = True
            # the rotation (c, s) = (cos, sin) that makes the pair orthogonal (the smaller of the
            # two angles): tan = 2 ga sgn(d) / (|d| + r) with d = be - al, r = sqrt(d^2 + 4 ga^2),
            # and 1 + tan^2 = 2 r / (|d| + r): one division, no cancellation (all terms >= 0)
            d = be - al
            ad = abs(d)
            r = math.sqrt(d * d + 4.0 * ga * ga)
            w = 1.0 / math.sqrt(2.0 * r * (r + ad))
            c = (ad + r) * w
            s = math.copysign(2.0, d) * ga * w
            for a in range(3):
                bp = U[a, p]
                bq = U[a, q]
                U[a, p] = c * bp - s * bq
                U[a, q] = s * bp + c * bq
                vp = V[a, p]
                vq = V[a, q]
                V[a, p] = c * vp - s * vq
                V[a, q] = s * vp + c * vq
        if not rotated:
            break
    for a in range(3):
        sig[a] = U[0, a] * U[0, a] + U[1, a] * U[1, a] + U[2, a] * U[2, a]
    # sort columns by decreasing norm (3 compare-swaps); an odd permutation flips det V
    odd = False
    for p, q in ((0, 1), (1, 2), (0, 1)):
        if sig[q] > sig[p]:
            odd = not odd
            sig[p], sig[q] = sig[q], sig[p]
            for a in range(3):
                U[a, p], U[a, q] = U[a, q], U[a, p]
                V[a, p], V[a, q] = V[a, q], V[a, p]
    if odd:
        for a in range(3):
            U[a, 2] = -U[a, 2]
            V[a, 2] = -V[a, 2]
    b30, b31, b32 = U[0, 2], U[1, 2], U[2, 2]
    # u1: the largest column is at least |F|_F / sqrt(3) >= 1/sqrt(3) after the scaling
    n1 = math.sqrt(sig[0])
    u10, u11, u12 = U[0, 0] / n1, U[1, 0] / n1, U[2, 0] / n1
    # u2: Gram-Schmidt of b2 against u1
    d = u10 * U[0, 1] + u11 * U[1, 1] + u12 * U[2, 1]
    w0, w1, w2 = U[0, 1] - d * u10, U[1, 1] - d * u11, U[2, 1] - d * u12
    m2 = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    if m2 > _TINY:
        u20, u21, u22 = w0 / m2, w1 / m2, w2 / m2
        s2 = m2
    else:
        # rank F <= 1: any unit vector orthogonal to u1 (from the axis least aligned with it)
        a0, a1, a2 = abs(u10), abs(u11), abs(u12)
        if a0 <= a1 and a0 <= a2:
            w0, w1, w2 = 1.0 - u10 * u10, -u10 * u11, -u10 * u12
        elif a1 <= a2:
            w0, w1, w2 = -u11 * u10, 1.0 - u11 * u11, -u11 * u12
        else:
            w0, w1, w2 = -u12 * u10, -u12 * u11, 1.0 - u12 * u12
        m = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
        u20, u21, u22 = w0 / m, w1 / m, w2 / m
        s2 = u20 * U[0, 1] + u21 * U[1, 1] + u22 * U[2, 1]
        if s2 < 0.0:
            u20, u21, u22, s2 = -u20, -u21, -u22, -s2
    # u3 = u1 x u2 (det U = +1); sig3 = u3 . b3 carries the sign of det F
    u30 = u11 * u22 - u12 * u21
    u31 = u12 * u20 - u10 * u22
    u32 = u10 * u21 - u11 * u20
    s3 = u30 * b30 + u31 * b31 + u32 * b32
    if not signed and s3 < 0.0:
        u30, u31, u32, s3 = -u30, -u31, -u32, -s3
    # the column norms were sorted; keep the order exact through the last-ulp changes above
    s2 = min(s2, n1)
    if abs(s3) > s2:
        s3 = math.copysign(s2, s3)
    U[0, 0], U[1, 0], U[2, 0] = u10, u11, u12
    U[0, 1], U[1, 1], U[2, 1] = u20, u21, u22
    U[0, 2], U[1, 2], U[2, 2] = u30, u31, u32
    sig[0] = n1 * scale
    sig[1] = s2 * scale
    sig[2] = s3 * scale


@njit(error_model="numpy")
def _svd3_batch(F, signed, U, sig, V):
    """:func:`_svd3` over a batch: F (n, 3, 3) -> U (n, 3, 3), sig (n, 3), V (n, 3, 3)."""
    for e in range(F.shape[0]):
        _svd3(F[e], signed, U[e], sig[e], V[e])


def svd3(F, *, signed: bool = False):
    """SVD of a batch of 3x3 matrices by Jacobi rotations (compiled).

    Parameters
    ----------
    F : array_like, shape (n, 3, 3) or (3, 3)
        Finite matrices (any units).
    signed : bool, keyword-only
        False: ordinary SVD, ``sig`` descending and >= 0.  True: rotation-signed
        SVD, ``det U = det V = +1`` and ``sig[..., 2]`` has the sign of det F.

    Returns
    -------
    U : ndarray, shape (n, 3, 3) or (3, 3)
        Left singular vectors (columns); ``det U = +1``, unless ``signed`` is
        False and det F < 0.
    sig : ndarray, shape (n, 3) or (3,)
        Singular values, ``sig1 >= sig2 >= |sig3|``.
    V : ndarray, shape (n, 3, 3) or (3, 3)
        Right singular vectors (columns), ``det V = +1``; ``F = U diag(sig) V^T``
        (note: V, not numpy's ``Vh``).

    Examples
    --------
    >>> import numpy as np
    >>> U, sig, V = svd3(np.diag([1.0, 3.0, -2.0]), signed=True)
    >>> sig.tolist()
    [3.0, 2.0, -1.0]
    """
    from voxflex.errors import InputError

    F = np.asarray(F, dtype=np.float64)
    single = F.shape == (3, 3)
    if single:
        F = F[None]
    if F.ndim != 3 or F.shape[1:] != (3, 3):
        raise InputError(f"F must have shape (n, 3, 3) or (3, 3), got {F.shape}; pass one 3x3 matrix per sample")
    if not np.all(np.isfinite(F)):
        raise InputError("F contains NaN or infinite entries; pass finite matrices")
    F = np.ascontiguousarray(F)
    n = F.shape[0]
    U, sig, V = np.empty((n, 3, 3)), np.empty((n, 3)), np.empty((n, 3, 3))
    _svd3_batch(F, bool(signed), U, sig, V)
    return (U[0], sig[0], V[0]) if single else (U, sig, V)


def np_svd3(F, signed=False):
    """Numpy twin of :func:`_svd3` (same algorithm, vectorized with masks): (n,3,3) -> U, sig, V."""
    F = np.asarray(F, dtype=np.float64)
    n = F.shape[0]
    scale = np.abs(F).max(axis=(1, 2))
    zero = ~(scale > 0)
    safe = np.where(zero, 1.0, scale)
    B = F / safe[:, None, None]
    V = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    for _ in range(MAX_SWEEPS):
        any_rot = False
        for p, q in ((0, 1), (0, 2), (1, 2)):
            al = np.einsum("na,na->n", B[:, :, p], B[:, :, p])
            be = np.einsum("na,na->n", B[:, :, q], B[:, :, q])
            ga = np.einsum("na,na->n", B[:, :, p], B[:, :, q])
            rot = ga * ga > TOL * TOL * al * be
            if not rot.any():
                continue
            any_rot = True
            d = be - al
            ad = np.abs(d)
            r = np.sqrt(d * d + 4.0 * ga * ga)
            w = np.where(rot, 1.0 / np.sqrt(np.where(rot, 2.0 * r * (r + ad), 1.0)), 0.0)
            c = np.where(rot, (ad + r) * w, 1.0)
            s = np.copysign(2.0, d) * ga * w
            for X in (B, V):
                xp, xq = X[:, :, p].copy(), X[:, :, q].copy()
                X[:, :, p] = c[:, None] * xp - s[:, None] * xq
                X[:, :, q] = s[:, None] * xp + c[:, None] * xq
        if not any_rot:
            break
    nrm2 = np.einsum("nab,nab->nb", B, B)
    order = np.argsort(-nrm2, axis=1, kind="stable")
    B = np.take_along_axis(B, order[:, None, :], axis=2)
    V = np.take_along_axis(V, order[:, None, :], axis=2)
    nrm2 = np.take_along_axis(nrm2, order, axis=1)
    odd = np.linalg.det(V) < 0
    B[odd, :, 2] *= -1
    V[odd, :, 2] *= -1
    n1 = np.sqrt(nrm2[:, 0])
    u1 = B[:, :, 0] / np.where(zero, 1.0, n1)[:, None]
    w = B[:, :, 1] - np.einsum("na,na->n", u1, B[:, :, 1])[:, None] * u1
    m2 = np.linalg.norm(w, axis=1)
    flat = ~(m2 > _TINY)
    if flat.any():
        ax = np.argmin(np.abs(u1[flat]), axis=1)
        e = np.eye(3)[ax]
        wf = e - u1[flat][np.arange(ax.size), ax][:, None] * u1[flat]
        w[flat] = wf
        m2[flat] = np.linalg.norm(wf, axis=1)
    u2 = w / m2[:, None]
    s2 = np.einsum("na,na->n", u2, B[:, :, 1])
    neg = s2 < 0
    u2[neg] *= -1
    s2[neg] *= -1
    u3 = np.cross(u1, u2)
    s3 = np.einsum("na,na->n", u3, B[:, :, 2])
    if not signed:
        neg = s3 < 0
        u3[neg] *= -1
        s3[neg] *= -1
    s2 = np.minimum(s2, n1)
    s3 = np.copysign(np.minimum(np.abs(s3), s2), s3)
    U = np.stack([u1, u2, u3], axis=2)
    sig = np.stack([n1, s2, s3], axis=1) * scale[:, None]
    U[zero] = np.eye(3)
    V[zero] = np.eye(3)
    sig[zero] = scale[zero, None]
    return U, sig, V
