"""Moving-least-squares (MLS) mapping: points moved by a local affine fit of their parent nodes' motion.

At every material point X (rest position, m) with weights ``w_a(X) ≥ 0`` on its
parents a (any :class:`~voxflex.voronoi.shape_functions.ShapeValues`, e.g.
Shepard's inverse distances), the point moves with the affine map
``y ↦ M y + T`` that best fits the parents' motion in the weighted least-squares
sense,

    (M, T) = argmin  Σ_a w_a(X) [ |M X_a + T - t_a|²  +  ℓ_a² |M - A_a|_F² ],      x = M X + T,

where ``X_a`` is the rest origin of node a, ``t_a`` its current origin and ``A_a``
its linear part (the matrix A of an affine frame, the rotation R of a rigid
frame; point nodes have none and take ℓ_a = 0).  The first term is the affine
MLS deformation of Schaefer et al. (2006) with handles at the node origins; the
second also fits the frames' own linear parts, with ``ℓ_a² = r_a²/5``: it is
exactly the mismatch of the two affine maps averaged over a ball of radius
``r_a`` (``radius``) around the frame's origin, since the second moment of a
ball is ``r² / 5`` per axis.  With ``X* = Σ w_a X_a / W``, ``X̂_a = X_a - X*``,
``λ = Σ w_a ℓ_a²``, ``G = Σ_a w_a X̂_a X̂_aᵀ + λ I`` and ``g = G⁻¹ (X - X*)`` the
minimiser gives

    x = Σ_a [ φ_a t_a + A_a c_a ],   φ_a = w_a / W + w_a X̂_a · g,   c_a = w_a ℓ_a² g,

the linear-blend-skinning form ``Σ_a w_a [A_a (X - X_a) + t_a]`` with other
coefficients: ``φ_a`` (dimensionless) and ``c_a`` (m) depend only on the rest
configuration and are computed once.  Properties:

* **affine motions are reproduced exactly**: if every node moves by one affine
  map (``t_a = B X_a + b``, ``A_a = B``) the fit has zero residual and
  ``x = B X + b`` (``Σ φ_a = 1`` and ``Σ_a φ_a X_a + λ g = X``), whatever the
  weights; in particular a common rigid motion of the nodes moves the points
  rigidly;
* point nodes (ℓ = 0) get **linear precision** that linear blend skinning of
  points (``x = Σ w_a t_a``, Shepard interpolation) lacks; they need ``G``
  invertible: at least four parents with positive weight whose origins are not
  coplanar (a frame's linear part, ℓ > 0, makes ``G`` positive definite for
  any number of parents);
* one parent (or a single weight) gives the frame's own motion ``A_a (X - X_a) + t_a``.

Derivatives.  ``x`` is linear in the node parameters ``(A_a, t_a)``, so for
point nodes and affine frames the Jacobian is constant and the geometric
stiffness zero (``constant_jacobian``).  For rigid frames the velocity is
``(v, ω)`` with ``δt = v``, ``δR = [ω]× R`` (:mod:`voxflex.deform.chain.nodes`): each
parent contributes the 3×6 block ``[φ_a I, -[R_a c_a]×]``, which depends on
the rotation, and the geometric stiffness of a point force f is
``d(Jᵀ f)/dq · (v, ω) = (0, Σ (ω_a × R_a c_a) × f)`` per frame (zero when
``radius = 0``, where only the origins are used).

Compared with linear blend skinning with the same weights: for point nodes LBS
is Shepard interpolation and misses even a uniform stretch (see the example);
for affine frames both reproduce affine motions, and MLS replaces each frame's
extrapolation ``A_a (X - X_a)`` by a fit through all parents' origins, so the
origins' motion (not only the frames' matrices) sets the point's stretch.

References
----------
S. Schaefer, T. McPhail, J. Warren, "Image deformation using moving least
squares", ACM TOG 25(3), 2006.  B. Gilles, G. Bousquet, F. Faure, D. K. Pai,
"Frame-based elastic models", ACM TOG 30(2), 2011 (MLS mapping of frames).

Example
-------
Four point nodes stretched twice along x: MLS moves a point by the stretch,
linear blend skinning (Shepard interpolation of the nodes) does not.

>>> import numpy as np
>>> from voxflex.deform.chain.nodes import Points
>>> from voxflex.deform.chain.mappings import PointMapping
>>> from voxflex.voronoi.shape_functions import shepard
>>> nodes = Points(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]))
>>> sv = shepard(np.array([[0.2, 0.3, 0.1]]), nodes.rest_positions)
>>> q = nodes.rest * [2.0, 1.0, 1.0]
>>> np.round(MovingLeastSquaresMapping(nodes, sv).apply(q), 12) + 0.0
array([[0.4, 0.3, 0.1]])
>>> np.round(PointMapping(nodes, sv, backend="numpy").apply(q), 3) + 0.0
array([[0.237, 0.162, 0.093]])
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ...errors import InputError
from ...voronoi.shape_functions import ShapeValues
from .nodes import AffineFrames, Points, RigidFrames, skew

__all__ = ["MovingLeastSquaresMapping"]

_SINGULAR = 1e-10
"""Smallest eigenvalue of G relative to its largest below which the fit is refused (ℓ = 0 only)."""


def _default_radius(X: np.ndarray) -> np.ndarray:
    """Per node: half the distance to its nearest other node (1 m for a single node, where any radius is exact)."""
    n = len(X)
    if n == 1:
        return np.ones(1)
    d = np.linalg.norm(X[:, None, :] - X[None, :, :], axis=2)
    np.fill_diagonal(d, np.inf)
    return 0.5 * d.min(axis=1)


def _coefficients(index, w, rest, node_rest, ell2):
    """MLS coefficients φ (m, P) and c (m, P, 3) (m) and the smallest relative eigenvalue of G (m,).

    ``ell2`` (n,) are the squared lengths ℓ_a² (m²); padded slots (index -1) get zero coefficients.
    """
    valid = index >= 0
    ii = np.where(valid, index, 0)
    w = np.where(valid, w, 0.0)
    W = w.sum(axis=1)
    Xa = node_rest[ii]  # (m, P, 3)
    Xs = np.einsum("mp,mpi->mi", w, Xa) / W[:, None]
    Xh = Xa - Xs[:, None, :]
    psi = w * ell2[ii]
    lam = psi.sum(axis=1)
    G = np.einsum("mp,mpi,mpj->mij", w, Xh, Xh) + lam[:, None, None] * np.eye(3)
    ev = np.linalg.eigvalsh(G)
    rel = ev[:, 0] / np.maximum(ev[:, 2], 1e-300)
    d = rest - Xs
    # a point on its only weighted parent's origin (Shepard weights at a node) takes that parent's
    # motion, the limit of the fit as the weight grows: G may vanish there but g = 0 is exact
    on_node = ((w > 0).sum(axis=1) == 1) & (np.linalg.norm(d, axis=1) <= 1e-12 * (1.0 + np.linalg.norm(rest, axis=1)))
    rel = np.where(on_node, 1.0, rel)
    ok = rel > _SINGULAR
    Gs = np.where(ok[:, None, None] & ~on_node[:, None, None], G, np.eye(3))
    g = np.where(on_node[:, None], 0.0, np.linalg.solve(Gs, d[:, :, None])[:, :, 0])
    phi = w / W[:, None] + w * np.einsum("mpi,mi->mp", Xh, g)
    c = psi[:, :, None] * g[:, None, :]
    phi[~valid] = 0.0
    return phi, c, rel


class MovingLeastSquaresMapping:
    """Nodes → world positions of points ``(m, 3)`` (m) by a moving-least-squares affine fit.

    See the module docstring for the formula and its properties.

    Parameters
    ----------
    nodes : Points, AffineFrames or RigidFrames
        The parent nodes.
    shape : ShapeValues
        The points' weights on the nodes (``rest`` = the points' rest positions, m); only
        ``index``, ``w`` and ``rest`` are used; the weights need not sum to one (MLS is
        invariant to their scale) but must not all vanish.
    radius : float or (n,) float array, keyword-only
        Radius r_a (m) of the ball over which frame a's own affine map is fitted
        (``ℓ_a² = r_a² / 5``); ``0`` uses the frames' origins only (Schaefer's affine
        MLS; J is then constant even for rigid frames).  Default: ``0`` for point
        nodes; for frames, half the distance from each frame to its nearest other frame.

    Raises
    ------
    InputError
        On a wrong node type or shape values, a negative or non-finite radius, a positive
        radius with point nodes, a point whose weights all vanish, or (radius 0) a point
        whose weighted parent origins do not span 3-D (fewer than four or coplanar).

    Attributes
    ----------
    phi : (m, P) float array
        The coefficients φ_a of the parents' origins (dimensionless).
    c : (m, P, 3) float array
        The vectors c_a (m) the parents' linear parts act on.
    """

    def __init__(self, nodes, shape: ShapeValues, *, radius=None):
        if not isinstance(nodes, (Points, AffineFrames, RigidFrames)):
            raise InputError(f"nodes must be Points, AffineFrames or RigidFrames, got {type(nodes).__name__}")
        if not isinstance(shape, ShapeValues):
            raise InputError(f"shape must be a ShapeValues, got {type(shape).__name__}")
        if shape.n_nodes is not None and shape.n_nodes != nodes.n:
            raise InputError(f"shape functions were built for {shape.n_nodes} nodes but there are {nodes.n}; rebuild them on these nodes")
        if shape.m and shape.index.max() >= nodes.n:
            raise InputError(f"shape functions refer to node {int(shape.index.max())} but there are only {nodes.n}")
        if shape.m and np.any(shape.w < 0):
            raise InputError("MLS weights must be non-negative; use a non-negative shape function (shepard, natural-neighbour)")
        if radius is None:
            r = np.zeros(nodes.n) if isinstance(nodes, Points) else _default_radius(nodes.rest_positions)
        else:
            try:
                r = np.broadcast_to(np.asarray(radius, dtype=np.float64), (nodes.n,)).copy()
            except (TypeError, ValueError):
                raise InputError(f"radius must be a number or an array of {nodes.n} numbers (m), got {radius!r}") from None
            if not np.all(np.isfinite(r)) or np.any(r < 0):
                raise InputError(f"radius must be finite and >= 0 (m), got {radius!r}")
            if isinstance(nodes, Points) and np.any(r > 0):
                raise InputError("point nodes have no linear part to fit: use radius = 0 (the default) or frames")
        self.nodes = nodes
        self.shape = shape
        self.radius = r
        if shape.m:
            if np.any(np.where(shape.index >= 0, shape.w, 0.0).sum(axis=1) <= 0):
                raise InputError("some points have all weights zero; every point needs a parent with a positive weight")
            phi, c, rel = _coefficients(shape.index, shape.w, shape.rest, nodes.rest_positions, r * r / 5.0)
            bad = rel <= _SINGULAR
            if np.any(bad):
                k = int(np.argmax(bad))
                raise InputError(
                    f"the MLS fit is singular at {int(bad.sum())} point(s) (first: {shape.rest[k].tolist()}): their weighted "
                    "parent origins do not span 3-D; give frames a positive radius, or more (non-coplanar) parents"
                )
        else:
            phi, c = np.zeros((0, shape.n_parents)), np.zeros((0, shape.n_parents, 3))
        self.phi = phi
        self.c = c
        self._ii = np.where(shape.index >= 0, shape.index, 0)
        self._valid = shape.index >= 0

    # -- sizes -------------------------------------------------------------
    @property
    def m(self) -> int:
        """Number of points."""
        return self.shape.m

    @property
    def constant_jacobian(self) -> bool:
        """True when J does not depend on the state: point nodes, affine frames, or a zero radius."""
        return not isinstance(self.nodes, RigidFrames) or not np.any(self.radius > 0)

    # -- helpers -----------------------------------------------------------
    def _check_f(self, f, name="f"):
        f = np.asarray(f, dtype=np.float64)
        if f.shape != (self.m, 3):
            raise InputError(f"{name} must have shape ({self.m}, 3), got {f.shape}")
        return f

    def _scatter(self, per):
        """Sum per-(point, parent) rows ``(m, P, k)`` into nodes ``(n, k)``."""
        out = np.zeros((self.nodes.n, per.shape[-1]))
        np.add.at(out, self._ii.ravel(), per.reshape(-1, per.shape[-1]))
        return out

    def _Rc(self, s):
        """R_a c_a per (point, parent) ``(m, P, 3)`` for frames."""
        A = s[:, :9].reshape(-1, 3, 3)
        return np.einsum("mpij,mpj->mpi", A[self._ii], self.c)

    def _linear(self, s):
        """x of node parameters s (state layout; linear in s)."""
        if isinstance(self.nodes, Points):
            return np.einsum("mp,mpi->mi", self.phi, s[self._ii])
        return np.einsum("mp,mpi->mi", self.phi, s[self._ii, 9:]) + self._Rc(s).sum(axis=1)

    # -- public API ----------------------------------------------------------
    def apply(self, state) -> np.ndarray:
        """Point positions ``(m, 3)`` (m) of the node state."""
        return self._linear(self.nodes.check_state(state))

    def jvp(self, state, dq) -> np.ndarray:
        """``J(state) dq``: point velocities ``(m, 3)`` for node velocities ``dq`` ``(n, dofs_per_node)``."""
        s = self.nodes.check_state(state)
        v = self.nodes.check_velocity(dq)
        if not isinstance(self.nodes, RigidFrames):
            return self._linear(v)
        return np.einsum("mp,mpi->mi", self.phi, v[self._ii, :3]) + np.cross(v[self._ii, 3:], self._Rc(s)).sum(axis=1)

    def vjp(self, state, f) -> np.ndarray:
        """``J(state)ᵀ f``: node forces ``(n, dofs_per_node)`` of point forces ``f`` ``(m, 3)`` (N)."""
        s = self.nodes.check_state(state)
        f = self._check_f(f)
        ft = self.phi[:, :, None] * f[:, None, :]  # (m, P, 3)
        if isinstance(self.nodes, Points):
            return self._scatter(ft)
        if isinstance(self.nodes, AffineFrames):
            fA = f[:, None, :, None] * self.c[:, :, None, :]  # ∂x_i/∂A_ij = c_j
            return self._scatter(np.concatenate([fA.reshape(self.m, -1, 9), ft], axis=2))
        torque = np.cross(self._Rc(s), f[:, None, :])
        return self._scatter(np.concatenate([ft, torque], axis=2))

    def jacobian(self, state) -> sp.csr_matrix:
        """Assembled J ``(3m, n * dofs_per_node)``; rows are the flattened points."""
        s = self.nodes.check_state(state)
        m, P = self._ii.shape
        dpn = self.nodes.dofs_per_node
        blocks = np.zeros((m, P, 3, dpn))
        eye = np.eye(3)
        if isinstance(self.nodes, Points):
            blocks[:] = self.phi[:, :, None, None] * eye
        elif isinstance(self.nodes, AffineFrames):
            blocks[..., 9:] = self.phi[:, :, None, None] * eye
            # column 3i + j of row i holds c_j
            blocks[..., :9] = (eye[None, None, :, :, None] * self.c[:, :, None, None, :]).reshape(m, P, 3, 9)
        else:
            blocks[..., :3] = self.phi[:, :, None, None] * eye
            blocks[..., 3:] = -skew(self._Rc(s))
        rows = np.broadcast_to((3 * np.arange(m))[:, None, None, None] + np.arange(3)[None, None, :, None], blocks.shape)
        cols = np.broadcast_to(dpn * self._ii[:, :, None, None] + np.arange(dpn), blocks.shape)
        keep = np.broadcast_to(self._valid[:, :, None, None], blocks.shape)
        J = sp.csr_matrix((blocks[keep], (rows[keep], cols[keep])), shape=(3 * m, self.nodes.n_dofs))
        J.sum_duplicates()
        return J

    def geometric_vp(self, state, f, v) -> np.ndarray:
        """``(d/dq [J(q)ᵀ f]) v`` ``(n, dofs_per_node)``: the change of the node forces ``Jᵀ f`` (point
        forces ``f`` (m, 3) held) along the node increment ``v``.

        Zero for point nodes and affine frames; for rigid frames ``(0, Σ (ω_a × R_a c_a) × f)`` per frame.
        """
        s = self.nodes.check_state(state)
        vv = self.nodes.check_velocity(v, "v")
        f = self._check_f(f)
        if not isinstance(self.nodes, RigidFrames):
            return np.zeros_like(vv)
        dRc = np.cross(vv[self._ii, 3:], self._Rc(s))
        per = np.zeros(self._ii.shape + (6,))
        per[..., 3:] = np.cross(dRc, f[:, None, :])
        return self._scatter(per)

    def geometric(self, state, f) -> sp.csr_matrix:
        """Geometric stiffness d(Jᵀ f)/dq as a sparse ``(n_dofs, n_dofs)`` matrix.

        Rigid frames: the block ``Σ [f]× [R_a c_a]×`` on each frame's rotation DOFs (not symmetric
        away from equilibrium); zero otherwise.
        """
        s = self.nodes.check_state(state)
        f = self._check_f(f)
        nd = self.nodes.n_dofs
        if not isinstance(self.nodes, RigidFrames):
            return sp.csr_matrix((nd, nd))
        n = self.nodes.n
        Kw = self._scatter((skew(f)[:, None] @ skew(self._Rc(s))).reshape(self.m, -1, 9)).reshape(n, 3, 3)
        blocks = np.zeros((n, 6, 6))
        blocks[:, 3:, 3:] = Kw
        return sp.bsr_matrix((blocks, np.arange(n), np.arange(n + 1)), shape=(nd, nd)).tocsr()
