"""Frame models from scenes: [nodes] kind = "affine", end to end.

Placement, natural-neighbour weights (blended), samples, the frame model, the
solvers, the result file.  Oracles: the affine patch test (exact), the voxel
model on the same image (the SOFA frames-beam set-up), energy decay of
backward Euler.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import paths
import pytest

import voxflex as vf
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
)


def _bar(h=0.1, **kw):
    kw.setdefault("elasticity", ElasticitySpec(strain="linear"))
    kw.setdefault("nodes", NodesSpec(kind="voxel"))  # the reference; frame scenes say kind = "affine"
    return Scene(object=ObjectSpec(shape="box", size=(0.4, 0.4, 2.0), voxel_size=h),
                 materials=(MaterialSpec(model="hooke", young=1e5, poisson=0.3, strain="linear", density=1000.0),),
                 probes=(ProbeSpec("tip", (0.2, 0.2, 2.0)), ProbeSpec("inner", (0.13, 0.31, 0.77))), **kw)


@pytest.mark.parametrize("quadrature", ["midpoint", "elaston", "gauss-legendre"])
def test_affine_patch_test_through_frames_and_samples(tmp_path, quadrature):
    """Every frame moved by one affine map (a fixed region covering the body with a transform):
    surface and probes follow it to 1e-10, with any sampler."""
    T = np.array([[1.1, 0.2, 0.0, 0.03], [-0.1, 0.95, 0.05, -0.02], [0.0, 0.1, 1.05, 0.04]])
    scene = _bar(nodes=NodesSpec(kind="affine", count=8), fixed=(FixedSpec(transform=tuple(map(tuple, T))),),
                 elasticity=ElasticitySpec(strain="linear", quadrature=quadrature, samples=40))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # few samples for a free body: the rank check may warn
        result = vf.simulate(scene, progress=False, output=tmp_path / "patch.h5")
    moved = result.surface_rest @ T[:, :3].T + T[:, 3]
    assert np.max(np.abs(result.surface_positions[-1] - moved)) < 1e-10
    for pos in result.probes.values():
        assert np.max(np.abs(pos[-1] - (pos[0] @ T[:, :3].T + T[:, 3]))) < 1e-10
    back = Result.load(tmp_path / "patch.h5")
    assert back.node_kind == "affine" and back.nodes_state.shape[1:] == (8, 12)
    assert back.model["quadrature"] == quadrature and back.model["shape_function"] == "natural-neighbour"
    assert back.model["precompute_seconds"] > 0


@pytest.mark.slow
def test_sofa_frames_beam_within_five_percent_of_the_voxel_model():
    """Bar 0.4 x 0.4 x 2 (voxels 0.02: 40,000), clamped at z = 0, E = 1e5, nu = 0.3, 1 N at the tip:
    40 frames and 1000 mid-point samples give the voxel model's tip deflection within 5 % (the
    issue's bar; SOFA's own test accepted 27 %).  Measured +1.0 % (benchmarks/bench_frames_accuracy.py)."""
    scene = _bar(h=0.02, fixed=(FixedSpec(max=(1e9, 1e9, 1e-6)),),
                 loads=(LoadSpec(kind="force", vector=(1.0, 0.0, 0.0), min=(-1e9, -1e9, 2.0 - 1e-6)),))
    ref = vf.simulate(scene, progress=False).probe_displacements()["tip"][0]
    frames = replace(scene, nodes=NodesSpec(kind="affine", count=40),
                     elasticity=ElasticitySpec(strain="linear", quadrature="midpoint", samples=1000))
    got = vf.simulate(frames, progress=False).probe_displacements()["tip"][0]
    assert ref == pytest.approx(0.0127, rel=0.01)  # beam theory PL^3/3EI = 0.0125, plus shear
    assert abs(got - ref) <= 0.05 * abs(ref)


def test_released_frame_beam_never_gains_energy():
    """Implicit Euler with frames: a bar clamped at one end, released from its bent static state,
    loses energy at every step (backward Euler dissipates)."""
    base = _bar(h=0.1, fixed=(FixedSpec(max=(1e9, 1e9, 1e-6)),), nodes=NodesSpec(kind="affine", count=10),
                elasticity=ElasticitySpec(strain="linear", quadrature="midpoint", samples=200))
    # a sideways 0.5 m/s^2 bends the 2 m bar's tip by about 0.55 m (50 m/s^2 bent it to 28 times its size, a
    # linear-strain state the run now flags as implausible)
    bent = vf.simulate(replace(base, loads=(LoadSpec(kind="gravity", vector=(0.5, 0.0, 0.0)),)), progress=False)
    model = vf.model(base)
    from voxflex.deform.solve.boundary import FixedRegion
    from voxflex.deform.solve.options import SolverOptions
    from voxflex.deform.solve.stepping import solve

    records = solve(model, fixed=[FixedRegion([-1e9] * 3, [1e9, 1e9, 1e-6])], densities={1: 1000.0},
                    options=SolverOptions(kind="implicit-euler", dt=0.002, steps=20), q0=bent.nodes_state[-1])
    total = np.array([r.elastic_energy + r.kinetic_energy for r in records])
    assert total[0] > 0 and np.all(np.diff(total) <= 1e-12 * total[0]) and total[-1] < total[0]


def test_a_static_frame_scene_with_zero_energy_modes_is_refused_before_solving():
    """The cantilever example (8x2x2 voxels) with 20 affine frames and one mid-point sample per voxel:
    32 samples cannot hold 20 frames (47 spurious modes in the free body, some among the free frames).
    Static: refused at build time with one line naming the samples and the fixes (it used to run
    through 8 load cuts and fail).  Implicit Euler (mass makes each step well posed): only the
    SpuriousModesWarning."""

    from voxflex.deform.models.frames.modes import SpuriousModesWarning
    from voxflex.errors import InputError
    from voxflex.scene import Scene

    scene = Scene.from_toml(paths.ROOT / "examples" / "cantilever.toml")
    scene = replace(scene, nodes=replace(scene.nodes, kind="affine"),
                    elasticity=replace(scene.elasticity, quadrature="midpoint"))
    with pytest.raises(InputError, match=r"32 midpoint samples leave \d+ zero-energy mode.*samples.*gauss-legendre"):
        vf.model(scene)
    dynamic = replace(scene, solver=replace(scene.solver, kind="implicit-euler", steps=1, dt=0.01))
    with pytest.warns(SpuriousModesWarning, match="spurious zero-energy modes"):
        vf.model(dynamic)


def test_a_static_frame_scene_with_a_near_zero_energy_mode_is_refused(tmp_path, monkeypatch):
    """The cantilever example (8x2x2 voxels) with 8 affine frames on the 7 elastons the sampler makes:
    no exactly free mode, but one 14,000 times softer than with a mid-point sample in every voxel (in
    a sweep that model's probe was 16 % off and its surface 79 %).  Static: refused before solving,
    naming the ratio and the fixes; implicit Euler: a SpuriousModesWarning.  The ratio is stored with
    the cached precompute, so a second run judges it alike without recomputing it."""

    from voxflex.deform.models.frames.modes import SpuriousModesWarning
    from voxflex.errors import InputError
    from voxflex.scene import Scene

    monkeypatch.setenv("VOXFLEX_CACHE_DIR", str(tmp_path))
    scene = Scene.from_toml(paths.ROOT / "examples" / "cantilever.toml")
    scene = replace(scene, nodes=replace(scene.nodes, kind="affine", count=8),
                    elasticity=replace(scene.elasticity, quadrature="elaston", samples=40))
    with pytest.raises(InputError, match=r"7 elaston samples leave a deformation mode \d+ times softer .*"
                                         r"near-zero-energy.*samples.*gauss-legendre"):
        vf.model(scene)
    dynamic = replace(scene, solver=replace(scene.solver, kind="implicit-euler", steps=1, dt=0.01))
    for run in ("fresh", "cached"):
        with pytest.warns(SpuriousModesWarning, match="near-zero-energy mode"):
            m = vf.model(dynamic)
        assert m.info["precompute_cached"] == (run == "cached")
    # the same image with 5 frames on the same elastons is sound: no warning
    sound = replace(dynamic, nodes=replace(dynamic.nodes, count=5))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        vf.model(sound)
