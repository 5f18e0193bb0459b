"""Compiled kernels of the strain measures; their plain numpy twins are in
:mod:`voxflex.deform.materials._strain_twins`.

Four kernels cover every measure (few kernels keep the compile time down):

* :func:`_tensor_kernel` -- ``linear``, ``green`` and ``corotational-small``
  (polynomial in F, constant second derivative);
* :func:`_corot_kernel` -- ``corotational`` (polar), ``corotational-svd`` and
  ``corotational-qr`` (``F = R M`` with M symmetric or upper triangular);
* :func:`_invariant_kernel` -- ``invariant`` and ``invariant-deviatoric``;
* :func:`_stretch_kernel` -- ``principal-stretch``.

Each kernel fills ``E (n, m)`` and, when asked, ``J (n, m, 3, 3)`` with
``J[e, k, i, j] = dE_k / dF_ij`` and ``G (n, 3, 3, 3, 3)`` with
``G[e, i, j, k, l] = sum_c s_c d2E_c / dF_ij dF_kl``.  The integer ``kind`` /
``method`` arguments are private switches of this module only; the public
names live in :mod:`voxflex.deform.materials.strains`.

Voigt order ``[xx, yy, zz, xy, yz, xz]``; strains carry engineering shear
(``e_xy = E_xy + E_yx``), the conjugate stress vector does not, so the
symmetric stress matrix built from ``s`` has ``S_xy = s_3`` and ``s . e = S : E``.

Corotational derivatives (derivation used by the kernel and its twin)
--------------------------------------------------------------------
Write ``F = R M`` with R orthogonal and M in a linear subspace (symmetric for
polar/SVD, upper triangular for QR).  Along a direction h, with the skew
``Omega = R^T dR``::

    R^T h = Omega M + dM                                   (first order)
    d2M[h1,h2] + Xi M = -1/2 (O1 O2 + O2 O1) M - O1 dM2 - O2 dM1  (second order)

where ``Xi`` is skew.  Both are the same "solve": split ``A`` into
``Omega M + D`` with Omega skew and D in the subspace.

* polar / SVD, in the frame of the right singular vectors V (``M = diag(sig)``):
  ``Omega_pq = (A_pq - A_qp) / (sig_p + sig_q)``,
  ``D_pq = (sig_p A_pq + sig_q A_qp) / (sig_p + sig_q)`` for p != q and
  ``D_pp = A_pp``: only pairs p != q divide, so repeated singular values are
  fine; it fails only when ``sig_p + sig_q = 0`` for some pair (two zero
  singular values, or an inverted F whose flipped value equals minus another).
* QR (``M = T`` upper triangular with positive diagonal): ``X = A T^-1``,
  Omega = strict lower part of X minus its transpose, ``D = (X - Omega) T``;
  fails when F's columns are linearly dependent.

E = sym(M) - I, so ``dE = sym(dM)`` and the geometric term is
``S : d2M[e_ij, e_kl]`` for every pair of basis directions: 45 solves for QR
(:func:`_corot_qr`); for polar / SVD the solves are done in closed form,
reducing the 45 to one 9x9 bilinear form (:func:`_corot_polar`).

The 3x3 SVDs come from :func:`voxflex.deform.materials._svd3._svd3` (Jacobi rotations,
no LAPACK call per sample); the numpy twins keep ``np.linalg.svd`` so that the
tests compare two independent decompositions.
"""

from __future__ import annotations

import numpy as np

from voxflex._jit import chunk_bounds, njit, prange

from ._svd3 import _svd3

# private switches of the kernels below
LINEAR, GREEN, SMALL = 0, 1, 2
POLAR, SVD, QR = 0, 1, 2

_VA = np.array([0, 1, 2, 0, 1, 0])
_VB = np.array([0, 1, 2, 1, 2, 2])


# ----------------------------------------------------------------------------- helpers
@njit(error_model="numpy")
def _stress_matrix(s, S):
    """Symmetric matrix of a Voigt stress vector (no factor 2 on the shear)."""
    for a in range(3):
        S[a, a] = s[a]
    S[0, 1] = S[1, 0] = s[3]
    S[1, 2] = S[2, 1] = s[4]
    S[0, 2] = S[2, 0] = s[5]


@njit(error_model="numpy")
def _det3(A):
    return (
        A[0, 0] * (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1])
        - A[0, 1] * (A[1, 0] * A[2, 2] - A[1, 2] * A[2, 0])
        + A[0, 2] * (A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0])
    )


@njit(error_model="numpy")
def _matmul(A, B, C):
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += A[i, k] * B[k, j]
            C[i, j] = acc


# ----------------------------------------------------------------------------- linear / green / small
@njit(error_model="numpy")
def _tensor_kernel(F, s, kind, want_j, want_g, E, J, G):
    """linear: sym(F) - I; green: (F^T F - I)/2; small: sym((I - W) F) - I, W = skew(F)."""
    n = F.shape[0]
    M = np.empty((3, 3))
    dM = np.empty((3, 3))
    W = np.empty((3, 3))
    S = np.empty((3, 3))
    for e in range(n):
        f = F[e]
        # M is the matrix whose engineering-Voigt symmetric part (minus I) is E
        if kind == LINEAR:
            for a in range(3):
                for b in range(3):
                    M[a, b] = f[a, b]
        elif kind == GREEN:
            for a in range(3):
                for b in range(3):
                    acc = 0.0
                    for i in range(3):
                        acc += f[i, a] * f[i, b]
                    M[a, b] = 0.5 * acc + (0.5 if a == b else 0.0)
        else:
            for a in range(3):
                for b in range(3):
                    W[a, b] = 0.5 * (f[a, b] - f[b, a])
            for a in range(3):
                for b in range(3):
                    acc = f[a, b]
                    for c in range(3):
                        acc -= W[a, c] * f[c, b]
                    M[a, b] = acc
        for k in range(6):
            a, b = _VA[k], _VB[k]
            E[e, k] = M[a, a] - 1.0 if a == b else M[a, b] + M[b, a]
        if want_j:
            for i in range(3):
                for j in range(3):
                    # dM along the basis direction e_ij
                    if kind == LINEAR:
                        for a in range(3):
                            for b in range(3):
                                dM[a, b] = 1.0 if (a == i and b == j) else 0.0
                    elif kind == GREEN:
                        # d(F^T F)/2 = (h^T F + F^T h)/2 with h = e_ij
                        for a in range(3):
                            for b in range(3):
                                v = 0.0
                                if a == j:
                                    v += f[i, b]
                                if b == j:
                                    v += f[i, a]
                                dM[a, b] = 0.5 * v
                    else:
                        # dM = h - skew(h) F - W h
                        for a in range(3):
                            for b in range(3):
                                v = 1.0 if (a == i and b == j) else 0.0
                                if a == i:
                                    v -= 0.5 * f[j, b]
                                if a == j:
                                    v += 0.5 * f[i, b]
                                if b == j:
                                    v -= W[a, i]
                                dM[a, b] = v
                    for k in range(6):
                        a, b = _VA[k], _VB[k]
                        J[e, k, i, j] = dM[a, a] if a == b else dM[a, b] + dM[b, a]
        if want_g:
            _stress_matrix(s[e], S)
            for i in range(3):
                for j in range(3):
                    for k in range(3):
                        for l in range(3):
                            v = 0.0
                            if kind == GREEN:
                                if i == k:
                                    v = S[j, l]
                            elif kind == SMALL:
                                # -S : (skew(e_ij) e_kl + skew(e_kl) e_ij)
                                if i == k:
                                    v += S[j, l]
                                if j == k:
                                    v -= 0.5 * S[i, l]
                                if i == l:
                                    v -= 0.5 * S[k, j]
                            G[e, i, j, k, l] = v


# ----------------------------------------------------------------------------- corotational
@njit(error_model="numpy")
def _corot_solve(A, T, Tinv, Om, D, X):
    """Split A = Om T + D with Om skew and D upper triangular (the QR factor's subspace); see the module
    docstring.  (The polar and SVD variants have closed forms: :func:`_corot_polar`.)"""
    _matmul(A, Tinv, X)
    for p in range(3):
        for q in range(3):
            if p > q:
                Om[p, q] = X[p, q]
            elif p < q:
                Om[p, q] = -X[q, p]
            else:
                Om[p, q] = 0.0
    for p in range(3):
        for q in range(3):
            acc = 0.0
            for r in range(q + 1):  # T upper triangular
                acc += (X[p, r] - Om[p, r]) * T[r, q]
            D[p, q] = acc


@njit(error_model="numpy")
def _corot_qr(F, s, want_j, want_g, E, J, G):
    """E = sym(T) - I with F = R T (Gram-Schmidt), by the generic solves of the module docstring."""
    n = F.shape[0]
    R = np.empty((3, 3))
    T = np.zeros((3, 3))
    Tinv = np.zeros((3, 3))
    A = np.empty((3, 3))
    X = np.empty((3, 3))
    Om = np.empty((9, 3, 3))
    Dm = np.empty((9, 3, 3))
    B = np.empty((3, 3))
    Xi = np.empty((3, 3))
    D2 = np.empty((3, 3))
    S = np.empty((3, 3))
    tmp = np.empty((3, 3))
    for e in range(n):
        f = F[e]
        # modified Gram-Schmidt on the columns: F = R T
        for a in range(3):
            for b in range(3):
                R[a, b] = f[a, b]
                T[a, b] = 0.0
        for c in range(3):
            for d in range(c):
                dot = 0.0
                for a in range(3):
                    dot += R[a, d] * R[a, c]
                T[d, c] = dot
                for a in range(3):
                    R[a, c] -= dot * R[a, d]
            nrm = np.sqrt(R[0, c] ** 2 + R[1, c] ** 2 + R[2, c] ** 2)
            T[c, c] = nrm
            for a in range(3):
                R[a, c] /= nrm
        Tinv[0, 0] = 1.0 / T[0, 0]
        Tinv[1, 1] = 1.0 / T[1, 1]
        Tinv[2, 2] = 1.0 / T[2, 2]
        Tinv[0, 1] = -T[0, 1] / (T[0, 0] * T[1, 1])
        Tinv[1, 2] = -T[1, 2] / (T[1, 1] * T[2, 2])
        Tinv[0, 2] = (T[0, 1] * T[1, 2] - T[0, 2] * T[1, 1]) / (T[0, 0] * T[1, 1] * T[2, 2])
        for k in range(6):
            a, b = _VA[k], _VB[k]
            E[e, k] = T[a, a] - 1.0 if a == b else T[a, b] + T[b, a]
        if not (want_j or want_g):
            continue
        for i in range(3):
            for j in range(3):
                h = 3 * i + j
                # A = R^T e_ij = outer(R[i, :], e_j)
                for a in range(3):
                    for b in range(3):
                        A[a, b] = R[i, a] if b == j else 0.0
                _corot_solve(A, T, Tinv, Om[h], Dm[h], X)
                if want_j:
                    D = Dm[h]
                    for k in range(6):
                        a, b = _VA[k], _VB[k]
                        J[e, k, i, j] = D[a, a] if a == b else D[a, b] + D[b, a]
        if want_g:
            _stress_matrix(s[e], S)
            for h1 in range(9):
                for h2 in range(h1, 9):
                    O1, O2, D1, D2_ = Om[h1], Om[h2], Dm[h1], Dm[h2]
                    for a in range(3):
                        for b in range(3):
                            acc = 0.0
                            for c in range(3):
                                acc += O1[a, c] * O2[c, b] + O2[a, c] * O1[c, b]
                            tmp[a, b] = -0.5 * acc
                    for a in range(3):
                        for b in range(3):
                            acc = 0.0
                            for c in range(3):
                                acc += tmp[a, c] * T[c, b] - O1[a, c] * D2_[c, b] - O2[a, c] * D1[c, b]
                            B[a, b] = acc
                    _corot_solve(B, T, Tinv, Xi, D2, X)
                    v = 0.0
                    for a in range(3):
                        for b in range(3):
                            v += S[a, b] * D2[a, b]
                    G[e, h1 // 3, h1 % 3, h2 // 3, h2 % 3] = v
                    G[e, h2 // 3, h2 % 3, h1 // 3, h1 % 3] = v


@njit(error_model="numpy")
def _corot_polar(F, s, signed, want_j, want_g, E, J, G):
    """E = V diag(sig) V^T - I from the SVD F = U diag(sig) V^T (R = U V^T); closed forms.

    The solves of the module docstring in the frame V, with ``A = outer(U[i], V[j])``
    for the direction ``e_ij``, give per direction the rotation vector ``w``
    (``Omega = [w]x``, ``w_r = Omega[r+2, r+1]``, indices mod 3) and the
    symmetric ``D``; ``J`` is the Voigt vector of ``V D V^T``.  The geometric term
    ``S : d2M[h1, h2]`` reduces to a bilinear form in (w, D)::

        G[h1, h2] = w1 . K w2 - w1 . l(D2) - w2 . l(D1)

    with ``Sh_pp = Sf_pp``, ``Sh_pq = 2 sig_p Sf_pq / (sig_p + sig_q)`` (``Sf = V^T S V``),
    ``K = tr(Y) I - (Y + Y^T) / 2`` for ``Y = diag(sig) Sh^T``, and
    ``l_r(D) = (Sh D)[r+2, r+1] - (Sh D)[r+1, r+2]``
    (from ``[a]x [b]x = b a^T - (a . b) I`` and ``<Sh, [w]x D> = w . l(D)``).
    """
    n = F.shape[0]
    U = np.empty((3, 3))
    V = np.empty((3, 3))
    sig = np.empty(3)
    cinv = np.empty(3)  # 1 / (sig_p + sig_q) for the pair opposite to axis r
    W = np.empty((6, 6))  # J_k = sum_m W[k, m] D_m, D_m in the order 00, 11, 22, 12, 20, 01
    Dv = np.empty((9, 6))
    w = np.empty((9, 3))
    Sf = np.empty((3, 3))
    Sh = np.empty((3, 3))
    K = np.empty((3, 3))
    Kw = np.empty((9, 3))
    ell = np.empty((9, 3))
    SD = np.empty((3, 3))
    tmp = np.empty((3, 3))
    Dm = np.empty((3, 3))
    for e in range(n):
        f = F[e]
        _svd3(f, signed, U, sig, V)
        for k in range(6):
            a, b = _VA[k], _VB[k]
            m = V[a, 0] * sig[0] * V[b, 0] + V[a, 1] * sig[1] * V[b, 1] + V[a, 2] * sig[2] * V[b, 2]
            E[e, k] = m - 1.0 if a == b else 2.0 * m
        if not (want_j or want_g):
            continue
        for r in range(3):
            cinv[r] = 1.0 / (sig[(r + 1) % 3] + sig[(r + 2) % 3])
        if want_j:
            for k in range(6):
                a, b = _VA[k], _VB[k]
                fac = 1.0 if a == b else 2.0
                for p in range(3):
                    W[k, p] = fac * V[a, p] * V[b, p]
                    p1, p2 = (p + 1) % 3, (p + 2) % 3
                    W[k, 3 + p] = fac * (V[a, p1] * V[b, p2] + V[a, p2] * V[b, p1])
        for i in range(3):
            for j in range(3):
                h = 3 * i + j
                for p in range(3):
                    Dv[h, p] = U[i, p] * V[j, p]
                for r in range(3):
                    p, q = (r + 1) % 3, (r + 2) % 3
                    apq = U[i, p] * V[j, q]
                    aqp = U[i, q] * V[j, p]
                    # w_r = Omega[q, p] = (A_qp - A_pq) / (sig_p + sig_q)
                    w[h, r] = (aqp - apq) * cinv[r]
                    Dv[h, 3 + r] = (sig[p] * apq + sig[q] * aqp) * cinv[r]
                if want_j:
                    for k in range(6):
                        acc = 0.0
                        for m in range(6):
                            acc += W[k, m] * Dv[h, m]
                        J[e, k, i, j] = acc
        if not want_g:
            continue
        _stress_matrix(s[e], Sf)
        _matmul(Sf, V, tmp)
        for a in range(3):
            for b in range(a, 3):
                acc = 0.0
                for c in range(3):
                    acc += V[c, a] * tmp[c, b]
                Sf[a, b] = acc
                Sf[b, a] = acc
        trY = sig[0] * Sf[0, 0] + sig[1] * Sf[1, 1] + sig[2] * Sf[2, 2]
        for a in range(3):
            Sh[a, a] = Sf[a, a]
            K[a, a] = trY - sig[a] * Sf[a, a]
        for r in range(3):
            p, q = (r + 1) % 3, (r + 2) % 3
            Sh[p, q] = 2.0 * sig[p] * Sf[p, q] * cinv[r]
            Sh[q, p] = 2.0 * sig[q] * Sf[p, q] * cinv[r]
            K[p, q] = K[q, p] = -2.0 * sig[p] * sig[q] * Sf[p, q] * cinv[r]
        for h in range(9):
            for r in range(3):
                Kw[h, r] = K[r, 0] * w[h, 0] + K[r, 1] * w[h, 1] + K[r, 2] * w[h, 2]
            for p in range(3):
                Dm[p, p] = Dv[h, p]
            for r in range(3):
                p, q = (r + 1) % 3, (r + 2) % 3
                Dm[p, q] = Dm[q, p] = Dv[h, 3 + r]
            for a in range(3):
                for b in range(3):
                    if a != b:
                        SD[a, b] = Sh[a, 0] * Dm[0, b] + Sh[a, 1] * Dm[1, b] + Sh[a, 2] * Dm[2, b]
            for r in range(3):
                p, q = (r + 1) % 3, (r + 2) % 3
                ell[h, r] = SD[q, p] - SD[p, q]
        for h1 in range(9):
            for h2 in range(h1, 9):
                v = 0.0
                for r in range(3):
                    v += w[h2, r] * Kw[h1, r] - w[h1, r] * ell[h2, r] - w[h2, r] * ell[h1, r]
                G[e, h1 // 3, h1 % 3, h2 // 3, h2 % 3] = v
                G[e, h2 // 3, h2 % 3, h1 // 3, h1 % 3] = v


@njit(error_model="numpy")
def _corot_kernel(F, s, method, want_j, want_g, E, J, G):
    """E = sym(R^T F) - I with R from the polar decomposition, the signed SVD or QR."""
    if method == QR:
        _corot_qr(F, s, want_j, want_g, E, J, G)
    else:
        _corot_polar(F, s, method == SVD, want_j, want_g, E, J, G)


# ----------------------------------------------------------------------------- invariants
@njit(error_model="numpy")
def _invariants_of(f, C):  # pragma: no cover - compiled
    """(I1, I2, J) of one F ``f``, with ``C = f^T f`` written into C (the invariant kernels' common start)."""
    for a in range(3):
        for b in range(3):
            C[a, b] = f[0, a] * f[0, b] + f[1, a] * f[1, b] + f[2, a] * f[2, b]
    I1 = C[0, 0] + C[1, 1] + C[2, 2]
    trC2 = 0.0
    for a in range(3):
        for b in range(3):
            trC2 += C[a, b] * C[a, b]
    return I1, 0.5 * (I1 * I1 - trC2), _det3(f)


@njit(error_model="numpy")
def _scalings(Jd, deviatoric):  # pragma: no cover - compiled
    """(c1, c2, c1', c2', c1'', c2'') of the invariant strains: ``c = J^p`` with p = -2/3, -4/3 when
    deviatoric (real cube root: defined for J < 0 too), c' = p c / J, c'' = p (p - 1) c / J^2; else 1 and 0."""
    if not deviatoric:
        return 1.0, 1.0, 0.0, 0.0, 0.0, 0.0
    cr = np.cbrt(Jd)
    c1 = 1.0 / (cr * cr)
    c2 = c1 * c1
    return (c1, c2, -2.0 / 3.0 * c1 / Jd, -4.0 / 3.0 * c2 / Jd, (-2.0 / 3.0) * (-5.0 / 3.0) * c1 / (Jd * Jd),
            (-4.0 / 3.0) * (-7.0 / 3.0) * c2 / (Jd * Jd))


@njit(error_model="numpy")
def _invariant_kernel(F, s, deviatoric, want_j, want_g, E, J, G):
    """(I1, I2, J) of C = F^T F, or (J^-2/3 I1, J^-4/3 I2, J) when deviatoric."""
    n = F.shape[0]
    C = np.empty((3, 3))
    Bm = np.empty((3, 3))
    FC = np.empty((3, 3))
    g1 = np.empty((3, 3))
    g2 = np.empty((3, 3))
    g3 = np.empty((3, 3))
    for e in range(n):
        f = F[e]
        I1, I2, Jd = _invariants_of(f, C)
        if not (want_j or want_g):  # the strain alone (energy, line-search trials): no derivative below
            c1, c2 = _scalings(Jd, deviatoric)[:2]
            E[e, 0] = c1 * I1
            E[e, 1] = c2 * I2
            E[e, 2] = Jd
            continue
        _matmul(f, C, FC)
        if want_g:
            for a in range(3):
                for b in range(3):
                    Bm[a, b] = f[a, 0] * f[b, 0] + f[a, 1] * f[b, 1] + f[a, 2] * f[b, 2]
        # cofactor = dJ/dF
        for i in range(3):
            for j in range(3):
                i1, i2 = (i + 1) % 3, (i + 2) % 3
                j1, j2 = (j + 1) % 3, (j + 2) % 3
                g3[i, j] = f[i1, j1] * f[i2, j2] - f[i1, j2] * f[i2, j1]
                g1[i, j] = 2.0 * f[i, j]
                g2[i, j] = 2.0 * I1 * f[i, j] - 2.0 * FC[i, j]
        c1, c2, d1, d2, dd1, dd2 = _scalings(Jd, deviatoric)
        E[e, 0] = c1 * I1
        E[e, 1] = c2 * I2
        E[e, 2] = Jd
        if want_j:
            for i in range(3):
                for j in range(3):
                    J[e, 0, i, j] = c1 * g1[i, j] + d1 * I1 * g3[i, j]
                    J[e, 1, i, j] = c2 * g2[i, j] + d2 * I2 * g3[i, j]
                    J[e, 2, i, j] = g3[i, j]
        if want_g:
            s1, s2, s3 = s[e, 0], s[e, 1], s[e, 2]
            w1 = s1 * c1  # weight of d2 I1
            w2 = s2 * c2  # weight of d2 I2
            w3 = s3 + s1 * d1 * I1 + s2 * d2 * I2  # weight of d2 J
            a13 = s1 * d1
            a23 = s2 * d2
            a33 = s1 * dd1 * I1 + s2 * dd2 * I2
            # rank-one and rank-two parts, written into all 81 entries (flat 9-vectors: ij = 3 i + j)
            full = w2 != 0.0 or a23 != 0.0  # I2 enters (neo-Hooke's laws leave it out: s2 = 0)
            for ij in range(9):
                i, j = ij // 3, ij % 3
                u3 = g3[i, j]
                u1 = g1[i, j]
                for kl in range(9):
                    k, l = kl // 3, kl % 3
                    G[e, i, j, k, l] = a33 * u3 * g3[k, l] + a13 * (u3 * g1[k, l] + u1 * g3[k, l])
                if full:
                    u2 = g2[i, j]
                    fij = f[i, j]
                    for kl in range(9):
                        k, l = kl // 3, kl % 3
                        G[e, i, j, k, l] += (a23 * (u3 * g2[k, l] + u2 * g3[k, l])
                                             + w2 * (4.0 * fij * f[k, l] - 2.0 * f[i, l] * f[k, j]))
            # delta terms: d2 I1 = 2 dik djl; d2 I2 adds 2 I1 dik djl - 2 dik C_lj - 2 B_ik djl
            diag = 2.0 * w1 + 2.0 * w2 * I1
            for i in range(3):
                for j in range(3):
                    G[e, i, j, i, j] += diag
            if w2 != 0.0:
                for i in range(3):
                    for j in range(3):
                        for l in range(3):
                            G[e, i, j, i, l] -= 2.0 * w2 * C[l, j]
                        for k in range(3):
                            G[e, i, j, k, j] -= 2.0 * w2 * Bm[i, k]
            # d2 J / dF_ij dF_kl = eps_ikm eps_jlq F_mq (i != k, j != l; eps_ikm = +1 when k = i + 1 mod 3)
            if w3 != 0.0:
                for i in range(3):
                    for k in range(3):
                        if i == k:
                            continue
                        m = 3 - i - k
                        si = w3 if (k - i) % 3 == 1 else -w3
                        for j in range(3):
                            for l in range(3):
                                if j == l:
                                    continue
                                q = 3 - j - l
                                sj = si if (l - j) % 3 == 1 else -si
                                G[e, i, j, k, l] += sj * f[m, q]


# ----------------------------------------------------------------------------- principal stretches

@njit(error_model="numpy")
def _invariant_vjp_kernel(F, s, deviatoric, P):  # pragma: no cover - compiled
    """``P = sum_k s_k dE_k/dF`` (n, 3, 3) of the invariant strains without their Jacobian (27 numbers a
    sample written and read again by the chain rule): the stress of a law's ``s = dW/dE`` in one pass.

    With ``g1 = 2 F``, ``g2 = 2 I1 F - 2 F C`` and ``g3 = cof F`` (the derivatives of I1, I2, J) and the
    scalings of :func:`_invariant_kernel`: ``P = (2 s1 c1 + 2 s2 c2 I1) F - 2 s2 c2 F C + (s3 + s1 d1 I1 +
    s2 d2 I2) cof F``; ``F C`` only where the law reads I2 (``s2 != 0``)."""
    n = F.shape[0]
    C = np.empty((3, 3))
    for e in range(n):
        f = F[e]
        I1, I2, Jd = _invariants_of(f, C)
        c1, c2, d1, d2, _, _ = _scalings(Jd, deviatoric)
        s1, s2, s3 = s[e, 0], s[e, 1], s[e, 2]
        cf = 2.0 * s1 * c1 + 2.0 * s2 * c2 * I1
        cc = s3 + s1 * d1 * I1 + s2 * d2 * I2
        cb = -2.0 * s2 * c2
        for i in range(3):
            i1, i2 = (i + 1) % 3, (i + 2) % 3
            for j in range(3):
                j1, j2 = (j + 1) % 3, (j + 2) % 3
                v = cf * f[i, j] + cc * (f[i1, j1] * f[i2, j2] - f[i1, j2] * f[i2, j1])
                if s2 != 0.0:
                    v += cb * (f[i, 0] * C[0, j] + f[i, 1] * C[1, j] + f[i, 2] * C[2, j])
                P[e, i, j] = v


@njit(error_model="numpy")
def _stretch_kernel(F, s, gap, want_j, want_g, E, J, G, K):
    """Singular values of F (descending); ``gap`` is the relative floor of divided differences.

    ``K`` (n, 3, 3) is the law's tangent ds/dsig, or an empty (0, 3, 3) array: when given,
    pairs closer than the floor use the limit ``(K_pp + K_qq)/2 - (K_pq + K_qp)/2`` of
    ``(s_p - s_q)/(sig_p - sig_q)`` (exact for laws symmetric in the stretches).
    """
    n = F.shape[0]
    use_k = K.shape[0] > 0
    u = np.empty((3, 3))
    sv = np.empty(3)
    v = np.empty((3, 3))
    vh = np.empty((3, 3))
    for e in range(n):
        _svd3(F[e], False, u, sv, v)
        for a in range(3):
            for b in range(3):
                vh[a, b] = v[b, a]
        for k in range(3):
            E[e, k] = sv[k]
        if want_j:
            for k in range(3):
                for i in range(3):
                    for j in range(3):
                        J[e, k, i, j] = u[i, k] * vh[k, j]
        if want_g:
            floor = gap * max(sv[0], 1e-300)
            for i in range(3):
                for j in range(3):
                    for k in range(3):
                        for l in range(3):
                            G[e, i, j, k, l] = 0.0
            for p in range(3):
                for q in range(3):
                    if p == q:
                        continue
                    # sorted descending: sig_p - sig_q >= 0 for p < q; keep |dm| >= floor
                    dm = sv[p] - sv[q]
                    if p < q:
                        dm = max(dm, floor)
                    else:
                        dm = min(dm, -floor)
                    dp = max(sv[p] + sv[q], floor)
                    if use_k and abs(sv[p] - sv[q]) <= floor:
                        alpha = 0.5 * (K[e, p, p] + K[e, q, q] - K[e, p, q] - K[e, q, p])
                    else:
                        alpha = (s[e, p] - s[e, q]) / dm
                    beta = (s[e, p] + s[e, q]) / dp
                    dg = 0.5 * (alpha + beta)  # coefficient of a_pq a_pq
                    od = 0.5 * (alpha - beta)  # coefficient of a_pq a_qp
                    # a_pq = sum_ij U_ip V_jq F_ij with V_jq = vh[q, j]
                    for i in range(3):
                        for j in range(3):
                            x = u[i, p] * vh[q, j]
                            if x == 0.0:
                                continue
                            for k in range(3):
                                for l in range(3):
                                    G[e, i, j, k, l] += x * (dg * u[k, p] * vh[q, l] + od * u[k, q] * vh[p, l])


# ----------------------------------------------------------------------------- large batches
TENSOR, COROT, INVARIANT, STRETCH = 0, 1, 2, 3


@njit(parallel=True)
def chunked_strain(family, F, s, switch, gap, want_j, want_g, E, J, G, K, chunks):  # pragma: no cover
    """The kernel of ``family`` (``TENSOR`` ... ``STRETCH``) over ``chunks`` slices of the samples on numba's
    threads: every sample is independent, so the bits equal one serial pass.  ``switch`` is the int switch
    of the first three, ``gap`` the stretch kernel's; arrays a flag leaves out stay empty."""
    for c in prange(chunks):
        a, b = chunk_bounds(F.shape[0], chunks, c)
        sc = s[a:b] if want_g else s[0:0]
        Jc = J[a:b] if want_j else J[0:0]
        Gc = G[a:b] if want_g else G[0:0]
        if family == TENSOR:
            _tensor_kernel(F[a:b], sc, switch, want_j, want_g, E[a:b], Jc, Gc)
        elif family == COROT:
            _corot_kernel(F[a:b], sc, switch, want_j, want_g, E[a:b], Jc, Gc)
        elif family == INVARIANT:
            _invariant_kernel(F[a:b], sc, switch, want_j, want_g, E[a:b], Jc, Gc)
        else:
            _stretch_kernel(F[a:b], sc, gap, want_j, want_g, E[a:b], Jc, Gc, K[a:b] if K.shape[0] > 0 else K[0:0])



@njit(parallel=True)
def chunked_invariant_vjp(F, s, switch, P, chunks):  # pragma: no cover - compiled
    """:func:`_invariant_vjp_kernel` over ``chunks`` slices on numba's threads (the same bits as one pass)."""
    for c in prange(chunks):
        a, b = chunk_bounds(F.shape[0], chunks, c)
        _invariant_vjp_kernel(F[a:b], s[a:b], switch, P[a:b])
