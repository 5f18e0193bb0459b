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


# ------------------------------------------------------------------------------------------------
# moment-fitted sub-rules (what the frame model integrates elastons with): every material
# ------------------------------------------------------------------------------------------------
def _l_region_rule():
    """The sub-rule of an L-shaped region of 5 voxels (edge 0.3): offsets (k, 3) from its centroid and
    weights (k,), from :func:`voxflex.sampling.subrule.moment_fitted_rule` (degree 2, fewer points than
    the 40 Gauss points)."""
    from voxflex.image import LabelImage
    from voxflex.sampling.subrule import gauss_points, moment_fitted_rule

    labels = np.zeros((3, 3, 2), dtype=np.uint8)
    labels[:, 0, 0] = 1
    labels[0, 1:, 0] = 1
    img = LabelImage(labels, spacing=(0.3, 0.3, 0.3))
    pts, vol, _ = gauss_points(img)
    sel, wts = moment_fitted_rule(pts, vol, np.zeros(len(pts), dtype=np.int64), 1, h=0.3)
    c = (vol @ pts) / vol.sum()
    return pts[sel] - c, wts


def _subrule_case(label):
    from contract_materials import f_large, f_near_identity, make

    from voxflex.deform.materials.elaston import subrule_energy

    mat = make(label)
    d, v = _l_region_rule()
    cases = []
    for bname, F in (("near-identity", f_near_identity(3, seed=4)), ("large", f_large(3, seed=5))):
        rng = np.random.default_rng(8)
        dF = 0.2 * rng.standard_normal((3, 3, 3, 3))
        x0 = np.concatenate([F.reshape(3, 9), dF.reshape(3, 27)], axis=1)
        D = np.broadcast_to(d, (3,) + d.shape)
        V = np.broadcast_to(v, (3,) + v.shape)

        def run(x, hessian, D=D, V=V):
            n = x.shape[0]
            return subrule_energy(mat, x[:, :9].reshape(n, 3, 3), x[:, 9:].reshape(n, 3, 3, 3), D, V, hessian=hessian)

        def grad(x, run=run):
            r = run(x, False)
            return np.concatenate([r.grad_F.reshape(-1, 9), r.grad_dF.reshape(-1, 27)], axis=1)

        cases.append(MappingCase(
            name=f"subrule-elaston:{label}:{bname}",
            x0=x0,
            apply=lambda x, run=run: run(x, False).energy,
            jvp=lambda x, v, grad=grad: np.einsum("nx,nx->n", grad(x), v),
            vjp=lambda x, u, grad=grad: u[:, None] * grad(x),
            geometric=lambda x, u, v, run=run: u[:, None] * np.einsum("nxy,ny->nx", run(x, True).hessian, v),
        ))
    return cases


def _subrule_cases():
    from contract_materials import MATERIAL_SPECS

    out = []
    for label in MATERIAL_SPECS:
        out += _subrule_case(label)
    return out


CASES += _subrule_cases()
