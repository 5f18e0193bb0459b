"""Deformation core: nodes, mappings, strains, materials, models, mass, solvers.

Models (the voxel model, the frame model) satisfy one protocol
(:mod:`voxflex.deform.models.protocol`) through which solvers, loads and boundary
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

from .._lazy import lazy

__getattr__, __dir__, __all__ = lazy(__name__, {
    "material": "voxflex.deform.materials.constitutive",
    "Material": "voxflex.deform.materials.constitutive",
    "MATERIALS": "voxflex.deform.materials.constitutive",
    "strain": "voxflex.deform.materials.strains",
    "get_strain": "voxflex.deform.materials.strains",
    "STRAINS": "voxflex.deform.materials.strains",
    "Points": "voxflex.deform.chain.nodes",
    "AffineFrames": "voxflex.deform.chain.nodes",
    "RigidFrames": "voxflex.deform.chain.nodes",
    "PointMapping": "voxflex.deform.chain.mappings",
    "DeformationGradientMapping": "voxflex.deform.chain.mappings",
    "DeformationGradientWithGradientMapping": "voxflex.deform.chain.mappings",
    "Model": "voxflex.deform.models.protocol",
    "VoxelModel": "voxflex.deform.models.voxel.model",
    "FrameModel": "voxflex.deform.models.frames.model",
    "RigidFrameModel": "voxflex.deform.models.rigid.model",
    "ContactModel": "voxflex.deform.layers.contact",
    "with_contact": "voxflex.deform.layers.contact",
    "CableModel": "voxflex.deform.layers.cables",
    "with_cables": "voxflex.deform.layers.cables",
    "obstacle": "voxflex.deform.layers.obstacles",
    "DistanceMapping": "voxflex.deform.chain.spring",
    "ExtensionMapping": "voxflex.deform.chain.spring",
    "LogRigidMapping": "voxflex.deform.chain.rigid",
    "RelativeRigidMapping": "voxflex.deform.chain.rigid",
    "TriangleDeformationMapping": "voxflex.deform.chain.membrane",
    "StVKMembrane": "voxflex.deform.chain.membrane",
    "DualQuaternionSkinning": "voxflex.deform.chain.skinning",
    "MovingLeastSquaresMapping": "voxflex.deform.chain.mls",
    "PlasticMaterial": "voxflex.deform.layers.plasticity",
    "SolverOptions": "voxflex.deform.solve.options",
    "FixedRegion": "voxflex.deform.solve.boundary",
    "ForceRegion": "voxflex.deform.solve.boundary",
})
