"""Cables and springs: a layer of mapped material points joined by tension-only cables.

A cable is a polyline through material points of the object (given at rest,
mapped by the model's own point mapping ``x = J q``, constant J for voxel
corners and affine frames), optionally starting at a fixed ``anchor`` in the
world.  It slides without friction through its interior points (eyelets), so
one tension ``T`` acts along the whole cable; its length is the sum of its
segment lengths (:class:`~voxflex.deform.chain.spring.DistanceMapping`):

    l(x) = sum_e |b_e - a_e|,   L(s) = L_0 - s * shorten,   delta = l - L(s).

``s`` is where the run stands (the static load factor, or t / t_end in
implicit Euler), ``L_0`` the rest length (default: the rest polyline length,
so the cable is just taut at rest) and ``shorten`` the total length reduction
reached at the end of the run (pulling the cable in, as an actuator does).
With a stiffness ``k`` (N/m, the whole cable's axial stiffness EA / L_0):

    E = k/2 <delta>_+^2,   T = k <delta>_+,   dT/dl = k [delta > 0],

with ``<delta>_+ = max(delta, 0)``: a slack cable stores no energy and pulls
nothing.  E is C1 (its gradient T is continuous); its second derivative jumps
from 0 to k where the cable becomes taut, so the Hessian is only piecewise
continuous (Newton's convergence is then semismooth: quadratic once the
taut/slack pattern settles; the solvers' line search keeps it stable).
``tension_only=False`` makes it a two-sided spring (``<delta>`` without the
positive part).  A force-controlled cable instead has a prescribed tension
``T = s * pull`` (N) and the energy ``E = s * pull * l`` (the actuator's
potential).

A spring between two points is a cable of two points; springs attached at
every point are one cable per segment.

Forces and stiffness, through the point mapping (x the (m, 3) cable points):

    dE/dq = J^T (T g),    d2E/dq2 = J^T (dT/dl g g^T + T G) J,

with ``g = dl/dx`` the sum of the segments' unit directions (the distance
mapping's ``J^T 1``) and ``G`` the segments' geometric stiffness
``(I - u u^T) / l_e`` (positive semi-definite for T >= 0: no projection).

:class:`CableModel` wraps any model of the protocol
(:mod:`voxflex.deform.models.protocol`) whose point mapping is linear in q, like
:class:`~voxflex.deform.layers.contact.ContactModel`: it adds ``E`` to the energy,
``J^T (T g)`` to the gradient and the stiffness above to the Hessian, and
forwards everything else (``begin_step`` included, after noting the fraction).

Example
-------
>>> import numpy as np
>>> from voxflex.image.label_image import LabelImage
>>> from voxflex.deform.materials.constitutive import material
>>> from voxflex.deform.models.voxel.model import VoxelModel
>>> inner = VoxelModel.from_image(LabelImage(np.ones((4, 1, 1))), {1: material("hooke", young=1.0, poisson=0.3)})
>>> model = CableModel(inner, [Cable([[0.5, 0.5, 1.0], [3.5, 0.5, 1.0]], stiffness=10.0, shorten=0.3)])
>>> model.set_time(1.0)
>>> model.tensions(model.rest)          # at the rest shape, 0.3 m short: T = 10 N/m * 0.3 m
array([3.])
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import scipy.sparse as sp

from ...errors import InputError
from ..chain.spring import DistanceMapping
from ..models.protocol import OnePass
from .base import ModelLayer
from .cable import Cable, cable_law

__all__ = ["Cable", "CableModel", "cable_law", "with_cables"]








# ---------------------------------------------------------------------------
# the wrapper
# ---------------------------------------------------------------------------
class CableModel(OnePass, ModelLayer):
    """A model with cables (see the module docstring).

    Parameters
    ----------
    inner : Model
        Any model of the protocol whose point mapping is linear in q (voxel
        nodes, affine frames), possibly already wrapped (contact).
    cables : sequence of Cable

    Attributes
    ----------
    inner : Model
    cables : tuple of Cable
    points : (m, 3) float
        All cables' material points at rest, cable after cable.
    fraction : float
        Where the run stands (0 at the start, 1 at its end): shortening and pull.

    Raises
    ------
    InputError
        No cable; a point outside the material (names the cable and the point).
    NotImplementedError
        A model whose point mapping is not linear in q (rigid frames).
    """

    layer = "cable"
    layer_advice = "cables: a large shortening or pull in one step can fail to converge; use more steps"

    def __init__(self, inner, cables: Sequence[Cable]):
        cables = tuple(cables)
        if not cables:
            raise InputError("a cable model needs at least one cable; give [[cable]] tables")
        for i, c in enumerate(cables):
            if not isinstance(c, Cable):
                raise InputError(f"cable {i} must be a Cable, got {type(c).__name__}")
        self.inner = inner
        self.cables = cables
        counts = np.array([len(c.points) for c in cables])
        start = np.concatenate([[0], np.cumsum(counts)])
        self.points = np.vstack([c.points for c in cables])
        for i, c in enumerate(cables):  # one mapping per cable first: the error names the cable
            try:
                inner.point_mapping(c.points)
            except InputError as exc:
                raise InputError(f"[[cable]] {i}: {exc}") from None
        self.mapping = inner.point_mapping(self.points)
        if not getattr(self.mapping, "constant_jacobian", False):
            raise NotImplementedError("cables need a model whose point mapping is linear in the state "
                                      "(voxel nodes or affine frames)")
        self._J = None
        n = len(self.points)
        pairs, pair_cable, anchored, targets, anchor_cable = [], [], [], [], []
        for i, c in enumerate(cables):
            idx = np.arange(start[i], start[i + 1])
            pairs += list(zip(idx[:-1], idx[1:]))
            pair_cable += [i] * (len(idx) - 1)
            if c.anchor is not None:
                anchored.append(idx[0])
                targets.append(c.anchor)
                anchor_cable.append(i)
        self._pairs = DistanceMapping(np.array(pairs, dtype=np.int64).reshape(-1, 2), n) if pairs else None
        self._anchors = (DistanceMapping.to_targets(anchored, np.array(targets), n_points=n) if anchored else None)
        self._pair_cable = np.array(pair_cable, dtype=np.int64)
        self._anchor_cable = np.array(anchor_cable, dtype=np.int64)
        self._point_cable = np.repeat(np.arange(len(cables)), counts)
        self._elastic = np.array([c.pull is None for c in cables])
        self._k = np.array([c.stiffness if c.pull is None else 0.0 for c in cables])
        self._pull = np.array([c.pull if c.pull is not None else 0.0 for c in cables])
        self._one_sided = np.array([bool(c.tension_only) for c in cables])
        self.fraction = 0.0

    def describe(self) -> dict:
        out = dict(self.inner.describe())
        out.update({"cables": len(self.cables), "cable_points": len(self.points)})
        return out

    # -- time ---------------------------------------------------------------------
    def begin_step(self, fraction: float, q_prev, q_start):
        """Note the step's fraction, then let the inner model choose the start state."""
        self.set_time(fraction)
        return self.inner.begin_step(fraction, q_prev, q_start)

    # -- the cables' terms ----------------------------------------------------------
    def lengths(self, q) -> np.ndarray:
        """Current length (m) of every cable at state q (n, d): (c,)."""
        return self._lengths(self.mapping.apply(np.asarray(q, dtype=float)))

    def _lengths(self, x):
        out = np.zeros(len(self.cables))
        if self._pairs is not None:
            np.add.at(out, self._pair_cable, self._pairs.apply(x))
        if self._anchors is not None:
            np.add.at(out, self._anchor_cable, self._anchors.apply(x))
        return out

    def _law(self, x, fraction):
        """Per cable: energy (J), tension (N), dT/dl (N/m) at points x and run fraction s."""
        s = self.fraction if fraction is None else float(fraction)
        l = self._lengths(x)
        L = np.array([c.length_at(s) if c.pull is None else 0.0 for c in self.cables])
        E = np.zeros(len(self.cables))
        T = np.zeros(len(self.cables))
        dT = np.zeros(len(self.cables))
        el = self._elastic
        for one_sided in (True, False):
            m = el & (self._one_sided == one_sided)
            if np.any(m):
                E[m], T[m], dT[m] = cable_law(l[m] - L[m], self._k[m], tension_only=one_sided)
        pull = ~el
        E[pull] = s * self._pull[pull] * l[pull]
        T[pull] = s * self._pull[pull]
        return E, T, dT

    def tensions(self, q, fraction=None) -> np.ndarray:
        """Tension (N) of every cable at state q (n, d) and run fraction (default :attr:`fraction`): (c,)."""
        return self._law(self.mapping.apply(np.asarray(q, dtype=float)), fraction)[1]

    def cable_energy(self, q, fraction=None) -> float:
        """Energy stored in the cables (J) at state q (n, d)."""
        return float(np.sum(self._law(self.mapping.apply(np.asarray(q, dtype=float)), fraction)[0]))

    def _point_forces(self, x, T):
        """dE/dx (m, 3): each segment's tension along its direction."""
        g = np.zeros_like(x)
        if self._pairs is not None:
            g += self._pairs.vjp(x, T[self._pair_cable])
        if self._anchors is not None:
            g += self._anchors.vjp(x, T[self._anchor_cable])
        return g

    def _point_hessian(self, x, T, dT):
        """d2E/dx2 (3m, 3m) sparse: dT/dl g g^T per cable plus the segments' geometric stiffness."""
        n3 = 3 * len(x)
        H = sp.csr_matrix((n3, n3))
        if self._pairs is not None:
            H = H + self._pairs.geometric(x, T[self._pair_cable])
        if self._anchors is not None:
            H = H + self._anchors.geometric(x, T[self._anchor_cable])
        taut = np.flatnonzero(dT != 0)
        if len(taut):
            g = self._point_forces(x, np.where(dT != 0, 1.0, 0.0))  # dl/dx of the taut cables, per point
            rows, cols, vals = [], [], []
            for c in taut:
                dofs = (3 * np.flatnonzero(self._point_cable == c)[:, None] + np.arange(3)).ravel()
                gc = g.ravel()[dofs]
                rows.append(np.repeat(dofs, len(dofs)))
                cols.append(np.tile(dofs, len(dofs)))
                vals.append(dT[c] * np.outer(gc, gc).ravel())
            H = H + sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                  shape=(n3, n3))
        return H

    def _jacobian(self, q):
        if self._J is None:
            self._J = sp.csr_matrix(self.mapping.jacobian(q))
        return self._J

    # -- energy -----------------------------------------------------------------------
    def energy_gradient_hessian(self, q, *, gradient: bool = True, hessian: bool = True, u=None):
        """(energy J, gradient (n, d) or None, Hessian (nd, nd) or None) of the inner model plus the cables.

        The Hessian has the inner model's type (sparse, or dense for frame models).
        Where the inner energy is not finite its (energy, None, None) is returned as is.  ``u`` (= q - rest):
        the inner model's strains from the displacement (the layer's displacement form, :class:`ModelLayer`).
        """
        q = np.asarray(q, dtype=float)
        E, g, H = self._inner_terms(q, u, gradient, hessian)
        if not np.isfinite(E):
            return E, g, H
        x = self.mapping.apply(q)
        Ec, T, dT = self._law(x, None)
        E = E + float(np.sum(Ec))
        if gradient and np.any(T != 0):
            g = g + self.mapping.vjp(q, self._point_forces(x, T))
        if hessian and (np.any(T != 0) or np.any(dT != 0)):
            J = self._jacobian(q)
            Hc = (J.T @ (self._point_hessian(x, T, dT) @ J)).tocsr()
            H = H + Hc.toarray() if isinstance(H, np.ndarray) else (H + Hc).tocsr()
        return E, g, H


def with_cables(model, scene):
    """``model`` wrapped in a :class:`CableModel` for the scene's ``[[cable]]`` tables.

    Returns ``model`` unchanged when the scene has no cable or ``model`` is a
    CableModel already.  The scene is read by attribute (``scene.cables``:
    points, anchor, stiffness, rest_length, shorten, pull, tension_only), so
    this stage does not import the scene module.
    """
    specs = tuple(getattr(scene, "cables", ()) or ())
    if not specs or isinstance(model, CableModel):
        return model
    cables = [Cable(points=s.points, anchor=s.anchor, stiffness=s.stiffness, rest_length=s.rest_length,
                    shorten=s.shorten, pull=s.pull, tension_only=s.tension_only) for s in specs]
    return CableModel(model, cables)
