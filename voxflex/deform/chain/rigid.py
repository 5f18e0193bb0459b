"""Rigid-frame mappings: a frame → its logarithm, and a frame expressed in another's frame.

Both take a :class:`~voxflex.deform.chain.nodes.RigidFrames` state ``(n, 12)`` (R
row-major, then t) and velocities ``(n, 6)`` = ``(v, ω)`` with the nodes'
convention: ``R ← exp([ω]×) R`` (world-frame ω), ``t ← t + v``.

* :class:`LogRigidMapping` — ``(t, θ)`` ``(n, 6)`` with θ the rotation vector
  of R (``R = exp([θ]×)``, |θ| ≤ π, rad), translation first as in the
  velocity layout.  With the left Jacobian ``J_l`` of SO(3), a velocity gives
  ``δθ = J_l(θ)⁻¹ ω`` and
  ``J_l⁻¹ = I - [θ]×/2 + c(θ) [θ]×²``, ``c = 1/θ² - (1 + cos θ) / (2 θ sin θ)``.
  The map is smooth for |θ| < π (at π the rotation vector jumps sign).
* :class:`RelativeRigidMapping` — for pairs (a, b), the frame b in a's frame:
  ``R = R_aᵀ R_b``, ``t = R_aᵀ (t_b - t_a)``; its output is again a rigid
  frame state ``(e, 12)`` and its velocities are rigid-frame velocities
  ``(e, 6)`` in the same convention (ω expressed in a's frame):
  ``ω = R_aᵀ (ω_b - ω_a)``, ``v = R_aᵀ (v_b - v_a + (t_b - t_a) × ω_a)``, so
  the two compose (joint angles: ``LogRigidMapping`` of a relative frame).

Both offer ``apply``, ``jvp``, ``vjp``, ``jacobian`` (sparse) and
``geometric_vp`` = ``(d/dq [J(q)ᵀ f]) v`` with q moved through
``RigidFrames.integrate`` (not symmetric in general, as for the node mappings).

Example
-------
>>> import numpy as np
>>> from voxflex.deform.chain.nodes import RigidFrames
>>> rig = RigidFrames(np.zeros((1, 3)))
>>> s = rig.integrate(rig.rest, [[1.0, 2, 3, 0, 0, 0.5]])
>>> LogRigidMapping(rig).apply(s).round(12)
array([[1. , 2. , 3. , 0. , 0. , 0.5]])
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ...errors import InputError
from .nodes import RigidFrames, skew

__all__ = ["LogRigidMapping", "RelativeRigidMapping", "rotation_log", "left_jacobian_inverse"]

_SMALL = 1e-4


def rotation_log(R) -> np.ndarray:
    """Rotation vectors θ ``(n, 3)`` (rad, |θ| ≤ π) of rotation matrices ``(n, 3, 3)``.

    Through the unit quaternion (Shepperd's branch choice), so that it stays
    accurate at small angles and near π.
    """
    R = np.asarray(R, dtype=np.float64)
    n = R.shape[0]
    tr = np.trace(R, axis1=1, axis2=2)
    diag = np.diagonal(R, axis1=1, axis2=2)
    cand = np.concatenate([tr[:, None], diag], axis=1)
    k = np.argmax(cand, axis=1)
    q = np.empty((n, 4))
    for c in range(4):
        sel = k == c
        if not np.any(sel):
            continue
        r = R[sel]
        if c == 0:
            w = 0.5 * np.sqrt(1.0 + tr[sel])
            q[sel] = np.stack([w, (r[:, 2, 1] - r[:, 1, 2]) / (4 * w), (r[:, 0, 2] - r[:, 2, 0]) / (4 * w),
                               (r[:, 1, 0] - r[:, 0, 1]) / (4 * w)], axis=1)
        else:
            i = c - 1
            j, l = (i + 1) % 3, (i + 2) % 3
            s = 0.5 * np.sqrt(1.0 + 2 * r[:, i, i] - tr[sel])
            qq = np.empty((int(sel.sum()), 4))
            qq[:, 0] = (r[:, l, j] - r[:, j, l]) / (4 * s)
            qq[:, 1 + i] = s
            qq[:, 1 + j] = (r[:, j, i] + r[:, i, j]) / (4 * s)
            qq[:, 1 + l] = (r[:, l, i] + r[:, i, l]) / (4 * s)
            q[sel] = qq
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    s = np.linalg.norm(q[:, 1:], axis=1)
    ang = 2.0 * np.arctan2(s, q[:, 0])
    small = s < 1e-8
    factor = np.where(small, 2.0 / np.where(q[:, 0] > 0, q[:, 0], 1.0), ang / np.where(small, 1.0, s))
    return q[:, 1:] * factor[:, None]


def _c_and_dc(th):
    """c(θ) of J_l⁻¹ and c'(θ)/θ, with series below _SMALL."""
    small = th < _SMALL
    t = np.where(small, 1.0, th)
    t2 = th * th
    cot = np.cos(t / 2) / np.sin(t / 2)
    c = np.where(small, 1 / 12 + t2 / 720 + t2 * t2 / 30240, 1 / t**2 - cot / (2 * t))
    dc = -2 / t**3 + cot / (2 * t**2) + 1 / (4 * t * np.sin(t / 2) ** 2)
    dc_over = np.where(small, 1 / 360 + t2 / 7560, dc / t)
    return c, dc_over


def left_jacobian_inverse(theta) -> np.ndarray:
    """``J_l(θ)⁻¹`` ``(n, 3, 3)``: maps a world-frame angular increment ω to δθ (|θ| < π)."""
    th = np.asarray(theta, dtype=np.float64)
    c, _ = _c_and_dc(np.linalg.norm(th, axis=1))
    K = skew(th)
    return np.eye(3) - 0.5 * K + c[:, None, None] * (K @ K)


def _jl_inv_T_apply(th, u):
    """J_l(θ)⁻ᵀ u = u + θ×u/2 + c (θ (θ·u) - θ² u)."""
    c, _ = _c_and_dc(np.linalg.norm(th, axis=1))
    tu = np.einsum("ni,ni->n", th, u)
    t2 = np.einsum("ni,ni->n", th, th)
    return u + 0.5 * np.cross(th, u) + c[:, None] * (th * tu[:, None] - t2[:, None] * u)


def _jl_inv_T_derivative(th, u, w):
    """d/dθ [J_l(θ)⁻ᵀ u] along w."""
    c, dco = _c_and_dc(np.linalg.norm(th, axis=1))
    tu = np.einsum("ni,ni->n", th, u)
    tw = np.einsum("ni,ni->n", th, w)
    wu = np.einsum("ni,ni->n", w, u)
    t2 = np.einsum("ni,ni->n", th, th)
    out = 0.5 * np.cross(w, u)
    out += c[:, None] * (w * tu[:, None] + th * wu[:, None] - 2 * tw[:, None] * u)
    out += (dco * tw)[:, None] * (th * tu[:, None] - t2[:, None] * u)
    return out


def _check_frames(frames):
    if not isinstance(frames, RigidFrames):
        raise InputError(f"frames must be RigidFrames, got {type(frames).__name__}")
    return frames


def _f6(f, m, name="f"):
    a = np.asarray(f, dtype=np.float64)
    if a.shape == (6 * m,):
        a = a.reshape(m, 6)
    if a.shape != (m, 6):
        raise InputError(f"{name} must have shape ({m}, 6), got {a.shape}")
    return a


def _block_diag(blocks, rows_per, cols_per):
    n = len(blocks)
    return sp.bsr_matrix((blocks, np.arange(n), np.arange(n + 1)), shape=(rows_per * n, cols_per * n)).tocsr()


class LogRigidMapping:
    """Rigid frames → ``(t, θ)`` ``(n, 6)``: translation (m) then rotation vector (rad).

    Parameters
    ----------
    frames : RigidFrames
    """

    constant_jacobian = False

    def __init__(self, frames: RigidFrames):
        self.frames = _check_frames(frames)

    @property
    def m(self) -> int:
        return self.frames.n

    def _theta(self, s):
        return rotation_log(s[:, :9].reshape(-1, 3, 3))

    def apply(self, state) -> np.ndarray:
        """``(t, θ)`` ``(n, 6)`` of the frames' state ``(n, 12)``."""
        s = self.frames.check_state(state)
        return np.concatenate([s[:, 9:], self._theta(s)], axis=1)

    def jvp(self, state, dq) -> np.ndarray:
        """``(v, J_l(θ)⁻¹ ω)`` ``(n, 6)``."""
        s = self.frames.check_state(state)
        v = self.frames.check_velocity(dq)
        Ji = left_jacobian_inverse(self._theta(s))
        return np.concatenate([v[:, :3], np.einsum("nij,nj->ni", Ji, v[:, 3:])], axis=1)

    def vjp(self, state, f) -> np.ndarray:
        """``(f_t, J_l(θ)⁻ᵀ f_θ)`` ``(n, 6)``: force and torque on the frames."""
        s = self.frames.check_state(state)
        f = _f6(f, self.m)
        return np.concatenate([f[:, :3], _jl_inv_T_apply(self._theta(s), f[:, 3:])], axis=1)

    def jacobian(self, state) -> sp.csr_matrix:
        """Assembled J ``(6n, 6n)``, block diagonal."""
        s = self.frames.check_state(state)
        B = np.zeros((self.m, 6, 6))
        B[:, :3, :3] = np.eye(3)
        B[:, 3:, 3:] = left_jacobian_inverse(self._theta(s))
        return _block_diag(B, 6, 6)

    def geometric_vp(self, state, f, v) -> np.ndarray:
        """``(d/dq [Jᵀ f]) v`` ``(n, 6)`` (only the rotation part is non-zero)."""
        s = self.frames.check_state(state)
        f = _f6(f, self.m)
        v = self.frames.check_velocity(v, "v")
        th = self._theta(s)
        dth = np.einsum("nij,nj->ni", left_jacobian_inverse(th), v[:, 3:])
        out = np.zeros_like(v)
        out[:, 3:] = _jl_inv_T_derivative(th, f[:, 3:], dth)
        return out


class RelativeRigidMapping:
    """Rigid frames → frame b of each pair (a, b) expressed in frame a: a rigid state ``(e, 12)``.

    Parameters
    ----------
    frames : RigidFrames
    pairs : (e, 2) int
        (a, b) frame index pairs, a != b.

    Notes
    -----
    ``apply`` gives ``(e, 12)`` states (``R_aᵀ R_b`` row-major, ``R_aᵀ (t_b - t_a)``);
    ``jvp`` gives ``(e, 6)`` child velocities, ``vjp`` takes ``(e, 6)`` child
    forces/torques (see the module docstring for the convention).
    """

    constant_jacobian = False

    def __init__(self, frames: RigidFrames, pairs):
        self.frames = _check_frames(frames)
        try:
            P = np.asarray(pairs, dtype=np.int64)
        except (TypeError, ValueError):
            raise InputError("pairs must be an (e, 2) integer array of frame indices") from None
        if P.ndim != 2 or P.shape[1] != 2:
            raise InputError(f"pairs must be an (e, 2) integer array of frame indices, got shape {P.shape}")
        if P.size and (P.min() < 0 or P.max() >= frames.n or np.any(P[:, 0] == P[:, 1])):
            raise InputError(f"pairs must join two different frames in [0, {frames.n})")
        self.pairs = P

    @property
    def m(self) -> int:
        return len(self.pairs)

    @property
    def children(self) -> RigidFrames:
        """The output frames, as RigidFrames (rest: b's rest origin in a's rest frame)."""
        X = self.frames.rest_positions
        return RigidFrames(X[self.pairs[:, 1]] - X[self.pairs[:, 0]])

    def _parts(self, s):
        a, b = self.pairs[:, 0], self.pairs[:, 1]
        R = s[:, :9].reshape(-1, 3, 3)
        return R[a], R[b], s[a, 9:], s[b, 9:]

    def apply(self, state) -> np.ndarray:
        """Child states ``(e, 12)``."""
        s = self.frames.check_state(state)
        Ra, Rb, ta, tb = self._parts(s)
        out = np.empty((self.m, 12))
        out[:, :9] = np.einsum("nki,nkj->nij", Ra, Rb).reshape(-1, 9)
        out[:, 9:] = np.einsum("nki,nk->ni", Ra, tb - ta)
        return out

    def jvp(self, state, dq) -> np.ndarray:
        """Child velocities ``(e, 6)`` = ``(R_aᵀ (v_b - v_a + d × ω_a), R_aᵀ (ω_b - ω_a))``, d = t_b - t_a."""
        s = self.frames.check_state(state)
        v = self.frames.check_velocity(dq)
        Ra, Rb, ta, tb = self._parts(s)
        a, b = self.pairs[:, 0], self.pairs[:, 1]
        lin = v[b, :3] - v[a, :3] + np.cross(tb - ta, v[a, 3:])
        ang = v[b, 3:] - v[a, 3:]
        return np.concatenate([np.einsum("nki,nk->ni", Ra, lin), np.einsum("nki,nk->ni", Ra, ang)], axis=1)

    def _scatter(self, ga, gb):
        out = np.zeros((self.frames.n, 6))
        np.add.at(out, self.pairs[:, 0], ga)
        np.add.at(out, self.pairs[:, 1], gb)
        return out

    def vjp(self, state, f) -> np.ndarray:
        """Frame forces/torques ``(n, 6)`` of child forces/torques ``(e, 6)`` (in a's frame)."""
        s = self.frames.check_state(state)
        f = _f6(f, self.m)
        Ra, Rb, ta, tb = self._parts(s)
        F = np.einsum("nij,nj->ni", Ra, f[:, :3])
        T = np.einsum("nij,nj->ni", Ra, f[:, 3:])
        d = tb - ta
        ga = np.concatenate([-F, np.cross(F, d) - T], axis=1)
        gb = np.concatenate([F, T], axis=1)
        return self._scatter(ga, gb)

    def jacobian(self, state) -> sp.csr_matrix:
        """Assembled J ``(6e, 6n)``."""
        s = self.frames.check_state(state)
        Ra, Rb, ta, tb = self._parts(s)
        RaT = Ra.transpose(0, 2, 1)
        e = self.m
        Ja = np.zeros((e, 6, 6))
        Jb = np.zeros((e, 6, 6))
        Ja[:, :3, :3] = -RaT
        Ja[:, :3, 3:] = RaT @ skew(tb - ta)
        Ja[:, 3:, 3:] = -RaT
        Jb[:, :3, :3] = RaT
        Jb[:, 3:, 3:] = RaT
        rows = np.broadcast_to((6 * np.arange(e))[:, None, None] + np.arange(6)[None, :, None], (e, 6, 6))
        data, r, c = [], [], []
        for blk, node in ((Ja, self.pairs[:, 0]), (Jb, self.pairs[:, 1])):
            cols = np.broadcast_to(6 * node[:, None, None] + np.arange(6)[None, None, :], (e, 6, 6))
            data.append(blk.ravel()), r.append(rows.ravel()), c.append(cols.ravel())
        out = sp.csr_matrix((np.concatenate(data), (np.concatenate(r), np.concatenate(c))),
                            shape=(6 * e, 6 * self.frames.n))
        out.sum_duplicates()
        return out.tocsr()

    def geometric_vp(self, state, f, v) -> np.ndarray:
        """``(d/dq [Jᵀ f]) v`` ``(n, 6)``."""
        s = self.frames.check_state(state)
        f = _f6(f, self.m)
        v = self.frames.check_velocity(v, "v")
        Ra, Rb, ta, tb = self._parts(s)
        a, b = self.pairs[:, 0], self.pairs[:, 1]
        F = np.einsum("nij,nj->ni", Ra, f[:, :3])
        T = np.einsum("nij,nj->ni", Ra, f[:, 3:])
        d = tb - ta
        wa = v[a, 3:]
        dF = np.cross(wa, F)
        dT = np.cross(wa, T)
        dd = v[b, :3] - v[a, :3]
        ga = np.concatenate([-dF, np.cross(dF, d) + np.cross(F, dd) - dT], axis=1)
        gb = np.concatenate([dF, dT], axis=1)
        return self._scatter(ga, gb)
