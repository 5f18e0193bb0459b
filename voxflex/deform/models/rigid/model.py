"""Rigid frames: affine frames constrained to rotations, 6 DOF each.

A :class:`RigidFrameModel` wraps a :class:`~voxflex.deform.models.frames.model.FrameModel`
(the same frames, shape functions, samples, materials and cache) and restricts
every frame's matrix to a rotation.  The state of frame ``a`` is 6 numbers,

    q_a = (p_a, theta_a):  p_a (3,) the world position of the frame's reference
                           point (m), theta_a (3,) its rotation vector (rad),

with ``R(theta) = exp([theta]x)`` (Rodrigues).  The reference point is the
frame's *mass centre* ``c_a = sum_p m_p w_a(X_p) X_p / sum_p m_p w_a(X_p)`` (the
weighted centroid of the material the frame carries, over the mass points the
gravity force uses), not the frame's position ``X_a``; at rest ``p_a = c_a``.
The affine state the wrapped model sees is

    A_a = R(theta_a),   t_a = p_a - R(theta_a) (c_a - X_a),

so a material point moves to ``x(X) = sum_a w_a(X) [R_a (X - c_a) + p_a]``.
With the mass centre as reference, gravity's work ``sum_p m_p g . x_p`` is
``g . sum_a M_a p_a``: linear in the state, so the constant generalised gravity
force the static solver applies is exact for any rotation (any other
reference point leaves a torque ``(c_a - X_a) x M_a g`` evaluated at the rest
orientation).  Other dead loads (force and traction regions) have a moment
about the reference point that turns with the frame; the solvers hold
generalised forces constant, so a scene refuses them with rigid frames
(:func:`voxflex.build.model`), and :meth:`RigidPointMap.vjp` is exact only at
the state it is given.

Energy, gradient and Hessian (exact, for any state):

    E6(q6) = E12(q12(q6)),   g6 = J^T g12,
    H6 = J^T H12 J + G,   G_a[i, j] = d2R/dtheta_i dtheta_j : (g_A - g_t (c_a - X_a)^T)

``J`` (12n, 6n) block diagonal, ``g_A`` (3, 3) and ``g_t`` (3,) the parts of
g12 of frame a; G is the geometric stiffness of the rotation parametrisation
(3x3 per frame).  ``R = I + a(s) K + b(s) K^2`` with ``s = theta . theta``,
``a = sin(r)/r``, ``b = (1 - cos r)/s`` (``r = sqrt s``); the first and
second derivatives of R come from ``a', a'', b', b''`` (closed forms, Taylor
series below ``|theta| = 1``, where the closed forms lose digits to cancellation).

The parametrisation is singular at ``|theta| = 2 pi``: :meth:`RigidFrameModel.begin_step`
replaces a rotation vector longer than pi by the equivalent one
(``|theta| <= pi``, same R) at the start of every step.

Dynamics are refused: the mass matrix in (p, theta) coordinates depends on
the rotation (the solvers use a constant one); use affine frames.

Example
-------
>>> import numpy as np
>>> from voxflex.image.label_image import LabelImage
>>> from voxflex.deform.materials.constitutive import material
>>> from voxflex.voronoi.shape_functions import shepard
>>> frames = np.array([[0.5, 1.0, 1.0], [3.5, 1.0, 1.0]])
>>> model = RigidFrameModel.from_image(LabelImage(np.ones((4, 2, 2))), frames, lambda p: shepard(p, frames),
...                                    {1: material("hooke", young=1e3, poisson=0.3)})
>>> model.rest.shape, model.node_kind
((2, 6), 'rigid')
>>> q = model.moved_state([[0.0, -1.0, 0.0, 0.1], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
>>> abs(model.energy(q)) < 1e-9, np.round(q[0, 3:], 12).tolist()
(True, [0.0, 0.0, 1.570796326795])
"""

from __future__ import annotations

from math import factorial
from typing import Mapping

import numpy as np
import scipy.sparse as sp

from ....errors import InputError
from ...chain.nodes import skew
from .kind import RIGID

__all__ = ["RigidFrameModel", "RigidPointMap", "rotation_derivatives", "wrap_rotation_vectors", "RIGID_TOL"]

RIGID_TOL = 1e-9
"""|A^T A - I| and |det A - 1| allowed in a prescribed transform of rigid frames (round-off of a written rotation)."""

_SERIES_BELOW = 1.0  # s = |theta|^2 below which a, b and their derivatives come from Taylor series
_TERMS = 10  # series terms: the first omitted one is below 1e-19 at s = 1 (the closed forms cancel below)
_A = np.array([(-1.0) ** k / factorial(2 * k + 1) for k in range(_TERMS)])  # a(s) = sum A_k s^k
_B = np.array([(-1.0) ** k / factorial(2 * k + 2) for k in range(_TERMS)])  # b(s) = sum B_k s^k
_E = skew(np.eye(3))  # _E[i] = [e_i]x


def _series(c, s, order):
    """d^order/ds^order of sum_k c_k s^k."""
    k = np.arange(len(c))
    f = np.ones(len(c))
    for j in range(order):
        f = f * (k - j)
    out = np.zeros_like(s)
    for kk in range(len(c) - 1, order - 1, -1):  # Horner in s over the surviving terms
        out = out * s + f[kk] * c[kk]
    return out


def _coefficients(s):
    """a, a', a'', b, b', b'' (derivatives in s) at s = |theta|^2 (m,)."""
    small = s < _SERIES_BELOW
    r = np.sqrt(np.where(small, 1.0, s))
    sin, cos = np.sin(r), np.cos(r)
    closed = (
        sin / r,
        (r * cos - sin) / (2 * r**3),
        (3 * sin - 3 * r * cos - r * r * sin) / (4 * r**5),
        (1 - cos) / r**2,
        (r * sin - 2 + 2 * cos) / (2 * r**4),
        (r * r * cos - 5 * r * sin + 8 - 8 * cos) / (4 * r**6),
    )
    series = tuple(_series(c, s, k) for c in (_A, _B) for k in range(3))
    return tuple(np.where(small, ser, cl) for ser, cl in zip(series, closed))


def rotation_derivatives(theta, *, second: bool = True):
    """R(theta), dR/dtheta_i and d2R/dtheta_i dtheta_j of rotation vectors.

    Parameters
    ----------
    theta : (n, 3) float, rotation vectors (rad)
    second : bool
        Also the second derivatives.

    Returns
    -------
    R : (n, 3, 3)
    dR : (n, 3, 3, 3), ``dR[:, i]`` = dR/dtheta_i
    d2R : (n, 3, 3, 3, 3) or None, ``d2R[:, i, j]`` = d2R/dtheta_i dtheta_j

    Example
    -------
    >>> R, dR, _ = rotation_derivatives(np.zeros((1, 3)), second=False)
    >>> np.allclose(R[0], np.eye(3)), np.allclose(dR[0, 2], [[0, -1, 0], [1, 0, 0], [0, 0, 0]])
    (True, True)
    """
    th = np.asarray(theta, dtype=float)
    s = (th * th).sum(-1)
    a, a1, a2, b, b1, b2 = (c[:, None, None] for c in _coefficients(s))
    K = skew(th)
    K2 = K @ K
    R = np.eye(3) + a * K + b * K2
    EK = np.einsum("irk,nkc->nirc", _E, K)
    M = EK + np.swapaxes(EK, 2, 3)  # E_i K + K E_i, as K E_i = (E_i K)^T for skew matrices
    ti = th[:, :, None, None]
    dR = (2 * ti * a1[:, None] * K[:, None] + a[:, None] * _E[None] + 2 * ti * b1[:, None] * K2[:, None]
          + b[:, None] * M)
    if not second:
        return R, dR, None
    n = len(th)
    tt = (th[:, :, None] * th[:, None, :])[..., None, None]  # (n, 3, 3, 1, 1)
    d = np.eye(3)[None, :, :, None, None]
    EE = np.einsum("irk,jkc->ijrc", _E, _E)
    EE = EE + EE.transpose(1, 0, 2, 3)
    A1, A2, B1, B2, B0 = (x[:, None] for x in (a1, a2, b1, b2, b))  # (n, 1, 1, 1)
    Ki, K2i = K[:, None, None], K2[:, None, None]
    cross_a = (th[:, :, None, None, None] * _E[None, None, :, :, :]
               + th[:, None, :, None, None] * _E[None, :, None, :, :])  # theta_i E_j + theta_j E_i
    cross_b = th[:, :, None, None, None] * M[:, None, :] + th[:, None, :, None, None] * M[:, :, None]
    d2R = (2 * d * A1[:, None] * Ki + 4 * tt * A2[:, None] * Ki + 2 * A1[:, None] * cross_a
           + 2 * d * B1[:, None] * K2i + 4 * tt * B2[:, None] * K2i + 2 * B1[:, None] * cross_b
           + B0[:, None] * EE[None])
    return R, dR, d2R.reshape(n, 3, 3, 3, 3)


def wrap_rotation_vectors(theta) -> np.ndarray:
    """Rotation vectors (n, 3) with the same rotations and ``|theta| <= pi`` (those already there unchanged)."""
    th = np.asarray(theta, dtype=float)
    phi = np.linalg.norm(th, axis=1)
    long = phi > np.pi
    out = th.copy()
    if np.any(long):
        p = phi[long]
        out[long] = th[long] * ((p - 2 * np.pi * np.round(p / (2 * np.pi))) / p)[:, None]
    return out


class RigidPointMap:
    """Material points mapped by rigid frames: the affine frames' map of ``q12(q6)``.

    ``apply`` is exact at any state; ``vjp(q, f)`` is ``J(q)^T`` of the affine
    point forces, exact at the state given (it depends on the rotation).  Not linear in the
    state (``constant_jacobian = False``): layers that need a linear point mapping (cables,
    contact) refuse it.
    """

    constant_jacobian = False

    def __init__(self, inner, model: "RigidFrameModel"):
        self.inner = inner
        self.model = model

    def apply(self, q) -> np.ndarray:
        """Positions (m, 3) at the state q (n, 6)."""
        return self.inner.apply(self.model.affine_state(q))

    def vjp(self, q, f) -> np.ndarray:
        """Node forces (n, 6) of point forces f (m, 3) at the state q (n, 6)."""
        q = self.model._check_q(q)
        return self.model._pullback(q[:, 3:], self.inner.vjp(self.model.affine_state(q), f))


class RigidFrameModel:
    """Rigid frames over a label image (see the module docstring).

    Build with :meth:`from_image` (or wrap an affine :class:`FrameModel`).  The
    state ``q`` is ``(n, 6)``: reference point p (m) then rotation vector theta
    (rad); energies in J, generalised forces in N and N m.

    Parameters
    ----------
    inner : FrameModel
        The affine frames this model restricts to rotations.
    densities : {label: kg/m^3}, optional
        Densities whose mass centres become the frames' reference points
        (default: one density for every label, i.e. volume centroids).

    Attributes
    ----------
    inner : FrameModel
    frames : (n, 3) float, the frames' positions X_a (m)
    origins : (n, 3) float, the reference points c_a at rest (m)
    """

    kind = RIGID
    node_kind = RIGID.name
    dofs_per_node = 6
    supported_by_contact = False

    def __init__(self, inner, *, densities: Mapping[int, float] | None = None):
        if getattr(inner, "dofs_per_node", None) != 12 or not hasattr(inner, "frames"):
            raise InputError("RigidFrameModel wraps an affine FrameModel (12 DOF per frame)")
        self.inner = inner
        self.image = inner.image
        self.materials = inner.materials  # the protocol's {label: material}: the affine model's, which it integrates
        self.frames = np.asarray(inner.frames, dtype=float)
        if densities is None:
            densities = {int(k): 1.0 for k in inner.materials}
        self.densities = {int(k): float(v) for k, v in dict(densities).items()}
        self.origins = self._mass_centres(self.densities)
        self.offset = self.origins - self.frames
        rest = np.zeros((len(self.frames), 6))
        rest[:, :3] = self.origins
        rest.setflags(write=False)
        self.rest = rest

    @classmethod
    def from_image(cls, image, frames, shape_function, materials, *, densities=None, **kwargs) -> "RigidFrameModel":
        """Rigid frames of ``image`` at ``frames`` (n, 3); the arguments and keywords of
        :meth:`FrameModel.from_image <voxflex.deform.models.frames.model.FrameModel.from_image>`, plus ``densities``."""
        from ..frames.model import FrameModel

        return cls(FrameModel.from_image(image, frames, shape_function, materials, **kwargs), densities=densities)

    def _mass_centres(self, densities) -> np.ndarray:
        """c_a (n, 3): centroid of the mass points weighted by mass and shape function."""
        # the affine gravity force of g = e_x: t_x part sum m w, row x of the A part sum m w (X - X_a)
        moment = self.inner.gravity_force(densities, np.array([1.0, 0.0, 0.0]))
        total = moment[:, 9]
        first = moment[:, :3]
        out = self.frames.copy()
        ok = total > 0
        out[ok] += first[ok] / total[ok, None]
        return out

    # -- sizes and states ------------------------------------------------------
    @property
    def n_nodes(self) -> int:
        return len(self.frames)

    @property
    def constant_tangent(self) -> bool:
        """False: the rotation makes the energy non-quadratic in the state."""
        return False

    def _check_q(self, q) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.shape == (6 * self.n_nodes,):
            q = q.reshape(self.n_nodes, 6)
        if q.shape != (self.n_nodes, 6):
            raise InputError(f"q must have shape ({self.n_nodes}, 6) (reference point, then rotation vector, "
                             f"per frame), got {q.shape}")
        return q

    def affine_state(self, q) -> np.ndarray:
        """The affine state (n, 12) (R row-major, then t = p - R (c - X)) of the rigid state q (n, 6)."""
        q = self._check_q(q)
        from ...chain.nodes import rotation_exp

        R = rotation_exp(q[:, 3:])
        out = np.empty((self.n_nodes, 12))
        out[:, :9] = R.reshape(-1, 9)
        out[:, 9:] = q[:, :3] - np.einsum("nij,nj->ni", R, self.offset)
        return out

    def jacobian(self, q) -> sp.csr_matrix:
        """d q12 / d q6 (12n, 6n), block diagonal."""
        q = self._check_q(q)
        return sp.block_diag(list(self._blocks(q[:, 3:])), format="csr")

    def _blocks(self, theta, dR=None) -> np.ndarray:
        if dR is None:
            dR = rotation_derivatives(theta, second=False)[1]
        n = len(theta)
        J = np.zeros((n, 12, 6))
        J[:, :9, 3:] = dR.reshape(n, 3, 9).transpose(0, 2, 1)
        J[:, 9:, 3:] = -np.einsum("nirc,nc->nri", dR, self.offset)
        J[:, 9:, :3] = np.eye(3)
        return J

    def _effective(self, g12) -> np.ndarray:
        """g_A - g_t (c - X)^T (n, 3, 3): what dR and d2R are contracted with."""
        return g12[:, :9].reshape(-1, 3, 3) - g12[:, 9:, None] * self.offset[:, None, :]

    def _pullback(self, theta, g12, dR=None) -> np.ndarray:
        """J^T g12 (n, 6)."""
        if dR is None:
            dR = rotation_derivatives(theta, second=False)[1]
        out = np.empty((len(theta), 6))
        out[:, :3] = g12[:, 9:]
        out[:, 3:] = np.einsum("nirc,nrc->ni", dR, self._effective(g12))
        return out

    # -- energy ------------------------------------------------------------------
    def energy(self, q) -> float:
        return self.inner.energy(self.affine_state(q))

    def gradient(self, q) -> np.ndarray:
        return self.energy_gradient_hessian(q, hessian=False)[1]

    def hessian(self, q):
        """d2E/dq2 (6n, 6n): dense ndarray (point samples) or CSR (elastons), as the affine model's."""
        return self.energy_gradient_hessian(q)[2]

    def energy_gradient_hessian(self, q, *, gradient: bool = True, hessian: bool = True):
        """Energy (J), gradient (n, 6) and Hessian (6n, 6n) with the geometric stiffness of the rotations."""
        q = self._check_q(q)
        theta = q[:, 3:]
        E, g12, H12 = self.inner.energy_gradient_hessian(self.affine_state(q), gradient=gradient or hessian,
                                                          hessian=hessian)
        if not (gradient or hessian):
            return E, None, None
        _, dR, d2R = rotation_derivatives(theta, second=hessian)
        g = self._pullback(theta, g12, dR) if gradient else None
        if not hessian:
            return E, g, None
        n = self.n_nodes
        J = self._blocks(theta, dR)
        G = np.einsum("nijrc,nrc->nij", d2R, self._effective(g12))
        G = 0.5 * (G + G.transpose(0, 2, 1))
        if sp.issparse(H12):
            Jsp = sp.block_diag(list(J), format="csr")
            H = (Jsp.T @ H12 @ Jsp).tolil()
            for a in range(n):
                H[6 * a + 3:6 * a + 6, 6 * a + 3:6 * a + 6] = H[6 * a + 3:6 * a + 6, 6 * a + 3:6 * a + 6].toarray() + G[a]
            return E, g, H.tocsr()
        H4 = np.asarray(H12).reshape(n, 12, n, 12)
        right = np.einsum("akbl,blj->akbj", H4, J, optimize=True)
        H = np.einsum("aki,akbj->aibj", J, right, optimize=True)
        idx = np.arange(n)
        H[idx, 3:, idx, 3:] += G
        H = H.reshape(6 * n, 6 * n)
        return E, g, 0.5 * (H + H.T)

    # -- mass and gravity ----------------------------------------------------------
    def mass_matrix(self, densities=None, *, lumped: bool = True):
        """Refused: the mass in (p, theta) coordinates depends on the rotation and the solvers
        take a constant mass matrix."""
        raise InputError('dynamics with rigid frames are not supported (their mass matrix depends on the '
                         'rotation); use [nodes] kind = "affine" for dynamics')

    def gravity_force(self, densities: Mapping[int, float], g) -> np.ndarray:
        """Generalised gravity force (n, 6): ``J^T`` of the affine frames' gravity force; with the
        mass centres as reference points it is ``(M_a g, 0)`` for every state (exact)."""
        f12 = self.inner.gravity_force(densities, g)
        eff = self._effective(f12)
        scale = np.linalg.norm(f12[:, 9:], axis=1) * float(np.max(np.ptp(self.frames, axis=0), initial=0.0) + 1.0)
        if np.any(np.linalg.norm(eff.reshape(-1, 9), axis=1) > 1e-9 * np.maximum(scale, 1e-300)):
            raise InputError("these densities move the frames' mass centres (the rigid frames' reference points); "
                             "build the rigid model with the densities of the run")
        return self._pullback(np.zeros((self.n_nodes, 3)), f12)

    # -- layers ------------------------------------------------------------------------
    def point_mapping(self, points) -> RigidPointMap:
        """Mapping of material points (m, 3) given at rest; InputError outside the material."""
        return RigidPointMap(self.inner.point_mapping(points), self)

    def boundary_surface(self):
        """The visual layer: the voxelized boundary (rest vertices, triangles) and its rigid-frame mapping."""
        V, F, pmap = self.inner.boundary_surface()
        return V, F, RigidPointMap(pmap, self)

    def load_surface(self, order: int = 2):
        return self.inner.load_surface(order)

    def node_points(self, q) -> np.ndarray:
        """Each frame's mass centre p (n, 3) at state q (the first three numbers of its state)."""
        return np.asarray(q, dtype=float).reshape(self.n_nodes, 6)[:, :3].copy()

    def volume_points(self):
        return self.inner.volume_points()

    def parts(self) -> list:
        return self.inner.parts()

    def sample_fields(self, q) -> dict:
        return self.inner.sample_fields(self.affine_state(q))

    # -- boundary conditions -----------------------------------------------------------
    def held_dofs(self, lo, hi, components: str = "xyz") -> np.ndarray:
        """DOFs a fixed box [lo, hi] holds: those of the frames the affine model would hold there.

        A held frame keeps, for each held component c, the coordinate c of every
        material point it moves (as affine frames keep row c of A and t_c): p_c and
        row c of R.  Two or more components fix two rows of R, hence R: every
        theta is held.  A single component c (a sliding support normal to c)
        holds p_c and the two theta components other than c, so the frame may
        still turn about the c axis (row c of R stays e_c).
        """
        comps = "".join(c for c in "xyz" if c in str(components))
        frames = np.unique(np.asarray(self.inner.held_dofs(lo, hi, "xyz"), dtype=np.int64) // 12)
        local = ["xyz".index(c) for c in comps]
        if len(comps) == 1:
            local += [3 + j for j in range(3) if j != local[0]]
        else:
            local += [3, 4, 5]
        local = np.array(sorted(local), dtype=np.int64)
        return np.sort((6 * frames[:, None] + local[None, :]).ravel())

    def moved_state(self, transform) -> np.ndarray:
        """State (n, 6) of the body moved by the rigid map ``[R | t]``: theta = log R, p = R c + t.

        Raises
        ------
        InputError
            A transform whose 3x3 part is not a rotation (|R^T R - I| or |det R - 1| above
            :data:`RIGID_TOL`).
        """
        from ...chain.rigid import rotation_log

        T = np.asarray(transform, dtype=float)
        if T.shape != (3, 4) or not np.all(np.isfinite(T)):
            raise InputError(f"a transform must be a finite 3x4 matrix [R | t], got shape {T.shape}")
        R, t = T[:, :3], T[:, 3]
        err = max(float(np.abs(R.T @ R - np.eye(3)).max()), abs(float(np.linalg.det(R)) - 1.0))
        if err > RIGID_TOL:
            raise InputError(f"rigid frames can only be moved rigidly: the transform's 3x3 part is not a rotation "
                             f"(|R^T R - I|, |det R - 1| up to {err:.1e}); give a rotation to full precision, or "
                             'use [nodes] kind = "affine"')
        out = np.empty((self.n_nodes, 6))
        out[:, :3] = self.origins @ R.T + t
        out[:, 3:] = rotation_log(R[None])[0]
        return out

    def rigid_modes(self) -> np.ndarray:
        """(6n, 6) at rest: translations (dp = e_k) and rotations about the reference points' centroid
        (dtheta = e_k, dp = e_k x (c_a - centroid))."""
        n = self.n_nodes
        B = np.zeros((n, 6, 6))
        r = self.origins - self.origins.mean(axis=0)
        for k in range(3):
            B[:, k, k] = 1.0
            B[:, 3 + k, 3 + k] = 1.0
            B[:, :3, 3 + k] = np.cross(np.eye(3)[k], r)
        return B.reshape(6 * n, 6)

    # -- steps and description -----------------------------------------------------------
    def begin_step(self, fraction: float, q_prev, q_start):
        """``q_start`` with every rotation vector longer than pi replaced by its equivalent
        (``|theta| <= pi``, same rotation); the same object when none is."""
        q = np.asarray(q_start, dtype=float).reshape(self.n_nodes, 6)
        if not np.any(np.linalg.norm(q[:, 3:], axis=1) > np.pi):
            return q_start
        out = q.copy()
        out[:, 3:] = wrap_rotation_vectors(q[:, 3:])
        return out.reshape(np.shape(q_start))

    def advice(self) -> str:
        return self.inner.advice()

    def describe(self) -> dict:
        out = dict(self.inner.describe())
        out.update({"node_kind": self.node_kind, "dofs": 6 * self.n_nodes})
        return out
