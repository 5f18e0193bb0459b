"""The voxel kind: trilinear nodes at the corners of occupied voxels (the full-resolution reference)."""

from __future__ import annotations

from ....sampling.quadrature import RULES
from ....voronoi.families import VOXEL_SHAPE_FUNCTIONS
from ..kinds import NodeKind

__all__ = ["VOXEL", "HOURGLASS"]

HOURGLASS = ("stiffness", "none")
"""``hourglass`` values (mid-point quadrature): the rest-stiffness stabilisation, or the bare one-point rule."""

VOXEL = NodeKind(
    name="voxel",
    noun="voxel node",
    plural="voxel nodes",
    dofs_per_node=3,
    quadratures=RULES,
    shape_functions=VOXEL_SHAPE_FUNCTIONS,
    description="trilinear nodes at the voxel corners (3 DOF each), 2x2x2 Gauss: the full-resolution reference",
    builder="voxflex.deform.models.voxel.build:build",
    estimator="voxflex.deform.models.voxel.build:estimate",
    reference=True,
    takes=frozenset({"plasticity", "obstacles", "cables", "force-loads", "dynamics"}),
)
