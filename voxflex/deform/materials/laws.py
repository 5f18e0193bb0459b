"""Energy densities over strain vectors: the last link of the chain.

A :class:`Law` maps a batch of strain vectors ``e`` (n, m) to the energy
density ``W`` (n,) [J/m^3 = Pa], its gradient, the conjugate stress
``s = dW/de`` (n, m), and its Hessian, the tangent ``K = d2W/de2`` (n, m, m).
Which strain measure a law reads is named by ``strain_kind``:

``"tensor"``
    Voigt vectors ``[xx, yy, zz, xy, yz, xz]`` with engineering shear (linear,
    Green, corotational strains); the conjugate stress has no factor 2, so
    ``W = 1/2 e^T C e`` uses the usual Voigt stiffness ``C``.
``"invariant"``
    ``(I1, I2, J)`` of ``C = F^T F``.
``"invariant-deviatoric"``
    ``(I1bar, I2bar, J)``.
``"principal-stretch"``
    the singular values of F (descending).

Every law has one compiled kernel (``voxflex._jit.njit``) and a plain numpy
twin, both in :mod:`voxflex.deform.materials._law_kernels`;
``evaluate(e, backend="numpy")`` runs the twin (the tests compare them).
``higher(e)`` gives the third and fourth derivatives (numpy), used by the
elaston integration (:mod:`voxflex.deform.materials.elaston`).

Samples outside a law's domain (``J <= 0`` for a law with ``ln J``, a
non-positive principal stretch for Ogden) get ``W = +inf`` and NaN stress and
tangent, so that a line search sees the infinite energy; nothing is clipped.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...errors import InputError
from ._law_kernels import (
    _arruda_boyce_kernel,
    _arruda_boyce_numpy,
    _hooke_kernel,
    _hooke_numpy,
    _mooney_rivlin_kernel,
    _mooney_rivlin_numpy,
    _neo_hookean_kernel,
    _neo_hookean_numpy,
    _ogden_kernel,
    _ogden_numpy,
    _stable_neo_hookean_kernel,
    _stable_neo_hookean_numpy,
    _veronda_westmann_kernel,
    _veronda_westmann_numpy,
    _volume_kernel,
    _volume_numpy,
)

__all__ = [
    "Law",
    "HookeLaw",
    "NeoHookeanLaw",
    "StableNeoHookeanLaw",
    "MooneyRivlinLaw",
    "ArrudaBoyceLaw",
    "VerondaWestmannLaw",
    "VolumeLogLaw",
    "VolumeQuadraticLaw",
    "OgdenLaw",
    "STRAIN_KINDS",
    "isotropic_stiffness",
    "orthotropic_stiffness",
]

STRAIN_KINDS = ("tensor", "invariant", "invariant-deviatoric", "principal-stretch")
"""The strain kinds a law may read (see the module docstring)."""

BACKENDS = ("numba", "numpy")


# ----------------------------------------------------------------------------------------------
# stiffness matrices (Voigt, engineering shear)
# ----------------------------------------------------------------------------------------------
def isotropic_stiffness(mu: float, lmbda: float) -> np.ndarray:
    """Voigt stiffness (6, 6) [Pa] of isotropic Hooke from the Lamé constants.

    ``C = lmbda 1 1^T + mu diag(2, 2, 2, 1, 1, 1)``: normal block ``lmbda + 2 mu``
    on the diagonal, shear block ``mu`` (engineering shear strain).
    """
    C = np.zeros((6, 6))
    C[:3, :3] = lmbda
    C[np.arange(3), np.arange(3)] += 2.0 * mu
    C[np.arange(3, 6), np.arange(3, 6)] = mu
    return C


def orthotropic_stiffness(E1, E2, E3, nu12, nu13, nu23, G12, G23, G13) -> np.ndarray:
    """Voigt stiffness (6, 6) [Pa] of orthotropic Hooke: the inverse of the compliance.

    The compliance ``S`` has ``S_ii = 1/E_i``, ``S_ij = -nu_ij / E_i`` (so
    ``nu_ji = nu_ij E_j / E_i`` and S is symmetric) and the shear entries
    ``1/G12, 1/G23, 1/G13`` for the Voigt shear order ``xy, yz, xz``.
    Raises :class:`InputError` when S is not positive definite.
    """
    S = np.zeros((6, 6))
    S[0, 0], S[1, 1], S[2, 2] = 1.0 / E1, 1.0 / E2, 1.0 / E3
    S[0, 1] = S[1, 0] = -nu12 / E1
    S[0, 2] = S[2, 0] = -nu13 / E1
    S[1, 2] = S[2, 1] = -nu23 / E2
    S[3, 3], S[4, 4], S[5, 5] = 1.0 / G12, 1.0 / G23, 1.0 / G13
    eig = np.linalg.eigvalsh(S)
    if not np.all(eig > 0):
        raise InputError(
            "orthotropic constants give a compliance that is not positive definite; "
            "need E_i, G_ij > 0 and 1 - nu12*nu21 - nu23*nu32 - nu13*nu31 - 2*nu21*nu32*nu13 > 0"
        )
    return np.linalg.inv(S)


# ----------------------------------------------------------------------------------------------
# the laws
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Law:
    """An energy density over strain vectors e (n, m); subclasses fill in the kernels.

    Attributes
    ----------
    strain_kind : str
        The strain measure it reads (one of :data:`STRAIN_KINDS`).
    size : int
        m, the length of a strain vector.
    quadratic : bool
        Whether W is a quadratic polynomial of e (constant tangent K).
    """

    strain_kind = "tensor"
    accepts = ("tensor",)
    size = 6
    quadratic = False
    _kernel = None
    _twin = None

    @property
    def params(self) -> np.ndarray:  # pragma: no cover - overridden
        raise NotImplementedError

    def check(self, e) -> np.ndarray:
        """Validate a strain batch: float64 array (n, size)."""
        e = np.asarray(e, dtype=np.float64)
        if e.ndim != 2 or e.shape[1] != self.size:
            raise InputError(f"strain vectors must have shape (n, {self.size}) for {type(self).__name__}, got {e.shape}")
        return np.ascontiguousarray(e)

    def evaluate(self, e, *, tangent: bool = True, backend: str = "numba"):
        """Energy, stress and (optionally) tangent in one pass.

        Parameters
        ----------
        e : array (n, m)
            Strain vectors.
        tangent : bool
            Also compute ``K``; otherwise the third result is None.
        backend : {"numba", "numpy"}
            The compiled kernel or its numpy twin.

        Returns
        -------
        W : (n,) energy density [Pa]; s : (n, m) dW/de [Pa]; K : (n, m, m) or None.
        """
        e = self.check(e)
        return self._evaluate(e, tangent, backend)

    def _evaluate(self, e, tangent, backend):
        if backend == "numpy":
            W, s, K = type(self)._twin(e, self.params)
            return W, s, (K if tangent else None)
        if backend != "numba":
            raise InputError(f"unknown backend '{backend}'; valid: {', '.join(BACKENDS)}")
        n, m = e.shape
        W = np.empty(n)
        s = np.empty((n, m))
        K = np.empty((n, m, m) if tangent else (1, m, m))
        type(self)._kernel(e, self.params, W, s, K, tangent)
        return W, s, (K if tangent else None)

    def energy(self, e) -> np.ndarray:
        """Energy density W (n,) [Pa]."""
        return self.evaluate(e, tangent=False)[0]

    def stress(self, e) -> np.ndarray:
        """Conjugate stress s = dW/de (n, m) [Pa]."""
        return self.evaluate(e, tangent=False)[1]

    def tangent(self, e) -> np.ndarray:
        """Tangent K = d2W/de2 (n, m, m) [Pa]."""
        return self.evaluate(e, tangent=True)[2]

    linear_in_i1 = False
    """Laws over ``(I1, I2, J)`` of the form ``W = a I1 + f(J)`` (no I2, no coupling): their tangent in F is
    ``2 s1 I + s3 d2J/dF2 + K33 dJ/dF dJ/dF`` (``s1 = a``), which the voxel model assembles into its
    element stiffness from ``s1, s3, K33`` and the cofactor of F without the (9, 9) tangent
    (:func:`voxflex.deform.models.voxel._kernels.element_stiffness_i1j`)."""

    shifted_energy = None
    """Optional, laws over ``(I1, I2, J)``: ``shifted_energy(i1, j) -> W (n,)`` from ``i1 = I1 - 3`` and
    ``j = J - 1`` given without cancellation (numpy; see :func:`shifted_invariants`), written so that the
    terms of first order in the strain cancel analytically.  Near rest ``W`` is then exact to round-off
    relative to itself, not to the moduli: with invariants near 3 and 1 every sample loses about
    ``eps mu`` (Pa), which swamps the energy changes of a soft part beside a 1e6 times stiffer one."""

    def higher(self, e):
        """Third and fourth derivatives ``T`` (n, m, m, m) and ``Q`` (n, m, m, m, m) (numpy).

        Zero for laws quadratic in e; used by :func:`voxflex.deform.materials.elaston.elaston_energy`.
        """
        e = self.check(e)
        n, m = e.shape
        return np.zeros((n, m, m, m)), np.zeros((n, m, m, m, m))


@dataclass(frozen=True, eq=False)
class HookeLaw(Law):
    """W = 1/2 e^T C e over a Voigt tensor strain (engineering shear).

    Parameters
    ----------
    C : array (6, 6)
        Symmetric positive definite Voigt stiffness [Pa]; see
        :func:`isotropic_stiffness`, :func:`orthotropic_stiffness`.
    """
    quadratic = True

    C: np.ndarray = field(default_factory=lambda: np.eye(6))
    strain_kind = "tensor"
    accepts = ("tensor",)
    size = 6
    _kernel = staticmethod(_hooke_kernel)
    _twin = staticmethod(_hooke_numpy)

    def __post_init__(self):
        C = np.array(self.C, dtype=np.float64)
        if C.shape != (6, 6) or not np.all(np.isfinite(C)) or not np.allclose(C, C.T, rtol=1e-12, atol=0):
            raise InputError("Hooke stiffness C must be a finite symmetric (6, 6) Voigt matrix")
        object.__setattr__(self, "C", C)
        object.__setattr__(self, "_params", np.ascontiguousarray(C.ravel()))

    @property
    def params(self):
        return self._params


def _scalar_derivs_log(J, a, b):
    """Derivatives 3 and 4 of h(J) = -a ln J + b/2 (ln J)^2."""
    L = np.log(J)
    h3 = (-2.0 * a + b * (2.0 * L - 3.0)) / J**3
    h4 = (6.0 * a + b * (11.0 - 6.0 * L)) / J**4
    return h3, h4


def _higher_in_J(e, h3, h4):
    n, m = e.shape
    T = np.zeros((n, m, m, m))
    Q = np.zeros((n, m, m, m, m))
    T[:, 2, 2, 2] = h3
    Q[:, 2, 2, 2, 2] = h4
    return T, Q


@dataclass(frozen=True, eq=False)
class NeoHookeanLaw(Law):
    """W = mu/2 (I1 - 3) - mu ln J + lmbda/2 (ln J)^2 over ``(I1, I2, J)``.

    ``J <= 0`` (inverted) gives W = +inf and NaN stress/tangent.
    """

    mu: float = 1.0
    lmbda: float = 1.0
    strain_kind = "invariant"
    accepts = ("invariant",)
    size = 3
    linear_in_i1 = True
    _kernel = staticmethod(_neo_hookean_kernel)
    _twin = staticmethod(_neo_hookean_numpy)

    @property
    def params(self):
        return np.array([self.mu, self.lmbda], dtype=np.float64)

    def shifted_energy(self, i1, j):
        """W (n,) [Pa] from ``i1 = I1 - 3``, ``j = J - 1``: ``mu/2 (i1 - 2 L) + mu (j - L) + lmbda/2 L^2``
        with ``L = log1p(j)`` and ``i1 - 2 j``, ``j - L`` of second order (+inf where J <= 0)."""
        bad = ~(j > -1.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            L = np.log1p(np.where(bad, 0.0, j))
            W = 0.5 * self.mu * (i1 - 2.0 * j) + self.mu * (j - L) + 0.5 * self.lmbda * L * L
        return np.where(bad, np.inf, W)

    def higher(self, e):
        e = self.check(e)
        with np.errstate(divide="ignore", invalid="ignore"):
            h3, h4 = _scalar_derivs_log(e[:, 2], self.mu, self.lmbda)
        return _higher_in_J(e, h3, h4)


@dataclass(frozen=True, eq=False)
class StableNeoHookeanLaw(Law):
    """Stable Neo-Hooke over ``(I1, I2, J)``, defined for inverted F.

    ``W = mu'/2 (I1 - 3) + lmbda'/2 (J - alpha)^2 - mu'/2 ln(I1 + 1) - W0`` with
    ``alpha = 1 + 3 mu' / (4 lmbda')``; W0 makes W(I) = 0 (the stress at rest is
    already zero).  Give ``mu_s = 4 mu / 3``, ``lmbda_s = lmbda + 5 mu / 6`` to
    linearize to Hooke with Lamé ``mu, lmbda``.

    References
    ----------
    B. Smith, F. de Goes, T. Kim, "Stable Neo-Hookean Flesh Simulation", ACM TOG 37(2), 2018.
    """

    mu_s: float = 1.0
    lmbda_s: float = 1.0
    strain_kind = "invariant"
    accepts = ("invariant",)
    size = 3
    _kernel = staticmethod(_stable_neo_hookean_kernel)
    _twin = staticmethod(_stable_neo_hookean_numpy)

    @property
    def alpha(self) -> float:
        return 1.0 + 0.75 * self.mu_s / self.lmbda_s

    @property
    def params(self):
        alpha = self.alpha
        w0 = 0.5 * self.lmbda_s * (1.0 - alpha) ** 2 - 0.5 * self.mu_s * np.log(4.0)
        return np.array([self.mu_s, self.lmbda_s, alpha, w0], dtype=np.float64)

    def shifted_energy(self, i1, j):
        """W (n,) [Pa] from ``i1 = I1 - 3``, ``j = J - 1``, first-order terms cancelled analytically:
        with ``x = i1 / 4`` and ``lmbda' (1 - alpha) = -3 mu'/4``,
        ``W = 3 mu'/8 (i1 - 2 j) + mu'/2 (x - log1p(x)) + lmbda'/2 j^2``."""
        x = 0.25 * i1
        with np.errstate(divide="ignore", invalid="ignore"):
            return 0.375 * self.mu_s * (i1 - 2.0 * j) + 0.5 * self.mu_s * (x - np.log1p(x)) + 0.5 * self.lmbda_s * j * j

    def higher(self, e):
        e = self.check(e)
        n = e.shape[0]
        T = np.zeros((n, 3, 3, 3))
        Q = np.zeros((n, 3, 3, 3, 3))
        x = e[:, 0] + 1.0
        T[:, 0, 0, 0] = -self.mu_s / x**3
        Q[:, 0, 0, 0, 0] = 3.0 * self.mu_s / x**4
        return T, Q


@dataclass(frozen=True, eq=False)
class MooneyRivlinLaw(Law):
    """W = c1 (I1bar - 3) + c2 (I2bar - 3) + bulk/2 (J - 1)^2 over ``(I1bar, I2bar, J)``.

    Small-strain shear modulus ``2 (c1 + c2)``, bulk modulus ``bulk``.
    """
    quadratic = True

    c1: float = 0.5
    c2: float = 0.0
    bulk: float = 1.0
    strain_kind = "invariant-deviatoric"
    accepts = ("invariant-deviatoric",)
    size = 3
    _kernel = staticmethod(_mooney_rivlin_kernel)
    _twin = staticmethod(_mooney_rivlin_numpy)

    @property
    def params(self):
        return np.array([self.c1, self.c2, self.bulk], dtype=np.float64)


def _higher_in_I1(e, t, q):
    """Third and fourth derivatives of a law whose only non-quadratic part is f(I1bar)."""
    n, m = e.shape
    T = np.zeros((n, m, m, m))
    Q = np.zeros((n, m, m, m, m))
    T[:, 0, 0, 0] = t
    Q[:, 0, 0, 0, 0] = q
    return T, Q


# Arruda-Boyce eight-chain series: W = mu sum_i C_i / lambda_m^(2i-2) (I1bar^i - 3^i)
ARRUDA_BOYCE_SERIES = (1.0 / 2.0, 1.0 / 20.0, 11.0 / 1050.0, 19.0 / 7000.0, 519.0 / 673750.0)
"""The coefficients C_i of the five-term eight-chain series (Arruda & Boyce 1993)."""


@dataclass(frozen=True, eq=False)
class ArrudaBoyceLaw(Law):
    """Arruda-Boyce (eight-chain) over ``(I1bar, I2bar, J)``.

    ``W = mu sum_{i=1..5} C_i / lambda_m^(2i-2) (I1bar^i - 3^i) + bulk/2 (J - 1)^2`` with
    ``C = (1/2, 1/20, 11/1050, 19/7000, 519/673750)`` (:data:`ARRUDA_BOYCE_SERIES`).  The
    volumetric part is the quadratic ``bulk/2 (J - 1)^2`` (as Mooney-Rivlin here): defined for
    any J, bulk modulus ``bulk`` at rest.  ``mu`` is the series coefficient; the small-strain
    shear modulus is :attr:`shear_modulus` ``= mu (1 + 3/(5 lm^2) + 99/(175 lm^4)
    + 513/(875 lm^6) + 42039/(67375 lm^8))``, ``lm = lambda_m``.

    Parameters
    ----------
    mu : float
        Series coefficient [Pa], > 0.
    lambda_m : float
        Locking stretch, > 1.
    bulk : float
        Bulk modulus [Pa], > 0.

    References
    ----------
    E. M. Arruda, M. C. Boyce, "A three-dimensional constitutive model for the large stretch
    behavior of rubber elastic materials", J. Mech. Phys. Solids 41(2), 1993.
    """

    mu: float = 1.0
    lambda_m: float = 2.8
    bulk: float = 1.0
    strain_kind = "invariant-deviatoric"
    accepts = ("invariant-deviatoric",)
    size = 3
    _kernel = staticmethod(_arruda_boyce_kernel)
    _twin = staticmethod(_arruda_boyce_numpy)

    def __post_init__(self):
        for name in ("mu", "lambda_m", "bulk"):
            v = getattr(self, name)
            if not np.isfinite(v):
                raise InputError(f"Arruda-Boyce {name} must be finite, got {v!r}")
        if not self.lambda_m > 1.0:
            raise InputError(f"Arruda-Boyce lambda_m = {self.lambda_m!r} is out of range; valid: (1, inf)")
        a = [self.mu * c / self.lambda_m ** (2 * i) for i, c in enumerate(ARRUDA_BOYCE_SERIES)]
        object.__setattr__(self, "_params", np.array([*a, self.bulk], dtype=np.float64))

    @property
    def params(self):
        return self._params

    @property
    def shear_modulus(self) -> float:
        """Small-strain shear modulus [Pa]: ``2 dW/dI1bar`` at rest."""
        p = np.arange(1.0, 6.0)
        return float(2.0 * np.sum(p * self._params[:5] * 3.0 ** (p - 1.0)))

    def higher(self, e):
        e = self.check(e)
        a = self._params[:5]
        p = np.arange(1.0, 6.0)
        x = e[:, :1]
        # p(p-1)(p-2) a_p x^(p-3) and p(p-1)(p-2)(p-3) a_p x^(p-4): the falling factorials vanish
        # where the power would be negative, so the clipped power never matters
        c3 = p * (p - 1) * (p - 2) * a
        c4 = c3 * (p - 3)
        t = np.sum(c3 * x ** np.maximum(p - 3.0, 0.0), axis=1)
        q = np.sum(c4 * x ** np.maximum(p - 4.0, 0.0), axis=1)
        return _higher_in_I1(e, t, q)


@dataclass(frozen=True, eq=False)
class VerondaWestmannLaw(Law):
    """Veronda-Westmann over ``(I1bar, I2bar, J)``.

    ``W = c1 (exp(c2 (I1bar - 3)) - 1) - c1 c2/2 (I2bar - 3) + bulk/2 (J - 1)^2``;
    small-strain shear modulus ``c1 c2``, bulk modulus ``bulk``.

    Parameters
    ----------
    c1 : float
        Stress scale [Pa], > 0.
    c2 : float
        Exponential stiffening (dimensionless), > 0.
    bulk : float
        Bulk modulus [Pa], > 0.

    References
    ----------
    D. R. Veronda, R. A. Westmann, "Mechanical characterization of skin - finite deformations",
    J. Biomech. 3(1), 1970.
    """

    c1: float = 1.0
    c2: float = 1.0
    bulk: float = 1.0
    strain_kind = "invariant-deviatoric"
    accepts = ("invariant-deviatoric",)
    size = 3
    _kernel = staticmethod(_veronda_westmann_kernel)
    _twin = staticmethod(_veronda_westmann_numpy)

    @property
    def params(self):
        return np.array([self.c1, self.c2, self.bulk], dtype=np.float64)

    def higher(self, e):
        e = self.check(e)
        x = self.c1 * np.exp(self.c2 * (e[:, 0] - 3.0))
        return _higher_in_I1(e, x * self.c2**3, x * self.c2**4)


@dataclass(frozen=True, eq=False)
class VolumeLogLaw(Law):
    """W = bulk/2 (ln J)^2, J the third entry of an invariant strain; J <= 0 gives +inf."""

    bulk: float = 1.0
    strain_kind = "invariant"
    accepts = ("invariant", "invariant-deviatoric")
    size = 3
    _kernel = staticmethod(_volume_kernel)
    _twin = staticmethod(_volume_numpy)

    @property
    def params(self):
        return np.array([self.bulk, 0.0])

    def higher(self, e):
        e = self.check(e)
        with np.errstate(divide="ignore", invalid="ignore"):
            h3, h4 = _scalar_derivs_log(e[:, 2], 0.0, self.bulk)
        return _higher_in_J(e, h3, h4)


@dataclass(frozen=True, eq=False)
class VolumeQuadraticLaw(Law):
    """W = bulk/2 (J - 1)^2, J the third entry of an invariant strain (defined for any J)."""

    quadratic = True

    bulk: float = 1.0
    strain_kind = "invariant"
    accepts = ("invariant", "invariant-deviatoric")
    size = 3
    _kernel = staticmethod(_volume_kernel)
    _twin = staticmethod(_volume_numpy)

    @property
    def params(self):
        return np.array([self.bulk, 1.0])


@dataclass(frozen=True, eq=False)
class OgdenLaw(Law):
    """Compressible Ogden over the principal stretches ``(l1, l2, l3)``.

    ``W = sum_p mu_p/alpha_p (sum_i l_i^alpha_p - 3 - alpha_p ln J) + lmbda/2 (ln J)^2``
    with ``ln J = sum_i ln l_i``; small-strain shear modulus
    ``mu = sum_p mu_p alpha_p / 2``, Lamé ``lmbda``.  One term with ``alpha = 2``
    is Neo-Hooke.  A non-positive stretch gives W = +inf.

    References
    ----------
    R. W. Ogden, "Large deformation isotropic elasticity", Proc. R. Soc. A 326, 1972.
    """

    mu_p: tuple = (1.0,)
    alpha_p: tuple = (2.0,)
    lmbda: float = 1.0
    strain_kind = "principal-stretch"
    accepts = ("principal-stretch",)
    size = 3
    _kernel = staticmethod(_ogden_kernel)
    _twin = staticmethod(_ogden_numpy)

    def __post_init__(self):
        mu = np.atleast_1d(np.asarray(self.mu_p, dtype=np.float64))
        al = np.atleast_1d(np.asarray(self.alpha_p, dtype=np.float64))
        if mu.ndim != 1 or mu.shape != al.shape or mu.size == 0:
            raise InputError("Ogden mu_p and alpha_p must be sequences of the same non-zero length")
        if np.any(al == 0) or not np.all(np.isfinite(al)) or not np.all(np.isfinite(mu)):
            raise InputError("Ogden alpha_p must be finite and non-zero, mu_p finite")
        object.__setattr__(self, "mu_p", tuple(float(v) for v in mu))
        object.__setattr__(self, "alpha_p", tuple(float(v) for v in al))
        p = np.empty(1 + 2 * mu.size)
        p[0] = self.lmbda
        p[1::2], p[2::2] = mu, al
        object.__setattr__(self, "_params", p)

    @property
    def params(self):
        return self._params

    def higher(self, e):
        e = self.check(e)
        n = e.shape[0]
        mus = np.asarray(self.mu_p)
        als = np.asarray(self.alpha_p)
        lm = self.lmbda
        with np.errstate(divide="ignore", invalid="ignore"):
            x = e
            lx = np.log(x)
            L = lx.sum(axis=1)
            xa = np.exp(als[None, None, :] * lx[:, :, None])
            # separable part phi(x): third and fourth derivatives
            p3 = np.einsum("p,nip->ni", mus, (als - 1) * (als - 2) * xa - 2.0 + 0 * xa) / x**3
            p4 = np.einsum("p,nip->ni", mus, (als - 1) * (als - 2) * (als - 3) * xa + 6.0 + 0 * xa) / x**4
            # derivatives of u = ln x
            u1, u2, u3, u4 = 1 / x, -1 / x**2, 2 / x**3, -6 / x**4
        d = np.eye(3)
        T = np.zeros((n, 3, 3, 3))
        Q = np.zeros((n, 3, 3, 3, 3))
        # psi = lm/2 (sum u)^2 composed with u_i = ln x_i (Faa di Bruno, diagonal inner map)
        for i in range(3):
            for j in range(3):
                for k in range(3):
                    t = lm * (d[i, k] * u2[:, i] * u1[:, j] + d[j, k] * u1[:, i] * u2[:, j] + d[i, j] * u1[:, k] * u2[:, i])
                    if i == j == k:
                        t = t + lm * L * u3[:, i] + p3[:, i]
                    T[:, i, j, k] = t
                    for l in range(3):
                        qv = lm * (
                            d[i, k] * (d[i, l] * u3[:, i] * u1[:, j] + d[j, l] * u2[:, i] * u2[:, j])
                            + d[j, k] * (d[i, l] * u2[:, i] * u2[:, j] + d[j, l] * u1[:, i] * u3[:, j])
                            + d[i, j] * (d[k, l] * u2[:, k] * u2[:, i] + d[i, l] * u1[:, k] * u3[:, i])
                        )
                        if i == j == k:
                            qv = qv + lm * u1[:, l] * u3[:, i]
                            if l == i:
                                qv = qv + lm * L * u4[:, i] + p4[:, i]
                        Q[:, i, j, k, l] = qv
        bad = ~np.all(e > 0, axis=1)
        T[bad] = np.nan
        Q[bad] = np.nan
        return T, Q
