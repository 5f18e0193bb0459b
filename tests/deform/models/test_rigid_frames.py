"""Rigid frames ([nodes] kind = "rigid"): 6-DOF frames, the affine frame model restricted to rotations.

Oracles: central finite differences (rotation derivatives, gradient, Hessian
with its geometric stiffness), Rodrigues' formula of voxflex.deform.chain.nodes
(an independent implementation of R), exact rigid motions (zero energy,
points moved by the rigid map), the linearity of the gravity potential in the
state, minimisation over a subspace (rigid frames are a subset of the affine
frames' motions, so their equilibrium potential is not lower).

Tolerances: as in test_frame_model.py, central differences with h = 1e-6 on
energies of order 1e1 have truncation ~1e-12 and round-off ~1e-10 relative;
1e-6 leaves margin and still catches any wrong or missing term (those give
O(1e-2..1) errors: the geometric stiffness alone is checked to matter).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pytest

import voxflex as vf
from voxflex.deform.chain.nodes import rotation_exp, skew
from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.rigid.model import (
    RigidFrameModel,
    rotation_derivatives,
    wrap_rotation_vectors,
)
from voxflex.errors import InputError
from voxflex.image.label_image import LabelImage
from voxflex.result import Result
from voxflex.scene import (
    ElasticitySpec,
    FixedSpec,
    LoadSpec,
    MaterialSpec,
    NodesSpec,
    ObjectSpec,
    ProbeSpec,
    Scene,
    SolverSpec,
)
from voxflex.voronoi.shape_functions import shepard

FRAMES = np.array([[0.25, 0.5, 0.5], [1.5, 0.25, 0.25], [1.5, 0.75, 0.75], [2.75, 0.5, 0.5], [2.0, 0.5, 0.9]])


@dataclass(frozen=True, eq=False)
class ShepardSF:
    """Hand-made shape functions (Shepard weights over the frames, a partition of unity)."""

    image: object
    frames: np.ndarray
    parents: int = 5

    def __call__(self, points):
        return shepard(np.asarray(points, dtype=float), self.frames, n_parents=min(self.parents, len(self.frames)))

    def voxel_values(self):
        ijk = np.argwhere(self.image.labels > 0)
        return self(self.image.index_to_world(ijk + 0.5))


def _model(mat, quadrature="midpoint"):
    image = LabelImage(np.ones((6, 2, 2), dtype=np.uint8), spacing=(0.5, 0.5, 0.5))
    sf = ShepardSF(image, FRAMES)
    samples = vf.sample(image, sf, kind=quadrature, count=40) if quadrature != "gauss-legendre" else None
    return RigidFrameModel.from_image(image, FRAMES, sf, {1: mat}, samples=samples, quadrature=quadrature)


def _turn(angle, axis=(1.0, 2.0, -0.5), t=(0.3, -0.2, 0.4)):
    axis = np.asarray(axis) / np.linalg.norm(axis)
    return np.hstack([rotation_exp(angle * axis[None])[0], np.asarray(t, dtype=float)[:, None]])


def test_rotation_and_its_derivatives():
    """R equals Rodrigues' formula of nodes.py (1e-15); dR and d2R equal central differences of R
    and dR (h = 1e-6: error ~1e-10 on entries of order 1; 1e-8 asserted), in the series branch
    (|theta| < 1), the closed forms and near 2 pi; d2R is symmetric in (i, j)."""
    rng = np.random.default_rng(0)
    h = 1e-6
    for scale in (1e-7, 1e-2, 0.5, 2.0, 6.0):
        th = rng.standard_normal((5, 3))
        th *= scale / np.linalg.norm(th, axis=1, keepdims=True) * rng.uniform(0.8, 1.2, (5, 1))
        R, dR, d2R = rotation_derivatives(th)
        assert np.abs(R - rotation_exp(th)).max() <= 1e-15 * max(1.0, scale)
        for i in range(3):
            e = np.zeros(3)
            e[i] = h
            Rp, dRp, _ = rotation_derivatives(th + e, second=False)
            Rm, dRm, _ = rotation_derivatives(th - e, second=False)
            assert np.abs((Rp - Rm) / (2 * h) - dR[:, i]).max() < 1e-8, scale
            assert np.abs((dRp - dRm) / (2 * h) - d2R[:, i]).max() < 1e-8, scale
        assert np.array_equal(d2R, d2R.transpose(0, 2, 1, 3, 4))
    # at theta = 0: dR_i = [e_i]x, d2R_ij = (E_i E_j + E_j E_i) / 2
    _, dR, d2R = rotation_derivatives(np.zeros((1, 3)))
    E = skew(np.eye(3))
    assert np.abs(dR[0] - E).max() < 1e-16
    assert np.abs(d2R[0] - 0.5 * (np.einsum("irk,jkc->ijrc", E, E) + np.einsum("jrk,ikc->ijrc", E, E))).max() < 1e-16


def test_wrap_keeps_the_rotation():
    """Rotation vectors longer than pi become |theta| <= pi with the same R (1e-14); shorter ones are untouched."""
    axis = np.array([[0.6, -0.8, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 1.0], [0.3, 0.1, -0.2]])
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    th = axis * np.array([[2 * np.pi - 0.1], [5.0], [9.0], [3.0]])
    w = wrap_rotation_vectors(th)
    assert np.all(np.linalg.norm(w, axis=1) <= np.pi + 1e-15)
    assert np.abs(rotation_exp(w) - rotation_exp(th)).max() < 1e-14
    assert np.array_equal(w[3], th[3])
    model = _model(material("neo-hookean", young=1e3, poisson=0.3))
    q = model.moved_state(_turn(0.4))
    assert model.begin_step(1.0, q, q) is q  # nothing to wrap: the very object
    q[:, 3:] = th[1] * (1 + 0.01 * np.arange(5))[:, None]
    moved = model.begin_step(1.0, q, q)
    assert np.all(np.linalg.norm(moved[:, 3:], axis=1) <= np.pi)
    assert np.abs(model.affine_state(moved) - model.affine_state(q)).max() < 1e-13
    assert model.energy(moved) == pytest.approx(model.energy(q), rel=1e-12)


CASES = [("neo-hookean", {}, "midpoint", 0.5), ("neo-hookean", {}, "midpoint", 1e-7),
         ("stvk", {}, "elaston", 0.5), ("hooke", {"strain": "corotational"}, "gauss-legendre", 0.5)]


@pytest.mark.parametrize("name, kw, quadrature, angle", CASES)
def test_gradient_and_hessian_against_finite_differences(name, kw, quadrature, angle):
    """The body turned by ``angle`` about a skew axis (rotation vectors of that size, the series branch
    for 1e-7) and every frame perturbed (positions 1e-2 m, rotations 5e-2 rad, 1e-8 rad with the tiny angle)."""
    model = _model(material(name, young=1e3, poisson=0.3, **kw), quadrature)
    rng = np.random.default_rng(3)
    q = model.moved_state(_turn(angle))
    q[:, :3] += 1e-2 * rng.standard_normal((5, 3))
    q[:, 3:] += min(5e-2, 0.1 * angle) * rng.standard_normal((5, 3))
    E, g, H = model.energy_gradient_hessian(q)
    assert E > 0
    H = H.toarray() if hasattr(H, "toarray") else H
    d = rng.standard_normal(q.shape)
    h = 1e-6
    fd = (model.energy(q + h * d) - model.energy(q - h * d)) / (2 * h)
    assert fd == pytest.approx(float((g * d).sum()), rel=1e-6)
    gd = (model.gradient(q + h * d) - model.gradient(q - h * d)) / (2 * h)
    Hd = (H @ d.ravel()).reshape(q.shape)
    assert np.max(np.abs(gd - Hd)) <= 1e-6 * np.max(np.abs(Hd))
    assert np.abs(H - H.T).max() <= 1e-12 * np.abs(H).max()
    # the geometric stiffness matters here: without it the same check fails by far more than 1e-6
    _, g12, H12 = model.inner.energy_gradient_hessian(model.affine_state(q))
    J = model.jacobian(q)
    Hm = J.T @ (H12 @ J.toarray() if not hasattr(H12, "toarray") else (H12 @ J).toarray())
    assert np.max(np.abs(gd - (Hm @ d.ravel()).reshape(q.shape))) > 1e-4 * np.max(np.abs(Hd))


def test_rigid_motion_costs_nothing_and_moves_points_exactly():
    """Every frame moved by one rigid map (1 rad about a skew axis and a translation): energy and
    gradient vanish to round-off (1e-9 J and N against a Hessian of order 1e3) and probes and
    the surface follow the map to 1e-10 m."""
    model = _model(material("neo-hookean", young=1e3, poisson=0.3))
    T = _turn(1.0)
    q = model.moved_state(T)
    assert np.abs(q[:, 3:] - q[0, 3:]).max() == 0 and np.linalg.norm(q[0, 3:]) == pytest.approx(1.0, rel=1e-14)
    E, g, _ = model.energy_gradient_hessian(q, hessian=False)
    assert abs(E) < 1e-9 and np.abs(g).max() < 1e-9
    pts = np.array([[0.1, 0.1, 0.1], [2.9, 0.9, 0.9], [1.3, 0.4, 0.6]])
    assert np.abs(model.point_mapping(pts).apply(q) - (pts @ T[:, :3].T + T[:, 3])).max() < 1e-10
    V, _, surf = model.boundary_surface()
    assert np.abs(surf.apply(q) - (V @ T[:, :3].T + T[:, 3])).max() < 1e-10
    with pytest.raises(InputError, match="not a rotation"):
        model.moved_state([[1.1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]])


def test_rigid_modes_are_the_motions_of_the_body_and_cost_nothing():
    """rigid_modes equal the derivative of moved_state along the six rigid motions (central
    differences, 1e-8) and lie in the null space of the rest Hessian (1e-9 of its largest entry)."""
    model = _model(material("neo-hookean", young=1e3, poisson=0.3))
    B = model.rigid_modes()
    c = model.origins.mean(axis=0)
    h = 1e-6
    for k in range(6):
        def moved(eps):
            w = np.zeros(3)
            t = np.zeros(3)
            if k < 3:
                t[k] = eps
            else:
                w[k - 3] = eps
            R = rotation_exp(w[None])[0]
            return model.moved_state(np.hstack([R, (c - R @ c + t)[:, None]])).ravel()
        assert np.abs((moved(h) - moved(-h)) / (2 * h) - B[:, k]).max() < 1e-8
    H = model.hessian(model.rest)
    assert np.abs(H @ B).max() < 1e-9 * np.abs(H).max()


def test_gravity_is_exact_for_any_rotation_and_dynamics_are_refused():
    """The reference points are the frames' mass centres, so the gravity potential
    -f12 . q12(q6) is linear in q6: its central differences at a turned, perturbed state equal the
    constant generalised force (1e-8 relative); the force carries the weight (1e-12)."""
    model = _model(material("neo-hookean", young=1e3, poisson=0.3))
    g = np.array([0.0, -3.0, -9.81])
    f6 = model.gravity_force({1: 2.0}, g)
    f12 = model.inner.gravity_force({1: 2.0}, g)
    mass = 2.0 * 3.0 * 1.0 * 1.0
    assert np.allclose(f6[:, :3].sum(axis=0), mass * g, rtol=1e-12)
    rng = np.random.default_rng(5)
    q = model.moved_state(_turn(1.2)) + 0.1 * rng.standard_normal((5, 6))
    d = rng.standard_normal(q.shape)
    h = 1e-6
    work = lambda x: float((f12 * model.affine_state(x)).sum())  # noqa: E731
    assert (work(q + h * d) - work(q - h * d)) / (2 * h) == pytest.approx(float((f6 * d).sum()), rel=1e-8)
    # with the frames' positions as reference points it would not be: their first moments are not zero
    assert np.abs(model.origins - model.frames).max() > 1e-2
    with pytest.raises(InputError, match='kind = "affine" for dynamics'):
        model.mass_matrix({1: 1.0})


def test_held_dofs_and_what_one_component_means():
    """A clamp holds p and theta of the frames in it; a sliding support "x" holds p_x, theta_y and
    theta_z: whatever the free DOFs do, the x coordinate of every point that frame moves stays put."""
    model = _model(material("neo-hookean", young=1e3, poisson=0.3))
    lo, hi = (-1.0, -1.0, -1.0), (0.3, 2.0, 2.0)  # holds frame 0 only
    assert model.held_dofs(lo, hi, "xyz").tolist() == list(range(6))
    assert model.held_dofs(lo, hi, "xz").tolist() == [0, 2, 3, 4, 5]
    held = model.held_dofs(lo, hi, "x")
    assert held.tolist() == [0, 4, 5]
    rng = np.random.default_rng(7)
    q = model.rest.copy()
    free = np.setdiff1d(np.arange(6), held)
    q[0, free] += rng.standard_normal(len(free))
    A = model.affine_state(q)[0]
    X = np.array([[0.1, 0.9, 0.3], [0.4, 0.2, 0.8]])  # points under frame 0 alone: R (X - X_0) + t_0
    x = (X - FRAMES[0]) @ A[:9].reshape(3, 3).T + A[9:]
    assert np.abs(x[:, 0] - X[:, 0]).max() < 1e-14 and np.abs(x[:, 1:] - X[:, 1:]).max() > 1e-2


# -- scenes ------------------------------------------------------------------------------------------
def _cantilever(kind, h=0.25, count=10, **kw):
    """The neo-Hooke cantilever [0,4]x[0,1]x[0,1], E = 1e3, nu = 0.3, rho g = 9.81, clamped at x = 0."""
    return Scene(object=ObjectSpec(shape="box", size=(4.0, 1.0, 1.0), voxel_size=h, origin=(0.0, 0.0, 0.0)),
                 materials=(MaterialSpec(model="neo-hookean", young=1e3, poisson=0.3, density=1.0),),
                 nodes=NodesSpec(kind=kind, count=None if kind == "voxel" else count),
                 elasticity=ElasticitySpec(quadrature="gauss-legendre" if kind == "voxel" else "midpoint",
                                           samples=None if kind == "voxel" else 200),
                 fixed=(FixedSpec(max=(1e-6, 1e9, 1e9)),),
                 loads=(LoadSpec(kind="gravity", vector=(0.0, 0.0, -9.81)),),
                 solver=SolverSpec(steps=4), probes=(ProbeSpec("tip", (4.0, 0.5, 0.5)),), **kw)


def test_cantilever_rigid_against_affine_frames_and_voxels(capsys):
    """16x4x4, 10 frames, 200 mid-point samples.  Rigid frames converge, the tip moves down, and
    their equilibrium total potential E - f . (q - rest) is not below the affine frames' (the same
    frames and samples: rigid motions of the frames are a subset of the affine ones, so the minimum
    over them is not lower; 1e-9 relative slack for round-off).  Tip displacements are printed."""
    tips, pots = {}, {}
    for kind in ("rigid", "affine", "voxel"):
        scene = _cantilever(kind)
        model = vf.model(scene)
        r = vf.simulate(scene, progress=False, model=model)
        assert r.complete and r.n_steps == 4
        tips[kind] = r.probe_displacements()["tip"]
        if kind != "voxel":
            q = r.nodes_state[-1]
            f = model.gravity_force({1: 1.0}, np.array([0.0, 0.0, -9.81]))
            pots[kind] = model.energy(q) - float((f * (q - model.rest)).sum())
    with capsys.disabled():
        print("\nneo-Hooke cantilever 16x4x4, tip displacement (m): "
              + ", ".join(f"{k} {np.round(v, 4).tolist()}" for k, v in tips.items()))
    assert tips["rigid"][2] < -0.5
    assert pots["rigid"] >= pots["affine"] - 1e-9 * abs(pots["affine"])
    assert vf.model(_cantilever("rigid")).describe()["dofs"] == 60


def test_scene_refusals():
    base = _cantilever("rigid", h=0.5, count=4)
    with pytest.raises(InputError, match='kind = "affine" for dynamics'):
        vf.model(replace(base, solver=SolverSpec(kind="implicit-euler", steps=2, dt=0.01)))
    with pytest.raises(InputError, match="gravity loads only"):
        vf.model(replace(base, loads=(LoadSpec(kind="force", vector=(0, 0, -1.0), min=(3.9, -1, -1)),)))
    turn = tuple(map(tuple, _turn(0.3, axis=(0, 0, 1))))
    with pytest.raises(InputError, match="not about the x axis"):
        vf.model(replace(base, fixed=(FixedSpec(max=(1e-6, 1e9, 1e9), components="x", transform=turn),)))


def test_cli_simulate_info_render_of_a_rigid_scene(tmp_path, capsys):
    """`voxflex simulate` of a small rigid-frame scene (turned at one end) writes a result with 6
    numbers per frame that `voxflex info` and `voxflex render` accept, and a ParaView series."""
    from voxflex.cli import main

    turn = tuple(map(tuple, _turn(0.5, axis=(1, 0, 0), t=(0.0, 0.0, 0.0))))
    scene = _cantilever("rigid", h=0.5, count=4)
    scene = replace(scene, loads=(), fixed=scene.fixed + (FixedSpec(min=(4 - 1e-6, -1e9, -1e9), transform=turn),))
    path = tmp_path / "rigid.toml"
    path.write_text(scene.to_toml())
    out = tmp_path / "rigid.h5"
    assert main(["simulate", str(path), "-o", str(out), "--quiet", "--vtk", str(tmp_path / "vtk")]) == 0
    r = Result.load(out)
    assert r.node_kind == "rigid" and r.nodes_state.shape == (5, 4, 6) and r.model["dofs"] == 24
    assert np.abs(r.nodes_state[-1][:, 3:]).max() > 0.1  # the frames at the turned end rotated
    assert (tmp_path / "vtk" / "result.pvd").exists()
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    assert "4 rigid frames, 24 DOF" in capsys.readouterr().out
    png = tmp_path / "rigid.png"
    if main(["render", str(out), "-o", str(png)]) != 0:
        pytest.skip("offscreen rendering unavailable here (see test_render.py)")
    assert png.stat().st_size > 1000
