"""Strain measures: hand-computed values, invariances, kernel == numpy twin, gradients (elastons).

Derivatives against finite differences are checked by the shared contract
(tests/contract_strains.py); here: values and properties.
"""

from __future__ import annotations

import numpy as np
import pytest
from contract import MappingCase, check_mapping  # noqa: E402
from contract_strains import _rotation, sample_F  # noqa: E402

import voxflex.deform.materials.strains as vs
from voxflex.errors import InputError  # noqa: E402

# the fixed non-trivial F of the hand computations
F_HAND = np.array([[1.1, 0.2, 0.0], [0.0, 0.9, 0.1], [0.05, 0.0, 1.2]])
# the hand values are exact decimals (or sqrt formulas) evaluated to 16 digits: 1e-12 allows round-off only
HAND_TOL = 1e-12


def test_linear_by_hand():
    # sym(F) - I: diag 1.1-1, 0.9-1, 1.2-1; shears F01+F10 = 0.2+0, F12+F21 = 0.1+0, F02+F20 = 0+0.05
    expected = [0.1, -0.1, 0.2, 0.2, 0.1, 0.05]
    np.testing.assert_allclose(vs.strain("linear", F_HAND), expected, rtol=0, atol=HAND_TOL)


def test_green_by_hand():
    # columns f0 = (1.1, 0, 0.05), f1 = (0.2, 0.9, 0), f2 = (0, 0.1, 1.2); C_ab = f_a . f_b:
    # C00 = 1.21 + 0.0025 = 1.2125, C11 = 0.04 + 0.81 = 0.85, C22 = 0.01 + 1.44 = 1.45,
    # C01 = 1.1*0.2 = 0.22, C12 = 0.9*0.1 = 0.09, C02 = 0.05*1.2 = 0.06
    # E = (C - I)/2 -> diag 0.10625, -0.075, 0.225; engineering shear 2 E_ab = C_ab
    expected = [0.10625, -0.075, 0.225, 0.22, 0.09, 0.06]
    np.testing.assert_allclose(vs.strain("green", F_HAND), expected, rtol=0, atol=HAND_TOL)


def test_invariants_by_hand():
    # I1 = 1.2125 + 0.85 + 1.45 = 3.5125
    # I2 = sum of the principal 2x2 minors of C
    #    = (1.2125*0.85 - 0.22^2) + (0.85*1.45 - 0.09^2) + (1.2125*1.45 - 0.06^2)
    #    = 0.982225 + 1.2244 + 1.754525 = 3.96115
    # J = 1.1*(0.9*1.2 - 0.1*0) - 0.2*(0*1.2 - 0.1*0.05) + 0 = 1.188 + 0.001 = 1.189
    np.testing.assert_allclose(vs.strain("invariant", F_HAND), [3.5125, 3.96115, 1.189], rtol=0, atol=HAND_TOL)
    # deviatoric: 1.189^(-2/3) * 3.5125 and 1.189^(-4/3) * 3.96115
    np.testing.assert_allclose(
        vs.strain("invariant-deviatoric", F_HAND),
        [1.189 ** (-2 / 3) * 3.5125, 1.189 ** (-4 / 3) * 3.96115, 1.189],
        rtol=1e-14,  # pow and cbrt differ in the last bits only
    )


def test_corotational_small_by_hand():
    # W = skew(F) = [[0, .1, -.025], [-.1, 0, .05], [.025, -.05, 0]]
    # W F rows: (-0.00125, 0.09, -0.02), (-0.1075, -0.02, 0.06), (0.0275, -0.04, -0.005)
    # M = F - W F = [[1.10125, 0.11, 0.02], [0.1075, 0.92, 0.04], [0.0225, 0.04, 1.205]]
    # E: diag M - 1; shears M01+M10 = 0.2175, M12+M21 = 0.08, M02+M20 = 0.0425
    expected = [0.10125, -0.08, 0.205, 0.2175, 0.08, 0.0425]
    np.testing.assert_allclose(vs.strain("corotational-small", F_HAND), expected, rtol=0, atol=HAND_TOL)


def test_corotational_qr_by_hand():
    # Gram-Schmidt F = R T is the Cholesky factor of C = T^T T:
    # T00 = sqrt(1.2125) = 1.1011357772772620, T01 = 0.22/T00 = 0.19979370804205990,
    # T02 = 0.06/T00 = 0.054489193102379970, T11 = sqrt(0.85 - T01^2) = 0.90004581784862710,
    # T12 = (0.09 - T01 T02)/T11 = 0.087899305227549250, T22 = sqrt(1.45 - T02^2 - T12^2) = 1.1997102316707837
    # E = sym(T) - I with engineering shear T_ab (T is upper triangular)
    expected = [0.1011357772772620, -0.0999541821513729, 0.1997102316707837,
                0.1997937080420599, 0.0878993052275493, 0.0544891931023800]
    np.testing.assert_allclose(vs.strain("corotational-qr", F_HAND), expected, rtol=0, atol=HAND_TOL)


@pytest.mark.parametrize("name", ["corotational", "corotational-svd"])
def test_corotational_polar_by_hand(name):
    # F = Q U with Q a rotation of 30 deg about z and U symmetric positive definite: E = U - I
    # U = [[1.2, 0.1, 0], [0.1, 0.9, 0], [0, 0, 1.1]] -> E = [0.2, -0.1, 0.1, 2*0.1, 0, 0]
    c, s = np.cos(np.pi / 6), np.sin(np.pi / 6)
    Q = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    U = np.array([[1.2, 0.1, 0.0], [0.1, 0.9, 0.0], [0.0, 0.0, 1.1]])
    np.testing.assert_allclose(vs.strain(name, Q @ U), [0.2, -0.1, 0.1, 0.2, 0.0, 0.0], rtol=0, atol=HAND_TOL)
    # on the hand F: (E + I)^2 = C = F^T F (U is the square root of C)
    E = vs.strain(name, F_HAND)
    Um = np.diag(E[:3] + 1) + np.array([[0, E[3], E[5]], [E[3], 0, E[4]], [E[5], E[4], 0]]) / 2
    np.testing.assert_allclose(Um @ Um, F_HAND.T @ F_HAND, rtol=0, atol=HAND_TOL)


def test_principal_stretches_of_rotated_diagonal():
    R, Q = _rotation([0.3, -1.2, 2.0]), _rotation([-1.0, 0.4, 0.7])
    # singular values are exact to a few ulps of the largest one
    np.testing.assert_allclose(vs.strain("principal-stretch", R @ np.diag([2.0, 4.0, 6.0]) @ Q.T), [6, 4, 2], atol=1e-13)


def test_signed_svd_inverted_and_flat():
    R, Q = _rotation([0.3, -1.2, 2.0]), _rotation([-1.0, 0.4, 0.7])
    st = vs.get_strain("corotational-svd")
    # inverted: the reflection goes into the smallest singular value: E = Q diag(3-1, 2-1, -0.5-1) Q^T
    F = R @ np.diag([3.0, 2.0, -0.5]) @ Q.T
    E = st.apply(F)
    Em = Q @ np.diag([2.0, 1.0, -1.5]) @ Q.T
    np.testing.assert_allclose(E, [Em[0, 0], Em[1, 1], Em[2, 2], 2 * Em[0, 1], 2 * Em[1, 2], 2 * Em[0, 2]], atol=1e-13)
    # flat F (sig_3 = 0): E and its Jacobian stay finite and J matches central differences through the flat state
    Ff = R @ np.diag([1.5, 1.0, 0.0]) @ Q.T
    J = st.jacobian(Ff)
    rng = np.random.default_rng(0)
    v = rng.standard_normal((3, 3))
    h = 1e-6
    fd = (st.apply(Ff + h * v) - st.apply(Ff - h * v)) / (2 * h)
    # O(h^2) truncation + O(1e-16/h) round-off -> 1e-8 relative is a safe, still tight bound
    np.testing.assert_allclose(np.einsum("kij,ij->k", J, v), fd, rtol=0, atol=1e-8 * np.abs(fd).max())


@pytest.mark.parametrize("name", ["corotational", "corotational-svd"])
@pytest.mark.parametrize("sig", [(1.2, 1.2, 0.9), (1.0, 1.0, 1.0), (1.3, 0.8, 0.8), (1.5, 1.0, -0.5)])
def test_corotational_derivatives_at_repeated_singular_values(name, sig):
    # the closed-form J and G divide by sig_p + sig_q only, so they stay exact where singular values
    # coincide (where the SVD itself is not unique); the last case is inverted (signed SVD only:
    # for polar it is a reflection with singular values (1.5, 1, 0.5), also smooth)
    st = vs.get_strain(name)
    R, Q = _rotation([0.3, -1.2, 2.0]), _rotation([-1.0, 0.4, 0.7])
    F = R @ np.diag(sig) @ Q.T
    rng = np.random.default_rng(4)
    s, v = rng.standard_normal(6), rng.standard_normal((3, 3))
    E, J, G = st.evaluate(F, s)
    h = 1e-6
    fd_e = (st.apply(F + h * v) - st.apply(F - h * v)) / (2 * h)
    jts = [np.einsum("kij,k->ij", st.jacobian(F + t * v), s) for t in (h, -h)]  # J^T s at F +- h v
    fd_g = (jts[0] - jts[1]) / (2 * h)
    # central differences: O(h^2) truncation + O(1e-16/h) round-off ~ 1e-10; 1e-7 relative is safe and still
    # catches any wrong term (those give O(1) errors)
    np.testing.assert_allclose(np.einsum("kij,ij->k", J, v), fd_e, rtol=0, atol=1e-7 * np.abs(fd_e).max())
    np.testing.assert_allclose(np.einsum("ijkl,kl->ij", G, v), fd_g, rtol=0, atol=1e-7 * np.abs(fd_g).max())


REST = {"invariant": [3, 3, 1], "invariant-deviatoric": [3, 3, 1], "principal-stretch": [1, 1, 1]}


@pytest.mark.parametrize("name", list(vs.STRAINS))
def test_rest_state(name):
    st = vs.STRAINS[name]
    expected = REST.get(name, np.zeros(6))
    np.testing.assert_allclose(st.apply(np.eye(3)[None])[0], expected, rtol=0, atol=1e-15)


RIGID = ["green", "corotational", "corotational-svd", "corotational-qr", "invariant", "invariant-deviatoric",
         "principal-stretch"]


@pytest.mark.parametrize("name", RIGID)
def test_rigid_invariance(name):
    F = sample_F(inverted=name != "corotational")  # polar: the reflection branch is checked in the contract
    Q = np.stack([_rotation(v) for v in np.random.default_rng(5).standard_normal((F.shape[0], 3)) * 2])
    st = vs.STRAINS[name]
    E0, E1 = st.apply(F), st.apply(Q @ F)
    # rotations change the arithmetic, not the value: round-off of a few ulps of |E| + 1
    np.testing.assert_allclose(E1, E0, rtol=0, atol=1e-13 * (1 + np.abs(E0).max()))


def test_small_rotation_variant_is_second_order():
    # corotational-small is exact to first order in the rotation: E(rotation theta) = O(theta^2)
    st = vs.get_strain("corotational-small")
    norms = [np.abs(st.apply(_rotation([t, 0.5 * t, -t]))).max() for t in (1e-2, 5e-3)]
    assert 3.9 < norms[0] / norms[1] < 4.1  # halving theta divides the error by 4


@pytest.mark.parametrize("name", list(vs.STRAINS))
def test_kernel_matches_numpy_twin(name):
    st = vs.STRAINS[name]
    F = sample_F(inverted=name != "principal-stretch")
    s = np.random.default_rng(1).standard_normal((F.shape[0], st.size))
    got, ref = st.evaluate(F, s), st.evaluate_reference(F, s)
    for a, b in zip(got, ref):
        # same formulas, different evaluation order: relative 1e-12 of the largest entry
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * max(np.abs(b).max(), 1.0))
    # geometric term is symmetric in (ij) <-> (kl) (the kernels fill it symmetrically or by formula)
    G = got[2]
    assert np.abs(G - G.transpose(0, 3, 4, 1, 2)).max() <= 1e-13 * np.abs(G).max()
    # evaluate == separate methods
    np.testing.assert_array_equal(st.apply(F), got[0])
    np.testing.assert_array_equal(st.jacobian(F), got[1])
    np.testing.assert_array_equal(st.geometric(F, s), got[2])


def test_validation():
    with pytest.raises(InputError, match="valid: .*green"):
        vs.get_strain("gren")
    with pytest.raises(InputError, match="shape"):
        vs.strain("green", np.eye(2))
    with pytest.raises(InputError, match="finite"):
        vs.strain("green", np.full((1, 3, 3), np.nan))
    assert vs.strain("green", np.eye(3)).shape == (6,)
    assert vs.strain("invariant", np.stack([np.eye(3)] * 4)).shape == (4, 3)
    assert vs.STRAINS["corotational-qr"].kind == "tensor" and vs.STRAINS["invariant"].kind == "invariant"


# ----------------------------------------------------------------------------- F with gradient
GRAD = ["linear", "green", "corotational-small"]


def _pack(F, dF):
    return np.concatenate([F[..., None], dF], axis=-1)  # (n, 3, 3, 4)


def _grad_case(name):
    st = vs.STRAINS[name]
    rng = np.random.default_rng(7)
    F = sample_F()
    x0 = _pack(F, 0.3 * rng.standard_normal(F.shape + (3,)))

    def apply(x):
        E, dE = vs.apply_with_gradient(st, x[..., 0], x[..., 1:])
        return np.concatenate([E[..., None], dE], axis=-1)  # (n, m, 4)

    def jvp(x, v):
        J, K = vs.jacobian_with_gradient(st, x[..., 0], x[..., 1:])
        y0 = np.einsum("nkij,nij->nk", J, v[..., 0])
        ya = np.einsum("nkapq,npq->nka", K, v[..., 0]) + np.einsum("nkij,nija->nka", J, v[..., 1:])
        return np.concatenate([y0[..., None], ya], axis=-1)

    def vjp(x, u):
        J, K = vs.jacobian_with_gradient(st, x[..., 0], x[..., 1:])
        gF = np.einsum("nkij,nk->nij", J, u[..., 0]) + np.einsum("nkapq,nka->npq", K, u[..., 1:])
        gd = np.einsum("nkij,nka->nija", J, u[..., 1:])
        return _pack(gF, gd)

    def geometric(x, u, v):
        GFF, GFd = vs.geometric_with_gradient(st, x[..., 0], x[..., 1:], u[..., 0], u[..., 1:])
        gF = np.einsum("nijkl,nkl->nij", GFF, v[..., 0]) + np.einsum("nijklb,nklb->nij", GFd, v[..., 1:])
        gd = np.einsum("nijklb,nij->nklb", GFd, v[..., 0])
        return _pack(gF, gd)

    return MappingCase(name=f"strain-gradient-{name}", x0=x0, apply=apply, jvp=jvp, vjp=vjp, geometric=geometric)


@pytest.mark.parametrize("name", GRAD)
def test_gradient_contract(name):
    # same checks and tolerances as tests/contract.py (central differences, rtol 1e-6)
    check_mapping(_grad_case(name))


@pytest.mark.parametrize("name", ["corotational", "invariant", "principal-stretch"])
def test_gradient_apply_and_jacobian_any_measure(name):
    # E and dE exist for every measure; check dE against central differences of E along x_a and
    # the Jacobian block K against central differences of dE w.r.t. F (rtol 1e-6 as in the contract)
    st = vs.STRAINS[name]
    rng = np.random.default_rng(2)
    F = sample_F()
    dF = rng.standard_normal(F.shape + (3,))
    E, dE = vs.apply_with_gradient(st, F, dF)
    h = 1e-6
    for a in range(3):
        fd = (st.apply(F + h * dF[..., a]) - st.apply(F - h * dF[..., a])) / (2 * h)
        np.testing.assert_allclose(dE[..., a], fd, rtol=0, atol=1e-6 * np.abs(fd).max())
    J, K = vs.jacobian_with_gradient(st, F, dF)
    v = rng.standard_normal(F.shape)
    fd = (vs.apply_with_gradient(st, F + h * v, dF)[1] - vs.apply_with_gradient(st, F - h * v, dF)[1]) / (2 * h)
    np.testing.assert_allclose(np.einsum("nkapq,npq->nka", K, v), fd, rtol=0, atol=1e-6 * np.abs(fd).max())
    with pytest.raises(NotImplementedError, match="third derivatives"):
        vs.geometric_with_gradient(st, F, dF, E, dE)


# ----------------------------------------------------------------------------- principal stretch + law tangent
def _stretch_law(sig):
    """psi = mu sum (sig_i - 1)^2 + lam/2 (sum sig_i - 3)^2, symmetric in the stretches: (s, K) = (dpsi, d2psi)."""
    mu, lam = 1.0, 2.0
    s = 2 * mu * (sig - 1) + lam * (sig.sum(axis=-1, keepdims=True) - 3)
    K = np.broadcast_to(2 * mu * np.eye(3) + lam, sig.shape[:-1] + (3, 3)).copy()
    return s, K


@pytest.mark.parametrize("sig", [(1.0, 1.0, 1.0), (1.2, 1.2, 0.9), (1.3, 0.8, 0.8), (1.4, 1.0, 0.7)])
def test_stretch_geometric_with_law_tangent(sig):
    # the full tangent A = J^T K J + G(s, K) of P(F) = sum_k s_k(sig) dsig_k/dF must match central differences
    # of P, also where stretches coincide (P is smooth there for a symmetric law, the split is not)
    st = vs.get_strain("principal-stretch")
    R, Q = _rotation([0.3, -1.2, 2.0]), _rotation([-1.0, 0.4, 0.7])
    F = R @ np.diag(sig) @ Q.T

    def P(F):
        e, J = st.evaluate(F)
        return np.einsum("k,kij->ij", _stretch_law(e)[0], J)

    e, J = st.evaluate(F)
    s, K = _stretch_law(e)
    G = st.geometric(F, s, law_tangent=K)
    A = np.einsum("kij,kl,lmn->ijmn", J, K, J) + G
    v = np.random.default_rng(6).standard_normal((3, 3))
    h = 1e-6
    fd = (P(F + h * v) - P(F - h * v)) / (2 * h)
    # O(h^2) truncation + round-off / h ~ 1e-10; a missing coincident-pair term is O(1)
    np.testing.assert_allclose(np.einsum("ijkl,kl->ij", A, v), fd, rtol=0, atol=1e-7 * np.abs(fd).max())
    # kernel == numpy twin (LAPACK SVD) with the tangent too; compared on the full tangent A, since J and G
    # alone depend on the basis chosen inside a repeated singular value, their sum does not (same
    # formulas, different bases and rounding: 1e-12 relative)
    er, Jr, Gr = st.evaluate_reference(F, s, law_tangent=K)
    Ar = np.einsum("kij,kl,lmn->ijmn", Jr, _stretch_law(er)[1], Jr) + Gr
    np.testing.assert_allclose(A, Ar, rtol=0, atol=1e-12 * np.abs(Ar).max())
    # separated stretches do not use the law's tangent at all
    if len(set(sig)) == 3:
        np.testing.assert_array_equal(G, st.geometric(F, s))
    else:  # without the law's tangent the coincident pairs lose their shear stiffness: visibly wrong
        A0 = np.einsum("kij,kl,lmn->ijmn", J, K, J) + st.geometric(F, s)
        assert np.abs(np.einsum("ijkl,kl->ij", A0, v) - fd).max() > 1e-2 * np.abs(fd).max()
    with pytest.raises(InputError, match="law_tangent"):
        st.geometric(F, s, law_tangent=np.eye(2))


@pytest.mark.parametrize("name", sorted(vs.STRAINS))
def test_large_batches_run_in_chunks_with_the_serial_bits(name, monkeypatch):
    """Batches of at least two chunks run on numba's threads (``chunked_strain``): values, Jacobians and
    geometric terms equal one serial pass bit for bit (every sample is independent)."""
    st = vs.STRAINS[name]
    rng = np.random.default_rng(11)
    F = np.eye(3) + 0.2 * rng.standard_normal((257, 3, 3))
    s = rng.standard_normal((257, st.size))
    serial = st.evaluate(F, s)
    monkeypatch.setattr(vs, "CHUNK_SAMPLES", 16)
    chunked = st.evaluate(F, s)
    for a, b in zip(serial, chunked):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("name", sorted(vs.STRAINS))
def test_vjp_is_the_jacobian_contracted_with_s(name, monkeypatch):
    """``vjp(F, s) = sum_k s_k dE_k/dF``: the invariant strains by a kernel of their own (no Jacobian formed),
    the others by the contraction; equal to round-off (1e-12 of the largest entry), inverted F included, and
    the chunked pass equal to the serial one bit for bit.  The strain alone (``apply``) keeps the bits of the
    pass with derivatives (it skips them)."""
    st = vs.STRAINS[name]
    F = sample_F(inverted=name != "principal-stretch")
    rng = np.random.default_rng(5)
    s = rng.standard_normal((F.shape[0], st.size))
    if st.kind.startswith("invariant"):
        s[::3, 1] = 0.0  # the laws that leave I2 out (neo-Hooke): the kernel skips F C there
    ref = np.einsum("nk,nkij->nij", s, st.jacobian(F))
    got = st.vjp(F, s)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12 * max(np.abs(ref).max(), 1.0))
    np.testing.assert_allclose(st.vjp(F[0], s[0]), ref[0], rtol=0, atol=1e-12 * max(np.abs(ref[0]).max(), 1.0))
    assert st.compiled_vjp == (st.family == "invariant")
    np.testing.assert_array_equal(st.apply(F), st.evaluate(F)[0])
    with pytest.raises(InputError, match="s must have shape"):
        st.vjp(F, s[:, :2])
    big = np.eye(3) + 0.2 * rng.standard_normal((257, 3, 3))
    sb = rng.standard_normal((257, st.size))
    serial = st.vjp(big, sb)
    monkeypatch.setattr(vs, "CHUNK_SAMPLES", 16)
    assert np.array_equal(serial, st.vjp(big, sb))
