"""The plain numpy twins of the strain kernels: the tests' reference.

One twin per kernel of :mod:`voxflex.deform.materials._strain_kernels` (:func:`np_tensor`,
:func:`np_corot`, :func:`np_invariant`, :func:`np_stretch`), with the same private switches and the same
outputs ``(E, J, G or None)``, written with whole-array numpy (``np.linalg.svd`` and ``qr`` where the
kernels use their own 3x3 decompositions, so that the tests compare two independent computations);
:class:`voxflex.deform.materials.strains.Strain` runs them for ``backend="numpy"``.  The corotational
derivatives follow the derivation in :mod:`voxflex.deform.materials._strain_kernels`.
"""

from __future__ import annotations

import numpy as np

from ._strain_kernels import _VA, _VB, GREEN, LINEAR, QR, SVD


# ============================================================================= numpy twins
def _np_voigt(M):
    """Engineering Voigt vector of sym(M): (..., 3, 3) -> (..., 6)."""
    return np.stack(
        [M[..., 0, 0], M[..., 1, 1], M[..., 2, 2],
         M[..., 0, 1] + M[..., 1, 0], M[..., 1, 2] + M[..., 2, 1], M[..., 0, 2] + M[..., 2, 0]],
        axis=-1,
    )


def _np_stress(s):
    S = np.empty(s.shape[:-1] + (3, 3))
    for k in range(6):
        S[..., _VA[k], _VB[k]] = s[..., k]
        S[..., _VB[k], _VA[k]] = s[..., k]
    return S


_I3 = np.eye(3)
_EIJ = np.eye(9).reshape(9, 3, 3)  # basis directions e_ij, index 3 i + j


def np_tensor(F, s, kind):
    """Numpy twin of :func:`_tensor_kernel`: returns (E, J, G or None)."""
    n = F.shape[0]
    if kind == LINEAR:
        E = _np_voigt(F - _I3)
        dM = np.broadcast_to(_EIJ, (n, 9, 3, 3))
        G = np.zeros((n, 3, 3, 3, 3)) if s is not None else None
    elif kind == GREEN:
        E = _np_voigt(0.5 * (np.einsum("nia,nib->nab", F, F) - _I3))
        dM = 0.5 * (np.einsum("hia,nib->nhab", _EIJ, F) + np.einsum("nia,hib->nhab", F, _EIJ))
        G = None if s is None else np.einsum("ik,njl->nijkl", _I3, _np_stress(s))
    else:
        W = 0.5 * (F - F.transpose(0, 2, 1))
        E = _np_voigt(F - W @ F - _I3)
        Wh = 0.5 * (_EIJ - _EIJ.transpose(0, 2, 1))
        dM = _EIJ[None] - np.einsum("hac,ncb->nhab", Wh, F) - np.einsum("nac,hcb->nhab", W, _EIJ)
        if s is None:
            G = None
        else:
            # -S : (skew(h1) h2 + skew(h2) h1)
            S = _np_stress(s)
            t = np.einsum("pac,qcb,nab->npq", Wh, _EIJ, S)
            G = -(t + t.transpose(0, 2, 1)).reshape(n, 3, 3, 3, 3)
    J = _np_voigt(dM).transpose(0, 2, 1).reshape(n, 6, 3, 3)
    return E, J, G


def _np_solve(method, A, sig, T, Tinv):
    if method == QR:
        X = A @ Tinv
        L = np.tril(X, -1)
        Om = L - np.swapaxes(L, -1, -2)
        D = (X - Om) @ T
    else:
        At = np.swapaxes(A, -1, -2)
        sp = sig[..., :, None]
        sq = sig[..., None, :]
        den = sp + sq
        with np.errstate(divide="ignore", invalid="ignore"):
            Om = (A - At) / den
            D = (sp * A + sq * At) / den
        d = np.arange(3)
        Om[..., d, d] = 0.0
        D[..., d, d] = A[..., d, d]
    return Om, D


def np_corot(F, s, method):
    """Numpy twin of :func:`_corot_kernel`: returns (E, J, G or None)."""
    n = F.shape[0]
    if method == QR:
        Q, T = np.linalg.qr(F)
        sgn = np.sign(np.diagonal(T, axis1=1, axis2=2))
        R = Q * sgn[:, None, :]
        T = T * sgn[:, :, None]
        Tinv = np.linalg.inv(T)
        P = np.broadcast_to(_I3, (n, 3, 3))
        Mf = T
        sig = None
        Mw = T
    else:
        U, sig, Vh = np.linalg.svd(F)
        sig = sig.copy()
        P = np.swapaxes(Vh, 1, 2).copy()
        U = U.copy()
        if method == SVD:
            fu = np.linalg.det(U) < 0
            U[fu, :, 2] *= -1
            sig[fu, 2] *= -1
            fv = np.linalg.det(P) < 0
            P[fv, :, 2] *= -1
            sig[fv, 2] *= -1
        R = U @ np.swapaxes(P, 1, 2)
        Mf = sig[:, :, None] * _I3
        Mw = P @ Mf @ np.swapaxes(P, 1, 2)
        T = Tinv = None
    E = _np_voigt(Mw - _I3)
    RP = R @ P
    A = np.einsum("nia,njb->nijab", RP, P).reshape(n, 9, 3, 3)
    Om, D = _np_solve(method, A, None if sig is None else sig[:, None, :],
                      None if T is None else T[:, None], None if Tinv is None else Tinv[:, None])
    Dw = P[:, None] @ D @ np.swapaxes(P, 1, 2)[:, None]
    J = _np_voigt(Dw).transpose(0, 2, 1).reshape(n, 6, 3, 3)
    if s is None:
        return E, J, None
    Sf = np.swapaxes(P, 1, 2) @ _np_stress(s) @ P
    G = np.empty((n, 9, 9))
    for h1 in range(9):
        O1, D1 = Om[:, h1], D[:, h1]
        for h2 in range(h1, 9):
            O2, D2 = Om[:, h2], D[:, h2]
            B = -0.5 * (O1 @ O2 + O2 @ O1) @ Mf - O1 @ D2 - O2 @ D1
            _, DD = _np_solve(method, B, sig, T, Tinv)
            v = np.einsum("nab,nab->n", Sf, DD)
            G[:, h1, h2] = v
            G[:, h2, h1] = v
    return E, J, G.reshape(n, 3, 3, 3, 3)


def np_invariant(F, s, deviatoric):
    """Numpy twin of :func:`_invariant_kernel` (formulas written with inverses, valid for det F != 0)."""
    C = np.einsum("nia,nib->nab", F, F)
    I1 = np.trace(C, axis1=1, axis2=2)
    I2 = 0.5 * (I1**2 - np.einsum("nab,nab->n", C, C))
    Jd = np.linalg.det(F)
    Finv_T = np.swapaxes(np.linalg.inv(F), 1, 2)
    g1 = 2 * F
    g2 = 2 * I1[:, None, None] * F - 2 * F @ C
    g3 = Jd[:, None, None] * Finv_T
    if deviatoric:
        p = np.array([-2.0 / 3.0, -4.0 / 3.0])
        c = np.stack([np.cbrt(Jd) ** -2, np.cbrt(Jd) ** -4], axis=1)
    else:
        p = np.zeros(2)
        c = np.ones((F.shape[0], 2))
    inv = np.stack([I1, I2], axis=1)
    E = np.stack([c[:, 0] * I1, c[:, 1] * I2, Jd], axis=1)
    gI = np.stack([g1, g2], axis=1)
    J = np.empty((F.shape[0], 3, 3, 3))
    J[:, :2] = c[:, :, None, None] * (gI + (p * inv / Jd[:, None])[:, :, None, None] * g3[:, None])
    J[:, 2] = g3
    if s is None:
        return E, J, None
    d = np.eye(3)
    H1 = 2 * np.einsum("ik,jl->ijkl", d, d)
    B = F @ np.swapaxes(F, 1, 2)
    H2 = (4 * np.einsum("nij,nkl->nijkl", F, F) + 2 * I1[:, None, None, None, None] * H1 / 2
          - 2 * (np.einsum("ik,nlj->nijkl", d, C) + np.einsum("nil,nkj->nijkl", F, F) + np.einsum("nik,jl->nijkl", B, d)))
    # d2J/dF_ij dF_kl = J (Finv_ji Finv_lk - Finv_li Finv_jk)
    Fi = np.linalg.inv(F)
    H3 = Jd[:, None, None, None, None] * (np.einsum("nji,nlk->nijkl", Fi, Fi) - np.einsum("nli,njk->nijkl", Fi, Fi))
    out = s[:, 2, None, None, None, None] * H3
    Hs = [H1[None], H2]
    gs = [g1, g2]
    for a in range(2):
        ca = c[:, a]
        d1 = p[a] * ca / Jd
        dd = p[a] * (p[a] - 1) * ca / Jd**2
        sa = s[:, a]
        w = lambda x: x[:, None, None, None, None]  # noqa: E731
        out = out + w(sa * ca) * Hs[a] + w(sa * d1 * inv[:, a]) * H3
        out = out + w(sa * d1) * (np.einsum("nij,nkl->nijkl", g3, gs[a]) + np.einsum("nij,nkl->nijkl", gs[a], g3))
        out = out + w(sa * dd * inv[:, a]) * np.einsum("nij,nkl->nijkl", g3, g3)
    return E, J, out


def np_stretch(F, s, gap, K=None):
    """Numpy twin of :func:`_stretch_kernel` (``K``: the law's tangent (n, 3, 3) or None)."""
    U, sv, Vh = np.linalg.svd(F)
    J = np.einsum("nik,nkj->nkij", U, Vh)
    if s is None:
        return sv, J, None
    n = F.shape[0]
    floor = gap * np.maximum(sv[:, 0], 1e-300)
    G = np.zeros((n, 3, 3, 3, 3))
    for p in range(3):
        for q in range(3):
            if p == q:
                continue
            dm = sv[:, p] - sv[:, q]
            dm = np.maximum(dm, floor) if p < q else np.minimum(dm, -floor)
            dp = np.maximum(sv[:, p] + sv[:, q], floor)
            alpha = (s[:, p] - s[:, q]) / dm
            if K is not None:
                close = np.abs(sv[:, p] - sv[:, q]) <= floor
                limit = 0.5 * (K[:, p, p] + K[:, q, q] - K[:, p, q] - K[:, q, p])
                alpha = np.where(close, limit, alpha)
            beta = (s[:, p] + s[:, q]) / dp
            x = np.einsum("ni,nj->nij", U[:, :, p], Vh[:, q, :])
            y = np.einsum("nk,nl->nkl", U[:, :, q], Vh[:, p, :])
            G += np.einsum("n,nij,nkl->nijkl", 0.5 * (alpha + beta), x, x)
            G += np.einsum("n,nij,nkl->nijkl", 0.5 * (alpha - beta), x, y)
    return sv, J, G
