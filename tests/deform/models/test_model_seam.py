"""The model seam: solvers, loads, results and renders run any model of the protocol.

Two models that are not the voxel model go through ``vf.simulate``, the
result file and ``voxflex render`` with no change to those modules:

* a frame model with hand-made (Shepard) weights: 12 DOF per node, a state
  that is not a list of positions;
* the voxel model seen through a change of units (state in millimetres):
  every number of the result must equal the voxel model's, so nothing on the
  way may assume that the state is the node positions in metres.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import paths
import pytest

import voxflex as vf
from voxflex.build import build_image
from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.frames.model import FrameModel
from voxflex.deform.models.protocol import Model, PointMap
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.result import Result
from voxflex.scene import FixedSpec, LoadSpec, ProbeSpec, Scene
from voxflex.voronoi.shape_functions import shepard

EXAMPLES = paths.ROOT / "examples"
FRAMES = np.array([[0.0, 0.5, 0.5], [1.0, 0.5, 0.5], [2.0, 0.5, 0.5], [3.0, 0.5, 0.5], [4.0, 0.5, 0.5]])


def _scene() -> Scene:
    return Scene.from_toml(EXAMPLES / "cantilever.toml")  # 8x2x2 voxels, linear Hooke, gravity, clamp at x = 0


def _frame_model(scene: Scene) -> FrameModel:
    image = build_image(scene)
    mats = {1: material("hooke", young=1e4, poisson=0.3, strain="linear")}
    return FrameModel.from_image(image, FRAMES, lambda p: shepard(p, FRAMES), mats)


class MillimetreModel:
    """The voxel model with its state in millimetres: q_mm = 1000 q (a linear change of variables)."""

    S = 1000.0

    def __init__(self, inner: VoxelModel):
        import dataclasses

        self.inner = inner
        self.image = inner.image
        self.materials = inner.materials
        self.dof_grid = inner.dof_grid  # an optional capability (OnVoxelGrid): multigrid may use it
        self.kind = dataclasses.replace(inner.kind, name="voxel-mm", noun="millimetre node", plural="millimetre nodes")
        self.node_kind = self.kind.name
        self.dofs_per_node = 3
        self.rest = inner.rest * self.S

    supported_by_contact = False
    n_nodes = property(lambda self: self.inner.n_nodes)

    def begin_step(self, fraction, q_prev, q_start):
        return q_start

    constant_tangent = property(lambda self: self.inner.constant_tangent)

    def describe(self):
        return {"node_kind": self.node_kind, "units": "mm"}

    def advice(self):
        return ""

    def energy(self, q):
        return self.inner.energy(q / self.S)

    def energy_gradient_hessian(self, q, *, gradient=True, hessian=True):
        E, g, H = self.inner.energy_gradient_hessian(q / self.S, gradient=gradient, hessian=hessian)
        return E, None if g is None else g / self.S, None if H is None else H / self.S**2

    def gradient(self, q):
        return self.inner.gradient(q / self.S) / self.S

    def hessian(self, q):
        return self.inner.hessian(q / self.S) / self.S**2

    def mass_matrix(self, densities, *, lumped=True):
        return self.inner.mass_matrix(densities, lumped=lumped) / self.S**2

    def gravity_force(self, densities, g):
        return self.inner.gravity_force(densities, g) / self.S

    def rigid_modes(self):
        return self.inner.rigid_modes()

    def point_mapping(self, points):
        return _Scaled(self.inner.point_mapping(points), self.S)

    def boundary_surface(self):
        V, F, pm = self.inner.boundary_surface()
        return V, F, _Scaled(pm, self.S)

    def load_surface(self, order=2):
        return self.inner.load_surface(order)

    def node_points(self, q):
        return None

    def volume_points(self):
        return self.inner.volume_points()

    def held_dofs(self, lo, hi, components):
        return self.inner.held_dofs(lo, hi, components)

    def parts(self):
        return self.inner.parts()

    def sample_fields(self, q):
        return self.inner.sample_fields(q / self.S)

    def moved_state(self, transform):
        return self.inner.moved_state(transform) * self.S


class _Scaled:
    def __init__(self, pm, S):
        self.pm, self.S = pm, S

    def apply(self, q):
        return self.pm.apply(q / self.S)

    def vjp(self, q, f):
        return self.pm.vjp(q / self.S, f) / self.S


def test_both_models_satisfy_the_protocol():
    scene = _scene()
    voxel = vf.model(scene)
    frames = _frame_model(scene)
    for m in (voxel, frames, MillimetreModel(voxel)):
        assert isinstance(m, Model)
        assert isinstance(m.point_mapping(np.array([[1.0, 0.5, 0.5]])), PointMap)
    assert (voxel.node_kind, voxel.dofs_per_node, frames.node_kind, frames.dofs_per_node) == ("voxel", 3, "affine", 12)


def test_a_change_of_variables_gives_the_same_result(tmp_path):
    """Gravity, a clamp, a moved region and a traction through the millimetre model: every
    surface and probe position equals the voxel model's to 1e-12 relative (the solver sees a
    rescaled system, so only round-off differs)."""
    scene = _scene()
    scene = replace(
        scene,
        fixed=scene.fixed + (FixedSpec(min=(3.9, -1, -1), max=(5, 2, 2), components="y",
                                       transform=((1, 0, 0, 0), (0, 1, 0, 0.05), (0, 0, 1, 0))),),
        loads=scene.loads + (LoadSpec(kind="traction", vector=(0.0, 0.0, -2.0), min=(2.0, -1, 0.99), max=(4, 2, 2)),),
        probes=scene.probes + (ProbeSpec("mid", (2.0, 0.0, 1.0)),),
    )
    ref = vf.simulate(scene, progress=False)
    mm = vf.simulate(scene, progress=False, model=MillimetreModel(vf.model(scene)), output=tmp_path / "mm.h5")
    scale = np.abs(ref.surface_positions).max()
    assert np.allclose(mm.surface_positions, ref.surface_positions, rtol=0, atol=1e-12 * scale)
    for name in ref.probes:
        assert np.allclose(mm.probes[name], ref.probes[name], rtol=0, atol=1e-12 * scale)
    assert mm.node_kind == "voxel-mm" and mm.model == {"node_kind": "voxel-mm", "units": "mm", "nodes": "millimetre nodes"}
    assert np.allclose(mm.nodes_state, 1000.0 * ref.nodes_state, rtol=1e-12, atol=1e-9)
    back = Result.load(tmp_path / "mm.h5")
    assert np.array_equal(back.surface_positions, mm.surface_positions) and back.model == mm.model


def test_frame_model_patch_test_through_simulate_and_the_result_file(tmp_path):
    """Every frame moved by one affine map: the surface and the probes follow it to 1e-10."""
    scene = _scene()
    T = np.array([[1.1, 0.2, 0.0, 0.3], [-0.1, 0.95, 0.05, -0.2], [0.0, 0.1, 1.05, 0.4]])
    scene = replace(scene, fixed=(FixedSpec(transform=tuple(map(tuple, T))),), loads=(),
                    probes=(ProbeSpec("tip", (4.0, 0.5, 0.5)), ProbeSpec("inner", (1.3, 0.2, 0.7))))
    model = _frame_model(scene)
    result = vf.simulate(scene, progress=False, model=model, output=tmp_path / "patch.h5")
    moved = result.surface_rest @ T[:, :3].T + T[:, 3]
    assert np.max(np.abs(result.surface_positions[-1] - moved)) < 1e-10
    for name, pos in result.probes.items():
        assert np.max(np.abs(pos[-1] - (pos[0] @ T[:, :3].T + T[:, 3]))) < 1e-10, name
    back = Result.load(tmp_path / "patch.h5")
    assert back.node_kind == "affine" and back.nodes_state.shape == (2, len(FRAMES), 12)
    assert back.model["count"] == len(FRAMES) and back.model["dofs"] == 12 * len(FRAMES)


@pytest.mark.slow
def test_frame_model_under_gravity_through_simulate_result_and_render(tmp_path):
    """The cantilever with 5 Shepard frames: the clamped frame stays put, the static solution
    equals a direct solve of the reduced linear system built from the model's own Hessian and
    gravity force (1e-10), the result file and `voxflex render` take it like a voxel result."""
    scene = _scene()
    model = _frame_model(scene)
    result = vf.simulate(scene, progress=False, model=model, output=tmp_path / "frames.h5")
    q = result.nodes_state[-1]
    assert np.array_equal(q[0], model.rest[0])  # frame 0 sits in the clamp box
    free = np.arange(12, 12 * len(FRAMES))
    K = np.asarray(model.hessian(model.rest))[np.ix_(free, free)]
    f = model.gravity_force({1: 1.0}, [0.0, 0.0, -9.81]).ravel()[free]
    u = np.linalg.solve(K, f)
    assert np.allclose((q - model.rest).ravel()[free], u, rtol=0, atol=1e-10 * np.abs(u).max())
    tip = result.probe_displacements()["tip"][2]
    voxel_tip = vf.simulate(scene, progress=False).probe_displacements()["tip"][2]
    # five frames are stiffer than the 32-voxel model, not softer (a reduced space of a linear problem)
    assert voxel_tip < tip < 0
    from voxflex.cli import main

    out = tmp_path / "frames.png"
    status = main(["render", str(tmp_path / "frames.h5"), "-o", str(out)])
    if status != 0:
        pytest.skip("offscreen rendering unavailable here (see test_render.py)")
    assert out.stat().st_size > 1000
