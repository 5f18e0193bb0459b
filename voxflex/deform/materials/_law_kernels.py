"""The compiled kernels of the energy laws and their numpy twins.

One kernel per law of :mod:`voxflex.deform.materials.laws`, declared with :func:`voxflex._jit.njit`: it
fills the energy density ``W`` (n,), the stress ``s = dW/de`` (n, m) and, when asked, the tangent
``K = d2W/de2`` (n, m, m) of a batch of strain vectors ``e`` (n, m) in place.  Each has a plain numpy twin
``_<law>_numpy(e, params) -> (W, s, K)``, the tests' reference.  Samples outside a law's domain get
``W = +inf`` and NaN stress and tangent.  A law's parameters arrive packed in ``params`` (see each law's
``params``).
"""

from __future__ import annotations

import numpy as np

from ..._jit import njit


# ----------------------------------------------------------------------------------------------
# kernels: (e (n,m), params (p,), W (n,), s (n,m), K (n,m,m), with_tangent) -> None, in place
# Each has a numpy twin ``_<law>_numpy(e, params) -> (W, s, K)``.
# ----------------------------------------------------------------------------------------------
@njit
def _hooke_kernel(e, params, W, s, K, with_tangent):
    n, m = e.shape
    for q in range(n):
        w = 0.0
        for a in range(m):
            acc = 0.0
            for b in range(m):
                acc += params[a * m + b] * e[q, b]
            s[q, a] = acc
            w += 0.5 * acc * e[q, a]
        W[q] = w
        if with_tangent:
            for a in range(m):
                for b in range(m):
                    K[q, a, b] = params[a * m + b]


def _hooke_numpy(e, params):
    m = e.shape[1]
    C = params.reshape(m, m)
    s = e @ C.T
    W = 0.5 * np.einsum("na,na->n", s, e)
    K = np.broadcast_to(C, (e.shape[0], m, m)).copy()
    return W, s, K


@njit
def _neo_hookean_kernel(e, params, W, s, K, with_tangent):
    # W = mu/2 (I1 - 3) - mu ln J + lmbda/2 (ln J)^2 over (I1, I2, J)
    mu, lm = params[0], params[1]
    n = e.shape[0]
    for q in range(n):
        J = e[q, 2]
        if with_tangent:
            for a in range(3):
                for b in range(3):
                    K[q, a, b] = 0.0
        if J <= 0.0:
            W[q] = np.inf
            for a in range(3):
                s[q, a] = np.nan
            if with_tangent:
                for a in range(3):
                    for b in range(3):
                        K[q, a, b] = np.nan
            continue
        L = np.log(J)
        W[q] = 0.5 * mu * (e[q, 0] - 3.0) - mu * L + 0.5 * lm * L * L
        s[q, 0] = 0.5 * mu
        s[q, 1] = 0.0
        s[q, 2] = (lm * L - mu) / J
        if with_tangent:
            K[q, 2, 2] = (mu + lm * (1.0 - L)) / (J * J)


def _invalid(W, s, K, bad):
    """Mark samples outside the domain: W = +inf, s = K = NaN (numpy twins)."""
    if np.any(bad):
        W[bad] = np.inf
        s[bad] = np.nan
        K[bad] = np.nan
    return W, s, K


def _neo_hookean_numpy(e, params):
    mu, lm = params[0], params[1]
    n = e.shape[0]
    J = e[:, 2]
    bad = ~(J > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        L = np.log(np.where(bad, 1.0, J))
        W = 0.5 * mu * (e[:, 0] - 3.0) - mu * L + 0.5 * lm * L * L
        s = np.zeros((n, 3))
        s[:, 0] = 0.5 * mu
        s[:, 2] = (lm * L - mu) / J
        K = np.zeros((n, 3, 3))
        K[:, 2, 2] = (mu + lm * (1.0 - L)) / (J * J)
    return _invalid(W, s, K, bad)


@njit
def _stable_neo_hookean_kernel(e, params, W, s, K, with_tangent):
    # W = mu'/2 (I1 - 3) + lm'/2 (J - alpha)^2 - mu'/2 ln(I1 + 1) - W(I)
    mu, lm, alpha, w0 = params[0], params[1], params[2], params[3]
    n = e.shape[0]
    for q in range(n):
        I1 = e[q, 0]
        J = e[q, 2]
        d = J - alpha
        W[q] = 0.5 * mu * (I1 - 3.0) + 0.5 * lm * d * d - 0.5 * mu * np.log(I1 + 1.0) - w0
        s[q, 0] = 0.5 * mu * (1.0 - 1.0 / (I1 + 1.0))
        s[q, 1] = 0.0
        s[q, 2] = lm * d
        if with_tangent:
            for a in range(3):
                for b in range(3):
                    K[q, a, b] = 0.0
            K[q, 0, 0] = 0.5 * mu / ((I1 + 1.0) * (I1 + 1.0))
            K[q, 2, 2] = lm


def _stable_neo_hookean_numpy(e, params):
    mu, lm, alpha, w0 = params
    n = e.shape[0]
    I1, J = e[:, 0], e[:, 2]
    W = 0.5 * mu * (I1 - 3.0) + 0.5 * lm * (J - alpha) ** 2 - 0.5 * mu * np.log(I1 + 1.0) - w0
    s = np.zeros((n, 3))
    s[:, 0] = 0.5 * mu * (1.0 - 1.0 / (I1 + 1.0))
    s[:, 2] = lm * (J - alpha)
    K = np.zeros((n, 3, 3))
    K[:, 0, 0] = 0.5 * mu / (I1 + 1.0) ** 2
    K[:, 2, 2] = lm
    return W, s, K


@njit
def _mooney_rivlin_kernel(e, params, W, s, K, with_tangent):
    # W = c1 (I1bar - 3) + c2 (I2bar - 3) + bulk/2 (J - 1)^2
    c1, c2, kb = params[0], params[1], params[2]
    n = e.shape[0]
    for q in range(n):
        d = e[q, 2] - 1.0
        W[q] = c1 * (e[q, 0] - 3.0) + c2 * (e[q, 1] - 3.0) + 0.5 * kb * d * d
        s[q, 0] = c1
        s[q, 1] = c2
        s[q, 2] = kb * d
        if with_tangent:
            for a in range(3):
                for b in range(3):
                    K[q, a, b] = 0.0
            K[q, 2, 2] = kb


def _mooney_rivlin_numpy(e, params):
    c1, c2, kb = params
    n = e.shape[0]
    d = e[:, 2] - 1.0
    W = c1 * (e[:, 0] - 3.0) + c2 * (e[:, 1] - 3.0) + 0.5 * kb * d * d
    s = np.zeros((n, 3))
    s[:, 0], s[:, 1], s[:, 2] = c1, c2, kb * d
    K = np.zeros((n, 3, 3))
    K[:, 2, 2] = kb
    return W, s, K



@njit
def _arruda_boyce_kernel(e, params, W, s, K, with_tangent):
    # W = sum_p a_p (I1bar^p - 3^p) + bulk/2 (J - 1)^2, p = 1..5, params = [a_1..a_5, bulk];
    # I1bar^p - 3^p = (I1bar - 3) g_p with g_1 = 1, g_p = 3^(p-1) + I1bar g_(p-1) (no cancellation at rest)
    kb = params[5]
    n = e.shape[0]
    for q in range(n):
        x = e[q, 0]
        g = 1.0
        t3 = 1.0
        xp1 = 0.0  # x^(p-2)
        xp = 1.0  # x^(p-1)
        w = 0.0
        d1 = 0.0
        d2 = 0.0
        for i in range(5):
            p = i + 1.0
            a = params[i]
            if i > 0:
                t3 *= 3.0
                g = t3 + x * g
                xp1 = xp
                xp = xp * x
            w += a * g
            d1 += p * a * xp
            d2 += p * (p - 1.0) * a * xp1
        d = e[q, 2] - 1.0
        W[q] = w * (x - 3.0) + 0.5 * kb * d * d
        s[q, 0] = d1
        s[q, 1] = 0.0
        s[q, 2] = kb * d
        if with_tangent:
            for a in range(3):
                for b in range(3):
                    K[q, a, b] = 0.0
            K[q, 0, 0] = d2
            K[q, 2, 2] = kb


def _arruda_boyce_numpy(e, params):
    a, kb = params[:5], params[5]
    n = e.shape[0]
    x = e[:, 0]
    p = np.arange(1.0, 6.0)
    xp = x[:, None] ** (p - 1.0)  # (n, 5): x^(p-1)
    g = np.empty((n, 5))
    g[:, 0] = 1.0
    for i in range(1, 5):
        g[:, i] = 3.0**i + x * g[:, i - 1]
    d = e[:, 2] - 1.0
    W = (g @ a) * (x - 3.0) + 0.5 * kb * d * d
    s = np.zeros((n, 3))
    s[:, 0] = xp @ (p * a)
    s[:, 2] = kb * d
    K = np.zeros((n, 3, 3))
    xpm = np.concatenate([np.zeros((n, 1)), xp[:, :4]], axis=1)  # x^(p-2), its p = 1 entry unused
    K[:, 0, 0] = xpm @ (p * (p - 1.0) * a)
    K[:, 2, 2] = kb
    return W, s, K


@njit
def _veronda_westmann_kernel(e, params, W, s, K, with_tangent):
    # W = c1 (exp(c2 (I1bar - 3)) - 1) - c1 c2/2 (I2bar - 3) + bulk/2 (J - 1)^2
    c1, c2, kb = params[0], params[1], params[2]
    n = e.shape[0]
    for q in range(n):
        z = c2 * (e[q, 0] - 3.0)
        x = np.exp(z)
        d = e[q, 2] - 1.0
        W[q] = c1 * np.expm1(z) - 0.5 * c1 * c2 * (e[q, 1] - 3.0) + 0.5 * kb * d * d
        s[q, 0] = c1 * c2 * x
        s[q, 1] = -0.5 * c1 * c2
        s[q, 2] = kb * d
        if with_tangent:
            for a in range(3):
                for b in range(3):
                    K[q, a, b] = 0.0
            K[q, 0, 0] = c1 * c2 * c2 * x
            K[q, 2, 2] = kb


def _veronda_westmann_numpy(e, params):
    c1, c2, kb = params
    n = e.shape[0]
    z = c2 * (e[:, 0] - 3.0)
    x = np.exp(z)
    d = e[:, 2] - 1.0
    W = c1 * np.expm1(z) - 0.5 * c1 * c2 * (e[:, 1] - 3.0) + 0.5 * kb * d * d
    s = np.zeros((n, 3))
    s[:, 0], s[:, 1], s[:, 2] = c1 * c2 * x, -0.5 * c1 * c2, kb * d
    K = np.zeros((n, 3, 3))
    K[:, 0, 0] = c1 * c2 * c2 * x
    K[:, 2, 2] = kb
    return W, s, K


@njit
def _volume_kernel(e, params, W, s, K, with_tangent):
    # params[1] == 0: k/2 (ln J)^2 ; params[1] == 1: k/2 (J - 1)^2 (J is e[:, 2])
    k = params[0]
    quadratic = params[1] != 0.0
    n = e.shape[0]
    for q in range(n):
        J = e[q, 2]
        if with_tangent:
            for a in range(3):
                for b in range(3):
                    K[q, a, b] = 0.0
        s[q, 0] = 0.0
        s[q, 1] = 0.0
        if quadratic:
            W[q] = 0.5 * k * (J - 1.0) * (J - 1.0)
            s[q, 2] = k * (J - 1.0)
            if with_tangent:
                K[q, 2, 2] = k
        elif J <= 0.0:
            W[q] = np.inf
            for a in range(3):
                s[q, a] = np.nan
            if with_tangent:
                for a in range(3):
                    for b in range(3):
                        K[q, a, b] = np.nan
        else:
            L = np.log(J)
            W[q] = 0.5 * k * L * L
            s[q, 2] = k * L / J
            if with_tangent:
                K[q, 2, 2] = k * (1.0 - L) / (J * J)


def _volume_numpy(e, params):
    k, quadratic = params
    n = e.shape[0]
    J = e[:, 2]
    s = np.zeros((n, 3))
    K = np.zeros((n, 3, 3))
    if quadratic:
        W = 0.5 * k * (J - 1.0) ** 2
        s[:, 2] = k * (J - 1.0)
        K[:, 2, 2] = k
        return W, s, K
    bad = ~(J > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        L = np.log(np.where(bad, 1.0, J))
        W = 0.5 * k * L * L
        s[:, 2] = k * L / J
        K[:, 2, 2] = k * (1.0 - L) / (J * J)
    return _invalid(W, s, K, bad)


@njit
def _ogden_kernel(e, params, W, s, K, with_tangent):
    # W = sum_i phi(l_i) + lmbda/2 (sum_i ln l_i)^2,
    # phi(x) = sum_p mu_p/alpha_p (x^alpha_p - 1 - alpha_p ln x); params = [lmbda, mu_1, a_1, mu_2, a_2, ...]
    lm = params[0]
    nterms = (params.shape[0] - 1) // 2
    n = e.shape[0]
    for q in range(n):
        ok = e[q, 0] > 0.0 and e[q, 1] > 0.0 and e[q, 2] > 0.0
        if not ok:
            W[q] = np.inf
            for a in range(3):
                s[q, a] = np.nan
            if with_tangent:
                for a in range(3):
                    for b in range(3):
                        K[q, a, b] = np.nan
            continue
        L = np.log(e[q, 0]) + np.log(e[q, 1]) + np.log(e[q, 2])
        w = 0.5 * lm * L * L
        for i in range(3):
            x = e[q, i]
            lx = np.log(x)
            d1 = 0.0
            d2 = 0.0
            for p in range(nterms):
                mu = params[1 + 2 * p]
                al = params[2 + 2 * p]
                xa = np.exp(al * lx)
                w += mu / al * (xa - 1.0 - al * lx)
                d1 += mu * (xa - 1.0) / x
                d2 += mu * ((al - 1.0) * xa + 1.0) / (x * x)
            s[q, i] = d1 + lm * L / x
            if with_tangent:
                for j in range(3):
                    K[q, i, j] = lm / (x * e[q, j])
                K[q, i, i] += d2 - lm * L / (x * x)
        W[q] = w


def _ogden_numpy(e, params):
    lm = params[0]
    mus, alphas = params[1::2], params[2::2]
    bad = ~np.all(e > 0, axis=1)
    x = np.where(bad[:, None], 1.0, e)
    lx = np.log(x)
    L = lx.sum(axis=1)
    xa = np.exp(alphas[None, None, :] * lx[:, :, None])  # (n, 3, p)
    W = 0.5 * lm * L * L + np.einsum("p,nip->n", mus / alphas, xa - 1.0 - alphas * lx[:, :, None])
    d1 = np.einsum("p,nip->ni", mus, xa - 1.0) / x
    d2 = np.einsum("p,nip->ni", mus, (alphas - 1.0) * xa + 1.0) / x**2
    s = d1 + lm * L[:, None] / x
    K = lm / (x[:, :, None] * x[:, None, :])
    K = K + (d2 - lm * L[:, None] / x**2)[:, :, None] * np.eye(3)
    return _invalid(W, s, K, bad)
