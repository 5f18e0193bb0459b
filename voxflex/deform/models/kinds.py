"""The registry of node kinds: one :class:`NodeKind` object per model, found by ``[nodes] kind``.

A node kind says what a model's nodes are (the noun messages use, DOFs per
node), which scene settings it takes (quadratures, shape functions: the first
of each is its default), what role it plays in a trade-off sweep (the
reference, or a reduced model whose node count the scene sets) and where its
builder and resource estimator live.  Everything outside the models (scene
validation, resources, progress lines, results, renders, boundary messages,
the trade-off sweep) asks the kind object instead of comparing names.

This module is light (no numpy, numba or scipy): reading a scene imports it.
Builders and estimators are named ``"module:function"`` and imported when used.

Adding a model kind: a package under ``voxflex/deform/models/`` with a light
``kind.py`` that defines a :class:`NodeKind`, and one line in :data:`_DECLARED`
(see docs/architecture.md).

>>> node_kind("affine").noun, node_kind("voxel").reference
('frame', True)
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field

from ...errors import InputError, did_you_mean

__all__ = ["NodeKind", "NodeEstimate", "node_kind", "node_kinds", "reference_kind", "default_kind"]


@dataclass(frozen=True)
class NodeEstimate:
    """What a kind's model of a scene is expected to need, before it is built (:mod:`voxflex.resources`).

    ``voxels`` and ``surface`` (cells of the material and vertices of the drawn surface) replace the
    object's voxel counts when the kind's own geometry is not the voxelized object (a membrane's mesh).
    """

    nodes: int
    dofs: int
    model_bytes: float
    seconds: float
    voxels: int | None = None
    surface: int | None = None


@dataclass(frozen=True)
class NodeKind:
    """What one kind of model is, for everything that is not the model itself.

    Attributes
    ----------
    name : str
        ``[nodes] kind`` in a scene, ``node_kind`` in a result file.
    noun, plural : str
        One node and several, as messages say them ("frame", "frames").
    dofs_per_node : int
    quadratures : tuple of str
        The ``[elasticity] quadrature`` values it takes; the first is its default.
    shape_functions : tuple of str
        The ``[nodes] shape_function`` values it takes; the first is its default; empty when its
        nodes carry no shape-function choice.
    description : str
        One line for help texts and ``voxflex info``.
    reference : bool
        The full-resolution model a trade-off sweep measures every other model against.
    reduced : bool
        A model whose node count ``[nodes] count`` sets (a trade-off sweep varies it).
    default_count : int or None
        Nodes placed when a scene does not say ``[nodes] count`` (reduced kinds).
    static_only : bool
        Runs static scenes only.
    takes : frozenset of str
        Scene features it supports beyond elasticity: ``"plasticity"``, ``"obstacles"``,
        ``"cables"``, ``"force-loads"`` (traction and force regions), ``"dynamics"``,
        ``"strain-placement"`` (``[nodes] placement = "strain"``: its builder takes the keyword
        ``placement_energy``, the strain-energy density image of :func:`voxflex.build.strain_indicator`).
    builder, estimator : str
        ``"module:function"``: ``builder(scene, image, materials, *, cache) -> Model`` and
        ``estimator(scene, size, material_class) -> NodeEstimate``
        (see :mod:`voxflex.resources`).
    image_builder : str or None
        ``"module:function"`` ``(scene) -> LabelImage`` when the kind's image is not the
        voxelized object (a membrane's footprint).
    shapes : dict str -> int
        ``[object] shape`` values only this kind takes, with the number of ``size`` values each needs.
    tables : dict str -> type
        Scene tables only this kind takes, with the dataclass that reads each (``[membrane]``); the
        :class:`~voxflex.scene.Scene` has a field of that name.
    load_kinds : tuple of str
        ``[[load]] kind`` values only this kind takes.
    check_scene : str or None
        ``"module:function"`` ``(scene) -> None``: the kind's own checks of a scene (one-line
        InputErrors naming the fix), run when the scene is made; it must import nothing heavy.
    """

    name: str
    noun: str
    plural: str
    dofs_per_node: int
    quadratures: tuple[str, ...]
    shape_functions: tuple[str, ...]
    description: str
    builder: str
    estimator: str
    reference: bool = False
    reduced: bool = False
    default_count: int | None = None
    static_only: bool = False
    takes: frozenset = field(default_factory=frozenset)
    image_builder: str | None = None
    shapes: dict = field(default_factory=dict)
    tables: dict = field(default_factory=dict)
    load_kinds: tuple[str, ...] = ()
    check_scene: str | None = None
    quadrature_by_weights: dict = field(default_factory=dict)

    @property
    def default_quadrature(self) -> str:
        return self.quadratures[0]

    def quadrature_for(self, shape_function: str | None) -> str:
        """The quadrature a scene gets when it names none: the kind's own, or the one its weight family
        needs (``quadrature_by_weights``)."""
        return self.quadrature_by_weights.get(shape_function, self.default_quadrature)

    @property
    def default_shape_function(self) -> str | None:
        return self.shape_functions[0] if self.shape_functions else None

    def count(self, n: int) -> str:
        """``"20 frames"``, ``"1 frame"``: a number of nodes as messages say it."""
        return f"{n} {self.noun if n == 1 else self.plural}"

    def build(self, scene, image, materials, *, cache: bool = True, **extra):
        """The model of ``scene`` on ``image`` (see :attr:`builder`); ``extra``: what the features in
        :attr:`takes` hand the builder (``placement_energy`` for ``"strain-placement"``)."""
        return _load(self.builder)(scene, image, materials, cache=cache, **extra)

    def estimate(self, scene, size, material_class: str):
        """A :class:`NodeEstimate` before building (see :attr:`estimator`); ``size`` = (voxels, corner nodes,
        surface nodes, voxel size) of the object, ``material_class`` "constant", "nonlinear" or "reduced"."""
        return _load(self.estimator)(scene, size, material_class)

    def check(self, scene) -> None:
        """Refuse (InputError) what this kind does not take in ``scene``; see :attr:`check_scene`."""
        if self.check_scene is not None:
            _load(self.check_scene)(scene)

    def build_image(self, scene):
        """The kind's own image of ``scene`` (:attr:`image_builder`), or None: the voxelized object."""
        return None if self.image_builder is None else _load(self.image_builder)(scene)


def _load(ref: str):
    module, _, name = ref.partition(":")
    return getattr(importlib.import_module(module), name)


_DECLARED = (
    "voxflex.deform.models.frames.kind:AFFINE",
    "voxflex.deform.models.rigid.kind:RIGID",
    "voxflex.deform.models.voxel.kind:VOXEL",
    "voxflex.deform.models.membrane.kind:MEMBRANE",
)
"""Every node kind, ``"module:name"`` of its :class:`NodeKind`; the first is a scene's default."""

_KINDS: dict[str, NodeKind] = {}


def node_kinds() -> dict[str, NodeKind]:
    """{name: NodeKind} of every registered kind, in declaration order."""
    if not _KINDS:
        for ref in _DECLARED:
            kind = _load(ref)
            _KINDS[kind.name] = kind
    return dict(_KINDS)


def node_kind(name) -> NodeKind:
    """The :class:`NodeKind` named ``name`` (a NodeKind is returned as is).

    Raises
    ------
    InputError
        An unknown name, with the valid ones.
    """
    if isinstance(name, NodeKind):
        return name
    kinds = node_kinds()
    if name not in kinds:
        raise InputError(f"unknown node kind {name!r}{did_you_mean(str(name), kinds)}; valid: {', '.join(kinds)}")
    return kinds[name]


def reference_kind() -> NodeKind:
    """The full-resolution reference kind (trade-off sweeps measure against it)."""
    return next(k for k in node_kinds().values() if k.reference)


def default_kind() -> NodeKind:
    """The kind a scene uses when it does not say ``[nodes] kind``."""
    return next(iter(node_kinds().values()))
