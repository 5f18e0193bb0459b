"""Coulomb friction of the collision layer (lagged, smoothed: voxflex.deform.layers.contact).

Oracles: the analytic block on an incline, a box on a plane inclined by alpha
(here the plane is horizontal and gravity tilted by alpha about y: the same
problem in the plane's frame), with

- mu < tan(alpha): it slides with a = g (sin(alpha) - mu cos(alpha));
- mu > tan(alpha): it sticks, up to the creep the smoothing allows: a point whose
  tangential load F_t stays below mu lambda slides y = eps (1 - sqrt(1 - F_t / (mu lambda)))
  per step (the root of mu lambda f0'(y) = F_t), eps the slip distance;

a conveyor (a plane moving along itself) accelerating a box at mu g; the
energy balance of implicit Euler (friction only removes energy); central
differences of the mollifier.  The derivative contract of the friction
energy is in tests/contract_contact.py.

Boxes are 2x2x2 voxels of 0.1 m.  Where the analytic oracle assumes a rigid
block the box is made stiff (E = 1e7 Pa or more, with the barrier stiffness
kept at 1e7 Pa): its elastic deformation under its weight (~1e-5 m at E = 1e7)
would otherwise blur a creep of a few micrometres.
"""

from __future__ import annotations

import numpy as np
import pytest

from voxflex.deform.layers.contact import ContactModel, friction_mollifier
from voxflex.deform.layers.obstacles import Plane, Sphere
from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.deform.solve.options import SolverOptions
from voxflex.deform.solve.stepping import solve
from voxflex.errors import InputError
from voxflex.image.label_image import LabelImage

ALPHA = np.radians(20.0)  # tan(alpha) = 0.364
G = 9.81
GRAVITY = G * np.array([np.sin(ALPHA), 0.0, -np.cos(ALPHA)])  # the incline's frame: x down the slope, z its normal
DENSITY = {1: 1000.0}
DHAT = 1e-3  # barrier distance (1 % of the voxel)
KAPPA = 1e7  # barrier stiffness (Pa)
SLIP = 1e-5  # the default: 1 % of DHAT


def _gap(young_barrier=KAPPA):
    """The barrier's gap under the box's weight: p = kappa b'(d) at d = dhat (1 - sqrt(p / (3 kappa)))
    to first order (a start near normal equilibrium keeps the ringing small)."""
    p = 1000.0 * G * 0.2 * np.cos(ALPHA)
    return DHAT * (1.0 - np.sqrt(p / (3.0 * young_barrier)))


def _box(mu, *, young=1e7, z0=None, obstacle=None, **kwargs):
    z0 = _gap() if z0 is None else z0
    image = LabelImage(np.ones((2, 2, 2), dtype=np.uint8), spacing=(0.1,) * 3, origin=(0.0, 0.0, z0))
    inner = VoxelModel.from_image(image, {1: material("neo-hookean", young=young, poisson=0.3)})
    ob = Plane(point=(0, 0, 0), normal=(0, 0, 1), friction=mu) if obstacle is None else obstacle
    return ContactModel(inner, [ob], distance=DHAT, stiffness=KAPPA, **kwargs)


def _frames_box(mu):
    from voxflex.deform.models.frames.model import FrameModel
    from voxflex.voronoi.shape_functions import shepard

    z0 = _gap()
    frames = np.array([[0.05, 0.05, 0.05], [0.15, 0.15, 0.05], [0.1, 0.1, 0.15], [0.15, 0.05, 0.15]]) + [0, 0, z0]
    image = LabelImage(np.ones((2, 2, 2), dtype=np.uint8), spacing=(0.1,) * 3, origin=(0.0, 0.0, z0))

    def sf(points):
        return shepard(np.asarray(points, dtype=float), frames, n_parents=4)

    inner = FrameModel.from_image(image, frames, sf, {1: material("neo-hookean", young=1e7, poisson=0.3)})
    return ContactModel(inner, [Plane(point=(0, 0, 0), normal=(0, 0, 1), friction=mu)], distance=DHAT,
                        stiffness=KAPPA)


def _dynamics(model, steps, dt=0.01, gravity=GRAVITY):
    opt = SolverOptions(kind="implicit-euler", dt=dt, steps=steps, tolerance=1e-10)
    return solve(model, gravity=gravity, densities=DENSITY, options=opt)


def _centre_x(model, records):
    """x of the box's mass centre (a material point: x is linear in the state for voxels and affine frames)."""
    z0 = float(np.min(model.rest[..., -1])) if model.dofs_per_node == 3 else _gap()
    centre = model.point_mapping(np.array([[0.1, 0.1, 0.1 + z0]]))
    return np.array([centre.apply(r.q)[0, 0] for r in records])


def _creep(mu, eps=SLIP, load=np.tan(ALPHA)):
    """The steady creep per step of a stuck box: the root of mu f0'(y) = tan(alpha) (all points alike)."""
    return eps * (1.0 - np.sqrt(1.0 - load / mu))


# ---------------------------------------------------------------------------
# the mollifier
# ---------------------------------------------------------------------------
def test_mollifier_is_c1_and_its_derivatives_match_central_differences():
    eps = 1e-3
    y = np.concatenate([np.linspace(0.0, 0.99, 23), np.linspace(1.01, 3.0, 9)]) * eps
    f0, f1, f1y, f2 = friction_mollifier(y, eps)
    h = 1e-7 * eps
    f0p, f1p, _, _ = friction_mollifier(y + h, eps)
    f0m, f1m, _, _ = friction_mollifier(np.abs(y - h), eps)  # f0 is even in the slip: |y - h| at y = 0
    inner = y > h
    # cubic pieces: central differences have truncation h^2 f''' ~ 1e-14 eps-relative, round-off 1e-16 / 1e-7
    np.testing.assert_allclose(f1[inner], ((f0p - f0m) / (2 * h))[inner], rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(f2[inner], ((f1p - f1m) / (2 * h))[inner], rtol=1e-6, atol=1e-3 / eps * 1e-6)
    np.testing.assert_allclose(f1y[inner], f1[inner] / y[inner], rtol=1e-12)
    assert f1y[0] == pytest.approx(2.0 / eps, rel=1e-15) and f0[0] == 0 and f1[0] == 0
    assert np.all((f1 >= 0) & (f1 <= 1)) and np.all(np.diff(f1) >= 0) and np.all(f2 >= 0)  # convex, increasing
    # C1 at eps: value and slope continuous (f0(eps) = 2 eps / 3, f0' = 1), the curvature jumps from 0 to 0
    a = friction_mollifier(np.array([eps * (1 - 1e-12), eps, eps * (1 + 1e-12)]), eps)
    np.testing.assert_allclose(a[0], 2 * eps / 3 + np.array([-1e-12, 0, 1e-12]) * eps, rtol=1e-11)
    np.testing.assert_allclose(a[1], 1.0, atol=1e-11)


# ---------------------------------------------------------------------------
# the incline: slide and stick
# ---------------------------------------------------------------------------
def test_box_slides_down_an_incline_with_the_coulomb_acceleration():
    mu = 0.2  # < tan(20 deg) = 0.364
    model = _box(mu)
    dt = 0.01
    records = _dynamics(model, steps=25, dt=dt)
    x = _centre_x(model, records)
    a = np.diff(x, 2) / dt**2  # = (v_n+1 - v_n) / dt of the mass centre
    exact = G * (np.sin(ALPHA) - mu * np.cos(ALPHA))  # 1.5115 m/s^2
    # after the first steps (the box settles into the barrier and starts from rest, slipping less than eps):
    # a step's momentum balance along x is exact, m a = m g sin - mu sum(lambda_lag), with sum(lambda_lag)
    # the normal force at the step's start; its ringing decays by backward Euler's 1/(1 + w^2 h^2) per step.
    # Measured: 1.51154068 against 1.51154068 (1e-9) at the end; brief's 2 % for the mean from step 5 on
    assert np.mean(a[5:]) == pytest.approx(exact, rel=0.02)
    assert a[-1] == pytest.approx(exact, rel=1e-6)
    # the friction force the plane exerts: mu times the normal force, against the slide
    force = model.contact_forces(records[-1].q)[0]
    assert -force[0] == pytest.approx(mu * force[2], rel=1e-6)
    assert np.all(np.array([model.mapping.apply(r.q)[:, 2].min() for r in records]) > 0)


def test_box_sticks_on_an_incline_and_creeps_as_the_smoothing_allows():
    mu = 0.6  # > tan(20 deg)
    model = _box(mu)
    assert model.slip == pytest.approx(0.01 * DHAT)  # the default slip distance
    records = _dynamics(model, steps=30)
    x = _centre_x(model, records)
    creep = np.diff(x)
    # steady creep per step: eps (1 - sqrt(1 - tan / mu)) = 3.728e-6 m (0.37 mm/s at dt = 0.01 s);
    # measured 3.7280e-6 from step 15 on; 1e-3 relative covers the decaying elastic settling
    assert creep[-1] == pytest.approx(_creep(mu), rel=1e-3)
    # stuck: the whole run moves less than steps x eps (plus the first step's elastic settling, < eps)
    assert x[-1] - x[0] < (len(creep) + 1) * SLIP
    assert x[-1] - x[0] < 0.002 * 0.1  # 0.2 % of the voxel over 0.3 s


def test_static_box_sticks_with_the_predicted_slip():
    """One static load step from a state resting on the plane: lambda is the barrier force of the rest
    state; each bottom point slips by eps (1 - sqrt(1 - W sin / (mu lambda_0))).  A near-rigid box
    (E = 1e10 Pa: elastic displacements ~4e-8 m, 1 % of the slip) makes the points slip alike."""
    mu = 0.6
    model = _box(mu, young=1e10)
    lam0 = model.contact_forces(model.rest)[0, 2]  # before any step: the barrier alone
    weight = 1000.0 * 0.2**3 * G
    records = solve(model, gravity=GRAVITY, densities=DENSITY, options=SolverOptions(steps=1, tolerance=1e-10))
    bottom = model.points[:, 2] < model.points[:, 2].min() + 1e-12
    slip = model.mapping.apply(records[-1].q)[bottom, 0] - model.points[bottom, 0]
    expected = _creep(mu, load=weight * np.sin(ALPHA) / lam0)  # 3.703e-6 m; measured 3.699e-6 ... 3.708e-6
    np.testing.assert_allclose(slip, expected, rtol=0.01)
    # equilibrium: the plane holds the weight, its friction part against the slope load (Newton tolerance)
    force = model.contact_forces(records[-1].q)[0]
    np.testing.assert_allclose(force, -weight * GRAVITY / G, rtol=1e-8, atol=1e-8 * weight)
    assert np.abs(model.friction_forces(records[-1].q)[0, 2]) < 1e-12 * weight  # friction is tangential


def test_affine_frames_slide_and_stick_like_voxels():
    dt = 0.01
    model = _frames_box(0.2)
    x = _centre_x(model, _dynamics(model, steps=20, dt=dt))
    exact = G * (np.sin(ALPHA) - 0.2 * np.cos(ALPHA))
    assert np.diff(x, 2)[-1] / dt**2 == pytest.approx(exact, rel=1e-6)  # measured 1e-8
    model = _frames_box(0.6)
    creep = np.diff(_centre_x(model, _dynamics(model, steps=20, dt=dt)))
    assert creep[-1] == pytest.approx(_creep(0.6), rel=1e-3)  # measured 3.72798e-6 against 3.72801e-6


def test_a_conveyor_accelerates_a_box_at_mu_g_until_it_moves_with_it():
    """A horizontal plane moving along itself at V = 0.2 m/s (its rigid motion) under a box at rest:
    friction relative to the plane accelerates the box at mu g until it rides along at V."""
    mu, V, dt, steps = 0.5, 0.2, 0.005, 30
    T = dt * steps
    belt = Plane(point=(0, 0, 0), normal=(0, 0, 1), friction=mu,
                 motion=[[1, 0, 0, V * T], [0, 1, 0, 0], [0, 0, 1, 0]])
    gap = DHAT * (1.0 - np.sqrt(1000.0 * G * 0.2 / (3.0 * KAPPA)))
    model = _box(mu, z0=gap, obstacle=belt)
    records = _dynamics(model, steps=steps, dt=dt, gravity=(0.0, 0.0, -G))
    v = np.diff(_centre_x(model, records)) / dt
    # mu g = 4.905 m/s^2 reaches V after 0.041 s (8 steps).  While it slips (more than eps per step) each
    # step's momentum balance is exactly m a_k = mu N_k, N_k the normal force at the step's start (lagged);
    # N rings by +-4 % (the friction at the base rocks the box), so a_k does too; the mean over the
    # slipping phase is tested against mu g (measured 4.909: 0.1 %; 1 % allowed)
    M = model.mass_matrix(DENSITY)
    mass = 1000.0 * 0.2**3
    momentum = np.array([(M @ r.v.ravel())[0::3].sum() for r in records])  # along x (kg m/s)
    normal = np.array([model.contact_forces(r.q, fraction=k / steps)[0, 2] for k, r in enumerate(records)])
    # step k (records k-1 -> k) has the lag of records k-1; steps 2..7 slip by more than eps (0.9 mm against
    # 0.01 mm) along x, but the base breathes (Poisson) so the slips have a small y part: the x force is
    # mu N cos(angle), measured 1 - 4e-6 at step 2, 2e-7 later; 1e-5 allowed
    np.testing.assert_allclose(np.diff(momentum)[1:7] / dt, mu * normal[1:7], rtol=1e-5)
    assert (momentum[7] - momentum[1]) / (6 * dt * mass) == pytest.approx(mu * G, rel=0.01)
    assert v[-1] == pytest.approx(V, rel=1e-3)  # then it rides along (measured 0.2000000 at the end)


# ---------------------------------------------------------------------------
# energy, mu = 0, validation
# ---------------------------------------------------------------------------
def test_friction_never_adds_energy():
    """A soft box (E = 1e5 Pa: it shears and rings) pushed along a flat plane slides, then sticks: the
    mechanical energy (elastic + barrier + kinetic - f.q) may only drop, each step by at least its
    friction potential."""
    image = LabelImage(np.ones((2, 2, 2), dtype=np.uint8), spacing=(0.1,) * 3, origin=(0.0, 0.0, 9.2e-4))
    inner = VoxelModel.from_image(image, {1: material("neo-hookean", young=1e5, poisson=0.3)})
    model = ContactModel(inner, [Plane(point=(0, 0, 0), normal=(0, 0, 1), friction=0.4)], distance=DHAT)
    g = np.array([0.0, 0.0, -G])
    v0 = np.tile([0.3, 0.1, 0.0], (len(inner.rest), 1))
    dt = 0.01
    opt = SolverOptions(kind="implicit-euler", dt=dt, steps=20, tolerance=1e-10)
    lost = []  # per step: the friction potential D of the step's lag at its converged state (>= 0)

    def record(rec):  # called after each step, while the model holds that step's lag
        lost.append(model.friction_energy(rec.q))

    records = solve(model, gravity=g, densities=DENSITY, options=opt, v0=v0, callback=record)
    M = model.mass_matrix(DENSITY)
    f = model.gravity_force(DENSITY, g).ravel()
    total = np.array([model.inner.energy(r.q) + model.barrier_energy(r.q) + 0.5 * r.v.ravel() @ M @ r.v.ravel()
                      - f @ r.q.ravel() for r in records])
    # backward Euler with a convex friction potential D (0 at the step's start): a step loses at least
    # grad D . dx >= D(x_new) (convexity); the elastic energy adds its own (non-negative near rest) loss.
    # Allowed: the Newton round-off (tolerance 1e-10 of forces ~80 N times displacements ~0.01 m: < 1e-9 J)
    assert len(lost) == len(records) - 1 and max(lost) > 0
    assert np.all(np.diff(total) <= -np.array(lost) + 1e-9)
    # the push's 0.4 J of kinetic energy (8 kg at 0.316 m/s) is gone: the sliding stops within ~0.08 s (mu g =
    # 3.9 m/s^2) and only the soft box's ringing on its stuck base is left; measured drop 0.421 J
    assert total[0] - total[-1] > 0.9 * 0.5 * 8.0 * (0.3**2 + 0.1**2)


def test_zero_friction_is_the_barrier_alone():
    """mu = 0 keeps no lag: energy, gradient and Hessian are bitwise those of today's frictionless
    contact, and the box slides down the incline with a = g sin(alpha) exactly."""
    model = _box(0.0)
    q = np.asarray(model.rest, dtype=float)
    before = model.energy_gradient_hessian(q)
    assert model.begin_step(0.5, q.ravel(), q.ravel().copy()) is not None and model._lag is None
    after = model.energy_gradient_hessian(q)
    assert before[0] == after[0] and np.array_equal(before[1], after[1])
    assert (before[2] != after[2]).nnz == 0
    assert after[0] == model.inner.energy(q) + model.barrier_energy(q)
    dt = 0.01
    x = _centre_x(model, _dynamics(model, steps=8, dt=dt))
    # frictionless: the momentum balance along x holds exactly (the barrier pushes along z only)
    np.testing.assert_allclose(np.diff(x, 2) / dt**2, G * np.sin(ALPHA), rtol=1e-8)


def test_friction_and_slip_are_validated():
    for bad in (float("nan"), -0.1, float("inf"), True, "0.3"):
        with pytest.raises(InputError, match="friction must be a number >= 0"):
            Sphere(center=(0, 0, -1), radius=0.5, friction=bad)
    for bad in (0.0, -1e-5, float("nan"), True):
        with pytest.raises(InputError, match="slip"):
            _box(0.3, slip=bad)
    from voxflex.scene import ObstacleSpec

    for bad in (float("nan"), -0.2, float("inf")):
        with pytest.raises(InputError, match="friction"):
            ObstacleSpec(kind="plane", point=(0, 0, 0), normal=(0, 0, 1), friction=bad)
    assert ObstacleSpec(kind="plane", point=(0, 0, 0), normal=(0, 0, 1), friction=0.3).parameters()["friction"] == 0.3


def test_a_scene_with_friction_slides_down_its_incline():
    """The incline through the scene path: [[obstacle]] friction = 0.2, gravity tilted by alpha, vf.simulate."""
    import voxflex as vf
    from voxflex.deform.layers.contact import with_contact
    from voxflex.scene import (
        ContactSpec,
        LoadSpec,
        MaterialSpec,
        NodesSpec,
        ObjectSpec,
        ObstacleSpec,
        Scene,
        SolverSpec,
    )

    mu, dt = 0.2, 0.01
    scene = Scene(
        object=ObjectSpec(shape="box", size=(0.2, 0.2, 0.2), voxel_size=0.1, origin=(0.0, 0.0, _gap())),
        nodes=NodesSpec(kind="voxel"),
        materials=(MaterialSpec(model="neo-hookean", young=1e7, poisson=0.3, density=1000.0),),
        loads=(LoadSpec(kind="gravity", vector=tuple(GRAVITY)),),
        obstacles=(ObstacleSpec(kind="plane", point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0), friction=mu),),
        contact=ContactSpec(distance=DHAT, stiffness=KAPPA),
        solver=SolverSpec(kind="implicit-euler", dt=dt, steps=12, tolerance=1e-10),
    )
    model = with_contact(vf.model(scene), scene)
    assert model.obstacles[0].friction == mu
    result = vf.simulate(scene, model=model, progress=False)
    x = np.array([q[:, 0].mean() for q in result.nodes_state])  # a near-rigid box: its nodes move alike
    # measured 1.5115407 at step 12 against 1.5115407 (1e-8); 1e-4 leaves the node mean (not the mass centre)
    assert np.diff(x, 2)[-1] / dt**2 == pytest.approx(G * (np.sin(ALPHA) - mu * np.cos(ALPHA)), rel=1e-4)
