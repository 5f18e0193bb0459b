"""Node types: the degrees of freedom a simulation solves for.

Three kinds of node carry the motion:

* :class:`Points` — a position per node; state ``(n, 3)``, 3 velocity DOF.
* :class:`AffineFrames` — an affine map per node; state ``(n, 12)`` = the 3×3
  matrix A (row-major) then the translation t; the world position of material
  point X under frame a alone is ``A_a (X - X_a) + t_a`` (rest: A = I, t = X_a);
  12 velocity DOF in the same layout.
* :class:`RigidFrames` — a rotation R and a translation t per node; state
  ``(n, 12)`` in the affine layout with ``A = R`` a proper rotation matrix;
  6 velocity DOF ``(v, ω)``: linear velocity then *world-frame* angular
  velocity.  The increment is applied by **left** multiplication,
  ``R ← exp([ω]×) R``, ``t ← t + v``, so that a velocity moves a mapped point
  ``p = R (X - X_a) + t`` by ``v + ω × (p - t)``; the mappings' Jacobians use
  the same convention.

Every type is a frozen dataclass built from the rest positions of its nodes.

Example
-------
>>> import numpy as np
>>> frames = AffineFrames(np.zeros((2, 3)))
>>> frames.rest.shape, frames.dofs_per_node
((2, 12), 12)
>>> rig = RigidFrames(np.zeros((1, 3)))
>>> s = rig.integrate(rig.rest, np.array([[0, 0, 0, 0, 0, np.pi / 2]]))
>>> np.round(rig.rotations(s)[0] @ [1.0, 0, 0], 12) + 0.0
array([0., 1., 0.])
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ...errors import InputError

__all__ = ["Points", "AffineFrames", "RigidFrames", "NODE_TYPES", "rotation_exp", "skew"]


def _validate_rest_positions(name, X):
    try:
        X = np.ascontiguousarray(X, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}.rest_positions must be a float array ({exc})") from None
    if X.ndim != 2 or X.shape[1] != 3:
        raise InputError(f"{name}.rest_positions must be an (n, 3) array, got shape {X.shape}")
    if not np.all(np.isfinite(X)):
        raise InputError(f"{name}.rest_positions has non-finite values")
    return X


class _NodeType:
    """Shared behaviour; subclasses set the class constants."""

    kind: ClassVar[str]
    state_width: ClassVar[int]
    dofs_per_node: ClassVar[int]
    rest_positions: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "rest_positions", _validate_rest_positions(type(self).__name__, self.rest_positions))

    @property
    def n(self) -> int:
        """Number of nodes."""
        return self.rest_positions.shape[0]

    @property
    def n_dofs(self) -> int:
        """Number of velocity degrees of freedom, ``n * dofs_per_node``."""
        return self.n * self.dofs_per_node

    def check_state(self, state) -> np.ndarray:
        """Validate a state; return it as a C-contiguous ``(n, state_width)`` float64 array."""
        s = np.asarray(state, dtype=np.float64)
        if s.shape == (self.n * self.state_width,):
            s = s.reshape(self.n, self.state_width)
        if s.shape != (self.n, self.state_width):
            raise InputError(
                f"{type(self).__name__} state must have shape ({self.n}, {self.state_width}), got {np.shape(state)}"
            )
        if not np.all(np.isfinite(s)):
            raise InputError(f"{type(self).__name__} state has non-finite values")
        return np.ascontiguousarray(s)

    def check_velocity(self, dq, name="dq") -> np.ndarray:
        """Validate a velocity / increment; return it as ``(n, dofs_per_node)`` float64."""
        v = np.asarray(dq, dtype=np.float64)
        if v.shape == (self.n_dofs,):
            v = v.reshape(self.n, self.dofs_per_node)
        if v.shape != (self.n, self.dofs_per_node):
            raise InputError(
                f"{name} for {type(self).__name__} must have shape ({self.n}, {self.dofs_per_node}), got {np.shape(dq)}"
            )
        return np.ascontiguousarray(v)


@dataclass(frozen=True)
class Points(_NodeType):
    """Point nodes: a world position per node (state ``(n, 3)``, 3 DOF).

    Parameters
    ----------
    rest_positions : (n, 3) float array
        Rest positions of the nodes (m).
    """

    rest_positions: np.ndarray
    kind: ClassVar[str] = "points"
    state_width: ClassVar[int] = 3
    dofs_per_node: ClassVar[int] = 3

    @property
    def rest(self) -> np.ndarray:
        """Rest state ``(n, 3)``: the rest positions."""
        return self.rest_positions.copy()

    def integrate(self, state, dq) -> np.ndarray:
        """``state + dq``; both ``(n, 3)`` (m)."""
        return self.check_state(state) + self.check_velocity(dq)

    def positions(self, state) -> np.ndarray:
        """Node positions ``(n, 3)`` (m)."""
        return self.check_state(state).copy()


@dataclass(frozen=True)
class AffineFrames(_NodeType):
    """Affine frames: state ``(n, 12)`` = A (row-major) then t; 12 DOF in the same layout.

    Parameters
    ----------
    rest_positions : (n, 3) float array
        Rest positions X_a of the frames (m).
    """

    rest_positions: np.ndarray
    kind: ClassVar[str] = "affine-frames"
    state_width: ClassVar[int] = 12
    dofs_per_node: ClassVar[int] = 12

    @property
    def rest(self) -> np.ndarray:
        """Rest state ``(n, 12)``: A = I, t = X_a."""
        return _frame_state(np.broadcast_to(np.eye(3), (self.n, 3, 3)), self.rest_positions)

    def integrate(self, state, dq) -> np.ndarray:
        """``state + dq``; both ``(n, 12)``."""
        return self.check_state(state) + self.check_velocity(dq)

    def positions(self, state) -> np.ndarray:
        """Frame origins t ``(n, 3)`` (m)."""
        return self.check_state(state)[:, 9:].copy()

    def matrices(self, state) -> np.ndarray:
        """The matrices A ``(n, 3, 3)``."""
        return self.check_state(state)[:, :9].reshape(-1, 3, 3).copy()

    def rigid_modes(self) -> np.ndarray:
        """(12n, 6): translations (dt = e_k) and rotations about the frames' centroid
        (dA = [e_k]x, dt = e_k x (X_a - c)), not normalised."""
        X = np.asarray(self.rest_positions, dtype=float)
        B = np.zeros((self.n, 12, 6))
        for k in range(3):
            B[:, 9 + k, k] = 1.0
        R = X - X.mean(axis=0)
        for k in range(3):
            e = np.zeros(3)
            e[k] = 1.0
            W = np.array([[0, -e[2], e[1]], [e[2], 0, -e[0]], [-e[1], e[0], 0]])
            B[:, :9, 3 + k] = W.reshape(9)
            B[:, 9:, 3 + k] = np.cross(e, R)
        return B.reshape(12 * self.n, 6)

    def gauge_modes(self) -> np.ndarray:
        """(12n, 18) orthonormal: the motions that move no material point when the weights
        reproduce linear fields (``sum_a w_a = 1``, ``sum_a w_a X_a = X``, e.g. reproducing kernels).

        ``dA_a = E + T (X_a - c) / L``, ``dt_a = 0``, with E any 3x3 matrix (9 modes) and T any
        third-order tensor antisymmetric in its last two indices (9 modes; c the frames' centroid,
        L their extent): ``sum_a w_a dA_a (X - X_a) = E (X - X) + T : (X X^T - Q) - T : (X X^T - Q) = 0``
        (``Q = sum_a w_a X_a X_a^T`` symmetric), and the deformation gradient is 0 too.  With weights
        that are linearly precise only in part of the material they are ordinary (soft) motions.
        """
        Q, _ = np.linalg.qr(self.gauge_candidates())
        return Q

    def gauge_basis(self):
        """The 18 gauge candidates as ``dA_a = sum_m C[k, m] phi_a[m]``: ``phi`` (n, 4) = (1, (X_a - c) / L)
        and ``C`` (18, 4, 3, 3) (E for k < 9 in the first slot; T's antisymmetric pairs after), so that a
        sample's response to each candidate follows from four sums over its parents
        (:func:`voxflex.deform.models.frames.modes.gauge_modes`)."""
        X = np.asarray(self.rest_positions, dtype=float)
        c = X.mean(axis=0)
        L = float(np.ptp(X, axis=0).max()) if self.n > 1 else 1.0
        phi = np.concatenate([np.ones((self.n, 1)), (X - c) / (L if L > 0 else 1.0)], axis=1)
        C = np.zeros((18, 4, 3, 3))
        for p in range(9):
            C[p, 0, p // 3, p % 3] = 1.0
        col = 9
        for i in range(3):
            for j, k in ((0, 1), (0, 2), (1, 2)):
                C[col, 1 + k, i, j] = 1.0
                C[col, 1 + j, i, k] = -1.0
                col += 1
        return phi, C

    def gauge_candidates(self) -> np.ndarray:
        """(12n, 18) the candidates of :meth:`gauge_modes` before orthonormalisation (A row by row, t = 0)."""
        phi, C = self.gauge_basis()
        A = np.einsum("kmij,am->aijk", C, phi)  # (n, 3, 3, 18)
        B = np.zeros((self.n, 12, 18))
        B[:, :9] = A.reshape(self.n, 9, 18)
        return B.reshape(12 * self.n, 18)


@dataclass(frozen=True)
class RigidFrames(_NodeType):
    """Rigid frames: state ``(n, 12)`` = rotation R (row-major) then t; 6 DOF ``(v, ω)``.

    The rotation is updated by left multiplication with the exponential of the
    world-frame angular increment: ``R ← exp([ω]×) R`` (see the module notes).

    Parameters
    ----------
    rest_positions : (n, 3) float array
        Rest positions X_a of the frames (m).
    """

    rest_positions: np.ndarray
    kind: ClassVar[str] = "rigid-frames"
    state_width: ClassVar[int] = 12
    dofs_per_node: ClassVar[int] = 6

    @property
    def rest(self) -> np.ndarray:
        """Rest state ``(n, 12)``: R = I, t = X_a."""
        return _frame_state(np.broadcast_to(np.eye(3), (self.n, 3, 3)), self.rest_positions)

    def state_from(self, rotations, translations) -> np.ndarray:
        """Pack ``(n, 3, 3)`` rotations and ``(n, 3)`` translations into a state (rotations are checked)."""
        R = np.asarray(rotations, dtype=np.float64)
        t = np.asarray(translations, dtype=np.float64)
        if R.shape != (self.n, 3, 3) or t.shape != (self.n, 3):
            raise InputError(f"rotations must be ({self.n}, 3, 3) and translations ({self.n}, 3), got {R.shape} and {t.shape}")
        err = np.abs(np.einsum("nki,nkj->nij", R, R) - np.eye(3)).max() if self.n else 0.0
        if err > 1e-10 or (self.n and np.any(np.linalg.det(R) <= 0)):
            raise InputError(f"rotations must be proper orthogonal matrices (|RᵀR - I| = {err:.1e}); orthonormalize them first")
        return _frame_state(R, t)

    def integrate(self, state, dq) -> np.ndarray:
        """Apply an increment ``dq = (v, ω)`` ``(n, 6)``: ``t + v``, ``exp([ω]×) R``."""
        s = self.check_state(state)
        v = self.check_velocity(dq)
        R = s[:, :9].reshape(-1, 3, 3)
        Rn = np.einsum("nij,njk->nik", rotation_exp(v[:, 3:]), R)
        return _frame_state(Rn, s[:, 9:] + v[:, :3])

    def positions(self, state) -> np.ndarray:
        """Frame origins t ``(n, 3)`` (m)."""
        return self.check_state(state)[:, 9:].copy()

    def rotations(self, state) -> np.ndarray:
        """The rotations R ``(n, 3, 3)``."""
        return self.check_state(state)[:, :9].reshape(-1, 3, 3).copy()


NODE_TYPES = {t.kind: t for t in (Points, AffineFrames, RigidFrames)}
"""Node types by name."""


def _frame_state(A, t):
    n = len(t)
    s = np.empty((n, 12))
    s[:, :9] = np.asarray(A).reshape(n, 9)
    s[:, 9:] = t
    return s


def skew(w) -> np.ndarray:
    """Cross-product matrices ``[w]×`` ``(n, 3, 3)`` of vectors ``(n, 3)``: ``[w]× x = w × x``."""
    w = np.asarray(w, dtype=np.float64)
    K = np.zeros(w.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2] = -w[..., 2], w[..., 1]
    K[..., 1, 0], K[..., 1, 2] = w[..., 2], -w[..., 0]
    K[..., 2, 0], K[..., 2, 1] = -w[..., 1], w[..., 0]
    return K


def rotation_exp(w) -> np.ndarray:
    """Rotation matrices ``exp([w]×)`` ``(n, 3, 3)`` of rotation vectors ``(n, 3)`` (rad), Rodrigues' formula.

    Uses Taylor series below angle 1e-4 so that small rotations keep full accuracy.
    """
    w = np.asarray(w, dtype=np.float64)
    th2 = (w * w).sum(-1)
    th = np.sqrt(th2)
    small = th < 1e-4
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th2 / 6.0 + th2 * th2 / 120.0, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th2 / 24.0 + th2 * th2 / 720.0, (1.0 - np.cos(ths)) / (ths * ths))
    K = skew(w)
    return np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)
