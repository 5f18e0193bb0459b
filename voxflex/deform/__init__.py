"""Deformation core: nodes, mappings, strains, materials, models, mass, solvers.

Models (the voxel model, the frame model) satisfy one protocol
(:mod:`voxflex.deform.model`) through which solvers, loads and boundary
conditions reach them.

The chain  nodes --J--> deformation gradients F --J--> strains --> energy.
Public names are imported lazily, so that importing one stage does not pull
in (or wait for) the others.

>>> import numpy as np, voxflex as vf
>>> mat = vf.material("neo-hookean", young=1e4, poisson=0.3)
>>> float(mat.energy(np.eye(3)[None])[0])
0.0
"""

from __future__ import annotations

import importlib

_LAZY = {
    "material": "voxflex.deform.materials",
    "Material": "voxflex.deform.materials",
    "MATERIALS": "voxflex.deform.materials",
    "strain": "voxflex.deform.strains",
    "get_strain": "voxflex.deform.strains",
    "STRAINS": "voxflex.deform.strains",
    "Points": "voxflex.deform.nodes",
    "AffineFrames": "voxflex.deform.nodes",
    "RigidFrames": "voxflex.deform.nodes",
    "PointMapping": "voxflex.deform.mappings",
    "DeformationGradientMapping": "voxflex.deform.mappings",
    "DeformationGradientWithGradientMapping": "voxflex.deform.mappings",
    "Model": "voxflex.deform.model",
    "VoxelModel": "voxflex.deform.voxel_model",
    "FrameModel": "voxflex.deform.frame_model",
    "RigidFrameModel": "voxflex.deform.rigid_frame_model",
    "ContactModel": "voxflex.deform.contact",
    "with_contact": "voxflex.deform.contact",
    "CableModel": "voxflex.deform.cables",
    "with_cables": "voxflex.deform.cables",
    "obstacle": "voxflex.deform.obstacles",
    "DistanceMapping": "voxflex.deform.spring_mappings",
    "ExtensionMapping": "voxflex.deform.spring_mappings",
    "LogRigidMapping": "voxflex.deform.rigid_mappings",
    "RelativeRigidMapping": "voxflex.deform.rigid_mappings",
    "TriangleDeformationMapping": "voxflex.deform.membrane",
    "StVKMembrane": "voxflex.deform.membrane",
    "DualQuaternionSkinning": "voxflex.deform.skinning",
    "MovingLeastSquaresMapping": "voxflex.deform.mls",
    "PlasticMaterial": "voxflex.deform.plasticity",
    "SolverOptions": "voxflex.deform.solvers",
    "solve": "voxflex.deform.solvers",
    "FixedRegion": "voxflex.deform.boundary",
    "ForceRegion": "voxflex.deform.boundary",
}

__all__ = list(_LAZY)


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'voxflex.deform' has no attribute '{name}'")


def __dir__():
    return sorted(__all__)
