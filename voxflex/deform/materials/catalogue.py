"""The names a scene may use for materials, their constants and strains (a light vocabulary).

The registries of objects live with the implementations
(:data:`voxflex.deform.materials.constitutive.MATERIALS`,
:data:`voxflex.deform.materials.strains.STRAINS`); the tests check that they
name the same things as this page, which reading a scene loads without
compiling anything.
"""

from __future__ import annotations

from ...errors import InputError, did_you_mean

__all__ = ["MATERIAL_NAMES", "MODEL_CONSTANTS", "POISSON_RANGE", "STRAIN_NAMES", "check_constants"]

_ORTHO = ("E1", "E2", "E3", "nu12", "nu13", "nu23", "G12", "G23", "G13")

MODEL_CONSTANTS: dict[str, tuple[str, ...]] = {
    "hooke": ("mu", "lmbda"),
    "hooke-orthotropic": _ORTHO,
    "stvk": ("mu", "lmbda"),
    "neo-hookean": ("mu", "lmbda"),
    "stable-neo-hookean": ("mu", "lmbda"),
    "mooney-rivlin": ("c1", "c2", "bulk"),
    "arruda-boyce": ("mu", "bulk", "lambda_m"),
    "veronda-westmann": ("c1", "c2", "bulk"),
    "volume-log": ("bulk",),
    "volume-quadratic": ("bulk",),
    "ogden": ("mu_p", "alpha_p", "lmbda"),
}
"""The constants each model takes besides ``young``, ``poisson`` and ``strain`` (the scene's
``[[material]]`` keys read this table too).  ``c2``, ``lambda_m`` and ``alpha_p`` may also
accompany young/poisson (see :func:`material`)."""

MATERIAL_NAMES = tuple(MODEL_CONSTANTS)
"""Every material model's name (``[[material]] model``)."""

STRAIN_NAMES = ("linear", "green", "corotational", "corotational-svd", "corotational-qr", "corotational-small",
                "invariant", "invariant-deviatoric", "principal-stretch")
"""Every strain's name (``strain`` of a material or ``[elasticity]``)."""

POISSON_RANGE = (-1.0, 0.5)
"""Open interval of Poisson's ratio for isotropic materials (negative values: auxetic materials)."""


def check_constants(model: str, names) -> None:
    """InputError for a constant ``model`` does not take, with a did-you-mean and that model's constants."""
    allowed = MODEL_CONSTANTS[model]
    for name in names:
        if name not in allowed:
            valid = ", ".join(["young", "poisson", "strain", *allowed]) if model != "hooke-orthotropic" else \
                ", ".join(["strain", *allowed])
            raise InputError(
                f"unknown parameter '{name}' for material '{model}'{did_you_mean(name, allowed)}; valid: {valid}"
            )
