"""Build a membrane model from a scene (a disk, a rectangle or a mesh file); its image and its estimate."""

from __future__ import annotations

import numpy as np

from ....errors import InputError
from ..kinds import NodeEstimate

__all__ = ["build", "estimate", "footprint", "membrane_mesh"]

BYTES_PER_DOF = 4.0e3
"""Peak bytes per DOF of a membrane solve (sparse Hessian, its factor and the vertex maps; an upper estimate)."""
SECONDS_PER_DOF_ITERATION = 2.5e-5
"""Seconds per Newton iteration per DOF (as the voxel model's nonlinear iterations)."""


def membrane_mesh(scene):
    """(points (n, 3), triangles (m, 3)) of a membrane scene: a disk or rectangle made at
    ``voxel_size`` (the target edge length), or the mesh file as it is."""
    from ....rasterize.membrane_mesh import (
        disk_mesh,
        load_membrane_mesh,
        rectangle_mesh,
    )

    obj = scene.object
    if obj.mesh is not None:
        return load_membrane_mesh(obj.mesh, up=obj.up)
    if obj.up != "z":
        raise InputError('[object] up applies to a membrane mesh file; a disk or rectangle lies in z = origin_z '
                         "(remove up)")
    origin = np.asarray(obj.origin if obj.origin is not None else (0.0, 0.0, 0.0), dtype=float)
    if obj.shape == "disk":
        r = obj.size[0]
        return disk_mesh(r, obj.voxel_size, center=origin + np.array([r, r, 0.0]))
    return rectangle_mesh(obj.size, obj.voxel_size, origin=origin)


def build(scene, image, materials, *, cache: bool = True):
    """The membrane of the scene (:class:`~voxflex.deform.models.membrane.model.MembraneModel`).

    The [[material]] (stvk: young, poisson, density) and ``[membrane] thickness``
    make the plane-stress StVK membrane; ``[[load]] kind = "pressure"`` loads
    add up to its pressure (ramped with the load factor in static runs, full in
    dynamics).  Refused: a pressure on a membrane whose open rim is not held in all
    three components (by ``rim = "clamped"`` or ``[[fixed]]`` regions), since
    the follower pressure is conservative only then.
    """
    from ....rasterize.membrane_mesh import open_rim
    from ...chain.membrane import StVKMembrane
    from .model import MembraneModel

    spec = scene.materials[0]
    law = StVKMembrane(young=spec.young, poisson=spec.poisson, thickness=scene.membrane.thickness)
    points, triangles = membrane_mesh(scene)
    pressure = float(sum(ld.pressure for ld in scene.loads if ld.kind == "pressure"))
    rim = open_rim(triangles)
    clamped = rim if scene.membrane.rim == "clamped" else None
    model = MembraneModel(points, triangles, law, density=spec.density, pressure=pressure,
                          pressure_ramp=scene.solver.kind == "static", clamped=clamped,
                          voxel_size=scene.object.voxel_size)
    model._image = image
    if pressure != 0.0 and clamped is None and len(rim):
        held = set()
        for f in scene.fixed:
            held.update(int(d) for d in model.held_dofs(f.min, f.max, f.components))
        loose = [int(v) for v in rim if not all(3 * int(model._index_of[v]) + k in held for k in range(3))]
        if loose:
            raise InputError(f"a pressure is conservative only on a clamped or closed membrane, and {len(loose)} of "
                             f"the {len(rim)} rim vertices are not held (e.g. {points[loose[0]].tolist()}); set "
                             '[membrane] rim = "clamped" or cover the rim with [[fixed]] regions')
    return model


def footprint(scene):
    """The label image of the voxels the membrane's mesh passes through (what the result file stores)."""
    from ....rasterize.membrane_mesh import footprint_image

    return footprint_image(*membrane_mesh(scene), scene.object.voxel_size)


def estimate(scene, size, material_class: str):
    """:class:`~voxflex.deform.models.kinds.NodeEstimate```: the mesh's vertices (made or read: cheap), 3 DOF each."""
    points, triangles = membrane_mesh(scene)
    clamped = 0
    if scene.membrane.rim == "clamped":
        from ....rasterize.membrane_mesh import open_rim

        clamped = len(open_rim(triangles))
    nodes = len(points) - clamped  # clamped rim vertices are not DOFs of the model
    dofs = 3 * nodes
    seconds = int(scene.solver.steps) * 5 * SECONDS_PER_DOF_ITERATION * dofs
    return NodeEstimate(nodes, dofs, BYTES_PER_DOF * dofs, seconds, voxels=len(triangles), surface=len(points))
