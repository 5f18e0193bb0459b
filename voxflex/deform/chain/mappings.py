"""Linear (skinning) mappings from nodes to points, to F, and to F with its gradient.

The first link of the chain nodes → F → strain → energy.  Given a node type
(:mod:`voxflex.deform.chain.nodes`) and the shape functions of the children
(:class:`voxflex.voronoi.shape_functions.ShapeValues`):

* :class:`PointMapping` — world positions of child points
  ``x_c = Σ_a w_a(X_c) y_a(X_c)`` with ``y_a(X) = x_a`` (points) or
  ``A_a (X - X_a) + t_a`` (affine; rigid with ``A = R``);
* :class:`DeformationGradientMapping` — ``F = Σ_a [w_a A_a + y_a(X) ⊗ ∇w_a]``
  (points: ``Σ_a x_a ⊗ ∇w_a``);
* :class:`DeformationGradientWithGradientMapping` — ``(F, ∇F)`` with
  ``∇F[i, j, k] = ∂F_ij / ∂X_k``, using the shape-function Hessians.

Every mapping offers ``apply`` (children), ``jvp`` (J v), ``vjp`` (Jᵀ f: forces
back to the nodes), ``jacobian`` (assembled ``scipy.sparse.csr_matrix``, rows =
flattened children, columns = flattened node velocity DOFs), and the geometric
stiffness ``geometric`` / ``geometric_vp`` = d(Jᵀ f)/dq.  For points and affine
frames J does not depend on the state (``constant_jacobian = True``: callers may
cache it) and the geometric stiffness is zero; for rigid frames it is not.

Rigid frames use the velocity ``(v, ω)`` with ``R ← exp([ω]×) R`` (left
multiplication, world-frame ω), so ``δA = [ω]× R`` and ``δt = v``.

Example
-------
>>> import numpy as np
>>> from voxflex.deform.chain.nodes import AffineFrames
>>> from voxflex.voronoi.shape_functions import shepard
>>> Xn = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
>>> frames = AffineFrames(Xn)
>>> fmap = DeformationGradientMapping(frames, shepard(np.full((2, 3), 0.3), Xn))
>>> np.allclose(fmap.apply(frames.rest), np.eye(3))
True
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import scipy.sparse as sp

from ...errors import InputError, check_choice
from ...voronoi.shape_functions import ShapeValues
from . import _kernels as K
from .nodes import AffineFrames, Points, RigidFrames, skew

__all__ = [
    "PointMapping",
    "DeformationGradientMapping",
    "DeformationGradientWithGradientMapping",
    "BACKENDS",
    "MAPPINGS",
]

BACKENDS = ("numba", "numpy")
"""Implementations: the compiled kernels, or their plain numpy twins (reference)."""

_NO_HESSIANS = np.zeros((1, 1, 3, 3))
_MIN_CHILDREN_PER_THREAD = 20_000
_POOL = None


def _over_children(kernel, m, *args):
    """Run ``kernel(c0, c1, *args)`` over [0, m), split over numba's thread count (the kernels release the GIL)."""
    import numba

    nt = min(numba.get_num_threads(), max(1, m // _MIN_CHILDREN_PER_THREAD))
    if nt <= 1:
        kernel(0, m, *args)
        return
    global _POOL
    if _POOL is None or _POOL._max_workers < nt:
        from concurrent.futures import ThreadPoolExecutor

        _POOL = ThreadPoolExecutor(max_workers=nt, thread_name_prefix="voxflex-mapping")
    bounds = np.linspace(0, m, nt + 1).astype(np.int64)
    futures = [_POOL.submit(kernel, int(bounds[k]), int(bounds[k + 1]), *args) for k in range(nt)]
    for fut in futures:
        fut.result()


def _rowmap(order: int) -> np.ndarray:
    """Internal row i*nα+α of a child -> position in the public child layout."""
    if order < 2:
        return np.arange(3 * K.N_ALPHA[order], dtype=np.int64)
    rm = np.empty(36, dtype=np.int64)
    for i in range(3):
        for al in range(12):
            rm[i * 12 + al] = 3 * i + al if al < 3 else 9 + 9 * i + (al - 3)
    return rm


@dataclass(frozen=True)
class _Mapping:
    nodes: Points | AffineFrames | RigidFrames
    shape: ShapeValues
    backend: str = "numba"

    order: ClassVar[int]

    def __post_init__(self):
        if not isinstance(self.nodes, (Points, AffineFrames, RigidFrames)):
            raise InputError(f"nodes must be Points, AffineFrames or RigidFrames, got {type(self.nodes).__name__}")
        if not isinstance(self.shape, ShapeValues):
            raise InputError(f"shape must be a ShapeValues, got {type(self.shape).__name__}")
        check_choice("backend", self.backend, BACKENDS)
        if self.shape.n_nodes is not None and self.shape.n_nodes != self.nodes.n:
            raise InputError(
                f"shape functions were built for {self.shape.n_nodes} nodes but there are {self.nodes.n}; rebuild them on these nodes"
            )
        if self.shape.m and self.shape.index.max() >= self.nodes.n:
            raise InputError(
                f"shape functions refer to node {int(self.shape.index.max())} but there are only {self.nodes.n} nodes"
            )
        if self.order == 2 and self.shape.ddw is None:
            raise InputError(f"{type(self).__name__} needs shape-function Hessians; build the ShapeValues with ddw")

    # -- sizes -------------------------------------------------------------
    @property
    def m(self) -> int:
        """Number of children."""
        return self.shape.m

    @property
    def child_size(self) -> int:
        """Number of scalars per child (3, 9 or 36)."""
        return 3 * K.N_ALPHA[self.order]

    @property
    def constant_jacobian(self) -> bool:
        """True when J does not depend on the state (points, affine frames)."""
        return not isinstance(self.nodes, RigidFrames)

    @property
    def shape_out(self) -> tuple[int, int]:
        """Shape of the assembled Jacobian: (m * child_size, n * dofs_per_node)."""
        return (self.m * self.child_size, self.nodes.n_dofs)

    # -- kernel plumbing ---------------------------------------------------
    @property
    def _affine(self) -> bool:
        return not isinstance(self.nodes, Points)

    def _args(self):
        s = self.shape
        ddw = s.ddw if (self.order == 2) else _NO_HESSIANS
        return s.index, s.w, s.dw, ddw, s.rest, self.nodes.rest_positions

    def _forward(self, S) -> np.ndarray:
        rm = _rowmap(self.order)
        if self.backend == "numpy":
            return K.forward_numpy(*self._args(), S, self.order, self._affine, rm)
        out = np.empty((self.m, self.child_size))
        _over_children(K.forward_kernel, self.m, *self._args(), np.ascontiguousarray(S), self.order, self._affine, rm, out)
        return out

    def _transpose(self, f) -> np.ndarray:
        rm = _rowmap(self.order)
        if self.backend == "numpy":
            return K.transpose_numpy(*self._args(), f, self.order, self._affine, rm, self.nodes.n)
        g = np.zeros((self.nodes.n, 12 if self._affine else 3))
        K.transpose_kernel(*self._args(), np.ascontiguousarray(f), self.order, self._affine, rm, g)
        return g

    def _jacobian_affine(self):
        """J with respect to the node parameters (points: x; affine and rigid: [A | t])."""
        rm = _rowmap(self.order)
        width = 12 if self._affine else 3
        shape = (self.m * self.child_size, self.nodes.n * width)
        if self.backend == "numpy":
            r, c, v = K.jacobian_numpy(*self._args(), self.order, self._affine, rm, self.nodes.n)
            return sp.csr_matrix((v, (r, c)), shape=shape)
        ncol = 4 if self._affine else 1
        nv = (self.shape.index >= 0).sum(axis=1).astype(np.int64)
        per_row = nv * ncol
        per_child = per_row * self.child_size
        child_ptr = np.zeros(self.m + 1, dtype=np.int64)
        np.cumsum(per_child, out=child_ptr[1:])
        nnz = int(child_ptr[-1])
        indptr = np.empty(self.m * self.child_size + 1, dtype=np.int64)
        indptr[:-1] = (child_ptr[:-1, None] + np.arange(self.child_size)[None, :] * per_row[:, None]).ravel()
        indptr[-1] = nnz
        itype = np.int32 if max(nnz, shape[1]) < 2**31 - 1 else np.int64
        indices = np.empty(nnz, dtype=itype)
        data = np.empty(nnz)
        _over_children(K.jacobian_kernel, self.m, *self._args(), self.order, self._affine, rm, child_ptr, indices, data)
        J = sp.csr_matrix((data, indices, indptr.astype(itype, copy=False)), shape=shape)
        J.has_sorted_indices = True
        return J

    # -- state handling ----------------------------------------------------
    def _params(self, state) -> np.ndarray:
        return self.nodes.check_state(state)

    def _dparams(self, state, dq) -> np.ndarray:
        """Node-parameter velocity (same layout as the state) of a DOF velocity."""
        v = self.nodes.check_velocity(dq)
        if not isinstance(self.nodes, RigidFrames):
            return v
        s = self.nodes.check_state(state)
        R = s[:, :9].reshape(-1, 3, 3)
        dS = np.empty_like(s)
        dS[:, :9] = (skew(v[:, 3:]) @ R).reshape(-1, 9)
        dS[:, 9:] = v[:, :3]
        return dS

    def _reduce(self, state, g) -> np.ndarray:
        """DOF forces from node-parameter forces g (state layout)."""
        if not isinstance(self.nodes, RigidFrames):
            return g
        s = self.nodes.check_state(state)
        R = s[:, :9].reshape(-1, 3, 3)
        gA = g[:, :9].reshape(-1, 3, 3)
        out = np.empty((self.nodes.n, 6))
        out[:, :3] = g[:, 9:]
        # τ = Σ_j R_{:,j} × gA_{:,j}
        out[:, 3:] = np.cross(R.transpose(0, 2, 1), gA.transpose(0, 2, 1)).sum(axis=1)
        return out

    # -- children layout (overridden for (F, ∇F)) ----------------------------
    def _to_children(self, y):
        raise NotImplementedError

    def _from_children(self, f, name="f") -> np.ndarray:
        raise NotImplementedError

    # -- public API ----------------------------------------------------------
    @property
    def linear(self) -> bool:
        """True when the children are linear in the node state (points, affine frames: ``jvp(X, q - X)`` is
        the children's displacement, to the digits of ``q - X``); False for rigid frames (rotations)."""
        return not isinstance(self.nodes, RigidFrames)

    def apply(self, state):
        """Children of the node state (see the class docstring for shapes)."""
        return self._to_children(self._forward(self._params(state)))

    def jvp(self, state, dq):
        """``J(state) dq``: the children's velocity for the DOF velocity ``dq`` ``(n, dofs_per_node)``."""
        self._params(state)
        return self._to_children(self._forward(self._dparams(state, dq)))

    def vjp(self, state, f) -> np.ndarray:
        """``J(state)ᵀ f``: forces on the node DOFs ``(n, dofs_per_node)`` from child forces ``f``."""
        s = self._params(state)
        return self._reduce(s, self._transpose(self._from_children(f)))

    def jacobian(self, state) -> sp.csr_matrix:
        """Assembled J ``(m * child_size, n * dofs_per_node)``; rows are the flattened children."""
        s = self._params(state)
        Ja = self._jacobian_affine()
        if not isinstance(self.nodes, RigidFrames):
            return Ja
        # chain with d[A|t]/d(v, ω): block-diagonal 12×6 per node
        n = self.nodes.n
        R = s[:, :9].reshape(-1, 3, 3)
        T = np.zeros((n, 12, 6))
        T[:, 9:, :3] = np.eye(3)
        E = skew(np.eye(3))  # E[k] = [e_k]×
        T[:, :9, 3:] = np.einsum("kil,nlj->nijk", E, R).reshape(n, 9, 3)
        Tm = sp.bsr_matrix((T, np.arange(n), np.arange(n + 1)), shape=(12 * n, 6 * n)).tocsr()
        J = (Ja @ Tm).tocsr()
        J.sum_duplicates()  # canonical: sorted columns, no duplicates
        return J

    def geometric_vp(self, state, f, v) -> np.ndarray:
        """``(d/dq [J(q)ᵀ f]) v`` ``(n, dofs_per_node)``; zero for points and affine frames."""
        s = self._params(state)
        vv = self.nodes.check_velocity(v, "v")
        fc = self._from_children(f)
        if not isinstance(self.nodes, RigidFrames):
            return np.zeros_like(vv)
        gA = self._transpose(fc)[:, :9].reshape(-1, 3, 3)
        R = s[:, :9].reshape(-1, 3, 3)
        dR = skew(vv[:, 3:]) @ R
        out = np.zeros_like(vv)
        out[:, 3:] = np.cross(dR.transpose(0, 2, 1), gA.transpose(0, 2, 1)).sum(axis=1)
        return out

    def geometric(self, state, f) -> sp.csr_matrix:
        """Geometric stiffness d(Jᵀ f)/dq as a sparse ``(n_dofs, n_dofs)`` matrix (not symmetric for rigid frames)."""
        s = self._params(state)
        fc = self._from_children(f)
        nd = self.nodes.n_dofs
        if not isinstance(self.nodes, RigidFrames):
            return sp.csr_matrix((nd, nd))
        n = self.nodes.n
        gA = self._transpose(fc)[:, :9].reshape(-1, 3, 3)
        R = s[:, :9].reshape(-1, 3, 3)
        # Σ_j [gA_j]× [R_j]×, columns j
        Kw = np.einsum("njab,njbc->nac", skew(gA.transpose(0, 2, 1)), skew(R.transpose(0, 2, 1)))
        blocks = np.zeros((n, 6, 6))
        blocks[:, 3:, 3:] = Kw
        return sp.bsr_matrix((blocks, np.arange(n), np.arange(n + 1)), shape=(nd, nd)).tocsr()


@dataclass(frozen=True)
class PointMapping(_Mapping):
    """Nodes → world positions of child points ``(m, 3)`` (m).

    Parameters
    ----------
    nodes : Points, AffineFrames or RigidFrames
    shape : ShapeValues
        Shape functions of the points (``rest`` = their rest positions).
    backend : {"numba", "numpy"}
        Compiled kernels or their numpy twins.

    Notes
    -----
    ``apply``/``jvp`` return ``(m, 3)``; ``vjp`` takes forces ``(m, 3)`` (N).
    """

    order: ClassVar[int] = 0

    def _to_children(self, y):
        return y

    def _from_children(self, f, name="f"):
        a = np.asarray(f, dtype=np.float64)
        if a.shape not in ((self.m, 3), (self.m * 3,)):
            raise InputError(f"{name} must have shape ({self.m}, 3), got {a.shape}")
        return np.ascontiguousarray(a.reshape(self.m, 3))


@dataclass(frozen=True)
class DeformationGradientMapping(_Mapping):
    """Nodes → deformation gradients F ``(m, 3, 3)`` at the samples.

    ``vjp`` takes the stress-like conjugate ``f`` ``(m, 3, 3)`` (e.g. volume ×
    first Piola-Kirchhoff stress) and returns node forces.  Parameters as
    :class:`PointMapping`.
    """

    order: ClassVar[int] = 1

    def _to_children(self, y):
        return y.reshape(self.m, 3, 3)

    def _from_children(self, f, name="f"):
        a = np.asarray(f, dtype=np.float64)
        if a.shape not in ((self.m, 3, 3), (self.m, 9), (self.m * 9,)):
            raise InputError(f"{name} must have shape ({self.m}, 3, 3), got {a.shape}")
        return np.ascontiguousarray(a.reshape(self.m, 9))


@dataclass(frozen=True)
class DeformationGradientWithGradientMapping(_Mapping):
    """Nodes → ``(F, ∇F)``: F ``(m, 3, 3)`` and ``∇F[c, i, j, k] = ∂F_ij/∂X_k`` ``(m, 3, 3, 3)`` (1/m).

    Needs the shape-function Hessians.  ``apply``/``jvp`` return the tuple
    ``(F, ∇F)``; ``vjp``/``geometric`` take ``(fF, f∇F)`` or the packed
    ``(m, 36)`` array.  The Jacobian rows of a sample are packed as F's 9
    entries then ∇F's 27 (see :meth:`pack`).
    """

    order: ClassVar[int] = 2

    def pack(self, F, dF) -> np.ndarray:
        """``(m, 36)`` rows ``[F.ravel(), ∇F.ravel()]`` per sample."""
        F = np.asarray(F, dtype=np.float64)
        dF = np.asarray(dF, dtype=np.float64)
        if F.shape != (self.m, 3, 3) or dF.shape != (self.m, 3, 3, 3):
            raise InputError(f"F must be ({self.m}, 3, 3) and its gradient ({self.m}, 3, 3, 3), got {F.shape} and {dF.shape}")
        return np.concatenate([F.reshape(self.m, 9), dF.reshape(self.m, 27)], axis=1)

    def unpack(self, y):
        """Inverse of :meth:`pack`: ``(m, 36)`` → ``(F, ∇F)``."""
        y = np.asarray(y, dtype=np.float64).reshape(self.m, 36)
        return y[:, :9].reshape(self.m, 3, 3), y[:, 9:].reshape(self.m, 3, 3, 3)

    def _to_children(self, y):
        return self.unpack(y)

    def _from_children(self, f, name="f"):
        if isinstance(f, tuple):
            if len(f) != 2:
                raise InputError(f"{name} must be a pair (fF, fdF) or a packed ({self.m}, 36) array")
            return self.pack(*f)
        a = np.asarray(f, dtype=np.float64)
        if a.shape not in ((self.m, 36), (self.m * 36,)):
            raise InputError(f"{name} must be a pair (fF, fdF) or a packed ({self.m}, 36) array, got shape {a.shape}")
        return np.ascontiguousarray(a.reshape(self.m, 36))


MAPPINGS = {
    "points": PointMapping,
    "deformation-gradient": DeformationGradientMapping,
    "deformation-gradient-with-gradient": DeformationGradientWithGradientMapping,
}
"""Mapping classes by name."""
