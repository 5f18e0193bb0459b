"""Derivative-contract cases of the contact barrier (voxflex.deform.layers.contact).

x is the node state q (n, d), y the barrier energy as a (1,) array: the total
energy of the ContactModel minus its inner model's (so a wrong barrier term
cannot hide behind a large elastic energy).  jvp = g . v, vjp = u g,
geometric = u (H v) with the exact Hessian (``exact=True``: no positive
semi-definite projection), jacobian = the gradient as a (1, N) row.

Geometry: unit voxels, activation distance dhat = 0.2, obstacles placed so that
several collision points sit inside the barrier's range (0.3-0.9 dhat) at the
perturbed state; with the contract's step h = 1e-6 * max|x| (<= 4e-6) the
distances change by O(1e-5) << d, so central differences of the log barrier
keep a truncation error near (h/d)^2 ~ 1e-8, below the contract's rtol 1e-6.
Kinds covered: plane, sphere, box (edge and corner region), a distance field
from a label image, a moving (rotated and translated) plane at fraction 0.6,
and an affine-frame model against a plane.
"""

from __future__ import annotations

import numpy as np
from contract import MappingCase

from voxflex.deform.layers.contact import ContactModel
from voxflex.deform.layers.obstacles import Box, DistanceField, Plane, Sphere
from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.image.label_image import LabelImage

DHAT = 0.2


def _voxel_model():
    labels = np.ones((2, 2, 2), dtype=np.uint8)
    return VoxelModel.from_image(LabelImage(labels), {1: material("neo-hookean", young=10.0, poisson=0.3)})


def _frame_model():
    from voxflex.deform.models.frames.model import FrameModel
    from voxflex.voronoi.shape_functions import shepard

    frames = np.array([[0.5, 0.5, 0.5], [1.5, 0.5, 1.5], [1.5, 1.5, 0.5], [0.5, 1.5, 1.5]])

    def sf(points):
        return shepard(np.asarray(points, dtype=float), frames, n_parents=4)

    image = LabelImage(np.ones((2, 2, 2), dtype=np.uint8))
    return FrameModel.from_image(image, frames, sf, {1: material("neo-hookean", young=10.0, poisson=0.3)})


def _case(name, inner, obstacle, *, scale=0.02, fraction=0.0, seed=3):
    model = ContactModel(inner, [obstacle], points=2, distance=DHAT, stiffness=50.0)
    model.set_time(fraction)
    rng = np.random.default_rng(seed)
    x0 = np.asarray(inner.rest, dtype=float) + scale * rng.standard_normal(inner.rest.shape)
    d = model._distances(model.mapping.apply(x0))[0]
    # the perturbed state stays out of the obstacle, with points inside the barrier's range
    assert d.min() > 0.2 * DHAT and np.count_nonzero(d < DHAT) >= 2, (name, d.min(), np.count_nonzero(d < DHAT))

    def parts(x, hessian):
        E, g, H = model.energy_gradient_hessian(x, hessian=hessian, exact=True)
        E0, g0, H0 = inner.energy_gradient_hessian(x, hessian=hessian)
        return E - E0, (g - g0).ravel(), (H - H0) if hessian else None

    return MappingCase(
        name=f"contact-{name}",
        x0=x0,
        apply=lambda x: np.array([parts(x, False)[0]]),
        jvp=lambda x, v: np.array([parts(x, False)[1] @ v.ravel()]),
        vjp=lambda x, u: (u[0] * parts(x, False)[1]).reshape(x.shape),
        geometric=lambda x, u, v: (u[0] * (parts(x, True)[2] @ v.ravel())).reshape(x.shape),
        jacobian=lambda x: parts(x, False)[1][None, :],
    )


def _cases():
    vox = _voxel_model()
    # label image of a slab [-2, 1] x [-2, 2] x [-2.1, -0.1] below the body: points near its edge x = 1 see a
    # curved field (mixed second derivatives of the trilinear interpolation)
    slab = LabelImage(np.ones((6, 8, 4), dtype=np.uint8), origin=(-2.0, -2.0, -2.1), spacing=(0.5, 0.5, 0.5))
    cases = [
        _case("plane", vox, Plane(point=(0.0, 0.0, -0.12), normal=(0.1, 0.05, 1.0))),
        _case("sphere", vox, Sphere(center=(1.0, 1.0, -3.1), radius=3.0)),
        _case("box-edge-corner", vox, Box(min=(-3.0, -3.0, -3.0), max=(1.1, 2.1, -0.1))),
        _case("sdf-labels", vox, DistanceField.from_labels(slab)),
        _case("moving-plane", vox, Plane(point=(0.0, 0.0, -0.5), normal=(0.0, 0.0, 1.0),
                                         motion=_rigid(0.1, (0.2, -0.1, 0.47))), fraction=0.6),
    ]
    try:
        cases.append(_case("affine-frames-plane", _frame_model(), Plane(point=(0.0, 0.0, -0.1), normal=(0, 0, 1)),
                           scale=0.005))
    except ImportError:  # pragma: no cover - the frame model is part of the package
        pass
    return cases


def _friction_case(name, inner, obstacle, *, scale=0.02, slide=0.01, start=0.0, fraction=0.0, seed=5):
    """The barrier plus the lagged friction potential: the lag taken (begin_step) at a perturbed state q_lag,
    the contract run at q_lag plus a slide, with the slip distance eps set between the two middle slips so
    that the smoothed (y < eps) and the Coulomb (y > eps) pieces are both exercised."""
    model = ContactModel(inner, [obstacle], points=2, distance=DHAT, stiffness=50.0)
    model.set_time(start)
    rng = np.random.default_rng(seed)
    q_lag = np.asarray(inner.rest, dtype=float) + scale * rng.standard_normal(inner.rest.shape)
    assert model.begin_step(fraction, q_lag.ravel(), q_lag.ravel().copy()) is not None
    pts, _, w, P, xbar = model._lag
    assert len(pts) >= 2 and np.all(w > 0), (name, len(pts))
    x0 = q_lag + slide * rng.standard_normal(q_lag.shape)
    y = np.linalg.norm(np.einsum("pij,pj->pi", P, model.mapping.apply(x0)[pts] - xbar), axis=1)
    ys = np.sort(y)
    model.slip = float(0.5 * (ys[len(ys) // 2 - 1] + ys[len(ys) // 2]))  # between the two middle slips
    # f0 is C1 only at y = eps (its curvature jumps): keep the contract's steps (~1e-6) well away from it
    assert np.min(np.abs(y - model.slip)) > 1e-4 * model.slip, name
    d = model._distances(model.mapping.apply(x0))[0]
    assert d.min() > 0.2 * DHAT, (name, d.min())

    def parts(x, hessian):
        E, g, H = model.energy_gradient_hessian(x, hessian=hessian, exact=True)
        E0, g0, H0 = inner.energy_gradient_hessian(x, hessian=hessian)
        return E - E0, (g - g0).ravel(), (H - H0) if hessian else None

    # the friction forces weigh in the total (a wrong friction term would show at the contract's rtol)
    g_friction = model.mapping.vjp(x0, model._friction_terms(model.mapping.apply(x0), hessian=False)[1])
    assert np.linalg.norm(g_friction) > 0.1 * np.linalg.norm(parts(x0, False)[1]), name
    return MappingCase(
        name=f"contact-friction-{name}",
        x0=x0,
        apply=lambda x: np.array([parts(x, False)[0]]),
        jvp=lambda x, v: np.array([parts(x, False)[1] @ v.ravel()]),
        vjp=lambda x, u: (u[0] * parts(x, False)[1]).reshape(x.shape),
        geometric=lambda x, u, v: (u[0] * (parts(x, True)[2] @ v.ravel())).reshape(x.shape),
        jacobian=lambda x: parts(x, False)[1][None, :],
    )


def _friction_cases():
    vox = _voxel_model()
    cases = [
        _friction_case("plane", vox, Plane(point=(0.0, 0.0, -0.12), normal=(0.1, 0.05, 1.0), friction=0.4)),
        _friction_case("sphere", vox, Sphere(center=(1.0, 1.0, -3.1), radius=3.0, friction=0.7)),
        _friction_case("moving-plane", vox, Plane(point=(0.0, 0.0, -0.5), normal=(0.0, 0.0, 1.0), friction=0.5,
                                                  motion=_rigid(0.1, (0.2, -0.1, 0.47))), start=0.58, fraction=0.6),
    ]
    cases.append(_friction_case("affine-frames-plane", _frame_model(),
                                Plane(point=(0.0, 0.0, -0.1), normal=(0, 0, 1), friction=0.4),
                                scale=0.005, slide=0.003))
    return cases


def _rigid(angle, t):
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(angle * np.array([0.6, 0.0, 0.8])).as_matrix()
    return np.hstack([R, np.asarray(t, dtype=float)[:, None]])


CASES = _cases() + _friction_cases()
