"""Spring mappings: mapped points → edge lengths (distances) and their relative change (extensions).

Springs and cables act on points that are themselves mapped from the nodes
(:class:`voxflex.deform.chain.mappings.PointMapping`), so these mappings take the
point positions ``x`` ``(n, 3)`` (m) as input.  Each edge joins two points, or
a point and a fixed target (an anchor in the world).

* :class:`DistanceMapping` — ``d_e = |b_e - a_e|`` (m);
* :class:`ExtensionMapping` — ``ε_e = (|b_e - a_e| - L_e) / L_e``, dimensionless,
  with rest lengths ``L_e`` (by default the lengths at the rest points).

With ``u = (b - a) / l`` the unit direction, the Jacobian row of an edge is
``±u / L`` on its two points and the geometric stiffness of an edge force f is
``(f / L) (I - u uᵀ) / l`` on the relative motion (``L = 1`` for distances).
J depends on the state (``constant_jacobian = False``).  A zero-length edge
has no direction: its Jacobian row is taken as zero there (a subgradient) and
its geometric stiffness is infinite, so keep edges away from zero length
(cables: rest lengths > 0, targets off the points).

Every mapping offers ``apply``, ``jvp`` (J v), ``vjp`` (Jᵀ f), ``jacobian``
(sparse ``(e, 3n)``), ``geometric_vp`` ((d/dx[Jᵀ f]) v) and ``geometric``
(sparse ``(3n, 3n)``, symmetric), as the node mappings do.

Example
-------
>>> import numpy as np
>>> x = np.array([[0.0, 0, 0], [2.0, 0, 0]])
>>> ext = ExtensionMapping(np.array([[0, 1]]), rest_lengths=[1.0], n_points=2)
>>> ext.apply(x)
array([1.])
>>> DistanceMapping.to_targets([1], [[2.0, 0, 1]], n_points=2).apply(x)
array([1.])
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ...errors import InputError

__all__ = ["DistanceMapping", "ExtensionMapping"]


def _check_points(x, n, name="x") -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.shape == (3 * n,):
        a = a.reshape(n, 3)
    if a.shape != (n, 3):
        raise InputError(f"{name} must be the ({n}, 3) point positions, got shape {np.shape(x)}")
    return a


class _Segments:
    """Edges (i, j) between points, j = -1 meaning the fixed target of the edge; per-edge scale and offset."""

    def __init__(self, edges, n_points, targets=None):
        try:
            E = np.asarray(edges, dtype=np.int64)
        except (TypeError, ValueError):
            raise InputError("edges must be an (e, 2) integer array of point indices") from None
        if E.ndim != 2 or E.shape[1] != 2:
            raise InputError(f"edges must be an (e, 2) integer array of point indices, got shape {E.shape}")
        n = int(n_points)
        if n < 1:
            raise InputError(f"n_points must be >= 1, got {n_points!r}")
        if targets is None:
            if E.size and (E.min() < 0 or E.max() >= n):
                raise InputError(f"edges refer to points outside [0, {n}); give indices of the mapped points")
            T = np.zeros((len(E), 3))
        else:
            T = np.asarray(targets, dtype=np.float64)
            if T.shape != (len(E), 3) or not np.all(np.isfinite(T)):
                raise InputError(f"targets must be a finite ({len(E)}, 3) array (m), one per edge, got shape {T.shape}")
            if E.size and (E[:, 0].min() < 0 or E[:, 0].max() >= n or np.any(E[:, 1] != -1)):
                raise InputError(f"target edges must be (point in [0, {n}), -1)")
        self.edges = E
        self.n = n
        self.targets = T
        self.fixed = E[:, 1] < 0

    @property
    def m(self) -> int:
        return len(self.edges)

    def delta(self, x):
        """b - a per edge (e, 3)."""
        i, j = self.edges[:, 0], self.edges[:, 1]
        b = np.where(self.fixed[:, None], self.targets, x[np.maximum(j, 0)])
        return b - x[i]

    def rel(self, v):
        """Relative velocity v_b - v_a (targets do not move)."""
        i, j = self.edges[:, 0], self.edges[:, 1]
        vb = np.where(self.fixed[:, None], 0.0, v[np.maximum(j, 0)])
        return vb - v[i]

    def scatter(self, g):
        """Node forces of per-edge vectors g acting on b (and -g on a)."""
        out = np.zeros((self.n, 3))
        np.add.at(out, self.edges[:, 0], -g)
        keep = ~self.fixed
        np.add.at(out, self.edges[keep, 1], g[keep])
        return out

    def incidence(self):
        """Sparse (e, n) matrix of b - a."""
        e = np.arange(self.m)
        keep = ~self.fixed
        rows = np.concatenate([e, e[keep]])
        cols = np.concatenate([self.edges[:, 0], self.edges[keep, 1]])
        vals = np.concatenate([-np.ones(self.m), np.ones(int(keep.sum()))])
        return sp.csr_matrix((vals, (rows, cols)), shape=(self.m, self.n))


def _direction(d):
    l = np.linalg.norm(d, axis=1)
    safe = np.where(l > 0, l, 1.0)
    return d / safe[:, None] * (l > 0)[:, None], l


class _LengthMapping:
    """y_e = (|b_e - a_e| - offset_e) * scale_e."""

    def __init__(self, seg: _Segments, scale, offset):
        self._seg = seg
        self.scale = np.asarray(scale, dtype=np.float64)
        self.offset = np.asarray(offset, dtype=np.float64)

    @property
    def m(self) -> int:
        """Number of edges."""
        return self._seg.m

    @property
    def n_points(self) -> int:
        return self._seg.n

    @property
    def edges(self) -> np.ndarray:
        """(e, 2) point indices; -1 in the second column for an edge to its fixed target."""
        return self._seg.edges

    constant_jacobian = False

    @property
    def shape_out(self) -> tuple[int, int]:
        return (self.m, 3 * self.n_points)

    def _f(self, f):
        a = np.asarray(f, dtype=np.float64)
        if a.shape != (self.m,):
            raise InputError(f"f must have shape ({self.m},) (one value per edge), got {a.shape}")
        return a

    def apply(self, x) -> np.ndarray:
        """Per-edge values (e,) of point positions ``x`` (n, 3)."""
        x = _check_points(x, self.n_points)
        return (np.linalg.norm(self._seg.delta(x), axis=1) - self.offset) * self.scale

    def jvp(self, x, v) -> np.ndarray:
        """J(x) v (e,) for point velocities ``v`` (n, 3)."""
        x = _check_points(x, self.n_points)
        v = _check_points(v, self.n_points, "v")
        u, _ = _direction(self._seg.delta(x))
        return self.scale * np.einsum("ei,ei->e", u, self._seg.rel(v))

    def vjp(self, x, f) -> np.ndarray:
        """Jᵀ f: point forces (n, 3) of per-edge forces ``f`` (e,)."""
        x = _check_points(x, self.n_points)
        u, _ = _direction(self._seg.delta(x))
        return self._seg.scatter((self._f(f) * self.scale)[:, None] * u)

    def jacobian(self, x) -> sp.csr_matrix:
        """Assembled J (e, 3n): row e, column 3 * point + component."""
        x = _check_points(x, self.n_points)
        u, _ = _direction(self._seg.delta(x))
        C = self._seg.incidence().tocoo()
        rows = np.repeat(C.row, 3)
        cols = (3 * C.col[:, None] + np.arange(3)).ravel()
        vals = (C.data[:, None] * u[C.row] * self.scale[C.row, None]).ravel()
        return sp.csr_matrix((vals, (rows, cols)), shape=self.shape_out)

    def _edge_stiffness(self, x, f):
        u, l = _direction(self._seg.delta(x))
        with np.errstate(divide="ignore"):
            c = self._f(f) * self.scale / l
        return c[:, None, None] * (np.eye(3) - u[:, :, None] * u[:, None, :])

    def geometric_vp(self, x, f, v) -> np.ndarray:
        """(d/dx [J(x)ᵀ f]) v (n, 3); infinite for a zero-length edge."""
        x = _check_points(x, self.n_points)
        v = _check_points(v, self.n_points, "v")
        Ke = self._edge_stiffness(x, f)
        return self._seg.scatter(np.einsum("eij,ej->ei", Ke, self._seg.rel(v)))

    def geometric(self, x, f) -> sp.csr_matrix:
        """Geometric stiffness d(Jᵀ f)/dx as a symmetric sparse (3n, 3n) matrix."""
        x = _check_points(x, self.n_points)
        Ke = self._edge_stiffness(x, f)
        C = self._seg.incidence()
        # Cᵀ diag(K_e) C with 3x3 blocks: kron on the (e, n) incidence
        B = sp.kron(C, sp.identity(3), format="csr")
        Kb = sp.block_diag(list(Ke), format="csr") if self.m else sp.csr_matrix((0, 0))
        return (B.T @ Kb @ B).tocsr()


class DistanceMapping(_LengthMapping):
    """Mapped points → distances ``d_e = |b_e - a_e|`` ``(e,)`` (m).

    Parameters
    ----------
    edges : (e, 2) int
        Point index pairs (a, b).
    n_points : int
        Number of mapped points n (the input is ``(n, 3)``).

    See :meth:`to_targets` for distances to fixed world points.
    """

    def __init__(self, edges, n_points):
        seg = _Segments(edges, n_points)
        super().__init__(seg, np.ones(seg.m), np.zeros(seg.m))

    @classmethod
    def to_targets(cls, points, targets, *, n_points) -> "DistanceMapping":
        """Distances from points ``points`` (e,) int to fixed targets ``targets`` (e, 3) (m)."""
        obj = cls.__new__(cls)
        idx = np.asarray(points, dtype=np.int64).reshape(-1)
        seg = _Segments(np.stack([idx, -np.ones_like(idx)], axis=1), n_points, targets)
        _LengthMapping.__init__(obj, seg, np.ones(seg.m), np.zeros(seg.m))
        return obj


class ExtensionMapping(_LengthMapping):
    """Mapped points → relative length changes ``(l_e - L_e) / L_e`` ``(e,)`` (dimensionless).

    Parameters
    ----------
    edges : (e, 2) int
        Point index pairs (a, b).
    rest_points : (n, 3) float, optional
        Rest positions of the points (m); they give the rest lengths and the
        number of points.
    rest_lengths : (e,) float, optional
        Rest lengths L_e > 0 (m), instead of (or overriding) those of ``rest_points``.
    n_points : int, optional
        Number of points when ``rest_points`` is not given.
    targets : (e, 3) float, optional
        Fixed world points: edges are then ``(point, -1)`` pairs to these targets.
    """

    def __init__(self, edges, *, rest_points=None, rest_lengths=None, n_points=None, targets=None):
        if rest_points is not None:
            rp = np.asarray(rest_points, dtype=np.float64)
            if rp.ndim != 2 or rp.shape[1] != 3:
                raise InputError(f"rest_points must be an (n, 3) array (m), got shape {rp.shape}")
            n_points = len(rp)
        if n_points is None:
            raise InputError("give rest_points or n_points (the number of mapped points)")
        seg = _Segments(edges, n_points, targets)
        if rest_lengths is None:
            if rest_points is None:
                raise InputError("give rest_points or rest_lengths (the edges' rest lengths, m)")
            L = np.linalg.norm(seg.delta(rp), axis=1)
        else:
            L = np.asarray(rest_lengths, dtype=np.float64)
            if L.shape != (seg.m,):
                raise InputError(f"rest_lengths must have shape ({seg.m},), got {L.shape}")
        if not np.all(np.isfinite(L) & (L > 0)):
            raise InputError("rest lengths must be > 0 (m); remove zero-length edges or give rest_lengths")
        self.rest_lengths = L
        super().__init__(seg, 1.0 / L, L)
