"""The collision layer: barrier, obstacles' signed distances, collision points, and contact physics.

Oracles: closed-form distances (plane, sphere, brute-force box), central
differences of the barrier and of the distances, the boundary area, and for
the physics the weight of the body (force balance), the discrete energy of
implicit Euler (it may only decrease) and the obstacle itself (no point may
reach it).  The derivative contract of the whole barrier energy is in
tests/contract_contact.py.

The solver calls ``ContactModel.begin_step`` once per step (one line the
solver owner adds); until it does, the stepped runs here go through the
solver's own Newton (``_Problem``, ``_newton``) in :func:`_run`, which is
``voxflex.deform.solve.stepping.solve`` with that line and without the static
support check (a body resting on an obstacle is held by contact, not by
fixed DOFs).
"""

from __future__ import annotations

import numpy as np
import paths
import pytest

import voxflex as vf
from voxflex.deform.layers.contact import (
    ContactModel,
    barrier,
    collision_points,
    with_contact,
)
from voxflex.deform.layers.obstacles import Box, DistanceField, Plane, Sphere, obstacle
from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.deform.solve import stepping as _solvers
from voxflex.deform.solve.options import SolverOptions
from voxflex.deform.solve.stepping import ConvergenceError
from voxflex.errors import InputError
from voxflex.image.label_image import LabelImage


def _run(model, *, f, fixed=(), M=None, dt=0.01, steps=10, tolerance=1e-10, x_fixed=None):
    """States and velocities of a static (M None) or implicit-Euler run of ``model`` (see the module docstring)."""
    X = np.asarray(model.rest, dtype=float).ravel()
    N = X.size
    fixed = np.asarray(fixed, dtype=np.int64)
    free = np.setdiff1d(np.arange(N), fixed)
    opt = SolverOptions(kind="static" if M is None else "implicit-euler", dt=dt, steps=steps, tolerance=tolerance)
    reduce = _solvers._FreeBlock(free, N)
    x, v = X.copy(), np.zeros(N)
    xs, vs = [x.copy()], [v.copy()]
    for k in range(1, steps + 1):
        factor = k / steps
        if M is None:
            start = x.copy()
        else:
            xhat = x + dt * v
            start = xhat.copy()
            start[fixed] = x[fixed]
        moved = model.begin_step(factor, x, start)  # the solver's proposed line
        v_start = v if moved is start else (moved - x) / dt  # and its velocity bookkeeping
        start = moved
        if M is None:
            problem = _solvers._Problem(model, factor * f, start)
        else:
            problem = _solvers._Problem(model, f, start, M=M, h=dt, xhat=xhat, xn=x)
        target = X[fixed] if x_fixed is None else x_fixed(factor)
        delta, *_ = _solvers._newton(problem, np.zeros(N), free, fixed, target - start[fixed], opt, None,
                                     f"step {k}", reduce)
        x_new = start + delta
        if M is not None:
            v0 = v_start.copy()
            v0[fixed] = 0.0
            v = v0 + delta / dt
        x = x_new
        xs.append(x.copy())
        vs.append(v.copy())
    return np.array(xs), np.array(vs)


def _cube(n=2, h=0.1, z0=0.0, young=1e5, model="neo-hookean"):
    image = LabelImage(np.ones((n, n, n), dtype=np.uint8), spacing=(h,) * 3, origin=(0.0, 0.0, z0))
    return VoxelModel.from_image(image, {1: material(model, young=young, poisson=0.3)})


# ---------------------------------------------------------------------------
# the barrier and the obstacles
# ---------------------------------------------------------------------------
def test_barrier_derivatives_and_limits():
    dhat = 1e-3
    d = np.linspace(0.02, 0.98, 25) * dhat
    b, db, ddb = barrier(d, dhat)
    h = 1e-9 * dhat
    bp, dbp, _ = barrier(d + h, dhat)
    bm, dbm, _ = barrier(d - h, dhat)
    # central differences with h = 1e-9 dhat: truncation (h/d)^2 < 1e-13, round-off ~1e-16 b / h ~ 1e-7 relative
    np.testing.assert_allclose(db, (bp - bm) / (2 * h), rtol=1e-6)
    np.testing.assert_allclose(ddb, (dbp - dbm) / (2 * h), rtol=1e-6)
    assert np.all(b > 0) and np.all(db < 0) and np.all(ddb > 0)
    # C2 at dhat (all three vanish there and beyond), infinite at and below 0
    e = barrier(np.array([dhat * (1 - 1e-6), dhat, 2 * dhat, 0.0, -1e-3]), dhat)
    assert np.all(np.abs(e[0][:3]) < 1e-15) and np.all(np.abs(e[1][:3]) < 1e-10) and abs(e[2][0]) < 1e-2 / dhat
    assert np.all(e[0][1:3] == 0) and np.all(e[1][1:3] == 0) and np.all(e[2][1:3] == 0)
    assert np.all(np.isinf(e[0][3:]))


def _box_distance_brute(y, lo, hi):
    outside = np.linalg.norm(y - np.clip(y, lo, hi), axis=1)
    inside = np.min(np.concatenate([y - lo, hi - y], axis=1), axis=1)
    return np.where(outside > 0, outside, -inside)


def test_signed_distances_against_closed_forms():
    rng = np.random.default_rng(0)
    y = rng.uniform(-2, 2, (200, 3))
    d, _, _ = Plane(point=(0.1, 0.2, 0.3), normal=(0, 0, 2.0)).signed_distance(y)
    np.testing.assert_allclose(d, y[:, 2] - 0.3, atol=1e-15)
    d, _, _ = Sphere(center=(0.5, 0, 0), radius=0.7).signed_distance(y)
    np.testing.assert_allclose(d, np.linalg.norm(y - [0.5, 0, 0], axis=1) - 0.7, atol=1e-15)
    lo, hi = np.array([-0.5, -1.0, 0.0]), np.array([1.0, 0.5, 0.8])
    d, _, _ = Box(min=lo, max=hi).signed_distance(y)
    np.testing.assert_allclose(d, _box_distance_brute(y, lo, hi), atol=1e-14)


def test_distance_field_from_labels_is_exact_in_front_of_faces():
    # a slab [0, 2] x [0, 2] x [0, 1] voxelized at 0.25: in front of its top face the field is z - 1 exactly
    image = LabelImage(np.ones((8, 8, 4), dtype=np.uint8), spacing=(0.25,) * 3)
    field = DistanceField.from_labels(image)
    rng = np.random.default_rng(1)
    y = np.column_stack([rng.uniform(0.4, 1.6, 50), rng.uniform(0.4, 1.6, 50), rng.uniform(0.6, 1.4, 50)])
    d, g, _ = field.signed_distance(y)
    # trilinear interpolation of a linear function is exact: round-off only
    np.testing.assert_allclose(d, y[:, 2] - 1.0, atol=1e-12)
    np.testing.assert_allclose(g, np.tile([0.0, 0.0, 1.0], (50, 1)), atol=1e-12)
    # beyond the padded field the distance keeps growing (the field's box is 2 voxels around the image)
    far = field.signed_distance(np.array([[1.0, 1.0, 5.0]]))[0][0]
    assert far == pytest.approx(4.0, abs=1e-12)


@pytest.mark.parametrize("ob", [
    Plane(point=(0, 0, 0.1), normal=(1, 2, 3)),
    Sphere(center=(0.2, -0.1, 0.3), radius=0.4),
    Box(min=(-0.3, -0.2, -0.4), max=(0.1, 0.4, 0.2)),
    DistanceField.from_labels(LabelImage(np.pad(np.ones((3, 2, 3), np.uint8), 1), spacing=(0.2, 0.25, 0.3),
                                         origin=(-0.5, -0.4, -0.6))),
    Sphere(center=(0.2, -0.1, 0.3), radius=0.4, motion=[[0, -1, 0, 0.1], [1, 0, 0, 0.2], [0, 0, 1, -0.3]]),
], ids=["plane", "sphere", "box", "sdf", "moving-sphere"])
def test_distance_gradient_and_hessian_by_central_differences(ob):
    rng = np.random.default_rng(2)
    y = rng.uniform(-1, 1, (60, 3))
    s = 0.7
    d, g, H = ob.signed_distance(y, s)
    h = 1e-6
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        dp, gp, _ = ob.signed_distance(y + e, s)
        dm, gm, _ = ob.signed_distance(y - e, s)
        # truncation ~h^2 |d'''| (curvatures <= 1/(0.1 m)^2), round-off ~1e-16 / h; a point within h of a kink
        # (box edges, sdf cell faces) would differ by O(1): the random points avoid them at this seed
        np.testing.assert_allclose(g[:, k], (dp - dm) / (2 * h), atol=1e-7)
        np.testing.assert_allclose(H[:, :, k], (gp - gm) / (2 * h), atol=2e-6)


def test_motion_reaches_its_target_and_must_be_rigid():
    T = np.array([[0.0, -1.0, 0.0, 0.3], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, -0.2]])
    ob = Sphere(center=(1.0, 0.0, 0.0), radius=0.5, motion=T)
    # at fraction 1 the centre sits at R c + t = (0.3, 1, -0.2); halfway the rotation is 45 degrees
    x = np.array([[0.3, 1.0, -0.2 + 0.5]])
    assert ob.signed_distance(x, 1.0)[0][0] == pytest.approx(0.0, abs=1e-14)
    R, t = ob.pose(0.5)
    np.testing.assert_allclose(R @ [1, 0, 0], [np.sqrt(0.5), np.sqrt(0.5), 0], atol=1e-15)
    np.testing.assert_allclose(t, [0.15, 0, -0.1], atol=1e-15)
    with pytest.raises(InputError, match="rigid"):
        Plane(motion=[[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]])
    with pytest.raises(InputError, match="sphere radius"):
        obstacle("sphere", center=(0, 0, 0), radius=-1.0)
    with pytest.raises(InputError, match="no parameter"):
        obstacle("plane", center=(0, 0, 0))


# ---------------------------------------------------------------------------
# the collision layer
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("rule", ["surface", 1, 3, "vertices"])
def test_collision_points_cover_the_boundary(rule):
    model = _cube(n=2, h=0.1)
    pts, area = collision_points(model, rule)
    # a 0.2 m cube: boundary area 6 * 0.04 m^2 (exact sums of quadrature weights)
    assert area.sum() == pytest.approx(0.24, rel=1e-12)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    assert np.all(lo >= -1e-15) and np.all(hi <= 0.2 + 1e-15)
    # every point lies on the boundary: on a face of the cube
    on_face = np.any(np.isclose(pts, 0.0, atol=1e-15) | np.isclose(pts, 0.2, atol=1e-15), axis=1)
    assert np.all(on_face)


def test_contact_model_refuses_what_it_cannot_do():
    model = _cube(z0=0.0)
    with pytest.raises(InputError, match="friction must be a number >= 0"):
        Plane(point=(0, 0, -1e-3), normal=(0, 0, 1), friction=float("nan"))
    with pytest.raises(InputError, match="friction must be a number >= 0"):
        Plane(point=(0, 0, -1e-3), normal=(0, 0, 1), friction=-0.1)
    with pytest.raises(InputError, match="slip"):
        ContactModel(model, [Plane(point=(0, 0, -1e-3), normal=(0, 0, 1), friction=0.3)], slip=0.0)
    with pytest.raises(InputError, match="touches or enters"):
        ContactModel(model, [Plane(point=(0, 0, 0.05), normal=(0, 0, 1))])
    with pytest.raises(InputError, match="at least one obstacle"):
        ContactModel(model, [])
    cm = ContactModel(model, [Plane(point=(0, 0, -5e-4), normal=(0, 0, 1))])
    assert cm.distance == pytest.approx(1e-3) and cm.stiffness == pytest.approx(1e5)  # 1 % of h; largest E
    q = np.array(model.rest)
    q[:, 2] -= 1e-3  # every bottom point 0.5 mm below the plane
    assert cm.energy(q) == np.inf and cm.energy_gradient_hessian(q)[1] is None
    assert np.all(np.isnan(cm.contact_forces(q)))


def test_hessian_blocks_are_projected_only_where_curvature_makes_them_indefinite():
    model = _cube(n=2, h=0.1, z0=0.0)
    plane = ContactModel(model, [Plane(point=(0, 0, -5e-4), normal=(0, 0, 1))])
    q = np.array(model.rest)
    Hp = plane.energy_gradient_hessian(q)[2] - model.hessian(q)
    He = plane.energy_gradient_hessian(q, exact=True)[2] - model.hessian(q)
    assert abs(Hp - He).max() <= 1e-12 * abs(He).max()  # a plane's blocks are PSD already
    ball = ContactModel(model, [Sphere(center=(0.1, 0.1, -1.0005), radius=1.0)], distance=2e-3)
    Hp = (ball.energy_gradient_hessian(q)[2] - model.hessian(q)).toarray()
    He = (ball.energy_gradient_hessian(q, exact=True)[2] - model.hessian(q)).toarray()
    assert np.linalg.eigvalsh(He).min() < -1e-6 * np.abs(He).max()  # curvature: indefinite
    assert np.linalg.eigvalsh(Hp).min() > -1e-9 * np.abs(Hp).max()  # projected: PSD


# ---------------------------------------------------------------------------
# physics
# ---------------------------------------------------------------------------
def test_box_dropped_on_a_plane_comes_to_rest_without_penetration_or_energy_gain():
    h = 0.1
    inner = _cube(n=2, h=h, z0=0.01)  # 0.2 m cube 1 cm above the floor, E = 1e5 Pa
    model = ContactModel(inner, [Plane(point=(0, 0, 0), normal=(0, 0, 1))])  # dhat = 1 % of h
    dens, g = {1: 1000.0}, np.array([0.0, 0.0, -9.81])
    M = model.mass_matrix(dens)
    f = model.gravity_force(dens, g).ravel()
    weight = -f.sum()
    xs, vs = _run(model, f=f, M=M, dt=0.01, steps=60)
    z = np.array([model.mapping.apply(x.reshape(-1, 3))[:, 2].min() for x in xs])
    assert np.all(z > 0)  # no collision point ever reaches the floor
    assert z[-1] <= 0.01 * h  # gap at rest below 1 % of the voxel size (it lies in (0, dhat])
    assert z[10] < 0.01 * h  # it did land (free fall of 1 cm takes 0.045 s)
    # total energy: elastic + barrier + kinetic + gravity potential (-f.q, exact for mapped mass points);
    # backward Euler dissipates, so it may only drop: allow the round-off of the Newton tolerance (1e-9 J
    # of an ~8 J total) and nothing more
    total = np.array([model.energy(x.reshape(-1, 3)) + 0.5 * v @ M @ v - f @ x for x, v in zip(xs, vs)])
    assert np.all(np.diff(total) <= 1e-9)
    assert total[-1] < total[0] - 0.05  # the impact dissipated energy
    # discrete momentum balance of every step (the z rows of the step's residual summed: elastic forces
    # cancel): contact force = weight + sum_z M (v_n+1 - v_n) / h, to the Newton tolerance (1e-10 relative,
    # times sqrt(DOFs)); 1e-6 of the weight leaves margin
    for k in range(1, len(xs)):
        force = model.contact_forces(xs[k].reshape(-1, 3))[0]
        inertia = (M @ (vs[k] - vs[k - 1]))[2::3].sum() / 0.01
        assert force[2] == pytest.approx(weight + inertia, abs=1e-6 * weight)
        assert np.abs(force[:2]).max() < 1e-9 * weight
    # at rest (velocity below 1e-6 m/s): the floor carries the weight up to the last ringing (1e-4)
    assert np.abs(vs[-1]).max() < 1e-6
    assert force[2] == pytest.approx(weight, rel=1e-4)


@pytest.mark.parametrize("project", [True, False])
def test_static_box_on_a_plane_carries_its_weight(project):
    h = 0.1
    inner = _cube(n=2, h=h, z0=5e-4)  # resting inside the barrier's range (dhat = 1e-3)
    model = ContactModel(inner, [Plane(point=(0, 0, 0), normal=(0, 0, 1))], project=project)
    f = model.gravity_force({1: 1000.0}, (0.0, 0.0, -9.81)).ravel()
    # hold x and y of one vertical edge and y of the next one: the in-plane rigid motions; the plane carries z
    edge = inner.nodes_in_box((-1, -1, -1), (1e-9, 1e-9, 1))
    other = inner.nodes_in_box((0.2 - 1e-9, -1, -1), (1, 1e-9, 1))
    fixed = np.sort(np.concatenate([(3 * edge[:, None] + np.array([0, 1])).ravel(), 3 * other + 1]))
    xs, _ = _run(model, f=f, fixed=fixed, steps=1, tolerance=1e-10)
    force = model.contact_forces(xs[-1].reshape(-1, 3))[0]
    # sum of the z residuals = contact force - weight (elastic forces sum to zero): bounded by the
    # Newton tolerance 1e-10 relative to the weight times sqrt(DOFs) ~ 1e-9, inside 1e-6
    assert force[2] == pytest.approx(-f.sum(), rel=1e-6)
    assert model.mapping.apply(xs[-1].reshape(-1, 3))[:, 2].min() > 0


def test_moving_sphere_indents_a_clamped_block():
    """A sphere moved down onto a block clamped at its base: begin_step carries the block along with
    the sphere when the previous state is inside the sphere's new position; the barrier keeps every
    point outside at every step and the force grows monotonically.  The sphere starts 2 mm above the top face,
    beyond the barrier's 1 mm (at 0.1 mm, as before the drawn triangles collided, the face's centre was within
    the barrier at rest: the unsolved rest state carried a force of 306 N)."""
    h = 0.1
    inner = _cube(n=3, h=h, young=1e4, model="hooke")
    R = 0.5
    sphere = Sphere(center=(0.15, 0.15, 0.3 + R + 2e-3), radius=R, motion=[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, -0.012]])
    model = ContactModel(inner, [sphere], distance=1e-3)
    base = inner.nodes_in_box((-1, -1, -1), (1, 1, 1e-9))
    fixed = np.sort((3 * base[:, None] + np.arange(3)).ravel())
    xs, _ = _run(model, f=np.zeros(inner.rest.size), fixed=fixed, steps=5)
    forces = np.array([model.contact_forces(x.reshape(-1, 3), fraction=k / 5)[0] for k, x in enumerate(xs)])
    for k, x in enumerate(xs):
        d = sphere.signed_distance(model.mapping.apply(x.reshape(-1, 3)), k / 5)[0]
        assert d.min() > 0
    assert np.all(np.diff(forces[:, 2]) < 0)  # pushed down harder each step
    # symmetry of the set-up about the block's vertical mid-planes: no net horizontal force
    assert np.abs(forces[-1, :2]).max() < 1e-8 * abs(forces[-1, 2])


def test_begin_step_refuses_an_impossible_start():
    inner = _cube(n=2, h=0.1)
    cm = ContactModel(inner, [Plane(point=(0, 0, -5e-4), normal=(0, 0, 1)),
                              Plane(point=(0, 0, 0.2005), normal=(0, 0, -1), motion=[[1, 0, 0, 0], [0, 1, 0, 0],
                                                                                     [0, 0, 1, -0.05]])])
    q = np.asarray(inner.rest, dtype=float).ravel()
    with pytest.raises(ConvergenceError, match="no admissible start"):
        cm.begin_step(1.0, q, q)  # the lid comes down 5 cm while the floor stays: no carry can help


# ---------------------------------------------------------------------------
# frames
# ---------------------------------------------------------------------------
def test_affine_frames_rest_on_a_plane_with_their_weight():
    from voxflex.deform.models.frames.model import FrameModel
    from voxflex.voronoi.shape_functions import shepard

    frames = np.array([[0.05, 0.05, 0.05], [0.15, 0.15, 0.05], [0.1, 0.1, 0.15], [0.15, 0.05, 0.15]])
    image = LabelImage(np.ones((2, 2, 2), dtype=np.uint8), spacing=(0.1,) * 3, origin=(0.0, 0.0, 5e-4))
    frames = frames + [0, 0, 5e-4]

    def sf(points):
        return shepard(np.asarray(points, dtype=float), frames, n_parents=4)

    inner = FrameModel.from_image(image, frames, sf, {1: material("neo-hookean", young=1e5, poisson=0.3)})
    model = ContactModel(inner, [Plane(point=(0, 0, 0), normal=(0, 0, 1))])
    f = model.gravity_force({1: 1000.0}, (0.0, 0.0, -9.81)).ravel()
    weight = 1000.0 * 9.81 * 0.2**3
    # the frames' translations in x and y and the in-plane rotation: hold t_x, t_y of every frame and A's
    # first two rows of frame 0 (an affine body needs more than a rigid one)
    fixed = np.sort(np.concatenate([12 * np.arange(4)[:, None] + np.array([9, 10]), [[0, 1, 2, 3, 4, 5]]], axis=None))
    xs, _ = _run(model, f=f, fixed=fixed, steps=1, tolerance=1e-10)
    force = model.contact_forces(xs[-1].reshape(4, 12))[0]
    # gravity reaches the frames through J^T at the mass points: its z part sums to the weight exactly
    assert f[11::12].sum() == pytest.approx(-weight, rel=1e-12)
    assert force[2] == pytest.approx(weight, rel=1e-6)
    assert model.mapping.apply(xs[-1].reshape(4, 12))[:, 2].min() > 0


# ---------------------------------------------------------------------------
# scene wiring
# ---------------------------------------------------------------------------
def _scene(obstacles=(), **solver):
    from voxflex.scene import (
        ContactSpec,
        FixedSpec,
        LoadSpec,
        MaterialSpec,
        NodesSpec,
        ObjectSpec,
        ObstacleSpec,
        Scene,
        SolverSpec,
    )

    return Scene(
        object=ObjectSpec(shape="box", size=(0.4, 0.1, 0.1), voxel_size=0.05, origin=(0.0, 0.0, 0.01)),
        nodes=NodesSpec(kind="voxel"),
        materials=(MaterialSpec(model="neo-hookean", young=2e4, poisson=0.3, density=1000.0),),
        fixed=(FixedSpec(max=(1e-9, 1.0, 1.0)),),
        loads=(LoadSpec(kind="gravity"),),
        obstacles=tuple(ObstacleSpec(**o) for o in obstacles),
        contact=ContactSpec(distance=5e-4),
        solver=SolverSpec(**solver),
    )


def test_with_contact_leaves_a_scene_without_obstacles_alone():
    scene = _scene()
    model = vf.model(scene)
    assert with_contact(model, scene) is model


def test_simulate_a_cantilever_sagging_onto_a_plane():
    """A clamped bar sags under gravity onto a floor 1 cm below it: vf.simulate with the wrapped model
    (no hook needed: the start is the rest state and the floor does not move) matches the stepped run
    and keeps the bar above the floor; the floor carries part of the weight."""
    scene = _scene([dict(kind="plane", point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0))], steps=4,
                   tolerance=1e-10)
    model = with_contact(vf.model(scene), scene)
    assert isinstance(model, ContactModel) and model.distance == 5e-4
    result = vf.simulate(scene, model=model, progress=False)
    q = result.nodes_state[-1]
    z = model.mapping.apply(q)[:, 2]
    assert z.min() > 0 and z.min() < 5e-4  # landed, not through
    force = model.contact_forces(q, fraction=1.0)[0]
    weight = 1000.0 * 9.81 * 0.4 * 0.1 * 0.1
    assert 0 < force[2] < weight
    fixed = np.flatnonzero(np.isin(np.arange(q.size) // 3, model.nodes_in_box((-1, -1, -1), (1e-9, 1, 1))))
    f = model.gravity_force({1: 1000.0}, (0.0, 0.0, -9.81)).ravel()
    xs, _ = _run(model, f=f, fixed=fixed, steps=4, tolerance=1e-10)
    np.testing.assert_allclose(xs[-1], q.ravel(), atol=1e-9)  # same Newton, same tolerance


def test_simulate_drop_through_the_solver_hook():
    from dataclasses import replace

    scene = _scene([dict(kind="plane", point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0))], kind="implicit-euler",
                   dt=0.01, steps=30)
    scene = replace(scene, fixed=())
    model = with_contact(vf.model(scene), scene)
    result = vf.simulate(scene, model=model, progress=False)
    z = np.array([model.mapping.apply(q)[:, 2].min() for q in result.nodes_state])
    assert np.all(z > 0) and z[-1] < 5e-4


# ---------------------------------------------------------------------------
# example scenes (run through the stepped loop until the solver calls begin_step)
# ---------------------------------------------------------------------------
def _example(name):

    from voxflex.scene import Scene

    return Scene.from_toml(paths.ROOT / "examples" / f"{name}.toml")


def test_example_ball_on_plane():
    scene = _example("ball_on_plane")
    model = with_contact(vf.model(scene), scene)
    dens = {1: 1000.0}
    M = model.mass_matrix(dens)
    f = model.gravity_force(dens, scene.gravity).ravel()
    xs, vs = _run(model, f=f, M=M, dt=scene.solver.dt, steps=scene.solver.steps, tolerance=1e-10)
    z = np.array([model.mapping.apply(x.reshape(-1, 3))[:, 2].min() for x in xs])
    assert np.all(z > 0) and 0 < z[-1] < 1e-3  # never through; resting inside the barrier's 1 mm
    force = model.contact_forces(xs[-1].reshape(-1, 3))[0]
    # the number in the example: voxelized volume 0.0625 m^3 x 1000 x 9.81 = 613.125 N, carried by the floor
    # up to the inertia of the last step (the discrete momentum balance, exact to the Newton tolerance)
    inertia = (M @ (vs[-1] - vs[-2]))[2::3].sum() / scene.solver.dt
    assert -f.sum() == pytest.approx(613.125, rel=1e-12)
    assert force[2] == pytest.approx(613.125 + inertia, abs=1e-6 * 613.125)
    assert abs(inertia) < 0.01 * 613.125  # nearly at rest after 1 s


def test_example_pushed_block():
    scene = _example("pushed_block")
    model = with_contact(vf.model(scene), scene)
    fixed = model.held_dofs(scene.fixed[0].min, scene.fixed[0].max, "xyz")
    xs, _ = _run(model, f=np.zeros(model.rest.size), fixed=fixed, steps=scene.solver.steps, tolerance=1e-8)
    forces = np.array([model.contact_forces(x.reshape(-1, 3), fraction=k / 5)[0] for k, x in enumerate(xs)])
    sphere = model.obstacles[0]
    for k, x in enumerate(xs):
        assert sphere.signed_distance(model.mapping.apply(x.reshape(-1, 3)), k / 5)[0].min() > 0
    # symmetric about the block's vertical mid-planes: the force is vertical, and grows with the indentation
    # faster than linearly (Hertz: F ~ delta^1.5; the contact area grows)
    assert np.abs(forces[-1, :2]).max() < 1e-8 * abs(forces[-1, 2])
    fz = -forces[1:, 2]
    assert np.all(np.diff(fz) > 0) and fz[-1] / fz[-2] > 5 / 4
    top = model.point_mapping(np.array([scene.probes[0].point])).apply(xs[-1].reshape(-1, 3))[0, 2]
    # the top centre follows the sphere down by at least the indentation less dhat.  It is a voxel corner,
    # not a collision point (those are the faces' Gauss points): between them the surface may pass the
    # sphere; here by 0.45 mm (0.9 % of the voxel size), bounded below by 1 mm
    assert 0.4 - 0.00505 - 1e-3 < top < 0.4 - 0.0049
