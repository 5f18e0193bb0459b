"""Build the full-resolution voxel model from a scene, and estimate what it will need before building it."""

from __future__ import annotations

from ..kinds import NodeEstimate

__all__ = ["build", "estimate", "BYTES_PER_DOF", "SECONDS_PER_DOF_ITERATION", "ITERATIONS_PER_STEP", "CHUNK_BYTES"]

# measured by benchmarks/bench_resources.py: slope of peak RSS over DOF, 28k -> 92k DOF (Hooke), 4k -> 29k (neo-Hooke)
BYTES_PER_DOF = {"constant": 4.3e3, "nonlinear": 7.1e3, "reduced": 8.5e3}
"""Peak bytes per DOF of a static solve: constant tangent (linear Hooke), nonlinear, nonlinear F-bar."""
CHUNK_BYTES = 2.5e8
"""Bounded per-batch work arrays (tangents of CHUNK_ELEMENTS voxels) once the model exceeds one batch."""
SECONDS_PER_DOF_ITERATION = {"constant": 3.1e-5, "nonlinear": 2.5e-5, "reduced": 6.6e-5}
"""Seconds per Newton iteration per DOF (2-core machine, sparse solve included)."""
ITERATIONS_PER_STEP = {"constant": 1, "nonlinear": 5, "reduced": 5}
"""Newton iterations a step typically takes (a constant tangent converges in one)."""


def build(scene, image, materials, *, cache: bool = True):
    """The :class:`~voxflex.deform.models.voxel.model.VoxelModel` of ``scene`` on ``image`` (no precompute to cache)."""
    from .model import VoxelModel

    el = scene.elasticity
    return VoxelModel.from_image(image, materials, quadrature=el.quadrature, use_occupancy=bool(scene.object.occupancy),
                                 volumetric=el.volumetric, hourglass=el.hourglass)


def estimate(scene, size, material_class: str):
    """:class:`~voxflex.deform.models.kinds.NodeEstimate``` from the object's ``size`` = (voxels, corner nodes, surface
    nodes, voxel size) and the costliest material class (see :mod:`voxflex.resources`)."""
    voxels, corner_nodes, _, _ = size
    dofs = 3 * corner_nodes
    chunk = CHUNK_BYTES * min(1.0, voxels / 16384.0)
    model = BYTES_PER_DOF[material_class] * dofs + chunk
    seconds = int(scene.solver.steps) * ITERATIONS_PER_STEP[material_class] \
        * SECONDS_PER_DOF_ITERATION[material_class] * dofs
    return NodeEstimate(corner_nodes, dofs, model, seconds)
