"""F-bar / B-bar with a projected volume ratio (the frame model's ``volumetric = "reduced"``).

:func:`bar_scalar` gives the derivatives of ``W(Phi(F, Jbar))`` per sample in its
``F`` and a scalar ``Jbar`` -- the sample's volume ratio (or trace) after the
frame model projects it onto the frames' weights
(:meth:`voxflex.deform.models.frames.model.FrameModel._projected_pass`) (numpy).
"""

from __future__ import annotations

import numpy as np

_I9 = np.eye(3).reshape(9)

__all__ = ["bar_scalar"]


def _inverse_products(Finv):
    """``T`` (k, 9, 9) with ``T[3i+j, 3k+l] = Finv[l, i] Finv[j, k]`` (``-d2 ln det F``)."""
    return np.einsum("eli,ejk->eijkl", Finv, Finv).reshape(-1, 9, 9)


def bar_scalar(material, F, Jbar, *, linear, gradient=True, tangent=True):
    """Derivatives of ``W(Phi(F, Jbar))`` per sample in (F, Jbar).

    ``Phi = (Jbar / det F)^(1/3) F`` (F-bar: the sample keeps its isochoric part and
    takes the volume ratio ``Jbar``) or, with ``linear``, ``F + (Jbar - tr F) I / 3``
    (B-bar: ``Jbar`` is then a trace).  F-bar, with ``r = (Jbar / det F)^(1/3)``,
    ``l = ln r`` (``dl/dF = lF = -F^-T / 3``, ``dl/dJbar = lJ = 1 / (3 Jbar)``), ``P~``,
    ``A~`` the material's stress and tangent at Phi and ``s = P~ : Phi``:
    ``dPhi/dF = a = r (I + vec F (x) lF)``, ``dPhi/dJbar = b = r lJ vec F``;
    ``gF = r P~ + s lF``, ``gJ = s lJ``;
    ``HFF = a^T A~ a + r (lF (x) P~ + P~ (x) lF) + s (lF (x) lF + T(F) / 3)``,
    ``HFJ = a^T A~ b + r lJ P~ + s lJ lF``, ``HJJ = b^T A~ b + s (lJ^2 - 1 / (3 Jbar^2))``
    (``T`` as in :func:`_inverse_products`, ``-d2 ln det F``).

    Parameters
    ----------
    F : (k, 3, 3) float, the samples' deformation gradients
    Jbar : (k,) float, their projected volume ratios (traces with ``linear``)

    Returns
    -------
    W : (k,) energy density (Pa), +inf where ``Jbar / det F <= 0`` (F-bar)
    gF : (k, 9) dW/dF (Pa) or None;  gJ : (k,) dW/dJbar (Pa) or None
    HFF : (k, 9, 9), HFJ : (k, 9), HJJ : (k,) second derivatives (Pa) or None
    """
    k = len(F)
    Jbar = np.asarray(Jbar, dtype=float)
    if linear:
        Ft = F + ((Jbar - np.trace(F, axis1=1, axis2=2)) / 3.0)[:, None, None] * np.eye(3)
        if not (gradient or tangent):
            return material.energy(Ft), None, None, None, None, None
        W, Pt, At = material.evaluate(Ft, tangent=tangent)
        Pt = Pt.reshape(k, 9)
        a = np.eye(9) - np.outer(_I9, _I9) / 3.0
        b = _I9 / 3.0
        gF, gJ = Pt @ a, Pt @ b
        if not tangent:
            return W, gF, gJ, None, None, None
        At = At.reshape(k, 9, 9)
        return W, gF, gJ, a @ At @ a, (a @ At) @ b, np.einsum("i,kij,j->k", b, At, b)
    J = np.linalg.det(F)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = Jbar / J
    ok = np.isfinite(ratio) & (ratio > 0)
    bad = ~ok
    r = np.where(ok, np.cbrt(np.where(ok, ratio, 1.0)), 1.0)
    Fs = np.where(ok[:, None, None], F, np.eye(3))
    Js = np.where(ok, Jbar, 1.0)
    Ft = r[:, None, None] * Fs
    if not (gradient or tangent):
        return np.where(bad, np.inf, material.energy(Ft)), None, None, None, None, None
    W, Pt, At = material.evaluate(Ft, tangent=tangent)
    W = np.where(bad, np.inf, W)
    Pt = Pt.reshape(k, 9)
    Finv = np.linalg.inv(Fs)
    lF = -Finv.transpose(0, 2, 1).reshape(k, 9) / 3.0
    lJ = 1.0 / (3.0 * Js)
    Fv = Fs.reshape(k, 9)
    s = r * np.einsum("ei,ei->e", Pt, Fv)  # P~ : Phi
    gF = r[:, None] * Pt + s[:, None] * lF
    gJ = s * lJ
    if np.any(bad):
        gF[bad] = np.nan
        gJ[bad] = np.nan
    if not tangent:
        return W, gF, gJ, None, None, None
    At = At.reshape(k, 9, 9)
    rr = r[:, None, None]
    a = rr * (np.eye(9)[None] + Fv[:, :, None] * lF[:, None, :])  # dPhi/dF (k, 9, 9)
    b = (r * lJ)[:, None] * Fv  # dPhi/dJbar (k, 9)
    aT = a.transpose(0, 2, 1)
    HFF = aT @ At @ a + s[:, None, None] * (lF[:, :, None] * lF[:, None, :] + _inverse_products(Finv) / 3.0) \
        + rr * (lF[:, :, None] * Pt[:, None, :] + Pt[:, :, None] * lF[:, None, :])
    Ab = np.einsum("kij,kj->ki", At, b)
    HFJ = np.einsum("kji,kj->ki", a, Ab) + (r * lJ)[:, None] * Pt + (s * lJ)[:, None] * lF
    HJJ = np.einsum("ki,ki->k", b, Ab) + s * (lJ * lJ - 1.0 / (3.0 * Js * Js))
    if np.any(bad):
        for M in (HFF, HFJ, HJJ):
            M[bad] = np.nan
    return W, gF, gJ, HFF, HFJ, HJJ
