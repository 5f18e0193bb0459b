"""Derivative-contract cases of the spring, rigid-frame and membrane mappings (see ``contract.py``).

* springs (voxflex.deform.chain.spring): 6 random points, 7 edges (one of
  them duplicated in reverse) for distances and extensions, and 3 point-to-target
  edges; x is the point array, edges stay far from zero length (>= 0.1 in a unit
  box: the geometric term grows as 1/l, so the finite-difference truncation
  error stays ~ (h/l)^2 << 1e-6).
* rigid frames (voxflex.deform.chain.rigid): x is a (v, ω) increment applied
  to a random state through ``RigidFrames.integrate`` (as in
  contract_mappings.py); rotation angles up to ~2.5 rad (below π, where the
  logarithm jumps) and one small angle (1e-6 rad, the series branch of J_l⁻¹).
  The relative mapping is checked composed with the logarithm (its output is a
  rigid frame), which exercises its jvp, vjp and geometric term and the chain
  rule ``K = K_rel(J_logᵀ u) + J_relᵀ K_log(u) J_rel``.
* membranes (voxflex.deform.chain.membrane): the triangle mapping on a random
  4-triangle fan (constant J), and the StVK membrane as a map F -> ψ(F) per
  triangle (jvp = P : v, vjp = u P, geometric = u A : v), which checks stress
  against the energy and tangent against the stress.

The contract's own tolerances apply (rtol 1e-6 against central differences).
"""

from __future__ import annotations

import numpy as np
from contract import MappingCase

from voxflex.deform.chain.membrane import StVKMembrane, TriangleDeformationMapping
from voxflex.deform.chain.nodes import RigidFrames
from voxflex.deform.chain.rigid import LogRigidMapping, RelativeRigidMapping
from voxflex.deform.chain.spring import DistanceMapping, ExtensionMapping


def _points(rng, n):
    while True:
        x = rng.random((n, 3))
        d = np.linalg.norm(x[:, None] - x[None], axis=2) + np.eye(n)
        if d.min() > 0.1:
            return x


def _spring_cases():
    rng = np.random.default_rng(11)
    X = _points(rng, 6)
    x0 = X + 0.1 * rng.standard_normal(X.shape)
    edges = np.array([[0, 1], [1, 2], [2, 3], [3, 4], [4, 5], [5, 0], [1, 0]])
    targets = rng.random((3, 3)) + np.array([2.0, 0, 0])
    maps = {
        "distance": DistanceMapping(edges, 6),
        "extension": ExtensionMapping(edges, rest_points=X),
        "distance-targets": DistanceMapping.to_targets([0, 3, 3], targets, n_points=6),
        "extension-targets": ExtensionMapping(np.array([[0, -1], [3, -1], [5, -1]]), rest_lengths=[0.5, 1.0, 2.0],
                                              n_points=6, targets=targets),
    }
    return [
        MappingCase(name=f"spring-{name}", x0=x0, apply=mp.apply, jvp=mp.jvp, vjp=mp.vjp,
                    geometric=mp.geometric_vp, jacobian=mp.jacobian)
        for name, mp in maps.items()
    ]


def _rigid_state(rng, frames, small=False):
    w = rng.standard_normal((frames.n, 3))
    w *= (rng.uniform(0.3, 2.5, frames.n) / np.linalg.norm(w, axis=1))[:, None]
    if small:
        w[0] *= 1e-6 / np.linalg.norm(w[0])
    v = np.concatenate([rng.standard_normal((frames.n, 3)), w], axis=1)
    return frames.integrate(frames.rest, v)


def _rigid_cases():
    rng = np.random.default_rng(12)
    frames = RigidFrames(rng.random((4, 3)))
    cases = []
    for small in (False, True):
        s0 = _rigid_state(rng, frames, small)
        lg = LogRigidMapping(frames)
        cases.append(MappingCase(
            name=f"rigid-log{'-small-angle' if small else ''}",
            x0=np.zeros((4, 6)),
            apply=lambda x, lg=lg, s0=s0: lg.apply(frames.integrate(s0, x)),
            jvp=lambda x, v, lg=lg, s0=s0: lg.jvp(frames.integrate(s0, x), v),
            vjp=lambda x, u, lg=lg, s0=s0: lg.vjp(frames.integrate(s0, x), u),
            geometric=lambda x, u, v, lg=lg, s0=s0: lg.geometric_vp(frames.integrate(s0, x), u, v),
            jacobian=lambda x, lg=lg, s0=s0: lg.jacobian(frames.integrate(s0, x)),
        ))
    # the relative frames of 3 pairs (frame 1 twice, once as parent once as child), through their log
    s0 = _rigid_state(rng, frames)
    rel = RelativeRigidMapping(frames, [[0, 1], [1, 2], [3, 0]])
    child = rel.children
    lg = LogRigidMapping(child)

    def state(x):
        return frames.integrate(s0, x)

    def geometric(x, u, v):
        s = state(x)
        c = rel.apply(s)
        return rel.geometric_vp(s, lg.vjp(c, u), v) + rel.vjp(s, lg.geometric_vp(c, u, rel.jvp(s, v)))

    cases.append(MappingCase(
        name="rigid-relative-log",
        x0=np.zeros((4, 6)),
        apply=lambda x: lg.apply(rel.apply(state(x))),
        jvp=lambda x, v: lg.jvp(rel.apply(state(x)), rel.jvp(state(x), v)),
        vjp=lambda x, u: rel.vjp(state(x), lg.vjp(rel.apply(state(x)), u)),
        geometric=geometric,
        jacobian=lambda x: lg.jacobian(rel.apply(state(x))) @ rel.jacobian(state(x)),
    ))
    return cases


def _membrane_cases():
    rng = np.random.default_rng(13)
    X = np.array([[0.0, 0, 0], [1, 0, 0.1], [0.9, 1, 0], [-0.2, 0.8, 0.3], [-0.6, -0.7, 0.0]])
    tris = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]])
    tri = TriangleDeformationMapping(X, tris)
    x0 = X + 0.2 * rng.standard_normal(X.shape)
    mem = StVKMembrane(young=3.0, poisson=0.3, thickness=0.5)
    F0 = tri.apply(x0)
    return [
        MappingCase(name="membrane-triangle-F", x0=x0, apply=tri.apply, jvp=tri.jvp, vjp=tri.vjp,
                    jacobian=lambda x: tri.jacobian(), constant_jacobian=True),
        MappingCase(
            name="membrane-stvk-energy",
            x0=F0,
            apply=mem.energy,
            jvp=lambda F, v: np.einsum("niJ,niJ->n", mem.stress(F), v),
            vjp=lambda F, u: u[:, None, None] * mem.stress(F),
            geometric=lambda F, u, v: u[:, None, None] * np.einsum("niJkL,nkL->niJ", mem.tangent(F), v),
        ),
    ]


CASES = _spring_cases() + _rigid_cases() + _membrane_cases()
