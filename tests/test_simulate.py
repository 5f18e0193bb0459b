"""vf.simulate: scene -> image -> model -> solver -> Result, against closed forms."""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import paths
import pytest
from golden import LINEAR_CANTILEVER_TIP, RELATIVE

import voxflex as vf
from voxflex.errors import InputError
from voxflex.image import LabelImage
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

EXAMPLES = paths.ROOT / "examples"

# sliding supports on the three faces through the origin (uniaxial stress states are exact)
SLIDING = (
    FixedSpec(max=(1e-6, 1e9, 1e9), components="x"),
    FixedSpec(max=(1e9, 1e-6, 1e9), components="y"),
    FixedSpec(max=(1e9, 1e9, 1e-6), components="z"),
)


def test_two_materials_in_series_from_an_image_file(tmp_path):
    """A bar [0,2]x[0,1]x[0,1]: label 1 on x < 1 (E1), label 2 on x > 1 (E2), nu = 0,
    pulled by a total force F on the face x = 2.  Uniaxial stress F/A in both parts,
    so the end moves by F (L1/E1 + L2/E2) / A exactly (a linear field is in the
    trilinear space)."""
    labels = np.ones((4, 2, 2), np.uint8)
    labels[2:] = 2
    LabelImage(labels, spacing=(0.5, 0.5, 0.5)).save(tmp_path / "bar.npz")
    E1, E2, F = 1e4, 3e4, 100.0
    scene = Scene(
        object=ObjectSpec(image=str(tmp_path / "bar.npz")),
        nodes=NodesSpec(kind="voxel"),
        materials=(
            MaterialSpec(label=1, model="hooke", young=E1, poisson=0.0),
            MaterialSpec(label=2, model="hooke", young=E2, poisson=0.0),
        ),
        elasticity=ElasticitySpec(strain="linear"),
        fixed=SLIDING,
        loads=(LoadSpec(kind="force", vector=(F, 0.0, 0.0), min=(2 - 1e-6, -1e9, -1e9)),),
        probes=(ProbeSpec("interface", (1.0, 0.5, 0.5)), ProbeSpec("end", (2.0, 1.0, 1.0))),
    )
    result = vf.simulate(scene, progress=False)
    u_interface = result.probes["interface"][-1] - result.probes["interface"][0]
    u_end = result.probes["end"][-1] - result.probes["end"][0]
    # Newton's relative residual tolerance is 1e-8 and the problem is linear: 1e-8 relative
    assert u_interface[0] == pytest.approx(F / E1, rel=1e-8)
    assert u_end[0] == pytest.approx(F / E1 + F / E2, rel=1e-8)
    assert abs(u_end[1]) < 1e-12 and abs(u_end[2]) < 1e-12  # nu = 0: no lateral contraction
    # elastic energy = work / 2 = F u / 2 for a linear problem
    assert result.energy_elastic[-1] == pytest.approx(F * u_end[0] / 2, rel=1e-8)
    assert result.n_voxels == 16 and set(np.unique(result.image_labels)) == {1, 2}


def test_output_file_from_the_scene_and_probe_shape(tmp_path):
    scene = Scene.from_toml(EXAMPLES / "cantilever.toml")
    scene = replace(scene, output=replace(scene.output, file=str(tmp_path / "c.h5")))
    result = vf.simulate(scene, progress=False)
    assert (tmp_path / "c.h5").exists()
    loaded = vf.Result.load(tmp_path / "c.h5")
    np.testing.assert_array_equal(loaded.probes["tip"], result.probes["tip"])
    assert result.probes["tip"].shape == (2, 3)
    # the 8x2x2 reference of scikit-fem / warp.fem / sfepy, 1e-5 relative
    assert result.probes["tip"][-1, 2] - 0.5 == pytest.approx(LINEAR_CANTILEVER_TIP[8], rel=RELATIVE)
    # the scene text in the result reads back to the same scene
    assert Scene.from_toml_text(result.scene) == scene


def test_not_implemented_parts_say_so():
    """What a node kind does not take is refused when the scene is made (its NodeKind says so), with the fix."""
    scene = Scene.from_toml(EXAMPLES / "cantilever.toml")
    # rigid frames refuse dynamics (their mass depends on the rotation) with the fix named
    with pytest.raises(InputError, match='rigid frames run static scenes only.*kind = "affine" for dynamics'):
        replace(scene, nodes=NodesSpec(kind="rigid", count=4), solver=replace(scene.solver, kind="implicit-euler"))
    with pytest.raises(InputError, match=r'quadrature = "elaston" does not apply to \[nodes\] kind = "voxel".*'
                                         "valid for it: gauss-legendre, midpoint"):
        replace(scene, elasticity=ElasticitySpec(quadrature="elaston"))
    with pytest.raises(InputError, match='shape_function = "shepard" does not apply to kind = "voxel"'):
        NodesSpec(kind="voxel", shape_function="shepard")
    # "barycentric" used to pass the scene and fail in the build with a wrong message: the voxel kind takes
    # "trilinear" only, and the scene says so
    with pytest.raises(InputError, match=r'shape_function: unknown value .barycentric.*valid: trilinear'):
        NodesSpec(kind="voxel", shape_function="barycentric")
    assert NodesSpec(kind="voxel", shape_function="trilinear").shape_function == "trilinear"


def test_bad_scenes_are_input_errors(tmp_path):
    scene = Scene.from_toml(EXAMPLES / "cantilever.toml")
    with pytest.raises(InputError, match=r"label 2 does not occur in the image"):
        vf.simulate(replace(scene, materials=scene.materials + (MaterialSpec(label=2),)), progress=False)
    with pytest.raises(InputError):  # a probe outside the material
        vf.simulate(replace(scene, probes=(ProbeSpec("far", (10.0, 0.5, 0.5)),)), progress=False)
    with pytest.raises(InputError, match="Scene or a scene file"):
        vf.simulate(42)


def test_midpoint_quadrature_and_dynamics_layers():
    """A free block falling under gravity with backward Euler and mid-point quadrature.
    Uniform gravity on a free body is a rigid translation (no strain, so hourglass modes
    of the one-point rule are not excited): v_n = n h g, x_n - x_0 = g h^2 n (n + 1) / 2,
    kinetic energy = M |v_n|^2 / 2 with M = rho * volume."""
    rho, h, n, g = 2.0, 0.01, 3, -9.81
    scene = Scene(
        object=ObjectSpec(shape="box", size=(2.0, 1.0, 1.0), voxel_size=0.5),
        nodes=NodesSpec(kind="voxel"),
        materials=(MaterialSpec(model="hooke", young=1e4, poisson=0.3, density=rho),),
        elasticity=ElasticitySpec(quadrature="midpoint", strain="linear"),
        loads=(LoadSpec(kind="gravity", vector=(0.0, 0.0, g)),),
        solver=SolverSpec(kind="implicit-euler", dt=h, steps=n),
        probes=(ProbeSpec("corner", (2.0, 1.0, 1.0)),),
    )
    result = vf.simulate(scene, progress=False)
    np.testing.assert_allclose(result.time, [0.0, 0.01, 0.02, 0.03], rtol=0, atol=1e-15)
    k = np.arange(n + 1)
    drop = result.probes["corner"][:, 2] - 1.0
    # one Newton step per time step on a linear problem: round-off only (1e-12 absolute)
    np.testing.assert_allclose(drop, g * h**2 * k * (k + 1) / 2, rtol=0, atol=1e-12)
    mass = rho * 2.0
    np.testing.assert_allclose(result.energy_kinetic, mass * (k * h * g) ** 2 / 2, rtol=1e-9, atol=1e-15)
    assert np.all(np.abs(result.energy_elastic) < 1e-18)  # no strain: the hourglass modes stay asleep


def _falling_sphere_mass(occupancy: bool) -> float:
    """Mass seen by the dynamics of a freely falling voxelized sphere.

    Backward Euler under constant gravity with no supports moves the body
    rigidly (no strain), so after n steps v = n g dt exactly and the kinetic
    energy is M (n g dt)^2 / 2: the kinetic energy measures the mass M.
    """
    text = f"""
[object]
shape = "sphere"
size = [0.5]
voxel_size = 0.125
occupancy = {str(occupancy).lower()}
[nodes]
kind = "voxel"
[[material]]
model = "neo-hookean"
young = 1e4
poisson = 0.3
density = 2.0
[[load]]
kind = "gravity"
vector = [0.0, 0.0, -9.81]
[solver]
kind = "implicit-euler"
dt = 0.01
steps = 2
"""
    result = vf.simulate(Scene.from_toml_text(text), progress=False)
    v = 2 * 9.81 * 0.01
    return float(result.energy_kinetic[-1] / (0.5 * v * v))


def test_occupancy_fractions_weight_the_mass():
    # a sphere of radius 0.5 at 4 voxels per radius: 0/1 voxels miss the volume by several
    # percent, occupancy fractions (4^3 sub-samples per boundary voxel) by well under 1 %
    exact = 2.0 * 4.0 / 3.0 * np.pi * 0.5**3
    err_binary = abs(_falling_sphere_mass(False) / exact - 1)
    err_fraction = abs(_falling_sphere_mass(True) / exact - 1)
    assert err_fraction < 0.01
    assert err_fraction < 0.25 * err_binary


def test_midpoint_static_failure_names_the_hourglass_modes():
    # one sample per voxel without stabilisation (hourglass = "none"): trilinear voxels keep
    # hourglass modes, the clamped beam's tangent is singular and Newton cannot converge; the
    # error must point at the cause and the fix
    text = """
[object]
shape = "box"
size = [2.0, 0.5, 0.5]
voxel_size = 0.25
[nodes]
kind = "voxel"
[[material]]
model = "neo-hookean"
young = 1e4
poisson = 0.3
density = 1.0
[elasticity]
quadrature = "midpoint"
hourglass = "none"
[[fixed]]
min = [-1.0, -1.0, -1.0]
max = [1e-6, 1.0, 1.0]
[[load]]
kind = "gravity"
vector = [0.0, 0.0, -9.81]
[solver]
max_iterations = 8
"""
    with pytest.raises(vf.ConvergenceError, match="hourglass") as exc:
        vf.simulate(Scene.from_toml_text(text), progress=False)
    assert 'quadrature = "gauss-legendre"' in str(exc.value)


def test_a_run_finds_its_held_dofs_loads_and_mass_once(monkeypatch):
    """The problem is translated once: the guards, the solver and the reactions' recorder read one set of
    held DOFs, one load vector and one mass matrix (each took 7-21 ms of a 20-step frame run on the
    bunny, and was computed two or three times), and the answer is the one the solver finds alone."""
    from voxflex.deform.models.frames.model import FrameModel
    from voxflex.deform.solve.boundary import FixedRegion
    from voxflex.deform.solve.options import SolverOptions
    from voxflex.deform.solve.stepping import solve
    from voxflex.scene import OutputSpec

    scene = Scene(
        object=ObjectSpec(shape="box", size=(2.0, 0.5, 0.5), voxel_size=0.25),
        nodes=NodesSpec(kind="affine", count=6),
        materials=(MaterialSpec(model="neo-hookean", young=1e4, poisson=0.3, density=100.0),),
        fixed=(FixedSpec(max=(0.01, 1e9, 1e9)),),
        loads=(LoadSpec(kind="gravity", vector=(0.0, 0.0, -9.81)),),
        solver=SolverSpec(kind="implicit-euler", dt=0.01, steps=3),
        output=OutputSpec(fields=("reaction",)),
    )
    model = vf.model(scene, cache=False)
    calls = {"held_dofs": 0, "gravity_force": 0, "mass_matrix": 0}
    for name in calls:
        inner = getattr(FrameModel, name)

        def counted(self, *a, _inner=inner, _name=name, **k):
            calls[_name] += 1
            return _inner(self, *a, **k)

        monkeypatch.setattr(FrameModel, name, counted)
    result = vf.simulate(scene, model=model, progress=False)
    assert calls == {"held_dofs": 1, "gravity_force": 1, "mass_matrix": 1}
    alone = solve(model, fixed=[FixedRegion(np.array([-1e9] * 3), np.array([0.01, 1e9, 1e9]))],
                  gravity=np.array([0.0, 0.0, -9.81]), densities={1: 100.0},
                  options=SolverOptions(kind="implicit-euler", dt=0.01, steps=3))
    np.testing.assert_array_equal(result.nodes_state[-1], alone[-1].q)


@pytest.mark.parametrize("example, voxel", [("plastic_bar", 0.01), ("pushed_block", 0.1)])
def test_a_model_reused_for_a_second_run_starts_from_rest(example, voxel):
    """Runs of one model must not see each other: the plastic layer kept the first run's last plastic strains
    (examples/plastic_bar.toml: the second run's intermediate states 5.9e-5 m apart) and the contact layer its
    obstacles where the first run left them (examples/pushed_block.toml: 'no admissible start state' at the
    second run's first step).  Now every run starts its layers at rest (``RunState.begin_run``): the same
    states, bitwise.  (Coarser voxels than the examples': the same layers, a second each.)"""
    scene = Scene.from_toml(EXAMPLES / f"{example}.toml")
    scene = replace(scene, object=replace(scene.object, voxel_size=voxel))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = vf.model(scene, cache=False)
        runs = [vf.simulate(scene, model=model, progress=False) for _ in range(2)]
    assert len(runs[0].surface_positions) > 2
    for a, b in zip(runs[0].surface_positions, runs[1].surface_positions):
        assert np.array_equal(np.asarray(a), np.asarray(b))
