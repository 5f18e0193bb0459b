"""Derivative-contract cases of dual-quaternion skinning (voxflex.deform.chain.skinning).

x is a (v, ω) increment of 4 rigid frames applied to a random state through
``RigidFrames.integrate`` (as for the other rigid-frame mappings), y the
skinned positions of 6 points with 3 parents each (Shepard weights).  Rotation
angles up to ~2.5 rad (below π, where the frames' logarithm jumps) and a case
of small rotations; the blend's hemisphere signs stay constant within the
contract's steps (1e-6).  The contract's own tolerances apply (rtol 1e-6).
"""

from __future__ import annotations

import numpy as np
from contract import MappingCase

from voxflex.deform.chain.nodes import RigidFrames
from voxflex.deform.chain.skinning import DualQuaternionSkinning
from voxflex.voronoi.shape_functions import shepard


def _case(name, seed, angle):
    rng = np.random.default_rng(seed)
    frames = RigidFrames(rng.random((4, 3)))
    sv = shepard(rng.random((6, 3)), frames.rest_positions, n_parents=3)
    w = rng.standard_normal((4, 3))
    w *= (angle * rng.uniform(0.3, 1.0, 4) / np.linalg.norm(w, axis=1))[:, None]
    s0 = frames.integrate(frames.rest, np.concatenate([0.3 * rng.standard_normal((4, 3)), w], axis=1))
    dqs = DualQuaternionSkinning(frames, sv)

    def state(x):
        return frames.integrate(s0, x)

    return MappingCase(
        name=f"skinning-dual-quaternion{name}",
        x0=np.zeros((4, 6)),
        apply=lambda x: dqs.apply(state(x)),
        jvp=lambda x, v: dqs.jvp(state(x), v),
        vjp=lambda x, u: dqs.vjp(state(x), u),
        geometric=lambda x, u, v: dqs.geometric_vp(state(x), u, v),
        jacobian=lambda x: dqs.jacobian(state(x)),
    )


CASES = [_case("", 0, 2.5), _case("-small-rotations", 1, 0.05)]
