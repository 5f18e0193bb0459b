"""The membrane kind: the vertices of a triangle mesh (3 DOF each), a plane-stress StVK membrane."""

from __future__ import annotations

from dataclasses import dataclass

from ...._checks import number, string
from ....errors import InputError
from ....rasterize.membrane_mesh import MEMBRANE_SHAPES
from ..kinds import NodeKind

__all__ = ["MEMBRANE", "RIMS", "MembraneSpec", "check_scene"]

RIMS = ("free", "clamped")
"""``[membrane] rim``: leave the open rim to ``[[fixed]]`` regions, or hold every rim vertex."""


@dataclass(frozen=True)
class MembraneSpec:
    """``[membrane]``: the sheet of ``[nodes] kind = "membrane"`` (:mod:`voxflex.deform.models.membrane.model`).

    ``thickness`` h (m, required); ``rim``: ``"clamped"`` holds every vertex of the
    mesh's open rim (the edges only one triangle uses) in place, ``"free"`` (the
    default) leaves it to ``[[fixed]]`` regions.
    """

    thickness: float | None = None
    rim: str = "free"

    def __post_init__(self):
        t = "membrane"
        if self.thickness is None:
            raise InputError("[membrane] needs thickness (m), e.g. thickness = 0.001")
        object.__setattr__(self, "thickness", number(t, "thickness", self.thickness, positive=True))
        string(t, "rim", self.rim, RIMS)


def check_scene(scene) -> None:
    """The keys that do not apply to membranes (one-line errors naming the fix)."""
    obj = scene.object
    fix = 'for [nodes] kind = "membrane"'
    if scene.membrane is None:
        raise InputError('[nodes] kind = "membrane" needs a [membrane] table with thickness (m)')
    if obj.image is not None or (obj.shape is not None and obj.shape not in MEMBRANE.shapes):
        raise InputError(f"a membrane is a surface: give [object] shape = \"disk\" or \"rectangle\", or mesh = a "
                         f"surface mesh file ({fix})")
    for key, default in (("occupancy", None), ("keep", "all"), ("min_component_voxels", 1)):
        if getattr(obj, key) != default:
            raise InputError(f"[object] {key} does not apply to membranes; remove it ({fix})")
    nodes = scene.nodes
    for key in ("count", "positions", "shape_function"):
        if getattr(nodes, key) is not None:
            raise InputError(f"[nodes] {key} applies to frames and voxels; remove it ({fix}: the mesh's vertices "
                             "are the nodes)")
    el = scene.elasticity
    if el.quadrature != "midpoint" or el.samples is not None or el.strain is not None:
        raise InputError("[elasticity] quadrature, samples and strain do not apply to membranes (one point per "
                         f"triangle, Green strain); remove them ({fix})")
    models = sorted({m.model for m in scene.materials})
    if models != ["stvk"] or len(scene.materials) != 1 or scene.materials[0].label != 1:
        raise InputError('a membrane takes one [[material]] with model = "stvk", young, poisson (label 1), '
                         f"got models {models}; the membrane law is the plane-stress StVK")
    if scene.materials[0].young is None or scene.materials[0].poisson is None:
        raise InputError('the membrane\'s [[material]] needs young (Pa) and poisson (model = "stvk")')
    kinds = [ld.kind for ld in scene.loads if ld.kind == "traction"]
    if kinds:
        raise InputError('[load] kind = "traction" needs voxel faces; push a membrane with kind = "pressure" or '
                         '"force"')
    if scene.obstacles:
        raise InputError("membranes do not take [[obstacle]] contact yet; remove the obstacles or use a solid")
    if scene.cables:
        raise InputError("membranes do not take [[cable]] tables yet; remove them or use a solid")
    if scene.output.fields:
        raise InputError("result fields ([output] fields) are not implemented for membranes yet; remove the key")


MEMBRANE = NodeKind(
    name="membrane",
    noun="membrane vertex",
    plural="membrane vertices",
    dofs_per_node=3,
    quadratures=("midpoint",),
    shape_functions=(),
    description="the vertices of a triangle mesh (3 DOF each): a plane-stress StVK membrane, one point per triangle",
    builder="voxflex.deform.models.membrane.build:build",
    estimator="voxflex.deform.models.membrane.build:estimate",
    image_builder="voxflex.deform.models.membrane.build:footprint",
    takes=frozenset({"force-loads", "dynamics"}),
    shapes=MEMBRANE_SHAPES,
    tables={"membrane": MembraneSpec},
    load_kinds=("pressure",),
    check_scene="voxflex.deform.models.membrane.kind:check_scene",
)
