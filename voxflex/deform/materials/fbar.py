"""F-bar / B-bar: the volumetric part of a material evaluated at a group's mean deformation.

The voxel model's remedy for volumetric locking (``[elasticity] volumetric``):
each voxel's volumetric term is evaluated at the mean volume change of its
Gauss points (F-bar; B-bar for a linear strain), with the exact gradient and
tangent of that modified energy.  :func:`nearly_incompressible` decides where
``volumetric = "auto"`` switches it on (effective Poisson ratio at rest >=
:data:`AUTO_REDUCED_POISSON`).
"""

from __future__ import annotations

import numpy as np

VOLUMETRIC = ("auto", "full", "reduced")
"""``volumetric`` values: reduced where the material is nearly incompressible, full Gauss, F-bar / B-bar."""


AUTO_REDUCED_POISSON = 0.4
"""``volumetric="auto"`` reduces the volumetric term of labels whose effective Poisson ratio at rest is at least this."""


def effective_lame(A0) -> tuple[float, float]:
    """Isotropic Lame constants (lambda, mu) of a rest tangent ``A0`` (3, 3, 3, 3), Pa.

    The isotropic projection: ``sum_ik A_iikk = 9 lambda + 6 mu`` and
    ``sum_ij A_ijij = 3 lambda + 12 mu`` (exact for an isotropic tangent).
    """
    a = float(np.einsum("iikk->", A0))
    b = float(np.einsum("ijij->", A0))
    mu = (3.0 * b - a) / 30.0
    return (a - 6.0 * mu) / 9.0, mu


def rest_lame(material) -> tuple[float, float] | None:
    """(lambda, mu) of ``material``'s tangent at F = I (its isotropic projection, :func:`effective_lame`), or None
    when that tangent is not finite."""
    A0 = material.evaluate(np.eye(3)[None], tangent=True)[2][0]
    if not np.all(np.isfinite(A0)):
        return None
    return effective_lame(A0)


def capped_bulk(material) -> float | None:
    """The bulk modulus of a material with ``material``'s shear modulus at rest and Poisson's ratio
    :data:`AUTO_REDUCED_POISSON`, ``2 mu (1 + nu_c) / (3 (1 - 2 nu_c))``, where the material's own bulk modulus
    is larger (None elsewhere, and for a material without a finite rest tangent).

    The stiffness the frames give the part of the volume change their weights cannot resolve
    (:mod:`voxflex.deform.models.frames.volumetric`): at nu = nu_c it is the material's own (the capped model is
    then the full one, so ``volumetric = "auto"`` does not jump where it switches)."""
    lame = rest_lame(material)
    if lame is None:
        return None
    lam, mu = lame
    nu_c = AUTO_REDUCED_POISSON
    cap = 2.0 * mu * (1.0 + nu_c) / (3.0 * (1.0 - 2.0 * nu_c))
    return cap if mu > 0 and lam + 2.0 * mu / 3.0 > cap else None


def nearly_incompressible(material) -> bool:
    """Whether ``material``'s effective Poisson ratio at rest is >= :data:`AUTO_REDUCED_POISSON`.

    Read from its tangent at F = I (any material, anisotropic ones through
    their isotropic projection); a material without a finite rest tangent counts as not.
    """
    lame = rest_lame(material)
    if lame is None:
        return False
    lam, mu = lame
    nu_bound = AUTO_REDUCED_POISSON
    # nu = lam / (2 (lam + mu)) >= nu_bound  <=>  lam (1 - 2 nu_bound) >= 2 nu_bound mu (lam, mu > 0)
    # (a relative 1e-9 of slack so that a material given nu = 0.4 exactly is reduced despite round-off)
    return lam > 0 and lam * (1.0 - 2.0 * nu_bound) >= 2.0 * nu_bound * mu * (1.0 - 1e-9)






def _det3(F) -> np.ndarray:
    """Determinants (...) of 3x3 matrices (..., 3, 3), by cofactors (30k matrices, min of 50: 0.9 ms
    against 4.8 ms for LAPACK's batched LU; equal to 7e-16 near the identity)."""
    return (F[..., 0, 0] * (F[..., 1, 1] * F[..., 2, 2] - F[..., 1, 2] * F[..., 2, 1])
            - F[..., 0, 1] * (F[..., 1, 0] * F[..., 2, 2] - F[..., 1, 2] * F[..., 2, 0])
            + F[..., 0, 2] * (F[..., 1, 0] * F[..., 2, 1] - F[..., 1, 1] * F[..., 2, 0]))


def _inv3(F) -> np.ndarray:
    """Inverses (..., 3, 3) of invertible 3x3 matrices: the adjugate over the determinant (30k
    matrices, min of 50: 5.6 ms against 14.3 ms for LAPACK's batched solve; equal to 9e-16 near the
    identity)."""
    adj = np.empty_like(F)
    for i in range(3):
        i1, i2 = (i + 1) % 3, (i + 2) % 3
        for j in range(3):
            j1, j2 = (j + 1) % 3, (j + 2) % 3
            adj[..., j, i] = F[..., i1, j1] * F[..., i2, j2] - F[..., i1, j2] * F[..., i2, j1]
    return adj / _det3(F)[..., None, None]






def _energy_density(material, F) -> np.ndarray:
    """W (n,) of F (n, 3, 3): the material's energy-only pass when it has one (no J, P or tangent)."""
    energy = getattr(material, "energy", None)
    return energy(F) if energy is not None else material.evaluate(F, tangent=False)[0]


_I9 = np.eye(3).reshape(9)


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
    J = _det3(F)
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
    Finv = _inv3(Fs)
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
