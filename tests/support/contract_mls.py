"""Derivative-contract cases of the moving-least-squares mapping (voxflex.deform.chain.mls).

Point nodes (6 nodes, Schaefer's affine MLS of the origins) and affine frames (5
frames, radius 0.2 m) map linearly, so their Jacobian is declared constant and
checked to be so.  Rigid frames (5 frames, radius 0.2 m) are moved by a (v, ω)
increment through ``RigidFrames.integrate`` from a random state with rotations up
to 2.5 rad (as for the other rigid-frame mappings); their geometric stiffness is
checked against finite differences of Jᵀ f.  8 points, 4 or 5 parents each
(Shepard weights).  The contract's own tolerances apply (rtol 1e-6).
"""

from __future__ import annotations

import numpy as np
from contract import MappingCase

from voxflex.deform.chain.mls import MovingLeastSquaresMapping
from voxflex.deform.chain.nodes import AffineFrames, Points, RigidFrames
from voxflex.voronoi.shape_functions import shepard


def _linear_case(name, nodes, seed, radius=None):
    rng = np.random.default_rng(100 + seed)  # not the nodes' seed: points must not sit on nodes
    sv = shepard(rng.random((8, 3)), nodes.rest_positions, n_parents=min(5, nodes.n))
    mls = MovingLeastSquaresMapping(nodes, sv, radius=radius)
    x0 = nodes.rest + 0.2 * rng.standard_normal(nodes.rest.shape)
    return MappingCase(
        name=name,
        x0=x0,
        apply=mls.apply,
        jvp=mls.jvp,
        vjp=mls.vjp,
        geometric=mls.geometric_vp,
        jacobian=mls.jacobian,
        constant_jacobian=True,
    )


def _rigid_case(name, seed, radius, angle=2.5):
    rng = np.random.default_rng(seed)
    frames = RigidFrames(rng.random((5, 3)))
    sv = shepard(rng.random((8, 3)), frames.rest_positions, n_parents=4)
    w = rng.standard_normal((5, 3))
    w *= (angle * rng.uniform(0.3, 1.0, 5) / np.linalg.norm(w, axis=1))[:, None]
    s0 = frames.integrate(frames.rest, np.concatenate([0.3 * rng.standard_normal((5, 3)), w], axis=1))
    mls = MovingLeastSquaresMapping(frames, sv, radius=radius)

    def state(x):
        return frames.integrate(s0, x)

    return MappingCase(
        name=name,
        x0=np.zeros((5, 6)),
        apply=lambda x: mls.apply(state(x)),
        jvp=lambda x, v: mls.jvp(state(x), v),
        vjp=lambda x, u: mls.vjp(state(x), u),
        geometric=lambda x, u, v: mls.geometric_vp(state(x), u, v),
        jacobian=lambda x: mls.jacobian(state(x)),
    )


CASES = [
    _linear_case("mls-points", Points(np.random.default_rng(1).random((6, 3))), 1),
    _linear_case("mls-affine", AffineFrames(np.random.default_rng(2).random((5, 3))), 2, radius=0.2),
    _rigid_case("mls-rigid", 3, 0.2),
    _rigid_case("mls-rigid-small-rotations", 4, 0.2, angle=0.05),
    _rigid_case("mls-rigid-radius-0", 5, 0.0),
]
