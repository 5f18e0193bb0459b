"""Membranes: the 2-D deformation gradient of triangles in 3-D, and a membrane material on it.

* :class:`TriangleDeformationMapping` — mapped points ``x`` ``(n, 3)`` (m) →
  ``F`` ``(m, 3, 2)`` per triangle: ``F = D_s D_m⁻¹`` with ``D_s = [x1 - x0,
  x2 - x0]`` (3×2) and ``D_m`` (2×2) the rest edges in the rest triangle's
  orthonormal basis (e1 along the rest edge 0→1, e2 = n × e1 in the rest
  plane).  F is linear in x: J is constant and the geometric stiffness is zero.
* :class:`StVKMembrane` — the Saint Venant-Kirchhoff membrane energy per rest
  area ``ψ(F) = h [μ tr(E²) + λ̄/2 tr(E)²]`` (J/m²) with ``E = (FᵀF - I)/2``
  (2×2), thickness h (m) and the plane-stress constant
  ``λ̄ = 2 μ λ / (λ + 2 μ)``; stress ``P = h F S``, ``S = 2μE + λ̄ tr(E) I``
  (N/m), tangent ``A_iJkL = h [δ_ik S_JL + F_iM F_kN C_MJNL]``.

A flat mesh stretched uniformly by s in its plane has
``ψ = h (μ/2 + λ̄/2) (s² - 1)²`` (the closed form the tests use).

Example
-------
>>> import numpy as np
>>> X = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
>>> tri = TriangleDeformationMapping(X, [[0, 1, 2]])
>>> F = tri.apply(2 * X)
>>> F.round(12) + 0.0
array([[[2., 0.],
        [0., 2.],
        [0., 0.]]])
>>> mem = StVKMembrane(young=1.0, poisson=0.0, thickness=1.0)
>>> float(mem.energy(F)[0])    # h (mu/2 + lambda_bar/2) (s^2 - 1)^2 with mu = 1/2, lambda_bar = 0
2.25
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ...errors import InputError
from ..materials.constitutive import lame

__all__ = ["TriangleDeformationMapping", "StVKMembrane"]


class TriangleDeformationMapping:
    """Mapped points → 2-D deformation gradients of triangles ``(m, 3, 2)``.

    Parameters
    ----------
    rest_points : (n, 3) float
        Rest positions of the points (m).
    triangles : (m, 3) int
        Point indices of each triangle (non-degenerate at rest).

    Attributes
    ----------
    area : (m,) float
        Rest areas (m²): integrate the membrane energy density with them.
    basis : (m, 3, 2) float
        Rest in-plane orthonormal basis (e1, e2) of each triangle (columns).
    """

    constant_jacobian = True

    def __init__(self, rest_points, triangles):
        X = np.asarray(rest_points, dtype=np.float64)
        if X.ndim != 2 or X.shape[1] != 3 or not np.all(np.isfinite(X)):
            raise InputError(f"rest_points must be a finite (n, 3) array (m), got shape {X.shape}")
        try:
            T = np.asarray(triangles, dtype=np.int64)
        except (TypeError, ValueError):
            raise InputError("triangles must be an (m, 3) integer array of point indices") from None
        if T.ndim != 2 or T.shape[1] != 3:
            raise InputError(f"triangles must be an (m, 3) integer array of point indices, got shape {T.shape}")
        if T.size and (T.min() < 0 or T.max() >= len(X)):
            raise InputError(f"triangles refer to points outside [0, {len(X)})")
        d1 = X[T[:, 1]] - X[T[:, 0]]
        d2 = X[T[:, 2]] - X[T[:, 0]]
        nrm = np.cross(d1, d2)
        area2 = np.linalg.norm(nrm, axis=1)
        scale = np.maximum(np.linalg.norm(d1, axis=1), np.linalg.norm(d2, axis=1)) ** 2
        bad = np.flatnonzero(area2 <= 1e-12 * scale)
        if bad.size:
            raise InputError(f"triangle {int(bad[0])} is degenerate at rest (zero area); remove it")
        e1 = d1 / np.linalg.norm(d1, axis=1)[:, None]
        e2 = np.cross(nrm / area2[:, None], e1)
        self.n_points = len(X)
        self.triangles = T
        self.area = 0.5 * area2
        self.basis = np.stack([e1, e2], axis=2)
        Dm = np.stack([np.einsum("ni,nik->nk", d1, self.basis), np.einsum("ni,nik->nk", d2, self.basis)], axis=2)
        self._Dm_inv = np.linalg.inv(Dm)  # (m, 2, 2)

    @property
    def m(self) -> int:
        """Number of triangles."""
        return len(self.triangles)

    def _x(self, x, name="x"):
        a = np.asarray(x, dtype=np.float64)
        if a.shape == (3 * self.n_points,):
            a = a.reshape(self.n_points, 3)
        if a.shape != (self.n_points, 3):
            raise InputError(f"{name} must be the ({self.n_points}, 3) point positions, got shape {np.shape(x)}")
        return a

    def _F(self, x):
        T = self.triangles
        Ds = np.stack([x[T[:, 1]] - x[T[:, 0]], x[T[:, 2]] - x[T[:, 0]]], axis=2)
        return Ds @ self._Dm_inv

    def apply(self, x) -> np.ndarray:
        """F ``(m, 3, 2)`` of point positions ``x`` ``(n, 3)``."""
        return self._F(self._x(x))

    def jvp(self, x, v) -> np.ndarray:
        """J v ``(m, 3, 2)`` (F is linear in x)."""
        self._x(x)
        return self._F(self._x(v, "v"))

    def vjp(self, x, f) -> np.ndarray:
        """Point forces ``(n, 3)`` of the conjugate ``f`` ``(m, 3, 2)`` (e.g. area × P)."""
        self._x(x)
        f = np.asarray(f, dtype=np.float64)
        if f.shape != (self.m, 3, 2):
            raise InputError(f"f must have shape ({self.m}, 3, 2), got {f.shape}")
        G = f @ self._Dm_inv.transpose(0, 2, 1)  # (m, 3, 2): forces on corners 1 and 2
        out = np.zeros((self.n_points, 3))
        T = self.triangles
        np.add.at(out, T[:, 1], G[:, :, 0])
        np.add.at(out, T[:, 2], G[:, :, 1])
        np.add.at(out, T[:, 0], -G.sum(axis=2))
        return out

    @property
    def corner_coefficients(self) -> np.ndarray:
        """``coef`` ``(m, 3, 2)``: ``F[t, i, J] = sum_c x[triangles[t, c], i] coef[t, c, J]`` (1/m)."""
        Di = self._Dm_inv  # F_iJ = sum_c (x_c - x_0)_i Di[c-1, J]
        coef = np.zeros((self.m, 3, 2))
        coef[:, 1, :] = Di[:, 0, :]
        coef[:, 2, :] = Di[:, 1, :]
        coef[:, 0, :] = -Di.sum(axis=1)
        return coef

    def jacobian(self, x=None) -> sp.csr_matrix:
        """Assembled J ``(6m, 3n)``: row ``6 t + 2 i + J`` = F[t, i, J], column ``3 point + i``."""
        m = self.m
        coef = self.corner_coefficients  # coef[t, corner, J]
        t, c, i, J = np.meshgrid(np.arange(m), np.arange(3), np.arange(3), np.arange(2), indexing="ij")
        rows = 6 * t + 2 * i + J
        cols = 3 * self.triangles[t, c] + i
        vals = coef[t, c, J]
        return sp.csr_matrix((vals.ravel(), (rows.ravel(), cols.ravel())), shape=(6 * m, 3 * self.n_points))

    def geometric_vp(self, x, f, v) -> np.ndarray:
        """Zero ``(n, 3)``: J is constant."""
        return np.zeros_like(self._x(v, "v"))


def _check_F2(F):
    F = np.asarray(F, dtype=np.float64)
    if F.ndim != 3 or F.shape[1:] != (3, 2):
        raise InputError(f"membrane deformation gradients F must have shape (m, 3, 2), got {F.shape}")
    return F


class StVKMembrane:
    """Saint Venant-Kirchhoff membrane on ``F`` ``(m, 3, 2)`` (plane stress; see the module docstring).

    Parameters
    ----------
    young : float
        Young's modulus E > 0 (Pa).
    poisson : float
        Poisson's ratio in (-1, 1/2).
    thickness : float
        Sheet thickness h > 0 (m).
    """

    def __init__(self, *, young: float, poisson: float, thickness: float):
        if not (np.isfinite(thickness) and thickness > 0):
            raise InputError(f"thickness must be > 0 (m), got {thickness!r}")
        mu, lm = lame(young, poisson)
        if not (np.isfinite(mu) and mu > 0 and np.isfinite(lm) and -1 < poisson < 0.5):
            raise InputError(f"young must be > 0 (Pa) and poisson in (-1, 0.5), got {young!r}, {poisson!r}")
        self.mu = float(mu)
        self.lmbda = float(2 * mu * lm / (lm + 2 * mu))
        self.thickness = float(thickness)

    def _ES(self, F):
        E = 0.5 * (np.einsum("nki,nkj->nij", F, F) - np.eye(2))
        tr = np.trace(E, axis1=1, axis2=2)
        S = 2 * self.mu * E + self.lmbda * tr[:, None, None] * np.eye(2)
        return E, tr, S

    def energy(self, F) -> np.ndarray:
        """Energy per rest area ψ ``(m,)`` (J/m²)."""
        E, tr, _ = self._ES(_check_F2(F))
        return self.thickness * (self.mu * np.einsum("nij,nij->n", E, E) + 0.5 * self.lmbda * tr**2)

    def stress(self, F) -> np.ndarray:
        """First Piola-Kirchhoff stress resultant ``P = dψ/dF`` ``(m, 3, 2)`` (N/m)."""
        F = _check_F2(F)
        return self.thickness * (F @ self._ES(F)[2])

    def tangent(self, F) -> np.ndarray:
        """``A[m, i, J, k, L] = dP_iJ/dF_kL`` ``(m, 3, 2, 3, 2)`` (N/m)."""
        F = _check_F2(F)
        _, _, S = self._ES(F)
        I2 = np.eye(2)
        C = self.lmbda * np.einsum("MJ,NL->MJNL", I2, I2) + self.mu * (
            np.einsum("MN,JL->MJNL", I2, I2) + np.einsum("ML,JN->MJNL", I2, I2))
        A = np.einsum("ik,nJL->niJkL", np.eye(3), S) + np.einsum("niM,nkN,MJNL->niJkL", F, F, C)
        return self.thickness * A
