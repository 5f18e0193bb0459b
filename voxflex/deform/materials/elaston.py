"""Elastons: integrate an energy over a region from its volume moments.

Two ways, for two uses:

* :func:`subrule_energy` -- what the frame model integrates: any material at a
  few points of the region whose non-negative weights reproduce its volume
  moments to degree 2 (:func:`voxflex.sampling.subrule.moment_fitted_rule`),
  with F at each point ``F + dF (x_k - x0)`` (the frame model evaluates the
  frames' own F there).  The energy is a weighted sum of ``W(F_k)``, so its
  gradient and Hessian are the material's stress and tangent (every material,
  no higher derivatives): exact for integrands quadratic over the region, error
  O(h^3) per unit volume for smooth ones (measured in ``tests/test_subrule.py``).
* :func:`elaston_energy` / :func:`material_elaston_energy` -- the Taylor
  expansion of a law about the region's point, below (its Hessian needs the
  law's third and fourth derivatives and a strain with a constant second
  derivative; kept as a library function).

An elaston is a quadrature sample that carries the volume moments of its
region Omega about the sample point x0:

* ``V = int dV`` (n,) [m^3],
* ``M1 = int (x - x0) dV`` (n, 3) [m^4],
* ``M2 = int (x - x0)(x - x0)^T dV`` (n, 3, 3) [m^5].

With a strain field linear over the region, ``e(x) = e0 + G (x - x0)``
(``e0`` (n, m), ``G`` (n, m, 3) the strain gradient), the energy of the region
is approximated by integrating the second-order Taylor expansion of the law
``W`` about ``e0``:

    E = V W(e0) + s(e0) . (G M1) + 1/2 K(e0) : (G M2 G^T)

with ``s = dW/de`` and ``K = d2W/de2``.  It is **exact** for laws quadratic in
e (Hooke, orthotropic Hooke, Mooney-Rivlin and volume-quadratic, whose
third derivative vanishes).  For any other law the error is the integral of
the Taylor remainder, ``int W'''(e0)[delta^3]/6 dV`` with
``delta = G (x - x0)``: per unit volume **O(|G|^3 h^3)** for a region of
diameter h containing x0, and **O(|G|^4 h^4)** when x0 is the centroid of a
point-symmetric region (the odd moments vanish).

:func:`elaston_energy` returns E with its exact first and second derivatives
with respect to ``e0`` and ``G`` (the derivatives of the truncated energy, so
a Newton solver converges quadratically on it); they need the law's third
and fourth derivatives (:meth:`voxflex.deform.materials.laws.Law.higher`).

References
----------
S. Martin, P. Kaufmann, M. Botsch, E. Grinspun, M. Gross, "Unified simulation
of elastic rods, shells, and solids", ACM TOG 29(4), 2010.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ...errors import InputError
from .constitutive import Material
from .laws import Law
from .strains import apply_with_gradient, geometric_with_gradient, jacobian_with_gradient

__all__ = [
    "subrule_energy",
    "SubruleEnergy",
    "ElastonEnergy",
    "ElastonHessian",
    "elaston_energy",
    "MaterialElastonEnergy",
    "MaterialElastonHessian",
    "material_elaston_energy",
]


class ElastonHessian(NamedTuple):
    """Second derivatives of the integrated energy.

    ``e0e0`` (n, m, m): d2E/de0 de0; ``e0G`` (n, m, m, 3): ``[n, a, b, x] = d2E/de0_a dG_bx``;
    ``GG`` (n, m, 3, m, 3): ``[n, a, x, b, y] = d2E/dG_ax dG_by``.
    """

    e0e0: np.ndarray
    e0G: np.ndarray
    GG: np.ndarray


class ElastonEnergy(NamedTuple):
    """Integrated energy E (n,) [J], dE/de0 (n, m), dE/dG (n, m, 3) and the Hessian blocks (or None)."""

    energy: np.ndarray
    grad_e0: np.ndarray
    grad_G: np.ndarray
    hessian: ElastonHessian | None


def _check(law, e0, G, V, M1, M2):
    if not isinstance(law, Law):
        raise InputError(f"law must be a voxflex Law, got {type(law).__name__}")
    e0 = law.check(e0)
    n, m = e0.shape
    arrays = {}
    for name, value, shape in (
        ("G", G, (n, m, 3)),
        ("V", V, (n,)),
        ("M1", M1, (n, 3)),
        ("M2", M2, (n, 3, 3)),
    ):
        a = np.asarray(value, dtype=np.float64)
        if a.shape != shape:
            raise InputError(f"elaston {name} must have shape {shape}, got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise InputError(f"elaston {name} must be finite")
        arrays[name] = a
    if np.any(arrays["V"] <= 0):
        raise InputError("elaston volumes V must be > 0")
    return e0, arrays["G"], arrays["V"], arrays["M1"], arrays["M2"]


def elaston_energy(law: Law, e0, G, V, M1, M2, *, hessian: bool = True) -> ElastonEnergy:
    """Energy of linearly varying strain integrated over elaston regions.

    Parameters
    ----------
    law : Law
        The energy law (any strain kind).
    e0 : array (n, m)
        Strain at the sample points x0.
    G : array (n, m, 3)
        Strain gradient: ``e(x) = e0 + G (x - x0)`` [1/m].
    V, M1, M2 : arrays (n,), (n, 3), (n, 3, 3)
        Volume moments of each region about its x0 [m^3, m^4, m^5].
    hessian : bool
        Also return the second derivatives.

    Returns
    -------
    ElastonEnergy
        ``energy`` (n,) [J], ``grad_e0`` (n, m), ``grad_G`` (n, m, 3), ``hessian``
        (:class:`ElastonHessian` or None): exact derivatives of the second-order
        Taylor energy (exact energy for laws quadratic in e; see the module
        docstring for the error order otherwise).

    Examples
    --------
    >>> import numpy as np
    >>> from voxflex.deform.materials.laws import HookeLaw, isotropic_stiffness
    >>> from voxflex.sampling.moments import box_moments
    >>> V, M1, M2 = box_moments([[0, 0, 0]], [[1, 1, 1]], [[0.5, 0.5, 0.5]])
    >>> law = HookeLaw(isotropic_stiffness(1.0, 0.0))
    >>> G = np.zeros((1, 6, 3)); G[0, 0, 0] = 1.0          # e_xx = x - 1/2
    >>> float(elaston_energy(law, np.zeros((1, 6)), G, V, M1, M2).energy[0])   # int (x-1/2)^2 dx
    0.08333333333333333
    """
    e0, G, V, M1, M2 = _check(law, e0, G, V, M1, M2)
    return _elaston_impl(law, e0, G, V, M1, M2, hessian)


def _elaston_impl(law, e0, G, V, M1, M2, hessian):
    W, s, K = law._evaluate(e0, True, "numba")
    T, Q = law.higher(e0)
    d1 = np.einsum("nax,nx->na", G, M1)  # G M1
    GM2 = np.einsum("nax,nxy->nay", G, M2)  # G M2
    S2 = np.einsum("nay,nby->nab", GM2, G)  # G M2 G^T
    energy = V * W + np.einsum("na,na->n", s, d1) + 0.5 * np.einsum("nab,nab->n", K, S2)
    grad_e0 = V[:, None] * s + np.einsum("nab,nb->na", K, d1) + 0.5 * np.einsum("nabc,nab->nc", T, S2)
    grad_G = s[:, :, None] * M1[:, None, :] + np.einsum("nab,nbx->nax", K, GM2)
    if not hessian:
        return ElastonEnergy(energy, grad_e0, grad_G, None)
    h00 = V[:, None, None] * K + np.einsum("ncdb,nb->ncd", T, d1) + 0.5 * np.einsum("nabcd,nab->ncd", Q, S2)
    h0g = np.einsum("nca,nx->ncax", K, M1) + np.einsum("ncad,ndx->ncax", T, GM2)
    hgg = np.einsum("nac,nxz->naxcz", K, M2)
    return ElastonEnergy(energy, grad_e0, grad_G, ElastonHessian(h00, h0g, hgg))


# ----------------------------------------------------------------------------------------------
# material level: (F, dF) -> strain with gradient -> integrated energy
# ----------------------------------------------------------------------------------------------
class MaterialElastonHessian(NamedTuple):
    """Second derivatives of the material-level elaston energy.

    ``FF`` (n, 3, 3, 3, 3): ``[n, i, j, k, l] = d2E/dF_ij dF_kl``;
    ``FdF`` (n, 3, 3, 3, 3, 3): ``[n, i, j, k, l, b] = d2E/dF_ij d(dF_klb)``;
    ``dFdF`` (n, 3, 3, 3, 3, 3, 3): ``[n, i, j, a, k, l, b] = d2E/d(dF_ija) d(dF_klb)``.
    """

    FF: np.ndarray
    FdF: np.ndarray
    dFdF: np.ndarray


class MaterialElastonEnergy(NamedTuple):
    """Integrated energy E (n,) [J], dE/dF (n, 3, 3) [J], dE/d(dF) (n, 3, 3, 3) [J m] and the Hessian (or None)."""

    energy: np.ndarray
    grad_F: np.ndarray
    grad_dF: np.ndarray
    hessian: MaterialElastonHessian | None


def material_elaston_energy(material: Material, F, dF, V, M1, M2, *, hessian: bool = True) -> MaterialElastonEnergy:
    """Elaston energy of a material from the deformation gradient and its spatial gradient.

    The strain with its gradient, ``e0 = E(F)`` and ``G[k, a] = sum_ij dE_k/dF_ij dF_ija``
    (:func:`voxflex.deform.materials.strains.apply_with_gradient`), is integrated over each region by
    :func:`elaston_energy`; the derivatives with respect to ``(F, dF)`` follow by the chain
    rule: the gradient is ``J^T g`` (J the Jacobian of the map (F, dF) -> (e0, G), g the
    law-level gradient), the Hessian ``J^T H J`` plus the geometric terms of the map.

    Accuracy: the strain is linearized over the region, so besides the law's Taylor
    remainder (see the module docstring) the energy misses
    ``1/2 s(e0) . E''(F)[dF (x - x0), dF (x - x0)]`` integrated over the region: the
    error per unit volume is **O(|dF|^2 h^2)** where the sample is stressed
    (``s(e0) != 0``) and the strain is nonlinear in F, O(h^3) where it is stress-free
    (off-centre x0), and zero for a quadratic law over ``linear`` strain.

    Parameters
    ----------
    material : Material
        Any material (strain measure composed with a law).
    F : array (n, 3, 3)
        Deformation gradient at the sample points x0.
    dF : array (n, 3, 3, 3)
        Its spatial gradient, ``dF[n, i, j, a] = dF_ij / dx_a`` [1/m].
    V, M1, M2 : arrays (n,), (n, 3), (n, 3, 3)
        Volume moments of each region about its x0 [m^3, m^4, m^5].
    hessian : bool
        Also return the second derivatives (only for strains whose second
        derivative is constant: ``linear``, ``green``, ``corotational-small``).

    Returns
    -------
    MaterialElastonEnergy
        ``energy`` (n,) [J], ``grad_F`` (n, 3, 3) [J], ``grad_dF`` (n, 3, 3, 3) [J m],
        ``hessian`` (:class:`MaterialElastonHessian` or None); exact derivatives of the
        returned energy.

    Raises
    ------
    InputError
        Wrong shapes, non-finite values, V <= 0, or not a Material.
    NotImplementedError
        ``hessian=True`` for a strain whose second derivative depends on F (its
        third derivatives would be needed); energy and gradient work for all.

    Examples
    --------
    >>> import numpy as np
    >>> from voxflex.deform.materials.constitutive import material
    >>> mat = material("hooke", young=1.0, poisson=0.0, strain="linear")
    >>> from voxflex.sampling.moments import box_moments
    >>> V, M1, M2 = box_moments([[0, 0, 0]], [[1, 1, 1]], [[0.5, 0.5, 0.5]])
    >>> dF = np.zeros((1, 3, 3, 3)); dF[0, 0, 0, 0] = 1.0    # F_xx = 1 + x - 1/2
    >>> float(material_elaston_energy(mat, np.eye(3)[None], dF, V, M1, M2).energy[0])
    0.041666666666666664
    """
    if not isinstance(material, Material):
        raise InputError(f"material must be a voxflex Material, got {type(material).__name__}")
    F = np.asarray(F, dtype=np.float64)
    if F.ndim != 3 or F.shape[1:] != (3, 3):
        raise InputError(f"F must have shape (n, 3, 3), got {F.shape}; pass one deformation gradient per elaston")
    dF = np.asarray(dF, dtype=np.float64)
    if dF.shape != F.shape + (3,):
        raise InputError(f"dF must have shape {F.shape + (3,)} (gradient of F, last index = direction), got {dF.shape}")
    if not (np.all(np.isfinite(F)) and np.all(np.isfinite(dF))):
        raise InputError("F and dF must be finite; pass finite deformation gradients and their gradients")
    strain = material.strain
    if hessian and not strain.constant_hessian:
        raise NotImplementedError(
            f"material_elaston_energy: the Hessian needs third derivatives of strain '{strain.name}', "
            "not implemented (available for linear, green and corotational-small); call with hessian=False"
        )
    return _material_elaston_impl(material, np.ascontiguousarray(F), np.ascontiguousarray(dF), V, M1, M2, hessian)


def _material_elaston_impl(material, F, dF, V, M1, M2, hessian):
    strain, law = material.strain, material.law
    n = F.shape[0]
    e0, G = apply_with_gradient(strain, F, dF)
    res = elaston_energy(law, e0, G, V, M1, M2, hessian=hessian)
    m = e0.shape[1]
    J = strain.jacobian(F)  # (n, m, 3, 3)
    gG = res.grad_G  # (n, m, 3)
    # dE/dF = J^T g_e0 + sum_a geometric(F, g_G[:, :, a]) : dF[..., a]   (the K block, 3 calls)
    grad_F = np.einsum("nkij,nk->nij", J, res.grad_e0)
    for a in range(3):
        geo = strain.geometric(F, np.ascontiguousarray(gG[:, :, a]))
        grad_F += np.einsum("nijpq,nij->npq", geo, dF[..., a])
    # dE/d(dF_ijb) = sum_k g_G[k, b] J[k, i, j]
    grad_dF = np.einsum("nkij,nkb->nijb", J, gG)
    if not hessian:
        return MaterialElastonEnergy(res.energy, grad_F, grad_dF, None)
    # full Jacobian of y = (e0, G) (m + 3m) with respect to x = (F, dF) (9 + 27)
    _, K = jacobian_with_gradient(strain, F, dF)  # K[n, k, a, p, q] = d G_ka / dF_pq
    Jy = np.zeros((n, m, 4, 9, 4))  # [n, k, (e0 | G_k0..2), (ij), (F | dF_ij0..2)]
    Jy[:, :, 0, :, 0] = J.reshape(n, m, 9)
    for a in range(3):
        Jy[:, :, 1 + a, :, 0] = K[:, :, a].reshape(n, m, 9)
        Jy[:, :, 1 + a, :, 1 + a] = J.reshape(n, m, 9)
    Jy = Jy.reshape(n, 4 * m, 36)
    H = res.hessian
    Hy = np.zeros((n, m, 4, m, 4))
    Hy[:, :, 0, :, 0] = H.e0e0
    Hy[:, :, 0, :, 1:] = H.e0G
    Hy[:, :, 1:, :, 0] = H.e0G.transpose(0, 2, 3, 1)
    Hy[:, :, 1:, :, 1:] = H.GG
    Hy = Hy.reshape(n, 4 * m, 4 * m)
    # two batched products (einsum's one three-operand loop took 0.5 s for 400 elastons: 50x the pass)
    Hx = np.matmul(Jy.transpose(0, 2, 1), np.matmul(Hy, Jy)).reshape(n, 9, 4, 9, 4)
    # geometric terms of the map (its second derivative is constant for these strains)
    G_FF, G_FdF = geometric_with_gradient(strain, F, dF, res.grad_e0, gG)
    Hx[:, :, 0, :, 0] += G_FF.reshape(n, 9, 9)
    G_FdF = G_FdF.reshape(n, 9, 9, 3)
    for b in range(3):
        Hx[:, :, 0, :, 1 + b] += G_FdF[..., b]
        Hx[:, :, 1 + b, :, 0] += G_FdF[..., b].transpose(0, 2, 1)
    FF = Hx[:, :, 0, :, 0].reshape(n, 3, 3, 3, 3)
    FdF = Hx[:, :, 0, :, 1:].reshape(n, 3, 3, 3, 3, 3)
    dFdF = Hx[:, :, 1:, :, 1:].reshape(n, 3, 3, 3, 3, 3, 3)
    return MaterialElastonEnergy(res.energy, grad_F, grad_dF, MaterialElastonHessian(FF, FdF, dFdF))


# ----------------------------------------------------------------------------------------------
# moment-fitted sub-rules: any material
# ----------------------------------------------------------------------------------------------
class SubruleEnergy(NamedTuple):
    """Energy E (n,) [J], dE/dF (n, 3, 3) [J], dE/d(dF) (n, 3, 3, 3) [J m] and the Hessian (n, 36, 36) over
    ``x = (F (9), dF (27))`` (C order) [J, J m, J m^2 blocks], or None."""

    energy: np.ndarray
    grad_F: np.ndarray
    grad_dF: np.ndarray
    hessian: np.ndarray | None


def subrule_energy(material: Material, F, dF, offsets, weights, *, hessian: bool = True) -> SubruleEnergy:
    """Energy of a linearly varying F integrated over regions by sub-rules: ``sum_k v_k W(F + dF d_k)``.

    Parameters
    ----------
    material : Material
        Any material.
    F : array (n, 3, 3)
        Deformation gradient at each region's point x0.
    dF : array (n, 3, 3, 3)
        Its spatial gradient, ``dF[n, i, j, a] = dF_ij / dx_a`` [1/m].
    offsets : array (n, k, 3)
        The sub-rule's points relative to x0 [m] (``x_k - x0``).
    weights : array (n, k)
        Their weights [m^3] (a rule from :func:`voxflex.sampling.subrule.moment_fitted_rule`:
        non-negative, reproducing the region's moments to degree 2).
    hessian : bool
        Also return the Hessian.

    Returns
    -------
    SubruleEnergy
        Exact derivatives of the returned energy: with ``phi_k = (1, d_k)``, the gradient
        ``sum_k v_k P_k (x) phi_k`` and the Hessian ``sum_k v_k (phi_k (x) I) A_k (phi_k (x) I)^T``
        (``P_k``, ``A_k`` the material's stress and tangent at ``F_k``).  ``energy`` is +inf where
        the material is undefined at a point (e.g. det F_k <= 0 for neo-Hooke).

    Examples
    --------
    >>> import numpy as np
    >>> from voxflex.deform.materials.constitutive import material
    >>> mat = material("hooke", young=1.0, poisson=0.0, strain="linear")
    >>> d = np.array([[[-0.5, 0, 0], [0.5, 0, 0]]]) / np.sqrt(3)    # 2-point Gauss along x on [-1/2, 1/2]
    >>> dF = np.zeros((1, 3, 3, 3)); dF[0, 0, 0, 0] = 1.0            # F_xx = 1 + x
    >>> float(subrule_energy(mat, np.eye(3)[None], dF, d, np.full((1, 2), 0.5)).energy[0])  # int x^2 / 2
    0.041666666666666664
    """
    if not isinstance(material, Material):
        raise InputError(f"material must be a voxflex Material, got {type(material).__name__}")
    F = np.asarray(F, dtype=np.float64)
    dF = np.asarray(dF, dtype=np.float64)
    d = np.asarray(offsets, dtype=np.float64)
    v = np.asarray(weights, dtype=np.float64)
    if F.ndim != 3 or F.shape[1:] != (3, 3):
        raise InputError(f"F must have shape (n, 3, 3), got {F.shape}")
    n = F.shape[0]
    if dF.shape != (n, 3, 3, 3):
        raise InputError(f"dF must have shape {(n, 3, 3, 3)}, got {dF.shape}")
    if d.ndim != 3 or d.shape[0] != n or d.shape[2] != 3 or v.shape != d.shape[:2]:
        raise InputError(f"offsets must be (n, k, 3) and weights (n, k) for n = {n}, got {d.shape} and {v.shape}")
    if not all(np.all(np.isfinite(a)) for a in (F, dF, d, v)):
        raise InputError("F, dF, offsets and weights must be finite")
    if np.any(v < 0):
        raise InputError("sub-rule weights must be >= 0")
    k = d.shape[1]
    Fk = F[:, None] + np.einsum("nija,nka->nkij", dF, d)  # (n, k, 3, 3)
    W, P, A = material.evaluate(Fk.reshape(-1, 3, 3), tangent=hessian)
    W = W.reshape(n, k)
    energy = np.einsum("nk,nk->n", v, W)
    P = P.reshape(n, k, 3, 3) * v[..., None, None]
    grad_F = P.sum(axis=1)
    grad_dF = np.einsum("nkij,nka->nija", P, d)
    H = None
    if hessian:
        phi = np.concatenate([np.ones((n, k, 1)), d], axis=2)  # (n, k, 4): 1, d
        A = A.reshape(n, k, 9, 9) * v[..., None, None]
        Hb = np.einsum("nka,nkxy,nkb->nxayb", phi, A, phi, optimize=True)  # (n, 9, 4, 9, 4)
        # x = (F (ij), dF (ij, a)): position of (ij, 0) is ij, of (ij, a >= 1) is 9 + 3 ij + a - 1
        perm = np.concatenate([np.arange(9) * 4, (np.arange(9)[:, None] * 4 + np.arange(1, 4)[None, :]).ravel()])
        H = Hb.reshape(n, 36, 36)[:, perm][:, :, perm]
    return SubruleEnergy(energy, grad_F, grad_dF, H)
