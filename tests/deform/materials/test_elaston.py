"""Elastons: integrated energy of a linear strain field from volume moments."""

from __future__ import annotations

import numpy as np
import pytest

from voxflex.deform.materials import laws as L
from voxflex.deform.materials.elaston import elaston_energy
from voxflex.errors import InputError
from voxflex.sampling.moments import box_moments

HOOKE = L.HookeLaw(L.isotropic_stiffness(1.3, 2.1))
ORTHO = L.HookeLaw(L.orthotropic_stiffness(3.0, 2.0, 1.0, 0.2, 0.1, 0.3, 0.7, 0.5, 0.4))
NEO = L.NeoHookeanLaw(1.3, 2.1)
STABLE = L.StableNeoHookeanLaw(1.3, 2.1)
OGDEN = L.OgdenLaw((0.6, 0.01, -0.02), (1.3, 5.0, -2.0), 2.0)
MOONEY = L.MooneyRivlinLaw(0.4, 0.25, 3.0)


def _gauss_box(law, e0, G, x0, lo, hi, order):
    """Tensor Gauss-Legendre integral of W(e0 + G (x - x0)) over boxes [lo, hi] (independent oracle)."""
    t, w = np.polynomial.legendre.leggauss(order)
    n = e0.shape[0]
    total = np.zeros(n)
    for a in range(order):
        for b in range(order):
            for c in range(order):
                xi = np.array([t[a], t[b], t[c]])
                x = 0.5 * (lo + hi) + 0.5 * (hi - lo) * xi
                wt = w[a] * w[b] * w[c] * np.prod(0.5 * (hi - lo), axis=1)
                e = e0 + np.einsum("nax,nx->na", G, x - x0)
                total += wt * law.energy(e)
    return total


def _field(law, n, seed, scale=1.0):
    rng = np.random.default_rng(seed)
    if law.size == 6:
        e0 = 0.1 * rng.standard_normal((n, 6))
    else:
        e0 = 1.0 + 0.1 * rng.uniform(-1, 1, (n, 3))
        if law.strain_kind != "principal-stretch":
            e0[:, :2] *= 3.0
    G = scale * 0.2 * rng.standard_normal((n, law.size, 3))
    return e0, G


@pytest.mark.parametrize("law", [HOOKE, ORTHO, MOONEY], ids=["hooke", "orthotropic", "mooney-rivlin"])
def test_quadratic_law_exact_on_boxes(law):
    # quadratic (in e) laws: the Taylor energy is the exact integral; 4-point Gauss per axis integrates
    # the quadratic exactly too, so both agree to round-off (1e-12 relative)
    rng = np.random.default_rng(0)
    n = 5
    lo = rng.uniform(-1, 0, (n, 3))
    hi = lo + rng.uniform(0.2, 1.5, (n, 3))
    x0 = lo + rng.uniform(-0.3, 1.3, (n, 3)) * (hi - lo)  # off-centre, even outside the box
    e0, G = _field(law, n, 1)
    V, M1, M2 = box_moments(lo, hi, x0)
    got = elaston_energy(law, e0, G, V, M1, M2).energy
    ref = _gauss_box(law, e0, G, x0, lo, hi, 4)
    assert np.max(np.abs(got - ref) / np.abs(ref)) < 1e-12


@pytest.mark.parametrize("law", [NEO, STABLE, OGDEN], ids=["neo-hookean", "stable-neo-hookean", "ogden"])
@pytest.mark.parametrize("centred", [False, True])
def test_taylor_error_order(law, centred):
    # error per unit volume vs 8^3-point Gauss (converged to ~1e-15 for these smooth integrands):
    # O(h^3) for an off-centre x0 (odd moments), O(h^4) for x0 at the centre of the box.
    # Observed order from halving h twice must be within +-0.5 of the stated order (brief).
    # (seed 7: a field whose cubic term is not accidentally small, so h = 0.2 is already asymptotic;
    # measured orders 2.87-3.06 off-centre, 4.00-4.01 centred)
    e0, G = _field(law, 1, 7, scale=2.0)
    frac = np.array([[0.5, 0.5, 0.5]]) if centred else np.array([[0.15, 0.3, 0.8]])
    errs = []
    hs = [0.2, 0.1, 0.05]
    for h in hs:
        lo = np.zeros((1, 3))
        hi = h * np.array([[1.0, 0.8, 1.2]])
        x0 = lo + frac * (hi - lo)
        V, M1, M2 = box_moments(lo, hi, x0)
        got = elaston_energy(law, e0, G, V, M1, M2, hessian=False).energy
        ref = _gauss_box(law, e0, G, x0, lo, hi, 8)
        errs.append(abs(got[0] - ref[0]) / V[0])
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    expected = 4.0 if centred else 3.0
    assert np.all(np.abs(orders - expected) < 0.5), (errs, orders)


@pytest.mark.parametrize("law", [NEO, STABLE, OGDEN, HOOKE], ids=["neo-hookean", "stable-neo-hookean", "ogden", "hooke"])
def test_derivatives_against_finite_differences(law):
    # the derivatives are exact for the truncated energy: central differences with h = 1e-6 agree to
    # ~1e-9 relative; rtol 1e-6 catches any missing term (O(1) error)
    rng = np.random.default_rng(5)
    n = 4
    lo = rng.uniform(-1, 0, (n, 3))
    hi = lo + rng.uniform(0.2, 0.6, (n, 3))
    x0 = lo + rng.uniform(0, 1, (n, 3)) * (hi - lo)
    V, M1, M2 = box_moments(lo, hi, x0)
    e0, G = _field(law, n, 6)
    res = elaston_energy(law, e0, G, V, M1, M2)
    h = 1e-6

    def rel(a, b):
        return np.linalg.norm(a - b) / max(np.linalg.norm(a), np.linalg.norm(b))

    for _ in range(2):
        de, dG = rng.standard_normal(e0.shape), rng.standard_normal(G.shape)
        p = elaston_energy(law, e0 + h * de, G + h * dG, V, M1, M2)
        m = elaston_energy(law, e0 - h * de, G - h * dG, V, M1, M2)
        fd = (p.energy - m.energy) / (2 * h)
        an = np.einsum("na,na->n", res.grad_e0, de) + np.einsum("nax,nax->n", res.grad_G, dG)
        assert rel(an, fd) < 1e-6
        H = res.hessian
        fd_ge = (p.grad_e0 - m.grad_e0) / (2 * h)
        an_ge = np.einsum("nab,nb->na", H.e0e0, de) + np.einsum("nabx,nbx->na", H.e0G, dG)
        assert rel(an_ge, fd_ge) < 1e-6
        fd_gG = (p.grad_G - m.grad_G) / (2 * h)
        an_gG = np.einsum("nbax,nb->nax", H.e0G, de) + np.einsum("naxby,nby->nax", H.GG, dG)
        assert rel(an_gG, fd_gG) < 1e-6


def test_box_moments_against_gauss():
    # exact polynomial moments: 2-point Gauss integrates degree <= 3 exactly (1e-13)
    lo = np.array([[0.1, -0.2, 0.3]])
    hi = np.array([[0.6, 0.5, 0.4]])
    x0 = np.array([[0.0, 0.1, 0.2]])
    V, M1, M2 = box_moments(lo, hi, x0)
    t, w = np.polynomial.legendre.leggauss(2)
    ref = [0.0, np.zeros(3), np.zeros((3, 3))]
    for a in range(2):
        for b in range(2):
            for c in range(2):
                x = 0.5 * (lo + hi)[0] + 0.5 * (hi - lo)[0] * np.array([t[a], t[b], t[c]])
                wt = w[a] * w[b] * w[c] * np.prod(0.5 * (hi - lo))
                d = x - x0[0]
                ref[0] += wt
                ref[1] += wt * d
                ref[2] += wt * np.outer(d, d)
    assert np.allclose(V, ref[0], rtol=1e-13) and np.allclose(M1[0], ref[1], rtol=1e-13, atol=1e-16)
    assert np.allclose(M2[0], ref[2], rtol=1e-13, atol=1e-16)


def test_bad_input():
    V, M1, M2 = box_moments(np.zeros((1, 3)), np.ones((1, 3)), np.zeros((1, 3)))
    with pytest.raises(InputError, match="G must have shape"):
        elaston_energy(NEO, np.ones((1, 3)), np.zeros((1, 6, 3)), V, M1, M2)
    with pytest.raises(InputError, match="V must be > 0"):
        elaston_energy(NEO, np.ones((1, 3)), np.zeros((1, 3, 3)), -V, M1, M2)
    with pytest.raises(InputError, match="upper corners"):
        box_moments(np.ones((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)))


# ------------------------------------------------------------------------ material level: (F, dF)
from voxflex.deform.materials.constitutive import MATERIALS, material  # noqa: E402
from voxflex.deform.materials.elaston import material_elaston_energy  # noqa: E402


def _material(name, strain=None):
    if name == "hooke-orthotropic":
        return material(name, strain=strain, E1=3.0, E2=2.0, E3=1.0, nu12=0.2, nu13=0.1, nu23=0.3,
                        G12=0.7, G23=0.5, G13=0.4)
    return material(name, strain=strain, young=2.0, poisson=0.3)


def _material_setup(seed=11, n=3):
    """3 samples near identity with a moderate gradient, off-centre x0 in boxes of size ~0.3-0.7."""
    rng = np.random.default_rng(seed)
    F = np.eye(3) + 0.1 * rng.standard_normal((n, 3, 3))
    dF = 0.5 * rng.standard_normal((n, 3, 3, 3))
    lo = rng.uniform(-1, 0, (n, 3))
    hi = lo + rng.uniform(0.3, 0.7, (n, 3))
    x0 = lo + rng.uniform(0.1, 0.9, (n, 3)) * (hi - lo)
    return F, dF, box_moments(lo, hi, x0)


def _rel(a, b):
    return np.linalg.norm(a - b) / max(np.linalg.norm(a), np.linalg.norm(b))


@pytest.mark.parametrize("name", list(MATERIALS))
def test_material_gradient_against_finite_differences(name):
    # exact chain rule: central differences with h = 1e-6 agree to ~1e-9 relative (O(h^2) truncation,
    # O(1e-16/h) round-off); rtol 1e-6 catches any missing term, which gives an O(1) error
    mat = _material(name)
    F, dF, (V, M1, M2) = _material_setup()
    res = material_elaston_energy(mat, F, dF, V, M1, M2, hessian=False)
    assert res.hessian is None and res.grad_F.shape == F.shape and res.grad_dF.shape == dF.shape
    rng = np.random.default_rng(12)
    h = 1e-6
    for _ in range(2):
        vF, vd = rng.standard_normal(F.shape), rng.standard_normal(dF.shape)
        p = material_elaston_energy(mat, F + h * vF, dF + h * vd, V, M1, M2, hessian=False).energy
        m = material_elaston_energy(mat, F - h * vF, dF - h * vd, V, M1, M2, hessian=False).energy
        an = np.einsum("nij,nij->n", res.grad_F, vF) + np.einsum("nija,nija->n", res.grad_dF, vd)
        assert _rel(an, (p - m) / (2 * h)) < 1e-6
    if not mat.strain.constant_hessian:
        with pytest.raises(NotImplementedError, match="third derivatives"):
            material_elaston_energy(mat, F, dF, V, M1, M2)


@pytest.mark.parametrize(("name", "strain"), [("hooke", "linear"), ("stvk", "green"), ("hooke", "corotational-small")])
def test_material_hessian_against_finite_differences(name, strain):
    # the Hessian against central differences of the (tested) gradient, rtol 1e-6 as above
    mat = _material(name, strain)
    F, dF, (V, M1, M2) = _material_setup(seed=13)
    res = material_elaston_energy(mat, F, dF, V, M1, M2)
    H = res.hessian
    rng = np.random.default_rng(14)
    h = 1e-6
    for _ in range(2):
        vF, vd = rng.standard_normal(F.shape), rng.standard_normal(dF.shape)
        p = material_elaston_energy(mat, F + h * vF, dF + h * vd, V, M1, M2, hessian=False)
        m = material_elaston_energy(mat, F - h * vF, dF - h * vd, V, M1, M2, hessian=False)
        an_F = np.einsum("nijkl,nkl->nij", H.FF, vF) + np.einsum("nijklb,nklb->nij", H.FdF, vd)
        an_d = np.einsum("nklija,nkl->nija", H.FdF, vF) + np.einsum("nijaklb,nklb->nija", H.dFdF, vd)
        assert _rel(an_F, (p.grad_F - m.grad_F) / (2 * h)) < 1e-6
        assert _rel(an_d, (p.grad_dF - m.grad_dF) / (2 * h)) < 1e-6
    # a Hessian is symmetric (to round-off)
    n = F.shape[0]
    full = np.zeros((n, 36, 36))
    full[:, :9, :9] = H.FF.reshape(n, 9, 9)
    full[:, :9, 9:] = H.FdF.reshape(n, 9, 27)
    full[:, 9:, :9] = H.FdF.reshape(n, 9, 27).transpose(0, 2, 1)
    full[:, 9:, 9:] = H.dFdF.reshape(n, 27, 27)
    assert np.max(np.abs(full - full.transpose(0, 2, 1))) < 1e-12 * np.max(np.abs(full))


def _gauss_box_material(mat, F0, dF, x0, lo, hi, order):
    """Tensor Gauss-Legendre integral of W(F0 + dF (x - x0)) over boxes [lo, hi] (independent oracle)."""
    t, w = np.polynomial.legendre.leggauss(order)
    total = np.zeros(F0.shape[0])
    for a in range(order):
        for b in range(order):
            for c in range(order):
                x = 0.5 * (lo + hi) + 0.5 * (hi - lo) * np.array([t[a], t[b], t[c]])
                wt = w[a] * w[b] * w[c] * np.prod(0.5 * (hi - lo), axis=1)
                total += wt * mat.energy(F0 + np.einsum("nija,na->nij", dF, x - x0))
    return total


def test_material_hooke_linear_exact_on_boxes():
    # Hooke over linear strain: W is quadratic in x, the elaston energy is the exact integral and so is
    # 4-point Gauss per axis: agreement to round-off (1e-12 relative)
    mat = _material("hooke", "linear")
    rng = np.random.default_rng(15)
    n = 4
    F = np.eye(3) + 0.1 * rng.standard_normal((n, 3, 3))
    dF = 0.5 * rng.standard_normal((n, 3, 3, 3))
    lo = rng.uniform(-1, 0, (n, 3))
    hi = lo + rng.uniform(0.2, 1.5, (n, 3))
    x0 = lo + rng.uniform(-0.3, 1.3, (n, 3)) * (hi - lo)  # off-centre, even outside the box
    got = material_elaston_energy(mat, F, dF, *box_moments(lo, hi, x0)).energy
    ref = _gauss_box_material(mat, F, dF, x0, lo, hi, 4)
    assert np.max(np.abs(got - ref) / np.abs(ref)) < 1e-12


def test_material_neo_hookean_convergence():
    # Neo-Hooke over invariants: the strain is linearized over the box, so the energy misses
    # 1/2 s(e0) . E''(F)[dF d, dF d] integrated (s = dW/de != 0 even at rest for invariants):
    # per unit volume O(h^2), total error O(h^5).  Measured (8^3-point Gauss oracle, converged to
    # ~1e-15): total-error orders 4.99-5.00 (>= 2.5 as required), per-volume orders 1.99-2.00, and
    # the error equals that predicted leading term to 1.01, 1.003, 1.0008 (ratio -> 1 at O(h)).
    mat = _material("neo-hookean")
    rng = np.random.default_rng(4)
    F0 = np.eye(3)[None] + 0.1 * rng.standard_normal((1, 3, 3))
    dF = 0.5 * np.random.default_rng(2).standard_normal((1, 3, 3, 3))
    e0 = mat.strain.apply(F0)
    s = mat.law._evaluate(e0, False, "numba")[1]
    geo = mat.strain.geometric(F0, s)
    errs, per_volume, ratio = [], [], []
    for h in (0.2, 0.1, 0.05):
        lo = np.zeros((1, 3))
        hi = h * np.array([[1.0, 0.8, 1.2]])
        x0 = 0.5 * (lo + hi)
        V, M1, M2 = box_moments(lo, hi, x0)
        got = material_elaston_energy(mat, F0, dF, V, M1, M2, hessian=False).energy[0]
        ref = _gauss_box_material(mat, F0, dF, x0, lo, hi, 8)[0]
        predicted = 0.5 * np.einsum("ab,ija,ijkl,klb->", M2[0], dF[0], geo[0], dF[0])
        errs.append(abs(ref - got))
        per_volume.append(abs(ref - got) / V[0])
        ratio.append((ref - got) / predicted)
    total_orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    volume_orders = np.log2(np.array(per_volume[:-1]) / np.array(per_volume[1:]))
    assert np.all(total_orders >= 2.5) and np.all(np.abs(total_orders - 5.0) < 0.1), total_orders
    assert np.all(np.abs(volume_orders - 2.0) < 0.1), volume_orders  # second order per unit volume
    assert abs(ratio[-1] - 1.0) < 5e-3 and abs(ratio[-1] - 1) < abs(ratio[0] - 1), ratio


def test_material_bad_input():
    mat = _material("neo-hookean")
    F, dF, (V, M1, M2) = _material_setup()
    with pytest.raises(InputError, match="dF must have shape"):
        material_elaston_energy(mat, F, dF[..., 0], V, M1, M2, hessian=False)
    with pytest.raises(InputError, match="F must have shape"):
        material_elaston_energy(mat, F[0], dF, V, M1, M2, hessian=False)
    with pytest.raises(InputError, match="must be a voxflex Material"):
        material_elaston_energy(NEO, F, dF, V, M1, M2, hessian=False)
    with pytest.raises(InputError, match="finite"):
        material_elaston_energy(mat, F * np.nan, dF, V, M1, M2, hessian=False)
    with pytest.raises(InputError, match="V must be > 0"):
        material_elaston_energy(mat, F, dF, -V, M1, M2, hessian=False)
