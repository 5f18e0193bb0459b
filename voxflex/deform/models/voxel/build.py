"""Build the full-resolution voxel model from a scene, and estimate what it will need before building it."""

from __future__ import annotations

from ..kinds import NodeEstimate

__all__ = ["build", "estimate", "BYTES_PER_DOF", "MATRIX_FREE_BYTES_PER_DOF", "LU_ENTRIES_PER_DOF_15",
           "SECONDS_PER_DOF_ITERATION", "ITERATIONS_PER_STEP", "CHUNK_BYTES"]

# measured by benchmarks/bench_resources.py: slope of peak RSS over DOF, 28k -> 92k DOF (Hooke), 4k -> 29k (neo-Hooke)
BYTES_PER_DOF = {"constant": 4.3e3, "nonlinear": 7.1e3, "reduced": 8.5e3}
"""Peak bytes per DOF of a static solve: constant tangent (linear Hooke), nonlinear, nonlinear F-bar."""
MATRIX_FREE_BYTES_PER_DOF = 1.3e3
"""A constant tangent above the direct limit (the lean path's matrix-free block, no stored stiffness): peak
bytes per DOF of a static solve, measured by ``benchmarks/bench_resources.py`` (Hooke, 2 runs: 1268-1301 at
28.6k DOF, 1000-1041 at 91.9k, 925-936 at 212k; 666 with the interpreter at 6.38M)."""
LU_ENTRIES_PER_DOF_15 = 9.0
"""Entries of a voxel tangent's sparse LU factor (MMD ordering) per DOF^1.5, measured by
``benchmarks/bench_direct_limit.py`` (cubes 8.5-8.9, beams 5.6-7.4, from 6k to 106k DOF); 12 bytes each
(value and index).  A solve factorises directly up to
:data:`~voxflex.deform.solve.linear.DIRECT_FALLBACK_MAX` DOF (the small systems, and the fallback of a
stalled multigrid solve) and never beyond: the estimate adds that factor only there."""
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
    lean = scene.solver.kind == "static" and scene.solver.linear_solver in ("auto", "multigrid")
    model = _bytes_per_dof(material_class, dofs, lean) * dofs + chunk + _factor_bytes(dofs)
    seconds = int(scene.solver.steps) * ITERATIONS_PER_STEP[material_class] \
        * SECONDS_PER_DOF_ITERATION[material_class] * dofs
    return NodeEstimate(corner_nodes, dofs, model, seconds)


def _bytes_per_dof(cls: str, dofs: int, lean: bool) -> float:
    """Peak bytes per DOF of a solve: :data:`MATRIX_FREE_BYTES_PER_DOF` for a static multigrid solve of a
    constant tangent above the direct limit (``lean``: no stiffness is kept there), else :data:`BYTES_PER_DOF`."""
    from ...._linalg import DIRECT_FALLBACK_MAX

    if lean and cls == "constant" and dofs > DIRECT_FALLBACK_MAX:
        return MATRIX_FREE_BYTES_PER_DOF
    return BYTES_PER_DOF[cls]


def _factor_bytes(dofs: int) -> float:
    """Memory of the sparse LU a solve of ``dofs`` may make (bytes): none above the direct limit."""
    from ...._linalg import DIRECT_FALLBACK_MAX

    return 12.0 * LU_ENTRIES_PER_DOF_15 * dofs**1.5 if dofs <= DIRECT_FALLBACK_MAX else 0.0
