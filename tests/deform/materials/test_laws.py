"""Energy laws over strain vectors: kernels vs numpy twins, derivatives vs finite differences."""

from __future__ import annotations

import numpy as np
import pytest

from voxflex.deform.materials import laws as L
from voxflex.errors import InputError

LAWS = {
    "hooke": L.HookeLaw(L.isotropic_stiffness(1.3, 2.1)),
    "hooke-orthotropic": L.HookeLaw(L.orthotropic_stiffness(3.0, 2.0, 1.0, 0.2, 0.1, 0.3, 0.7, 0.5, 0.4)),
    "neo-hookean": L.NeoHookeanLaw(1.3, 2.1),
    "stable-neo-hookean": L.StableNeoHookeanLaw(1.3, 2.1),
    "mooney-rivlin": L.MooneyRivlinLaw(0.4, 0.25, 3.0),
    "arruda-boyce": L.ArrudaBoyceLaw(0.8, 1.6, 3.0),
    "veronda-westmann": L.VerondaWestmannLaw(0.4, 1.7, 3.0),
    "volume-log": L.VolumeLogLaw(2.5),
    "volume-quadratic": L.VolumeQuadraticLaw(2.5),
    "ogden": L.OgdenLaw((0.6, 0.01, -0.02), (1.3, 5.0, -2.0), 2.0),
}


def _strains(law, n=7, seed=0):
    rng = np.random.default_rng(seed)
    if law.size == 6:
        return 0.2 * rng.standard_normal((n, 6))
    # invariants / stretches: positive, around the rest values (3, 3, 1) or (1, 1, 1)
    e = 1.0 + 0.3 * rng.uniform(-1, 1, (n, 3))
    if law.strain_kind != "principal-stretch":
        e[:, :2] *= 3.0
    return e


def _relerr(a, b):
    return np.linalg.norm(a - b) / max(np.linalg.norm(a), np.linalg.norm(b), 1e-300)


@pytest.mark.parametrize("name", LAWS)
def test_kernel_matches_numpy_twin(name):
    # same formulas in a different order of operations: equal to round-off (1e-12 relative)
    law = LAWS[name]
    e = _strains(law)
    for a, b in zip(law.evaluate(e), law.evaluate(e, backend="numpy")):
        assert _relerr(a, b) < 1e-12
    W, s, K = law.evaluate(e, tangent=False)
    assert K is None and _relerr(W, law.evaluate(e)[0]) == 0.0


@pytest.mark.parametrize("name", LAWS)
def test_derivatives_against_finite_differences(name):
    # central differences with h = 1e-6: truncation O(h^2) ~ 1e-12, round-off ~ 1e-10 relative;
    # rtol 1e-6 leaves 4 orders of margin and still catches any wrong term (O(1) error)
    law = LAWS[name]
    e = _strains(law, seed=1)
    rng = np.random.default_rng(2)
    h = 1e-6
    W, s, K = law.evaluate(e)
    T, Q = law.higher(e)
    for _ in range(2):
        v = rng.standard_normal(e.shape)
        ep, em = e + h * v, e - h * v
        fd_w = (law.energy(ep) - law.energy(em)) / (2 * h)
        assert _relerr(np.einsum("na,na->n", s, v), fd_w) < 1e-6
        fd_s = (law.stress(ep) - law.stress(em)) / (2 * h)
        assert _relerr(np.einsum("nab,nb->na", K, v), fd_s) < 1e-6
        fd_k = (law.tangent(ep) - law.tangent(em)) / (2 * h)
        fd_t = (law.higher(ep)[0] - law.higher(em)[0]) / (2 * h)
        if np.linalg.norm(fd_k) > 0:
            assert _relerr(np.einsum("nabc,nc->nab", T, v), fd_k) < 1e-6
        else:
            assert np.linalg.norm(T) == 0
        if np.linalg.norm(fd_t) > 0:
            assert _relerr(np.einsum("nabcd,nd->nabc", Q, v), fd_t) < 1e-6
        else:
            assert np.linalg.norm(Q) == 0
    # symmetric tangent (a Hessian): exact by construction
    assert np.max(np.abs(K - K.transpose(0, 2, 1))) <= 1e-14 * np.max(np.abs(K))


@pytest.mark.parametrize("name", ["neo-hookean", "volume-log", "ogden"])
@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_outside_domain_is_infinite_energy(name, backend):
    # documented behaviour: W = +inf (a line search sees it), stress/tangent NaN, never a finite lie
    law = LAWS[name]
    e = _strains(law, n=3)
    e[1, 2] = -0.5
    W, s, K = law.evaluate(e, backend=backend)
    assert np.isposinf(W[1]) and np.all(np.isnan(s[1])) and np.all(np.isnan(K[1]))
    assert np.all(np.isfinite(W[[0, 2]])) and np.all(np.isfinite(K[[0, 2]]))


def test_stable_neo_hookean_defined_when_inverted():
    law = LAWS["stable-neo-hookean"]
    e = np.array([[3.0, 3.0, -1.0]])  # a reflection: I1 = 3, J = -1
    W, s, K = law.evaluate(e)
    assert np.all(np.isfinite(W)) and W[0] > 0 and np.all(np.isfinite(K))


def test_ogden_with_alpha_two_is_neo_hookean():
    # W_ogden(l) = mu/2 (sum l^2 - 3 - 2 ln J) + lmbda/2 ln^2 J = W_nh(I1 = sum l^2, J = prod l): identical
    mu, lm = 1.7, 0.9
    stretches = _strains(LAWS["ogden"], n=20, seed=3)
    inv = np.stack([np.sum(stretches**2, 1), np.zeros(20), np.prod(stretches, 1)], 1)
    w_o = L.OgdenLaw((mu,), (2.0,), lm).energy(stretches)
    w_n = L.NeoHookeanLaw(mu, lm).energy(inv)
    assert _relerr(w_o, w_n) < 1e-13


def test_orthotropic_stiffness():
    # equal constants give isotropic Hooke (G = E / 2(1 + nu)): exact up to the inverse's round-off
    E, nu = 5.0, 0.3
    G = E / (2 * (1 + nu))
    mu, lm = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    C = L.orthotropic_stiffness(E, E, E, nu, nu, nu, G, G, G)
    assert _relerr(C, L.isotropic_stiffness(mu, lm)) < 1e-14
    # uniaxial stress along y: strain = S sigma, eps_yy = 1/E2, eps_xx = -nu21 = -nu12 E2/E1, eps_zz = -nu23
    C = LAWS["hooke-orthotropic"].C
    eps = np.linalg.solve(C, [0.0, 1.0, 0, 0, 0, 0])
    assert np.allclose(eps, [-0.2 / 3.0, 0.5, -0.3 / 2.0, 0, 0, 0], rtol=1e-13, atol=1e-15)
    eps = np.linalg.solve(C, [0, 0, 0, 0, 1.0, 0])  # shear yz: engineering strain 1/G23
    assert np.allclose(eps, [0, 0, 0, 0, 2.0, 0], rtol=1e-13, atol=1e-15)
    with pytest.raises(InputError, match="positive definite"):
        L.orthotropic_stiffness(1.0, 1.0, 1.0, 0.9, 0.9, 0.9, 1.0, 1.0, 1.0)


def test_bad_strain_shape():
    with pytest.raises(InputError, match=r"\(n, 3\)"):
        LAWS["neo-hookean"].energy(np.zeros((2, 6)))
    with pytest.raises(InputError, match="backend"):
        LAWS["neo-hookean"].evaluate(np.ones((2, 3)), backend="cuda")


def test_arruda_boyce_shear_modulus_series():
    # 2 dW/dI1bar at rest against the closed-form series of the brief (exact rationals: round-off, 1e-14)
    for lm in [1.2, 2.8, 7.0]:
        law = L.ArrudaBoyceLaw(1.7, lm, 1.0)
        factor = 1 + 3 / (5 * lm**2) + 99 / (175 * lm**4) + 513 / (875 * lm**6) + 42039 / (67375 * lm**8)
        assert abs(law.shear_modulus - 1.7 * factor) <= 1e-14 * 1.7 * factor
        assert abs(2 * law.stress(np.array([[3.0, 3.0, 1.0]]))[0, 0] - 1.7 * factor) <= 1e-14 * 1.7 * factor
    # the five-term series is the Taylor expansion of the Langevin chain in 1/lambda_m^2: as lambda_m grows
    # it tends to neo-Hooke mu/2 (I1bar - 3); at lambda_m = 1e4 the next term is 1e-8 of the first
    e = _strains(LAWS["arruda-boyce"], seed=4)
    w = L.ArrudaBoyceLaw(1.7, 1e4, 0.0).energy(e)
    assert _relerr(w, 0.85 * (e[:, 0] - 3.0)) < 1e-7


@pytest.mark.parametrize("lm", [1.0, 0.5, float("nan")])
def test_arruda_boyce_locking_stretch_range(lm):
    with pytest.raises(InputError, match="lambda_m"):
        L.ArrudaBoyceLaw(1.0, lm, 1.0)
