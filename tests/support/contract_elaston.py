"""Derivative-contract cases of the material-level elaston energy (voxflex.deform.materials.elaston).

x packs (F, dF) per elaston as (n, 36) (F's 9 entries, then dF's 27, C order), y is the
integrated energy (n,).  jvp = gradient . v, vjp = u * gradient, geometric = u * (Hessian v);
only the strains with a constant second derivative (linear, green, corotational-small) have
the Hessian.  Three elastons near identity with a moderate gradient, off-centre x0 in boxes.
"""

from __future__ import annotations

import numpy as np
from contract import MappingCase

from voxflex.deform.materials.constitutive import material
from voxflex.deform.materials.elaston import material_elaston_energy
from voxflex.sampling.moments import box_moments


def _setup(n=3, seed=21):
    rng = np.random.default_rng(seed)
    F = np.eye(3) + 0.1 * rng.standard_normal((n, 3, 3))
    dF = 0.5 * rng.standard_normal((n, 3, 3, 3))
    lo = rng.uniform(-1, 0, (n, 3))
    hi = lo + rng.uniform(0.3, 0.7, (n, 3))
    x0 = lo + rng.uniform(0.1, 0.9, (n, 3)) * (hi - lo)
    return np.concatenate([F.reshape(n, 9), dF.reshape(n, 27)], axis=1), box_moments(lo, hi, x0)


def _case(name, strain):
    mat = material(name, young=2.0, poisson=0.3, strain=strain)
    x0, (V, M1, M2) = _setup()

    def run(x, hessian):
        n = x.shape[0]
        return material_elaston_energy(mat, x[:, :9].reshape(n, 3, 3), x[:, 9:].reshape(n, 3, 3, 3), V, M1, M2,
                                       hessian=hessian)

    def grad(x):
        r = run(x, False)
        return np.concatenate([r.grad_F.reshape(-1, 9), r.grad_dF.reshape(-1, 27)], axis=1)

    def geometric(x, u, v):
        H = run(x, True).hessian
        n = x.shape[0]
        full = np.zeros((n, 36, 36))
        full[:, :9, :9] = H.FF.reshape(n, 9, 9)
        full[:, :9, 9:] = H.FdF.reshape(n, 9, 27)
        full[:, 9:, :9] = H.FdF.reshape(n, 9, 27).transpose(0, 2, 1)
        full[:, 9:, 9:] = H.dFdF.reshape(n, 27, 27)
        return u[:, None] * np.einsum("nxy,ny->nx", full, v)

    return MappingCase(
        name=f"elaston-{name}-{strain}",
        x0=x0,
        apply=lambda x: run(x, False).energy,
        jvp=lambda x, v: np.einsum("nx,nx->n", grad(x), v),
        vjp=lambda x, u: u[:, None] * grad(x),
        geometric=geometric,
    )


CASES = [_case("hooke", "linear"), _case("stvk", "green"), _case("hooke", "corotational-small")]
