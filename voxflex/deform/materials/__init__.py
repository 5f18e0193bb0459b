"""Materials: strains of F, energy laws of a strain, their composition, and how a group integrates them.

``strains`` (F -> Voigt strain with exact Jacobians and geometric terms),
``laws`` (energy, stress and tangent of a strain), ``material`` (a strain and a
law as one object, the registry of named models), ``fbar`` (F-bar / B-bar
against volumetric locking) and ``elaston`` (a material integrated over a
region from its volume moments).  The lowest stage of the deformation chain:
nothing here knows nodes or models.
"""

from ..._lazy import lazy

__getattr__, __dir__, __all__ = lazy(__name__, {
    "material": "voxflex.deform.materials.constitutive",
    "Material": "voxflex.deform.materials.constitutive",
    "MATERIALS": "voxflex.deform.materials.constitutive",
    "strain": "voxflex.deform.materials.strains",
    "get_strain": "voxflex.deform.materials.strains",
    "STRAINS": "voxflex.deform.materials.strains",
})
