"""Materials over F: rest state, frame invariance, linearization, uniaxial closed forms, kernels, inputs."""

from __future__ import annotations

import numpy as np
import pytest
from contract_materials import (  # noqa: E402
    MATERIAL_SPECS,
    NU,
    ORTHO,
    E,
    _rotation,
    f_inverted,
    f_large,
    f_near_identity,
    make,
)
from scipy.optimize import brentq

import voxflex as vf
from voxflex.deform import MATERIALS, Material, material
from voxflex.deform.materials.constitutive import lame, shifted_invariants
from voxflex.deform.materials.laws import NeoHookeanLaw
from voxflex.deform.materials.strains import get_strain
from voxflex.errors import InputError

MU, LM = lame(E, NU)
ISOTROPIC = [k for k in MATERIAL_SPECS if not k.startswith(("volume", "hooke-orthotropic"))]
# frame-invariant: all but the small-strain measures (hooke/linear; corotational-small is only
# invariant to second order in the rotation angle, see strains.py)
INVARIANT = [k for k in MATERIAL_SPECS if k not in ("hooke/linear", "hooke/corotational-small")]


def _rel(a, b):
    return np.linalg.norm(np.asarray(a) - b) / max(np.linalg.norm(a), np.linalg.norm(b), 1e-300)


def _hooke_tensor(C):
    """Voigt stiffness (engineering shear) -> A[i,j,k,l] acting on the displacement gradient."""
    voigt = {(0, 0): 0, (1, 1): 1, (2, 2): 2, (0, 1): 3, (1, 0): 3, (1, 2): 4, (2, 1): 4, (0, 2): 5, (2, 0): 5}
    A = np.zeros((3, 3, 3, 3))
    for (i, j), a in voigt.items():
        for (k, l), b in voigt.items():
            # e_a = sum_ij B_a,ij H_ij with B = 1 on (i,j) and (j,i) for the engineering shear entries,
            # so A = B^T C B is C[a(ij), b(kl)] itself
            A[i, j, k, l] = C[a, b]
    return A


def _isotropic_tangent(mu, lm):
    d = np.eye(3)
    return (
        lm * np.einsum("ij,kl->ijkl", d, d)
        + mu * (np.einsum("ik,jl->ijkl", d, d) + np.einsum("il,jk->ijkl", d, d))
    )


@pytest.mark.parametrize("label", MATERIAL_SPECS)
def test_rest_state(label):
    # W(I) = 0 and P(I) = 0: round-off only (1e-12 of the modulus)
    W, P, _ = make(label).evaluate(np.eye(3)[None])
    assert abs(W[0]) <= 1e-12 * E and np.max(np.abs(P)) <= 1e-12 * E


@pytest.mark.parametrize("label", ISOTROPIC)
def test_tangent_at_rest_is_isotropic_hooke(label):
    # the parameter conversions: every isotropic model linearizes to lmbda d_ij d_kl + mu (d_ik d_jl + d_il d_jk)
    # with (mu, lmbda) from young/poisson; exact up to round-off (1e-12 relative)
    A = make(label).tangent(np.eye(3)[None])[0]
    assert _rel(A, _isotropic_tangent(MU, LM)) < 1e-12


def test_tangent_at_rest_volume_and_orthotropic():
    k = E / (3 * (1 - 2 * NU))
    d = np.eye(3)
    for label in ["volume-log", "volume-quadratic"]:
        A = make(label).tangent(np.eye(3)[None])[0]
        assert _rel(A, k * np.einsum("ij,kl->ijkl", d, d)) < 1e-12
    mat = make("hooke-orthotropic")
    A = mat.tangent(np.eye(3)[None])[0]
    C = mat.law.C
    # contraction with symmetric gradients reproduces C (the minor-symmetric part of A is C)
    rng = np.random.default_rng(0)
    H = rng.standard_normal((3, 3))
    H = H + H.T
    e = np.array([H[0, 0], H[1, 1], H[2, 2], 2 * H[0, 1], 2 * H[1, 2], 2 * H[0, 2]])
    assert abs(np.einsum("ij,ijkl,kl->", H, A, H) - e @ C @ e) < 1e-12 * abs(e @ C @ e)
    sym = 0.25 * (A + A.transpose(1, 0, 2, 3) + A.transpose(0, 1, 3, 2) + A.transpose(1, 0, 3, 2))
    assert _rel(sym, _hooke_tensor(C)) < 1e-12


@pytest.mark.parametrize("label", INVARIANT)
def test_frame_invariance(label):
    # W(QF) = W(F), P(QF) = Q P(F): round-off (1e-10 relative; SVD/polar round-off ~1e-13)
    mat = make(label)
    rng = np.random.default_rng(3)
    F = np.concatenate([f_near_identity(), f_large()])
    Q = np.array([_rotation(rng) for _ in range(len(F))])
    W, P, _ = mat.evaluate(F, tangent=False)
    W2, P2, _ = mat.evaluate(Q @ F, tangent=False)
    assert _rel(W2, W) < 1e-10
    assert _rel(P2, Q @ P) < 1e-10


def test_small_strain_hooke_is_not_rotation_invariant():
    # the reason hooke/linear is excluded above: a pure rotation stores energy under linear strain
    R = _rotation(np.random.default_rng(4))[None]
    assert make("hooke/linear").energy(R)[0] > 1e-3 * E
    assert abs(make("hooke/corotational").energy(R)[0]) < 1e-10 * E


@pytest.mark.parametrize("label", MATERIAL_SPECS)
def test_numba_equals_numpy_twin(label):
    # same formulas, different order of operations: round-off only (1e-12 relative)
    mat = make(label)
    F = np.concatenate([f_near_identity(), f_large()])
    for a, b in zip(mat.evaluate(F), mat.evaluate(F, backend="numpy")):
        assert _rel(a, b) < 1e-12
    W, P, A = mat.evaluate(F, tangent=False)
    assert A is None and _rel(P, mat.stress(F)) == 0 and _rel(W, mat.energy(F)) == 0
    # the stress alone (the invariant strains' own kernel, no Jacobian formed) is the tangent pass's, to
    # round-off, and its energy the same bits
    Wt, Pt, _ = mat.evaluate(F, tangent=True)
    assert _rel(P, Pt) < 1e-12 and np.array_equal(W, Wt)


def test_shifted_invariants_kernel_equals_its_twin_and_the_definition():
    # the compiled one-pass kernel against the numpy twin (round-off of a few terms: 1e-12 relative
    # to the larger of the value and the strain's size), and both against I1 - 3 and J - 1 computed
    # from C = F^T F at strains large enough (>= 1e-3) that the plain formula loses at most ~1e-12
    rng = np.random.default_rng(3)
    size = np.logspace(-9, 0, 200)
    F = np.eye(3) + rng.standard_normal((200, 3, 3)) * size[:, None, None]
    F[np.linalg.det(F) <= 0] = np.eye(3)
    i1, j = shifted_invariants(F)
    i1n, jn = shifted_invariants(F, backend="numpy")
    assert np.all(np.abs(i1 - i1n) <= 1e-12 * np.maximum(np.abs(i1n), size))
    assert np.all(np.abs(j - jn) <= 1e-12 * np.maximum(np.abs(jn), size))
    big = size >= 1e-3
    C = np.einsum("nki,nkj->nij", F, F)
    assert np.allclose(i1[big], np.trace(C, axis1=1, axis2=2)[big] - 3.0, rtol=1e-10, atol=1e-12)
    assert np.allclose(j[big], np.linalg.det(F)[big] - 1.0, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("label", list(MATERIAL_SPECS))
def test_tangent_is_exactly_symmetric(label):
    # every law's tangent is a second derivative (the numpy twin's is symmetric to 2e-16 relative);
    # the chain kernel computes A's upper triangle and mirrors it: A_ijkl == A_klij bitwise
    A = make(label).tangent(np.concatenate([f_near_identity(), f_large()])).reshape(-1, 9, 9)
    assert np.array_equal(A, np.transpose(A, (0, 2, 1)))


# ---------------------------------------------------------------------------- uniaxial closed forms
STRETCHES = [0.7, 0.9, 1.1, 1.5, 2.0]


def _diag(lam, t):
    return np.diag([lam, t, t])[None]


def _lateral(fun, lo=0.2, hi=3.0):
    """Root of the closed-form lateral-stress equation (independent of the code under test)."""
    return brentq(fun, lo, hi, xtol=1e-15, rtol=4 * np.finfo(float).eps)


def _check_uniaxial(mat, lam, t, expected):
    # P_xx against its closed form (1e-10 relative, the brief's tolerance; the lateral stretch is
    # solved to machine precision, so round-off ~1e-14 is what remains) and P_yy = P_zz = 0 at that t
    P = mat.stress(_diag(lam, t))[0]
    assert abs(P[0, 0] - expected) <= 1e-10 * abs(expected)
    assert max(abs(P[1, 1]), abs(P[2, 2])) <= 1e-10 * abs(expected)
    assert np.max(np.abs(P - np.diag(np.diag(P)))) <= 1e-10 * abs(expected)


@pytest.mark.parametrize("lam", STRETCHES)
def test_uniaxial_small_strain_and_corotational(lam):
    # linear and every corotational strain see diag(lam, t, t) as e = (lam-1, t-1, t-1):
    # uniaxial stress gives t - 1 = -nu (lam - 1), P_xx = E (lam - 1)
    t = 1 - NU * (lam - 1)
    for s in ["linear", "corotational", "corotational-svd", "corotational-qr", "corotational-small"]:
        _check_uniaxial(material("hooke", young=E, poisson=NU, strain=s), lam, t, E * (lam - 1))


@pytest.mark.parametrize("lam", STRETCHES)
@pytest.mark.parametrize("nu", [0.0, 0.3])
def test_uniaxial_stvk(lam, nu):
    # Green strain: S_yy = 0 gives E_yy = -nu E_xx, P_xx = lam S_xx = E lam (lam^2 - 1) / 2
    # (nu = 0: t = 1, the brief's P = E lam (lam^2 - 1) / 2)
    t = np.sqrt(1 - nu * (lam**2 - 1))
    _check_uniaxial(material("stvk", young=E, poisson=nu), lam, t, E * lam * (lam**2 - 1) / 2)
    _check_uniaxial(material("hooke", young=E, poisson=nu, strain="green"), lam, t, E * lam * (lam**2 - 1) / 2)


@pytest.mark.parametrize("lam", STRETCHES)
@pytest.mark.parametrize("nu", [0.0, 0.3])
def test_uniaxial_neo_hookean(lam, nu):
    # P = mu (F - F^-T) + lmbda ln J F^-T; lateral: mu (t - 1/t) + lmbda ln(lam t^2) / t = 0
    # (nu = 0: lmbda = 0, t = 1, P = mu (lam - 1/lam))
    mu, lm = lame(E, nu)
    t = _lateral(lambda t: mu * (t - 1 / t) + lm * np.log(lam * t * t) / t)
    expected = mu * (lam - 1 / lam) + lm * np.log(lam * t * t) / lam
    _check_uniaxial(material("neo-hookean", young=E, poisson=nu), lam, t, expected)
    if nu == 0:
        assert t == pytest.approx(1.0, abs=1e-14) and expected == pytest.approx(mu * (lam - 1 / lam), rel=1e-14)


@pytest.mark.parametrize("lam", STRETCHES)
def test_uniaxial_stable_neo_hookean(lam):
    # P = mu' (1 - 1/(I_C + 1)) F + lmbda' (J - alpha) cof F, cof diag(l, t, t) = diag(t^2, l t, l t)
    mu, lm = lame(E, NU)
    ms, ls = 4 * mu / 3, lm + 5 * mu / 6
    alpha = 1 + 0.75 * ms / ls

    def p(lam, t, axis):
        ic, J = lam**2 + 2 * t**2, lam * t * t
        f, cof = (lam, t * t) if axis == 0 else (t, lam * t)
        return ms * (1 - 1 / (ic + 1)) * f + ls * (J - alpha) * cof

    t = _lateral(lambda t: p(lam, t, 1))
    _check_uniaxial(material("stable-neo-hookean", young=E, poisson=NU), lam, t, p(lam, t, 0))


@pytest.mark.parametrize("lam", STRETCHES)
def test_uniaxial_ogden(lam):
    # P_xx = dW/dl_1 = sum_p mu_p (lam^(a_p - 1) - 1/lam) + lmbda ln J / lam, the same with t laterally
    mat = material("ogden", young=E, poisson=NU)
    mus, als, lm = np.array(mat.law.mu_p), np.array(mat.law.alpha_p), mat.law.lmbda

    def d(x, J):
        return np.sum(mus * (x ** (als - 1) - 1 / x)) + lm * np.log(J) / x

    t = _lateral(lambda t: d(t, lam * t * t))
    _check_uniaxial(mat, lam, t, d(lam, lam * t * t))


@pytest.mark.parametrize("lam", STRETCHES)
@pytest.mark.parametrize("c2", [0.0, 800.0])
def test_uniaxial_mooney_rivlin_incompressible_limit(lam, c2):
    # at the isochoric stretch diag(lam, lam^-1/2, lam^-1/2) (J = 1, bulk term silent), the uniaxial
    # Cauchy stress of the incompressible model is sigma_xx - sigma_yy (a pressure clears sigma_yy),
    # so the nominal stress is (P_xx lam - P_yy t) / lam = 2 (lam - lam^-2)(c1 + c2/lam): exact identity
    mat = material("mooney-rivlin", young=E, poisson=NU, c2=c2)
    c1 = mat.law.c1
    t = lam**-0.5
    P = mat.stress(_diag(lam, t))[0]
    nominal = (P[0, 0] * lam - P[1, 1] * t) / lam
    expected = 2 * (lam - lam**-2) * (c1 + c2 / lam)
    assert abs(nominal - expected) <= 1e-10 * abs(expected)


def _incompressible_nominal(mat, lam):
    """Nominal uniaxial stress at the isochoric stretch diag(lam, lam^-1/2, lam^-1/2), pressure removed."""
    t = lam**-0.5
    P = mat.stress(_diag(lam, t))[0]
    return (P[0, 0] * lam - P[1, 1] * t) / lam


@pytest.mark.parametrize("lam", STRETCHES)
@pytest.mark.parametrize("lambda_m", [1.9, 2.8])
def test_uniaxial_arruda_boyce_incompressible_limit(lam, lambda_m):
    # as for Mooney-Rivlin: at J = 1 the (J - 1)^2 term is silent and the nominal stress with the pressure
    # removed is 2 (lam - lam^-2)(dW/dI1 + dW/dI2 / lam), here dW/dI2 = 0 and
    # dW/dI1 = mu sum_i i C_i / lambda_m^(2i-2) I1^(i-1) at I1 = lam^2 + 2/lam, written out independently:
    # exact identity, round-off only (1e-10)
    mat = material("arruda-boyce", young=E, poisson=NU, lambda_m=lambda_m)
    mu = mat.parameters["mu"]
    C = [1 / 2, 1 / 20, 11 / 1050, 19 / 7000, 519 / 673750]
    i1 = lam**2 + 2 / lam
    w1 = mu * sum((i + 1) * c / lambda_m ** (2 * i) * i1**i for i, c in enumerate(C))
    expected = 2 * (lam - lam**-2) * w1
    assert abs(_incompressible_nominal(mat, lam) - expected) <= 1e-10 * abs(expected)


@pytest.mark.parametrize("lam", STRETCHES)
@pytest.mark.parametrize("c2", [0.5, 1.0, 3.0])
def test_uniaxial_veronda_westmann_incompressible_limit(lam, c2):
    # dW/dI1 = c1 c2 exp(c2 (I1 - 3)), dW/dI2 = -c1 c2 / 2 at I1 = lam^2 + 2/lam: exact identity (1e-10)
    mat = material("veronda-westmann", young=E, poisson=NU, c2=c2)
    c1 = mat.parameters["c1"]
    assert c1 * c2 == pytest.approx(MU, rel=1e-15)
    i1 = lam**2 + 2 / lam
    expected = 2 * (lam - lam**-2) * (c1 * c2 * np.exp(c2 * (i1 - 3)) - 0.5 * c1 * c2 / lam)
    assert abs(_incompressible_nominal(mat, lam) - expected) <= 1e-10 * abs(expected)


def test_arruda_boyce_and_veronda_westmann_constants():
    # their own constants reproduce the young/poisson build (round-off, 1e-14), and the summaries invert
    F = f_large()
    ab = make("arruda-boyce")
    p = ab.parameters
    assert p["shear_modulus"] == pytest.approx(MU, rel=1e-14) and p["bulk"] == pytest.approx(LM + 2 * MU / 3, rel=1e-15)
    same = material("arruda-boyce", mu=p["mu"], lambda_m=1.9, bulk=p["bulk"])
    assert _rel(same.energy(F), ab.energy(F)) < 1e-14
    assert same.parameters["young"] == pytest.approx(E, rel=1e-14)
    assert same.parameters["poisson"] == pytest.approx(NU, rel=1e-14)
    assert material("arruda-boyce", young=E, poisson=NU).law.lambda_m == 2.8  # the documented default
    vw = make("veronda-westmann")
    same = material("veronda-westmann", c1=vw.parameters["c1"], c2=1.3, bulk=vw.parameters["bulk"])
    assert _rel(same.energy(F), vw.energy(F)) < 1e-14
    assert same.parameters["young"] == pytest.approx(E, rel=1e-14)
    assert same.parameters["poisson"] == pytest.approx(NU, rel=1e-14)
    assert material("veronda-westmann", young=E, poisson=NU).law.c2 == 1.0  # the documented default
    # the stiffening the models exist for: at 80 % isochoric stretch both carry a larger deviatoric nominal
    # stress than neo-Hooke of the same moduli, mu (lam - lam^-2) (checked first, 1e-10)
    p_nh = _incompressible_nominal(make("neo-hookean"), 1.8)
    assert abs(p_nh - MU * (1.8 - 1.8**-2)) <= 1e-10 * p_nh
    assert _incompressible_nominal(make("arruda-boyce"), 1.8) > 1.1 * p_nh
    assert _incompressible_nominal(make("veronda-westmann"), 1.8) > 1.1 * p_nh


@pytest.mark.parametrize("lam", STRETCHES)
def test_confined_volume_laws(lam):
    # confined compression/extension F = diag(lam, 1, 1): J = lam;
    # volume-log P_xx = k ln(lam)/lam, volume-quadratic P_xx = k (lam - 1)
    k = E / (3 * (1 - 2 * NU))
    P = make("volume-log").stress(_diag(lam, 1.0))[0, 0, 0]
    assert abs(P - k * np.log(lam) / lam) <= 1e-10 * abs(k * np.log(lam) / lam)
    P = make("volume-quadratic").stress(_diag(lam, 1.0))[0, 0, 0]
    assert abs(P - k * (lam - 1)) <= 1e-10 * abs(k * (lam - 1))


def test_ogden_tangent_at_coincident_stretches():
    # the strain's geometric term sees only s, so where stretches coincide the material supplies the
    # shear stiffness limit (materials._stretch_tangent).  (1) away from coincidence that formula equals
    # the chain-rule tangent (round-off, 1e-10); (2) at coincident stretches (not at rest) the tangent
    # matches central differences of the stress (h = 1e-6: rtol 1e-6 as in the contract)
    from voxflex.deform.materials.constitutive import _stretch_tangent

    mat = make("ogden")
    F = f_large()
    e = mat.strain.apply(F)
    _, s, K = mat.law.evaluate(e)
    assert _rel(_stretch_tangent(F, e, s, K), mat.tangent(F)) < 1e-10
    rng = np.random.default_rng(7)
    F = np.array([_rotation(rng) @ np.diag(d) @ _rotation(rng) for d in ([1.3, 1.3, 0.8], [1.2, 0.9, 0.9], [1.1] * 3)])
    A = mat.tangent(F)
    h = 1e-6
    for _ in range(2):
        dF = rng.standard_normal(F.shape)
        fd = (mat.stress(F + h * dF) - mat.stress(F - h * dF)) / (2 * h)
        assert _rel(np.einsum("nijkl,nkl->nij", A, dF), fd) < 1e-6


# ---------------------------------------------------------------------------- inversion
def test_inverted_elements():
    F = f_inverted()
    # neo-Hooke: documented +inf energy and NaN stress (a line search sees the inf)
    W, P, A = make("neo-hookean").evaluate(F)
    assert np.all(np.isposinf(W)) and np.all(np.isnan(P)) and np.all(np.isnan(A))
    # stable neo-Hooke and SVD-corotational Hooke: finite, positive energy with a restoring stress
    for label in ["stable-neo-hookean", "hooke/corotational-svd"]:
        W, P, A = make(label).evaluate(F)
        assert np.all(np.isfinite(W)) and np.all(W > 0) and np.all(np.isfinite(A))


# ---------------------------------------------------------------------------- parameters
def test_spec_entry_point_and_constants():
    mat = vf.material("neo-hookean", young=1e4, poisson=0.3)
    assert isinstance(mat, Material) and mat.name == "neo-hookean"
    assert mat.parameters["mu"] == pytest.approx(1e4 / 2.6, rel=1e-15)
    same = material("neo-hookean", mu=MU, lmbda=LM)
    F = f_large()
    assert _rel(same.energy(F), make("neo-hookean").energy(F)) < 1e-14
    assert same.parameters["young"] == pytest.approx(E, rel=1e-14)
    assert same.parameters["poisson"] == pytest.approx(NU, rel=1e-14)
    mr = material("mooney-rivlin", c1=MU / 2 - 100, c2=100, bulk=LM + 2 * MU / 3)
    assert mr.parameters["young"] == pytest.approx(E, rel=1e-14)
    assert material("volume-log", bulk=5.0).law.bulk == 5.0
    assert material("hooke", young=1, poisson=0).strain.name == "corotational"
    assert material("hooke", young=1, poisson=0, strain="linear").strain.name == "linear"
    assert material("stvk", young=1, poisson=0).strain.name == "green"
    og = material("ogden", young=E, poisson=NU, alpha_p=[2.0])
    assert _rel(og.energy(F), make("neo-hookean").energy(F)) < 1e-12  # one alpha = 2 term is neo-Hooke
    custom = Material(get_strain("invariant"), NeoHookeanLaw(MU, LM))
    assert _rel(custom.energy(F), make("neo-hookean").energy(F)) == 0
    assert set(MATERIALS) >= {"hooke", "hooke-orthotropic", "stvk", "neo-hookean", "stable-neo-hookean",
                              "mooney-rivlin", "volume-log", "volume-quadratic", "ogden",
                              "arruda-boyce", "veronda-westmann"}


def test_tangent_in_place_only_in_a_fresh_geometric_array():
    """Material.evaluate adds J^T K J into the strain's geometric-term array only when the strain says
    that array is new (voxflex's strains): a strain of the user's that hands out an array it keeps gets
    a copy, and both give the same tangent."""
    base = get_strain("invariant")

    class Keeping:  # a user's strain: geometric() returns the same array every time
        kind, size, name = base.kind, base.size, "keeping"

        def __init__(self):
            self.kept = None

        def evaluate(self, F, s=None, *, law_tangent=None):
            return base.evaluate(F, s, law_tangent=law_tangent)

        def geometric(self, F, s, *, law_tangent=None):
            self.kept = base.geometric(F, s, law_tangent=law_tangent)
            self.snapshot = self.kept.copy()
            return self.kept

    rng = np.random.default_rng(3)
    F = np.eye(3) + 0.1 * rng.standard_normal((20, 3, 3))
    keeping = Keeping()
    mine = Material(keeping, NeoHookeanLaw(MU, LM))
    ref = Material(base, NeoHookeanLaw(MU, LM))
    assert base.fresh_geometric and not hasattr(keeping, "fresh_geometric")
    A = mine.evaluate(F)[2]
    assert np.array_equal(keeping.kept, keeping.snapshot)  # left as it was handed out
    assert np.array_equal(A, ref.evaluate(F)[2])
    assert np.allclose(A, ref.evaluate(F, backend="numpy")[2], rtol=0, atol=1e-12 * np.abs(A).max())


BAD = [
    ("neo-hookean", dict(young=-1.0, poisson=0.3), r"young = -1.0 is out of range; valid: \(0, inf\)"),
    ("neo-hookean", dict(young=1.0, poisson=0.5), r"poisson = 0.5 is out of range; valid: \(-1, 0.5\)"),
    ("neo-hookean", dict(young=1.0, poisson=-1.0), r"poisson = -1.0 is out of range"),
    ("neo-hookean", dict(young=float("nan"), poisson=0.3), r"young = nan is out of range"),
    ("neo-hookean", dict(young=1.0, poisson=0.3, shear=2.0), r"unknown parameter 'shear'.*valid: young, poisson"),
    ("neo-hookean", dict(young=1.0, poisson=0.3, strain="green"), r"cannot use strain 'green'.*valid: invariant"),
    ("neo-hookean", dict(young=1.0), r"needs both young and poisson"),
    ("neo-hookean", dict(young=1.0, poisson=0.3, mu=1.0), r"either young/poisson or mu, lmbda"),
    ("neo-hookean", dict(mu=1.0), r"missing lmbda"),
    ("neo-hokean", dict(young=1.0, poisson=0.3), r"unknown material 'neo-hokean' \(did you mean 'neo-hookean'\?\)"),
    ("hooke", dict(young=1.0, poisson=0.3, strain="invariant"), r"cannot use strain 'invariant'"),
    ("hooke", dict(young=1.0, poisson=0.3, strain="gren"), r"unknown strain 'gren'"),
    ("hooke-orthotropic", dict(young=1.0, poisson=0.3), r"takes E1, E2"),
    ("hooke-orthotropic", {**ORTHO, "E1": -1.0}, r"E1 = -1.0 is out of range"),
    ("mooney-rivlin", dict(c1=-1.0, c2=0.0, bulk=1.0), r"c1 \+ c2 > 0"),
    ("ogden", dict(mu_p=[1.0], alpha_p=[2.0, 3.0], lmbda=1.0), r"same length"),
    ("volume-log", dict(bulk=0.0), r"bulk = 0.0 is out of range"),
    ("arruda-boyce", dict(young=1.0, poisson=0.3, lambda_m=1.0), r"lambda_m = 1.0 is out of range; valid: \(1, inf\)"),
    ("arruda-boyce", dict(mu=-1.0, bulk=1.0), r"mu = -1.0 is out of range; valid: \(0, inf\)"),
    ("arruda-boyce", dict(mu=1.0, bulk=0.0), r"bulk = 0.0 is out of range; valid: \(0, inf\)"),
    ("arruda-boyce", dict(mu=1.0), r"missing bulk"),
    ("arruda-boyce", dict(young=1.0, poisson=0.3, c2=1.0), r"unknown parameter 'c2'.*valid: .*lambda_m"),
    ("veronda-westmann", dict(young=1.0, poisson=0.3, c2=0.0), r"c2 = 0.0 is out of range; valid: \(0, inf\)"),
    ("veronda-westmann", dict(c1=-2.0, bulk=1.0), r"c1 = -2.0 is out of range; valid: \(0, inf\)"),
    ("veronda-westmann", dict(c1=1.0, c2=2.0, bulk=-1.0), r"bulk = -1.0 is out of range"),
    ("veronda-westmann", dict(young=1.0, poisson=0.3, c1=1.0), r"either young/poisson or c1, bulk"),
]


def test_auxetic_materials_are_accepted_and_linearize_to_hooke():
    """Poisson's ratio in (-1, 0): the tangent at rest is isotropic Hooke's with that E and nu (to 1e-12)."""
    for name in ("hooke", "neo-hookean", "stable-neo-hookean", "mooney-rivlin", "arruda-boyce"):
        mat = material(name, young=2.0, poisson=-0.4, **({"strain": "linear"} if name == "hooke" else {}))
        assert mat.parameters["poisson"] == pytest.approx(-0.4, rel=1e-12)
        mu, lm = 2.0 / (2 * (1 - 0.4)), 2.0 * -0.4 / ((1 - 0.4) * (1 + 0.8))
        A = mat.tangent(np.eye(3)[None])[0].reshape(9, 9)
        # the isotropic tangent: A_ijkl = lm d_ij d_kl + mu (d_ik d_jl + d_il d_jk)
        I = np.eye(3)
        ref = (lm * np.einsum("ij,kl->ijkl", I, I) + mu * (np.einsum("ik,jl->ijkl", I, I) + np.einsum("il,jk->ijkl", I, I))).reshape(9, 9)
        assert np.allclose(A, ref, atol=1e-12 * np.abs(ref).max()), name


@pytest.mark.parametrize("name, kw, match", BAD, ids=[f"{b[0]}-{i}" for i, b in enumerate(BAD)])
def test_bad_parameters(name, kw, match):
    with pytest.raises(InputError, match=match) as info:
        material(name, **kw)
    assert "\n" not in str(info.value)


def test_bad_F():
    with pytest.raises(InputError, match=r"\(n, 3, 3\)"):
        make("stvk").energy(np.eye(3))


def test_constant_tangent_flag_matches_the_tangent():
    """Only a quadratic law over an affine strain has dP/dF independent of F."""
    rng = np.random.default_rng(3)
    F1 = np.eye(3) + 0.2 * rng.standard_normal((2, 3, 3))
    F2 = np.eye(3) + 0.2 * rng.standard_normal((2, 3, 3))
    for name, strain, expected in [
        ("hooke", "linear", True),
        ("hooke", "green", False),
        ("hooke", "corotational", False),
        ("neo-hookean", None, False),
        ("mooney-rivlin", None, False),
    ]:
        mat = material(name, young=1e4, poisson=0.3, strain=strain)
        assert mat.constant_tangent is expected, (name, strain)
        same = np.allclose(mat.tangent(F1), mat.tangent(F2), rtol=1e-12, atol=1e-9)
        assert same is expected, (name, strain)
