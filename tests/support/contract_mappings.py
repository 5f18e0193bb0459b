"""Derivative-contract cases of the node -> child mappings (see ``contract.py``).

One :class:`MappingCase` per (node type × mapping) on a small random problem:
5 nodes, 7 children, Shepard weights on the 4 nearest nodes stored with P = 5
parent slots (one padded with -1 at a random position, parents unsorted), so
padding and the column sorting of the assembled Jacobian are exercised too.

Points and affine frames: x is the node state itself (J is constant).
Rigid frames: x is a velocity increment in the (v, ω) space applied to a
random rotated/translated state through ``integrate``, so the finite
differences follow the manifold: ``x(h) = apply(integrate(state, h v))``;
the contract evaluates at x = 0, where the jvp, vjp and geometric stiffness
of the mapping at ``state`` are exactly the derivatives of these wrappers.
The contract's own tolerances apply (rtol 1e-6 against central differences).
"""

from __future__ import annotations

import numpy as np
from contract import MappingCase

from voxflex.deform.chain.mappings import (
    DeformationGradientMapping,
    DeformationGradientWithGradientMapping,
    PointMapping,
)
from voxflex.deform.chain.nodes import AffineFrames, Points, RigidFrames
from voxflex.voronoi.shape_functions import ShapeValues, shepard


def padded_shepard(points, nodes, k, rng):
    """Shepard on the k nearest nodes, stored in k + 1 slots with one random -1 pad."""
    sv = shepard(points, nodes, n_parents=k)
    m = sv.m
    index = np.full((m, k + 1), -1, dtype=np.int64)
    w = np.zeros((m, k + 1))
    dw = np.zeros((m, k + 1, 3))
    ddw = np.zeros((m, k + 1, 3, 3))
    for c in range(m):
        slots = rng.permutation(k + 1)[:k]
        index[c, slots] = sv.index[c]
        w[c, slots] = sv.w[c]
        dw[c, slots] = sv.dw[c]
        ddw[c, slots] = sv.ddw[c]
    return ShapeValues(index=index, w=w, dw=dw, ddw=ddw, rest=sv.rest, n_nodes=len(nodes))


def _packer(mapping):
    if isinstance(mapping, DeformationGradientWithGradientMapping):
        return lambda y: mapping.pack(*y)
    return np.asarray


def _case(node_type, mapping_type, seed):
    rng = np.random.default_rng(seed)
    Xn = rng.random((5, 3))
    sv = padded_shepard(rng.random((7, 3)), Xn, 4, rng)
    nodes = node_type(Xn)
    mp = mapping_type(nodes, sv)
    pk = _packer(mp)
    name = f"mapping-{nodes.kind}-{mapping_type.__name__}"
    if isinstance(nodes, RigidFrames):
        s0 = nodes.integrate(nodes.rest, rng.standard_normal((5, 6)))
        return MappingCase(
            name=name,
            x0=np.zeros((5, 6)),
            apply=lambda x: pk(mp.apply(nodes.integrate(s0, x))),
            jvp=lambda x, v: pk(mp.jvp(nodes.integrate(s0, x), v)),
            vjp=lambda x, u: mp.vjp(nodes.integrate(s0, x), u),
            geometric=lambda x, u, v: mp.geometric_vp(nodes.integrate(s0, x), u, v),
            jacobian=lambda x: mp.jacobian(nodes.integrate(s0, x)),
            seed=seed,
        )
    s0 = nodes.rest + 0.3 * rng.standard_normal(nodes.rest.shape)
    return MappingCase(
        name=name,
        x0=s0,
        apply=lambda x: pk(mp.apply(x)),
        jvp=lambda x, v: pk(mp.jvp(x, v)),
        vjp=mp.vjp,
        jacobian=mp.jacobian,
        constant_jacobian=True,
        seed=seed,
    )


CASES = [
    _case(nt, mt, seed)
    for seed, (nt, mt) in enumerate(
        (nt, mt)
        for nt in (Points, AffineFrames, RigidFrames)
        for mt in (PointMapping, DeformationGradientMapping, DeformationGradientWithGradientMapping)
    )
]
