"""Dual-quaternion skinning: points moved by a normalised blend of their rigid frames' dual quaternions.

Frame a alone moves a rest point X to ``R_a (X - X_a) + t_a = R_a X + τ_a``
(``τ_a = t_a - R_a X_a``), the rigid motion of the unit dual quaternion
``q̂_a = r_a + ε d_a`` with ``r_a`` the rotation's unit quaternion and
``d_a = ½ (0, τ_a) r_a``.  A point with weights ``w_a`` takes
``b = Σ_a w_a σ_a q̂_a`` (σ_a = ±1 puts every r_a in the hemisphere of its
heaviest parent's), divides it by ``|b_r|`` (r = b_r/|b_r|, d = b_d/|b_r|) and
moves as ``x = X + 2 r_v × (r_v × X + r_0 X) + 2 (r_0 d_v - d_0 r_v + r_v × d_v)``
(Kavan et al. 2008).  Unlike linear blend skinning this never shrinks
(no "candy wrapper"); a common rigid motion of all frames moves the points rigidly.

The Jacobian is exact: per point and parent a 3×6 block
``M N (w_a σ_a B_a)`` with ``B_a`` the derivative of ``(r_a, d_a)`` with
respect to the frame's velocity ``(v, ω)`` (``δr_a = ½ (0, ω) r_a``,
``δτ_a = v - ω × (R_a X_a)``, ``δd_a = ½ (0, δτ_a) r_a + ½ (0, τ_a) δr_a``), ``N`` that of the
normalisation and ``M`` that of x in (r, d).  The geometric stiffness
(the derivative of Jᵀ f along a frame increment, :meth:`DualQuaternionSkinning.geometric_vp`) is
the product rule over ``B_a``, ``N`` and ``M`` (all polynomial in ``r_a``, ``τ_a``,
``R_a X_a``, ``r``, ``d`` and ``1/|b_r|``); it is in the shared derivative contract.

References
----------
Kavan, Collins, Žára, O'Sullivan, "Geometric skinning with approximate dual
quaternion blending", ACM TOG 27(4), 2008.

Example
-------
>>> import numpy as np
>>> from voxflex.deform.chain.nodes import RigidFrames
>>> from voxflex.voronoi.shape_functions import shepard
>>> frames = RigidFrames(np.array([[0.0, 0, 0], [2.0, 0, 0]]))
>>> dqs = DualQuaternionSkinning(frames, shepard(np.array([[1.0, 0.5, 0]]), frames.rest_positions))
>>> np.allclose(dqs.apply(frames.rest), [[1.0, 0.5, 0]])
True
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ...errors import InputError
from ...voronoi.shape_functions import ShapeValues
from .nodes import RigidFrames, skew
from .rigid import rotation_log

__all__ = ["DualQuaternionSkinning"]


def _quat(R):
    """Unit quaternions (w, x, y, z) (n, 4), w >= 0, of rotations (n, 3, 3)."""
    th = rotation_log(R)
    a = np.linalg.norm(th, axis=1)
    sinc = np.where(a < 1e-8, 0.5 - a * a / 48, np.sin(a / 2) / np.where(a < 1e-8, 1.0, a))
    return np.concatenate([np.cos(a / 2)[:, None], sinc[:, None] * th], axis=1)


def _Q(r):
    """(n, 4, 3): (0, ω) ⊗ r = Q(r) ω."""
    Q = np.empty(r.shape[:-1] + (4, 3))
    Q[..., 0, :] = -r[..., 1:]
    Q[..., 1:, :] = r[..., 0, None, None] * np.eye(3) - skew(r[..., 1:])
    return Q


def _L(t):
    """(n, 4, 4): (0, t) ⊗ q = L(t) q."""
    L = np.zeros(t.shape[:-1] + (4, 4))
    L[..., 0, 1:] = -t
    L[..., 1:, 0] = t
    L[..., 1:, 1:] = skew(t)
    return L


class DualQuaternionSkinning:
    """Rigid frames → point positions ``(m, 3)`` (m) by dual-quaternion blending.

    Parameters
    ----------
    frames : RigidFrames
    shape : ShapeValues
        Weights of the points (``rest`` = their rest positions); only ``index`` and ``w`` are used.
    """

    constant_jacobian = False

    def __init__(self, frames: RigidFrames, shape: ShapeValues):
        if not isinstance(frames, RigidFrames):
            raise InputError(f"frames must be RigidFrames, got {type(frames).__name__}")
        if not isinstance(shape, ShapeValues):
            raise InputError(f"shape must be a ShapeValues, got {type(shape).__name__}")
        if shape.m and shape.index.max() >= frames.n:
            raise InputError(f"shape functions refer to frame {int(shape.index.max())} but there are only {frames.n}")
        self.frames = frames
        self.shape = shape

    @property
    def m(self) -> int:
        return self.shape.m

    def _blend(self, s):
        """Per point: r, d (normalised), n = |b_r|, and per parent the signed weights, r_a, τ_a, R_a X_a."""
        idx = self.shape.index
        valid = idx >= 0
        ii = np.where(valid, idx, 0)
        R = s[:, :9].reshape(-1, 3, 3)
        ra = _quat(R)  # (n, 4)
        RX = np.einsum("nij,nj->ni", R, self.frames.rest_positions)
        tau = s[:, 9:] - RX
        w = np.where(valid, self.shape.w, 0.0)
        pivot = ii[np.arange(self.m), np.argmax(w, axis=1)]
        sig = np.where(np.einsum("mpk,mk->mp", ra[ii], ra[pivot]) < 0, -1.0, 1.0)
        ws = w * sig  # (m, P)
        da = 0.5 * np.einsum("nij,nj->ni", _L(tau), ra)
        br = np.einsum("mp,mpk->mk", ws, ra[ii])
        bd = np.einsum("mp,mpk->mk", ws, da[ii])
        n = np.linalg.norm(br, axis=1)
        return br / n[:, None], bd / n[:, None], n, ii, ws, ra, tau, RX

    def _points(self, r, d):
        X = self.shape.rest
        rv, r0, dv, d0 = r[:, 1:], r[:, :1], d[:, 1:], d[:, :1]
        return X + 2 * np.cross(rv, np.cross(rv, X) + r0 * X) + 2 * (r0 * dv - d0 * rv + np.cross(rv, dv))

    def apply(self, state) -> np.ndarray:
        """Point positions ``(m, 3)`` of the frames' state ``(n, 12)``."""
        s = self.frames.check_state(state)
        r, d = self._blend(s)[:2]
        return self._points(r, d)

    def _blocks(self, s):
        """(m, P, 3, 6) Jacobian blocks per point and parent slot (zero for padded slots)."""
        r, d, n, ii, ws, ra, tau, RX = self._blend(s)
        M = self._M(r, d, self.shape.rest)
        N = self._N(r, d, n)
        B = self._frame_blocks(ra, tau, RX)
        MN = M @ N  # (m, 3, 8)
        return np.einsum("mij,mp,mpjk->mpik", MN, ws, B[ii]), ii

    def jvp(self, state, dq) -> np.ndarray:
        """J dq ``(m, 3)`` for frame velocities ``dq`` ``(n, 6)``."""
        s = self.frames.check_state(state)
        v = self.frames.check_velocity(dq)
        Jb, ii = self._blocks(s)
        return np.einsum("mpik,mpk->mi", Jb, v[ii])

    def vjp(self, state, f) -> np.ndarray:
        """Jᵀ f: frame forces/torques ``(n, 6)`` of point forces ``f`` ``(m, 3)``."""
        s = self.frames.check_state(state)
        f = np.asarray(f, dtype=np.float64)
        if f.shape != (self.m, 3):
            raise InputError(f"f must have shape ({self.m}, 3), got {f.shape}")
        Jb, ii = self._blocks(s)
        g = np.einsum("mpik,mi->mpk", Jb, f)
        out = np.zeros((self.frames.n, 6))
        np.add.at(out, ii.ravel(), g.reshape(-1, 6))
        return out

    def jacobian(self, state) -> sp.csr_matrix:
        """Assembled J ``(3m, 6n)``."""
        s = self.frames.check_state(state)
        Jb, ii = self._blocks(s)
        m, P = ii.shape
        rows = np.broadcast_to((3 * np.arange(m))[:, None, None, None] + np.arange(3)[None, None, :, None], Jb.shape)
        cols = np.broadcast_to(6 * ii[:, :, None, None] + np.arange(6)[None, None, None, :], Jb.shape)
        J = sp.csr_matrix((Jb.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * m, 6 * self.frames.n))
        J.sum_duplicates()
        return J

    def geometric_vp(self, state, f, v) -> np.ndarray:
        """``(d/dq [J(q)ᵀ f]) v`` ``(n, 6)``: the change of the frame forces ``Jᵀ f`` (point forces ``f`` (m, 3)
        held) when the frames move by the increment ``v = (v, ω)`` ``(n, 6)`` (see the module docstring).

        Per point and parent ``Jᵀ f = w σ B_aᵀ (M N)ᵀ f``; its derivative is the product rule over
        ``B_a`` (through ``r_a``, ``τ_a`` and ``R_a X_a``), ``N`` (through ``r``, ``d`` and ``|b_r|``) and ``M``
        (linear in ``(r, d)``), with ``δr_a = ½ Q(r_a) ω``, ``δ(R_a X_a) = ω × R_a X_a``,
        ``δτ_a = v - ω × R_a X_a``; the blend's signs σ are locally constant.
        """
        st = self.frames.check_state(state)
        vv = self.frames.check_velocity(v, "v")
        f = np.asarray(f, dtype=np.float64)
        if f.shape != (self.m, 3):
            raise InputError(f"f must have shape ({self.m}, 3), got {f.shape}")
        r, d, n, ii, ws, ra, tau, RX = self._blend(st)
        X = self.shape.rest
        B = self._frame_blocks(ra, tau, RX)  # (n, 8, 6)
        # the frames' changes: of (r_a, d_a) (that is B v), of r_a, R_a X_a and τ_a themselves
        dra = 0.5 * np.einsum("nij,nj->ni", _Q(ra), vv[:, 3:])
        dRX = np.cross(vv[:, 3:], RX)
        dtau = vv[:, :3] - dRX
        dB = self._frame_blocks_change(ra, tau, RX, dra, dtau, dRX)
        dbl = np.einsum("nij,nj->ni", B, vv)  # (δr_a, δd_a)
        db = np.einsum("mp,mpk->mk", ws, dbl[ii])  # (δb_r, δb_d)
        dn = np.einsum("mk,mk->m", r, db[:, :4])
        dr = (db[:, :4] - r * dn[:, None]) / n[:, None]
        dd = (db[:, 4:] - d * dn[:, None]) / n[:, None]
        M = self._M(r, d, X)
        dM = self._M(dr, dd, X)  # M is linear in (r, d)
        N = self._N(r, d, n)
        dN = np.zeros((self.m, 8, 8))
        rr = r[:, :, None] * r[:, None, :]
        dN[:, :4, :4] = (-(dr[:, :, None] * r[:, None, :] + r[:, :, None] * dr[:, None, :]) / n[:, None, None]
                         - (np.eye(4) - rr) * (dn / n**2)[:, None, None])
        dN[:, 4:, :4] = (-(dd[:, :, None] * r[:, None, :] + d[:, :, None] * dr[:, None, :]) / n[:, None, None]
                         + d[:, :, None] * r[:, None, :] * (dn / n**2)[:, None, None])
        dN[:, 4:, 4:] = -np.eye(4) * (dn / n**2)[:, None, None]
        g = np.einsum("mij,mi->mj", M @ N, f)  # (M N)ᵀ f (m, 8)
        dg = np.einsum("mij,mi->mj", dM @ N + M @ dN, f)
        per = np.einsum("mp,mpjk,mj->mpk", ws, dB[ii], g) + np.einsum("mp,mpjk,mj->mpk", ws, B[ii], dg)
        out = np.zeros((self.frames.n, 6))
        np.add.at(out, ii.ravel(), per.reshape(-1, 6))
        return out

    @staticmethod
    def _M(r, d, X):
        """(m, 3, 8): dx/d(r, d) of the point formula (linear in (r, d))."""
        rv, r0, dv, d0 = r[:, 1:], r[:, 0], d[:, 1:], d[:, 0]
        M = np.zeros((len(r), 3, 8))
        M[:, :, 0] = 2 * np.cross(rv, X) + 2 * dv
        M[:, :, 1:4] = (-2 * skew(np.cross(rv, X) + r0[:, None] * X) - 2 * skew(rv) @ skew(X)
                        - 2 * d0[:, None, None] * np.eye(3) - 2 * skew(dv))
        M[:, :, 4] = -2 * rv
        M[:, :, 5:8] = 2 * r0[:, None, None] * np.eye(3) + 2 * skew(rv)
        return M

    @staticmethod
    def _N(r, d, n):
        """(m, 8, 8): d(r, d)/d(b_r, b_d) of the normalisation."""
        N = np.zeros((len(r), 8, 8))
        N[:, :4, :4] = (np.eye(4) - r[:, :, None] * r[:, None, :]) / n[:, None, None]
        N[:, 4:, :4] = -d[:, :, None] * r[:, None, :] / n[:, None, None]
        N[:, 4:, 4:] = np.eye(4) / n[:, None, None]
        return N

    @staticmethod
    def _frame_blocks(ra, tau, RX):
        """(n, 8, 6): d(r_a, d_a)/d(v, ω) per frame."""
        Q = _Q(ra)
        B = np.zeros((len(ra), 8, 6))
        B[:, :4, 3:] = 0.5 * Q
        B[:, 4:, :3] = 0.5 * Q
        B[:, 4:, 3:] = 0.5 * Q @ skew(RX) + 0.25 * _L(tau) @ Q
        return B

    @staticmethod
    def _frame_blocks_change(ra, tau, RX, dra, dtau, dRX):
        """(n, 8, 6): the change of :meth:`_frame_blocks` (Q and L are linear in their arguments)."""
        Q, dQ = _Q(ra), _Q(dra)
        dB = np.zeros((len(ra), 8, 6))
        dB[:, :4, 3:] = 0.5 * dQ
        dB[:, 4:, :3] = 0.5 * dQ
        dB[:, 4:, 3:] = (0.5 * dQ @ skew(RX) + 0.5 * Q @ skew(dRX) + 0.25 * _L(dtau) @ Q
                         + 0.25 * _L(tau) @ dQ)
        return dB
