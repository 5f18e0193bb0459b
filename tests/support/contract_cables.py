"""Derivative-contract cases of the cable layer (voxflex.deform.layers.cables).

As for contact: x is the node state q (n, d), y the cables' energy as a (1,)
array (the CableModel's total energy minus its inner model's, so a wrong cable
term cannot hide behind the elastic energy); jvp = g . v, vjp = u g,
geometric = u (H v), jacobian = the gradient as a (1, N) row.

The energy of a tension-only cable is C1 with a Hessian that jumps where the
cable becomes taut, so every elastic case is placed away from that kink: at the
perturbed state the excess length delta is >= 0.05 m (asserted), while the
contract's step h = 1e-6 * max|x| (<= 5e-6 here) changes lengths by O(1e-5):
central differences never straddle the kink and keep the contract's rtol 1e-6.
A slack cable (delta <= -0.05 m, asserted) must give exactly zero.

Cases: a straight two-point cable along a voxel bar; a polyline through four
points from a fixed anchor (kinks at the eyelets: geometric stiffness); a
force-controlled cable (pull); a two-sided spring under compression; a slack
cable; an affine-frame model with a polyline cable.
"""

from __future__ import annotations

import numpy as np
from contract import MappingCase

from voxflex.deform.layers.cables import Cable, CableModel
from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.image.label_image import LabelImage


def _voxel_bar():
    labels = np.ones((4, 1, 1), dtype=np.uint8)
    return VoxelModel.from_image(LabelImage(labels), {1: material("neo-hookean", young=10.0, poisson=0.3)})


def _frame_model():
    from voxflex.deform.models.frames.model import FrameModel
    from voxflex.voronoi.shape_functions import shepard

    frames = np.array([[0.5, 0.5, 0.5], [1.5, 0.5, 0.5], [2.5, 0.5, 0.5], [3.5, 0.5, 0.5]])

    def sf(points):
        return shepard(np.asarray(points, dtype=float), frames, n_parents=3)

    image = LabelImage(np.ones((4, 1, 1), dtype=np.uint8))
    return FrameModel.from_image(image, frames, sf, {1: material("neo-hookean", young=10.0, poisson=0.3)})


def _case(name, inner, cables, *, fraction=0.7, scale=0.02, seed=5, slack=False):
    model = CableModel(inner, cables)
    model.set_time(fraction)
    rng = np.random.default_rng(seed)
    x0 = np.asarray(inner.rest, dtype=float) + scale * rng.standard_normal(inner.rest.shape)
    l = model.lengths(x0)
    for i, c in enumerate(cables):
        if c.pull is None:
            delta = l[i] - c.length_at(fraction)
            # away from the taut/slack kink (see the module docstring)
            assert (delta <= -0.05) if slack else (abs(delta) >= 0.05), (name, i, delta)

    def parts(x, hessian):
        E, g, H = model.energy_gradient_hessian(x, hessian=hessian)
        E0, g0, H0 = inner.energy_gradient_hessian(x, hessian=hessian)
        return E - E0, (g - g0).ravel(), (H - H0) if hessian else None

    return MappingCase(
        name=f"cable-{name}",
        x0=x0,
        apply=lambda x: np.array([parts(x, False)[0]]),
        jvp=lambda x, v: np.array([parts(x, False)[1] @ v.ravel()]),
        vjp=lambda x, u: (u[0] * parts(x, False)[1]).reshape(x.shape),
        geometric=lambda x, u, v: (u[0] * (parts(x, True)[2] @ v.ravel())).reshape(x.shape),
        jacobian=lambda x: parts(x, False)[1][None, :],
    )


def _cases():
    vox = _voxel_bar()
    top = [[0.5, 0.5, 1.0], [1.5, 0.5, 0.9], [2.5, 0.5, 1.0], [3.5, 0.5, 0.8]]
    cases = [
        _case("straight", vox, [Cable([[0.2, 0.5, 0.9], [3.8, 0.4, 0.9]], stiffness=20.0, shorten=0.5)]),
        _case("anchor-polyline", vox, [Cable(top, anchor=[-1.0, 0.3, 1.5], stiffness=5.0, shorten=1.0)]),
        _case("pull", vox, [Cable(top, pull=3.0)]),
        _case("two-sided-compressed", vox, [Cable([[0.5, 0.2, 0.5], [3.0, 0.8, 0.5]], stiffness=8.0,
                                                  rest_length=3.0, tension_only=False)]),
        _case("slack", vox, [Cable([[0.5, 0.5, 0.5], [3.5, 0.5, 0.5]], stiffness=8.0, rest_length=3.5)],
              slack=True),
        _case("two-cables", vox, [Cable(top, stiffness=5.0, shorten=0.4),
                                  Cable([[0.1, 0.1, 0.1], [3.9, 0.9, 0.1]], anchor=[5.0, 0.5, 0.0], stiffness=3.0,
                                        shorten=0.3)]),
    ]
    try:
        cases.append(_case("affine-frames", _frame_model(), [Cable(top, stiffness=5.0, shorten=0.5)], scale=0.005))
    except ImportError:  # pragma: no cover - the frame model is part of the package
        pass
    return cases


CASES = _cases()
