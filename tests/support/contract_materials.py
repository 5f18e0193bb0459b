"""Material cases for the shared derivative contract (see ``contract.py``).

Every registered material (and Hooke with every tensor strain) on two batches
of deformation gradients: near the identity, and with large stretches
(0.6-1.8) and arbitrary rotations (det F > 0); the models defined for
inverted elements (stable Neo-Hooke, Hooke over ``corotational-svd``) also on
inverted F.  The contract's tolerance rtol = 1e-6 (central differences with
eps = 1e-6, see contract.py) applies unchanged.
"""

from __future__ import annotations

import numpy as np
from contract import MaterialCase

from voxflex.deform.materials.constitutive import material


def _rotation(rng):
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def f_near_identity(n=4, seed=0):
    rng = np.random.default_rng(seed)
    return np.eye(3) + 0.05 * rng.standard_normal((n, 3, 3))


def f_large(n=4, seed=1):
    """R1 diag(stretches) R2 with distinct stretches in [0.6, 1.8]: det F > 0."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        d = np.sort(rng.uniform(0.6, 1.8, 3))[::-1] + np.array([0.05, 0.0, -0.05])
        out.append(_rotation(rng) @ np.diag(d) @ _rotation(rng))
    return np.array(out)


def f_inverted(n=4, seed=2):
    """Large F with one axis reflected: det F < 0 (singular values distinct and away from zero)."""
    return f_large(n, seed) @ np.diag([1.0, 1.0, -1.0])


E, NU = 1.0e4, 0.3
ORTHO = dict(E1=1.2e4, E2=0.8e4, E3=0.5e4, nu12=0.25, nu13=0.2, nu23=0.3, G12=4e3, G23=2.5e3, G13=3e3)

MATERIAL_SPECS = {
    **{f"hooke/{s}": ("hooke", dict(young=E, poisson=NU, strain=s))
       for s in ["linear", "green", "corotational", "corotational-svd", "corotational-qr", "corotational-small"]},
    "hooke-orthotropic": ("hooke-orthotropic", dict(ORTHO)),
    "stvk": ("stvk", dict(young=E, poisson=NU)),
    "neo-hookean": ("neo-hookean", dict(young=E, poisson=NU)),
    "stable-neo-hookean": ("stable-neo-hookean", dict(young=E, poisson=NU)),
    "mooney-rivlin": ("mooney-rivlin", dict(young=E, poisson=NU, c2=500.0)),
    "arruda-boyce": ("arruda-boyce", dict(young=E, poisson=NU, lambda_m=1.9)),
    "veronda-westmann": ("veronda-westmann", dict(young=E, poisson=NU, c2=1.3)),
    "volume-log": ("volume-log", dict(young=E, poisson=NU)),
    "volume-quadratic": ("volume-quadratic", dict(young=E, poisson=NU)),
    "ogden": ("ogden", dict(young=E, poisson=NU)),
}
"""label -> (registry name, keywords): every material the tests sweep."""

INVERTIBLE = {"stable-neo-hookean", "hooke/corotational-svd"}


def make(label):
    name, kw = MATERIAL_SPECS[label]
    return material(name, **kw)


CASES = []
for _label in MATERIAL_SPECS:
    _mat = make(_label)
    _batches = {"near-identity": f_near_identity(), "large": f_large()}
    if _label in INVERTIBLE:
        _batches["inverted"] = f_inverted()
    for _bname, _F in _batches.items():
        CASES.append(
            MaterialCase(
                name=f"material:{_label}:{_bname}",
                F0=_F,
                energy=_mat.energy,
                stress=_mat.stress,
                tangent=_mat.tangent,
            )
        )
