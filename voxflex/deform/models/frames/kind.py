"""The affine frame kind: a few 12-DOF frames skinned over the image (the reduced model, a scene's default)."""

from __future__ import annotations

from ....errors import InputError
from ....sampling.quadrature import QUADRATURES
from ....voronoi.families import FRAME_SHAPE_FUNCTIONS, UNTRUNCATED
from ..kinds import NodeKind

__all__ = ["AFFINE", "DEFAULT_FRAMES", "check_scene"]

DEFAULT_FRAMES = 20
"""Frames placed when a scene does not say ``[nodes] count`` (fewer when the object has fewer voxels)."""

PLASTIC_SURFACE_FIELDS = ("stress", "von-mises", "energy-density")
"""Result fields that evaluate the materials on the frames' surface layer, which has no plastic state."""


def check_scene(scene) -> None:
    """Refuse what frames cannot do with plasticity: result fields of the surface layer (it has no plastic
    state).  Elastons carry plasticity on their sub-rule points; stabilised mid-point regions are refused
    by the model (their stabilisation is a rest stiffness)."""
    if not any(m.yield_strain is not None for m in scene.materials):
        return
    bad = [f for f in scene.output.fields if f in PLASTIC_SURFACE_FIELDS]
    if bad:
        raise InputError(f'[output] fields "{bad[0]}" with plasticity needs [nodes] kind = "voxel" (the frames\' '
                         "surface layer carries no plastic state); remove it or use voxel nodes")


AFFINE = NodeKind(
    name="affine",
    noun="frame",
    plural="frames",
    dofs_per_node=12,
    quadratures=("midpoint", *(q for q in QUADRATURES if q != "midpoint")),  # the first is the default
    quadrature_by_weights={sf: "elaston" for sf in UNTRUNCATED},  # weights never cut: elastons (families.py)
    shape_functions=FRAME_SHAPE_FUNCTIONS,
    description="affine frames (12 DOF each: the matrix A row-major, then t) skinned over the image",
    builder="voxflex.deform.models.frames.build:build",
    estimator="voxflex.deform.models.frames.build:estimate",
    reduced=True,
    default_count=DEFAULT_FRAMES,
    takes=frozenset({"plasticity", "obstacles", "cables", "force-loads", "dynamics", "strain-placement"}),
    check_scene="voxflex.deform.models.frames.kind:check_scene",
)
