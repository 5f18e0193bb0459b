"""The mapping chain: node kinds and the exact mappings from nodes to material quantities.

Nodes (points, affine and rigid frames) and the mappings that carry their
motion to material points: positions, deformation gradients F (and their
spatial gradients), rigid and spring mappings, membrane triangles, moving least
squares and dual-quaternion skinning.  Every mapping has an exact Jacobian
and geometric stiffness, checked against finite differences.
"""

from ..._lazy import lazy

__getattr__, __dir__, __all__ = lazy(__name__, {
    "Points": "voxflex.deform.chain.nodes",
    "AffineFrames": "voxflex.deform.chain.nodes",
    "RigidFrames": "voxflex.deform.chain.nodes",
    "PointMapping": "voxflex.deform.chain.mappings",
    "DeformationGradientMapping": "voxflex.deform.chain.mappings",
    "DeformationGradientWithGradientMapping": "voxflex.deform.chain.mappings",
    "DistanceMapping": "voxflex.deform.chain.spring",
    "ExtensionMapping": "voxflex.deform.chain.spring",
    "LogRigidMapping": "voxflex.deform.chain.rigid",
    "RelativeRigidMapping": "voxflex.deform.chain.rigid",
    "TriangleDeformationMapping": "voxflex.deform.chain.membrane",
    "StVKMembrane": "voxflex.deform.chain.membrane",
    "DualQuaternionSkinning": "voxflex.deform.chain.skinning",
    "MovingLeastSquaresMapping": "voxflex.deform.chain.mls",
})
