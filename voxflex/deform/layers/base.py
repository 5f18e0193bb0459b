"""The base of model layers: an energy added on top of a wrapped model (contact, cables, plasticity).

A layer satisfies the model protocol (:mod:`voxflex.deform.models.protocol`)
by forwarding what it does not change to the model it wraps.
"""

from __future__ import annotations

import numpy as np

from ...errors import InputError
from ..models.protocol import end_step

__all__ = ["ModelLayer", "NOT_FORWARDED"]

NOT_FORWARDED = frozenset({"energy_gradient_hessian_u", "strain_lengths"})
"""Capabilities of the wrapped model that a layer does not pass on: the displacement form
(:class:`~voxflex.deform.models.protocol.FromDisplacement`) would evaluate the wrapped model's energy
without the layer's own, so a layer is evaluated at the positions unless it defines the form itself."""


class ModelLayer:
    """Base of the layers that add an energy to a wrapped model (contact, cables).

    Forwards the protocol's description of the nodes to ``self.inner``, and
    every attribute it does not define (mass, gravity, mappings, faces, held
    DOFs ...) through ``__getattr__``.  A layer's energy changes with the state
    (``constant_tangent`` is False) and may move with the run fraction
    (:meth:`set_time`, stored as ``self.fraction``).  Subclasses set
    ``layer`` (a word for messages) and ``layer_advice`` (appended to the
    inner model's advice).
    """

    layer = "layer"
    layer_advice = ""

    kind = property(lambda self: self.inner.kind)
    node_kind = property(lambda self: self.inner.node_kind)
    dofs_per_node = property(lambda self: self.inner.dofs_per_node)
    rest = property(lambda self: self.inner.rest)
    image = property(lambda self: self.inner.image)
    supported_by_contact = property(lambda self: self.inner.supported_by_contact)

    @property
    def n_nodes(self) -> int:
        return self.inner.n_nodes

    @property
    def constant_tangent(self) -> bool:
        """False: the layer's Hessian changes with the state."""
        return False

    def __getattr__(self, name):
        if name == "inner" or name in NOT_FORWARDED:  # not set yet (construction, unpickling) / not the layer's
            raise AttributeError(name)
        return getattr(self.inner, name)

    def set_tangent_projection(self, on: bool) -> bool:
        """Forwarded to the wrapped model (the layer's own Hessian stays exact); False when it has none."""
        setter = getattr(self.inner, "set_tangent_projection", None)
        return bool(setter(on)) if setter is not None else False

    def advice(self) -> str:
        inner = self.inner.advice()
        return f"{inner}; {self.layer_advice}" if inner else self.layer_advice

    def end_step(self, q) -> bool:
        """Forward the post-convergence hook to the wrapped model (see :func:`end_step`)."""
        return end_step(self.inner, q)

    def set_time(self, fraction: float) -> None:
        """Set the run fraction (0 at the start of the run, 1 at its end)."""
        f = float(fraction)
        if not np.isfinite(f):
            raise InputError(f"{self.layer} time fraction must be finite, got {fraction!r}")
        self.fraction = f
