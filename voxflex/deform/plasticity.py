"""Plasticity by a rest-strain (relative) mapping: ``e → e - e_p`` with von Mises yield on the strain.

A :class:`PlasticMaterial` wraps an elastic :class:`~voxflex.deform.materials.Material`
whose strain is a Voigt tensor (``linear``, ``green``, the corotational
ones): the law sees the elastic strain ``e - e_p`` where ``e_p`` ``(s, 6)`` is
a plastic (rest) strain stored per quadrature sample.  Subtracting a fixed
``e_p`` is a relative mapping with identity Jacobian, so stress and tangent
are the base material's at the shifted strain (exact derivatives for a given
state).

Yield and hardening (strain space, isotropic, associative)
-----------------------------------------------------------
With ``dev`` the deviator of the elastic strain tensor (Voigt shear halved)
and ``ε_eq = sqrt(2/3) |dev(e - e_p)|`` the von Mises equivalent strain, a
sample yields when ``ε_eq > ε_y + H α`` (``ε_y`` the yield strain, H ≥ 0 the
dimensionless linear hardening modulus, α the accumulated equivalent plastic
strain).  The return mapping (radial, exact for linear hardening) moves e_p
along the trial deviator ``n``: ``Δγ = (sqrt(2/3) |dev_tr| - ε_y - H α_n) /
(sqrt(2/3) (1 + H))``, ``e_p += Δγ n``, ``α += sqrt(2/3) Δγ``.  For an
isotropic Hooke law the deviatoric stress is ``2 μ dev``, so this is the
classical von Mises model with yield stress ``σ_y = 3 μ ε_y`` and hardening
modulus ``3 μ H``; in uniaxial stress the elastic-plastic tangent is
``E·3μH / (E + 3μH)``.

The state is updated between solves, not inside Newton (a staggered scheme):
:meth:`PlasticMaterial.update` return-maps from the last committed state with
the current total strain; repeating solve + update until e_p stops changing
solves the implicit incremental problem of the load step, and
:meth:`PlasticMaterial.commit` then makes it the start of the next step.

Sample identity
---------------
``evaluate(F, samples=ids)`` takes the sample indices of the rows of F.
Without ``samples`` it requires F to hold every sample in order (one call
over all samples: a voxel model of one label under 16,384 voxels evaluates
exactly so, element-major, 8 Gauss points per voxel); any other row count is
refused, because the plastic strains could not be matched to the rows.

Example
-------
>>> import numpy as np
>>> from voxflex.deform.materials import material
>>> mat = PlasticMaterial(material("hooke", young=1.0, poisson=0.0, strain="linear"), 1, yield_strain=0.01)
>>> F = np.diag([1.1, 1.0, 1.0])[None]
>>> mat.update(F)                  # the sample yields
1
>>> bool(mat.energy(F)[0] < material("hooke", young=1.0, poisson=0.0, strain="linear").energy(F)[0])
True
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from .materials import Material, strain_kind

__all__ = ["PlasticMaterial", "von_mises_strain", "equilibrate"]

_SQ23 = np.sqrt(2.0 / 3.0)


def _deviator(e):
    """Deviatoric strain tensor in Voigt (tensor shear, no factor 2) and its Frobenius norm."""
    d = np.asarray(e, dtype=np.float64).copy()
    d[:, 3:] *= 0.5
    d[:, :3] -= d[:, :3].mean(axis=1, keepdims=True)
    norm = np.sqrt((d[:, :3] ** 2).sum(axis=1) + 2.0 * (d[:, 3:] ** 2).sum(axis=1))
    return d, norm


def von_mises_strain(e) -> np.ndarray:
    """Equivalent strain ``sqrt(2/3) |dev(e)|`` ``(s,)`` of Voigt strains ``(s, 6)`` (engineering shear)."""
    e = np.asarray(e, dtype=np.float64)
    if e.ndim != 2 or e.shape[1] != 6:
        raise InputError(f"strains must be (s, 6) Voigt vectors, got shape {e.shape}")
    return _SQ23 * _deviator(e)[1]


class _ShiftedStrain:
    """The base strain minus a per-row offset (set before each evaluation)."""

    kind = "tensor"
    size = 6

    def __init__(self, base):
        self.base = base
        self.name = f"{base.name}-minus-plastic"
        self.constant_jacobian = bool(getattr(base, "constant_jacobian", False))
        self.offset = None

    def apply(self, F):
        return self.base.apply(F) - self.offset

    def evaluate(self, F, s=None, *, law_tangent=None):
        out = self.base.evaluate(F, s, law_tangent=law_tangent)
        return (out[0] - self.offset,) + tuple(out[1:])

    def evaluate_reference(self, F, s=None, *, law_tangent=None):
        out = self.base.evaluate_reference(F, s, law_tangent=law_tangent)
        return (out[0] - self.offset,) + tuple(out[1:])

    def jacobian(self, F):
        return self.base.jacobian(F)

    def geometric(self, F, s, *, law_tangent=None):
        return self.base.geometric(F, s, law_tangent=law_tangent)


class PlasticMaterial:
    """An elastic material with a per-sample plastic rest strain (see the module docstring).

    Parameters
    ----------
    base : Material
        The elastic material; its strain must be a Voigt tensor strain.
    n_samples : int
        Number of quadrature samples s whose state is stored.
    yield_strain : float
        ε_y > 0, the von Mises equivalent strain at first yield (dimensionless).
    hardening : float
        H >= 0, the increase of the yield strain per unit equivalent plastic strain.

    Attributes
    ----------
    plastic_strain : (s, 6) float
        Current e_p (Voigt, engineering shear).
    alpha : (s,) float
        Current accumulated equivalent plastic strain.
    """

    constant_tangent = False  # the shift changes between steps: never cache the stiffness

    def __init__(self, base: Material, n_samples: int, *, yield_strain: float, hardening: float = 0.0):
        if not isinstance(base, Material):
            raise InputError(f"base must be a voxflex Material (vf.material(...)), got {type(base).__name__}")
        if strain_kind(base.strain) != "tensor":
            raise InputError(f"plasticity needs a tensor strain (linear, green, corotational...), not '{base.strain.name}'")
        if int(n_samples) != n_samples or n_samples < 1:
            raise InputError(f"n_samples must be a positive integer, got {n_samples!r}")
        if not (np.isfinite(yield_strain) and yield_strain > 0):
            raise InputError(f"yield_strain must be > 0 (equivalent strain), got {yield_strain!r}")
        if not (np.isfinite(hardening) and hardening >= 0):
            raise InputError(f"hardening must be >= 0 (dimensionless), got {hardening!r}")
        self.base = base
        self.n_samples = int(n_samples)
        self.yield_strain = float(yield_strain)
        self.hardening = float(hardening)
        self.name = f"plastic-{base.name}"
        self.parameters = dict(base.parameters, yield_strain=self.yield_strain, hardening=self.hardening)
        self._strain = _ShiftedStrain(base.strain)
        self._inner = Material(strain=self._strain, law=base.law, name=self.name, parameters=self.parameters)
        self.plastic_strain = np.zeros((self.n_samples, 6))
        self.alpha = np.zeros(self.n_samples)
        self._committed = (self.plastic_strain.copy(), self.alpha.copy())

    # -- rows <-> samples ----------------------------------------------------
    def _rows(self, F, samples):
        F = np.asarray(F, dtype=np.float64)
        if F.ndim != 3 or F.shape[1:] != (3, 3):
            raise InputError(f"deformation gradients F must have shape (n, 3, 3), got {F.shape}")
        if samples is None:
            if len(F) != self.n_samples:
                raise InputError(
                    f"F has {len(F)} rows but the plastic state has {self.n_samples} samples; pass samples= "
                    "(the sample index of each row) or evaluate every sample in one call"
                )
            return F, slice(None)
        ids = np.asarray(samples, dtype=np.int64).reshape(-1)
        if len(ids) != len(F) or (ids.size and (ids.min() < 0 or ids.max() >= self.n_samples)):
            raise InputError(f"samples must give one index in [0, {self.n_samples}) per row of F")
        return F, ids

    # -- material interface ----------------------------------------------------
    def evaluate(self, F, *, tangent: bool = True, backend: str = "numba", samples=None):
        """W (n,) Pa, P (n, 3, 3) Pa, A (n, 3, 3, 3, 3) Pa or None, at the current plastic state."""
        F, ids = self._rows(F, samples)
        self._strain.offset = self.plastic_strain[ids]
        try:
            return self._inner.evaluate(F, tangent=tangent, backend=backend)
        finally:
            self._strain.offset = None

    def energy(self, F, *, samples=None) -> np.ndarray:
        """Energy density W (n,) [Pa]."""
        return self.evaluate(F, tangent=False, samples=samples)[0]

    def stress(self, F, *, samples=None) -> np.ndarray:
        """First Piola-Kirchhoff stress (n, 3, 3) [Pa]."""
        return self.evaluate(F, tangent=False, samples=samples)[1]

    def tangent(self, F, *, samples=None) -> np.ndarray:
        """Tangent dP/dF (n, 3, 3, 3, 3) [Pa] at a fixed plastic state."""
        return self.evaluate(F, tangent=True, samples=samples)[2]

    # -- state -------------------------------------------------------------------
    def update(self, F, *, samples=None) -> int:
        """Return-map the samples from the committed state with total strain ``strain(F)``.

        Sets :attr:`plastic_strain` and :attr:`alpha` of those samples; returns
        the number of samples that yield.
        """
        F, ids = self._rows(F, samples)
        ep0, a0 = self._committed[0][ids], self._committed[1][ids]
        e = self.base.strain.apply(F)
        dev, r = _deviator(e - ep0)
        f = _SQ23 * r - (self.yield_strain + self.hardening * a0)
        yielding = f > 0
        dgamma = np.where(yielding, f, 0.0) / (_SQ23 * (1.0 + self.hardening))
        n = dev / np.where(r > 0, r, 1.0)[:, None]
        n[:, 3:] *= 2.0  # back to engineering shear
        self.plastic_strain[ids] = ep0 + dgamma[:, None] * n
        self.alpha[ids] = a0 + _SQ23 * dgamma
        return int(np.count_nonzero(yielding))

    def commit(self) -> None:
        """Make the current state the start of the next load step."""
        self._committed = (self.plastic_strain.copy(), self.alpha.copy())

    def reset(self) -> None:
        """Back to the virgin state (no plastic strain)."""
        self.plastic_strain[:] = 0.0
        self.alpha[:] = 0.0
        self.commit()


def equilibrate(model, material, q, fixed, *, tolerance: float = 1e-10, passes: int = 200,
                stationary: float = 1e-13):
    """Static equilibrium with plasticity by staggering, then commit the plastic state.

    Solves the model with the plastic strains held (one static step from ``q``),
    return-maps them at the solution (:meth:`PlasticMaterial.update`), and
    repeats until no plastic strain changes by more than ``stationary``; then
    :meth:`PlasticMaterial.commit`.  Returns the state (n, d).

    Raises
    ------
    ConvergenceError
        The plastic strains still change after ``passes`` solves.
    """
    from ..errors import ConvergenceError
    from .solvers import SolverOptions, solve

    for _ in range(passes):
        q = solve(model, fixed=fixed, options=SolverOptions(steps=1, tolerance=tolerance), q0=q)[-1].q
        before = material.plastic_strain.copy()
        material.update(model.deformation_gradients(q))
        if np.max(np.abs(material.plastic_strain - before)) < stationary:
            break
    else:
        raise ConvergenceError(f"staggered plasticity did not converge in {passes} solves; "
                               "use smaller load increments")
    material.commit()
    return q
