"""Unsupported parts and mechanisms are refused before a static solve, with the cause named.

Each case used to "converge" to displacements of 1e11-1e13 m with exit status 0
(issue: never report garbage as success).  The check is a rank test of the
rigid motions of every material component against the fixed DOFs (and the
nodes it shares with held components), see voxflex/deform/solve/supports.py.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest

import voxflex as vf
from voxflex.build import ComponentsDroppedWarning
from voxflex.deform.solve.supports import unsupported_components
from voxflex.errors import InputError
from voxflex.image.label_image import LabelImage
from voxflex.scene import (
    FixedSpec,
    LoadSpec,
    MaterialSpec,
    NodesSpec,
    ObjectSpec,
    ProbeSpec,
    Scene,
    SolverSpec,
)

BIG = 1e9
CLAMP = FixedSpec(min=(-BIG, -BIG, -BIG), max=(1e-6, BIG, BIG))


def _image_scene(tmp_path, labels, fixed=(CLAMP,), **kw) -> Scene:
    path = tmp_path / "img.npz"
    LabelImage(np.asarray(labels, dtype=np.uint8), spacing=(1.0, 1.0, 1.0)).save(path)
    return Scene(
        object=ObjectSpec(image=str(path), **kw),
        materials=(MaterialSpec(model="hooke", young=1e3, poisson=0.3, density=1.0),),
        nodes=NodesSpec(kind="voxel"),
        fixed=fixed,
        loads=(LoadSpec(kind="gravity", vector=(0.0, 0.0, -9.81)),),
    )


def _bar(nx=3):
    labels = np.zeros((nx + 3, 3, 3), dtype=np.uint8)
    labels[:nx, 1, 1] = 1
    return labels


@pytest.mark.parametrize(
    "case, edit, fixed, message",
    [
        ("no support at all", None, (), "component 1 of 1 (label 1, 3 voxels"),
        ("a floating block beside the clamped bar", "island", (CLAMP,), "component 2 of 2 (label 1, 1 voxels"),
        ("a block joined only along an edge", "edge", (CLAMP,), "a hinge"),
        ("a block joined only at a corner", "corner", (CLAMP,), "a hinge"),
        ("a clamp that holds only x", None, (replace(CLAMP, components="x"),), "3 free rigid motion(s)"),
        ("a single fixed node", None, (FixedSpec(min=(-0.1, 0.9, 0.9), max=(0.1, 1.1, 1.1)),), "3 free rigid motion(s)"),
    ],
)
def test_ill_posed_static_scenes_are_refused_naming_the_component(tmp_path, case, edit, fixed, message):
    labels = _bar()
    if edit == "island":
        labels[5, 1, 1] = 1
    elif edit == "edge":
        labels[3, 2, 1] = 1  # shares the edge x = 3, y = 2 with the bar's last voxel
    elif edit == "corner":
        labels[3, 2, 2] = 1  # shares the corner (3, 2, 2) only
    scene = _image_scene(tmp_path, labels, fixed=fixed)
    with pytest.raises(InputError) as info:
        vf.simulate(scene, progress=False)
    text = str(info.value)
    assert text.startswith("static scene is ill-posed") and message in text, text
    assert "[[fixed]]" in text and "keep" in text and "\n" not in text


def test_well_posed_scenes_pass_the_check(tmp_path):
    labels = _bar()
    labels[2, 1, 2] = 1  # on top of the bar's last voxel (a shared face): one component
    scene = _image_scene(tmp_path, labels)
    model = vf.model(scene)
    from voxflex.deform.solve.boundary import FixedRegion, fixed_dofs

    dofs, _ = fixed_dofs(model, [FixedRegion(np.array(CLAMP.min), np.array(CLAMP.max))])
    assert unsupported_components(model, dofs) == []
    result = vf.simulate(replace(scene, probes=(ProbeSpec("tip", (3.0, 1.5, 1.5)),)), progress=False)
    assert np.all(np.isfinite(result.nodes_state)) and result.probe_displacements()["tip"][2] < 0


def test_dynamics_may_leave_parts_free(tmp_path):
    """A block falling freely under gravity is a dynamic scene, not an error: it falls g t^2 / 2 (1e-9)."""
    scene = _image_scene(tmp_path, _bar(), fixed=())
    scene = replace(scene, solver=SolverSpec(kind="implicit-euler", dt=0.01, steps=3),
                    probes=(ProbeSpec("c", (1.5, 1.5, 1.5)),))
    result = vf.simulate(scene, progress=False)
    # backward Euler on a free body: x_k = x_0 - g h^2 k(k+1)/2
    assert result.probe_displacements()["c"][2] == pytest.approx(-9.81 * 0.01**2 * 6, rel=1e-9)


def test_islands_can_be_dropped_with_a_warning(tmp_path):
    labels = _bar()
    labels[5, 1, 1] = 1
    scene = _image_scene(tmp_path, labels, min_component_voxels=2)
    with pytest.warns(ComponentsDroppedWarning, match="dropped 1 of 2 material components"):
        result = vf.simulate(scene, progress=False)
    assert int((result.image_labels > 0).sum()) == 3
    with pytest.warns(ComponentsDroppedWarning):
        largest = vf.simulate(replace(scene, object=replace(scene.object, min_component_voxels=1, keep="largest")),
                              progress=False)
    assert int((largest.image_labels > 0).sum()) == 3
    with pytest.raises(InputError, match="drops every material component"):
        with warnings.catch_warnings():
            vf.simulate(replace(scene, object=replace(scene.object, min_component_voxels=10)), progress=False)


def test_the_frame_model_is_checked_too():
    """Frames: a bar with no frame held, and one with a single frame held in x only, are refused."""
    from voxflex.deform.materials.constitutive import material
    from voxflex.deform.models.frames.model import FrameModel
    from voxflex.deform.solve.boundary import FixedRegion
    from voxflex.deform.solve.options import SolverOptions
    from voxflex.deform.solve.stepping import solve
    from voxflex.voronoi.shape_functions import shepard

    image = LabelImage(np.ones((4, 1, 1), dtype=np.uint8))
    frames = np.array([[0.5, 0.5, 0.5], [3.5, 0.5, 0.5]])
    model = FrameModel.from_image(image, frames, lambda p: shepard(p, frames), {1: material("hooke", young=1e3, poisson=0.3)})
    with pytest.raises(InputError, match="component 1 of 1 .* is not held: 6 free"):
        solve(model, gravity=[0, 0, -9.81], densities={1: 1.0}, options=SolverOptions())
    with pytest.raises(InputError, match="3 free rigid motion"):
        solve(model, fixed=[FixedRegion([0, 0, 0], [1, 1, 1], components="x")], gravity=[0, 0, -9.81],
              densities={1: 1.0}, options=SolverOptions())
    # one frame held in all 12 DOF holds the body
    records = solve(model, fixed=[FixedRegion([0, 0, 0], [1, 1, 1])], gravity=[0, 0, -9.81], densities={1: 1.0},
                    options=SolverOptions())
    assert np.all(np.isfinite(records[-1].q))


@pytest.mark.parametrize("dt", [1e-9, 1e-6, 1e-3, 1.0, 100.0])
def test_free_fall_is_right_for_any_time_step(tmp_path, dt):
    """Backward Euler on a free body: after k steps the fall is g h^2 k(k+1)/2 exactly (1e-6 relative).

    With dt = 1e-9 the inertia term M / h^2 is 1e18 times the mass: the solver used to accept
    the unmoved state because its round-off floor grew with M / h^2 |x|; the increment
    formulation keeps the floor at the elastic stiffness."""
    scene = _image_scene(tmp_path, _bar(), fixed=())
    scene = replace(scene, solver=SolverSpec(kind="implicit-euler", dt=dt, steps=2),
                    probes=(ProbeSpec("c", (1.5, 1.5, 1.5)),))
    result = vf.simulate(scene, progress=False)
    assert result.probe_displacements()["c"][2] == pytest.approx(-9.81 * dt**2 * 3, rel=1e-6)
    total = result.energy_elastic + result.energy_kinetic
    assert np.all(np.isfinite(total))
