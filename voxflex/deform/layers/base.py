"""The base of model layers: an energy added on top of a wrapped model (contact, cables, plasticity).

A layer satisfies the model protocol (:mod:`voxflex.deform.models.protocol`)
by forwarding what it does not change to the model it wraps.
"""

from __future__ import annotations

import numpy as np

from ...errors import InputError
from ..models.protocol import FromDisplacement, begin_run, end_step

__all__ = ["ModelLayer", "NOT_FORWARDED"]

NOT_FORWARDED = frozenset({"energy_gradient_hessian_u", "strain_lengths"})
"""Capabilities of the wrapped model that a layer never forwards as they are: the wrapped model's
displacement form (:class:`~voxflex.deform.models.protocol.FromDisplacement`) would leave the layer's own
energy out (a cable's pull was dropped from the solve that way).  A layer has the form exactly when the model
it wraps has it: a layer that adds an energy (:attr:`ModelLayer.adds_energy`) evaluates the wrapped model's
displacement form plus its own term at the positions ``rest + u`` (:meth:`ModelLayer._layered_u`; its
``energy_gradient_hessian`` takes ``u``, else it is evaluated at the positions); one that only changes the
wrapped model's materials (plasticity) passes the form on."""


_TAKES_U: dict = {}


def _takes_u(cls) -> bool:
    """Whether ``cls.energy_gradient_hessian`` takes the displacement ``u`` (keyword), once per class."""
    if cls not in _TAKES_U:
        import inspect

        _TAKES_U[cls] = "u" in inspect.signature(cls.energy_gradient_hessian).parameters
    return _TAKES_U[cls]


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

    @property
    def adds_energy(self) -> bool:
        """Whether the layer adds an energy of its own: it defines ``energy_gradient_hessian`` (contact, cables);
        a layer that does not (plasticity: it changes the wrapped model's materials) has the wrapped model's."""
        return hasattr(type(self), "energy_gradient_hessian")

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
        if name == "inner":  # not set yet (construction, unpickling)
            raise AttributeError(name)
        if name in NOT_FORWARDED:
            if not isinstance(self.inner, FromDisplacement):
                raise AttributeError(name)  # evaluated at the positions, as the wrapped model is
            if name == "strain_lengths" or not self.adds_energy:
                return getattr(self.inner, name)
            if not _takes_u(type(self)):
                raise AttributeError(name)  # an energy of its own without the form: evaluated at the positions
            return self._layered_u
        return getattr(self.inner, name)

    def _layered_u(self, u, *, gradient: bool = True, hessian: bool = True):
        """The displacement form of a layer that adds an energy: the wrapped model's at ``u`` and the layer's own
        term at the positions ``rest + u`` (``energy_gradient_hessian(q, ..., u=u)``)."""
        u = np.asarray(u, dtype=float)
        q = np.asarray(self.rest, dtype=float) + u
        return self.energy_gradient_hessian(q, gradient=gradient, hessian=hessian, u=u)

    def _inner_terms(self, q, u, gradient: bool, hessian: bool):
        """The wrapped model's (energy, gradient, Hessian): from the displacement ``u`` when given (the layer's
        displacement form), else at the positions q."""
        if u is not None:
            return self.inner.energy_gradient_hessian_u(u, gradient=gradient, hessian=hessian)
        return self.inner.energy_gradient_hessian(q, gradient=gradient, hessian=hessian)

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

    def begin_run(self) -> None:
        """A run starts: the wrapped model's state back to rest, and the layer's run fraction to 0 (layers with
        more state of their own extend this)."""
        begin_run(self.inner)
        if "fraction" in self.__dict__:
            self.set_time(0.0)

    def set_time(self, fraction: float) -> None:
        """Set the run fraction (0 at the start of the run, 1 at its end)."""
        f = float(fraction)
        if not np.isfinite(f):
            raise InputError(f"{self.layer} time fraction must be finite, got {fraction!r}")
        self.fraction = f
