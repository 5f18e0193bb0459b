"""Steps below the round-off of the positions keep their digits (issue 27, item 7).

The solvers carry the displacement from rest ``u = q - X``, not the positions: a 1 m body at
dt = 1e-9 s falls 2.9e-17 m in two implicit-Euler steps, which ``X + u`` rounds away (eps |X| = 2.2e-16 m)
but ``u`` and the probes' displacements (``/probe_displacements``) keep to round-off.  Before, both
models returned exactly 0 for a neo-Hookean ball (the voxel model's linear path kept it only where the
probe sat at the origin).  The voxel model forms its strains from the displacement too
(:class:`~voxflex.deform.models.protocol.FromDisplacement`: F = I + grad u, a linear model's forces K u), so a
body far from the origin gets the answer it gets at the origin and a linear static motion of any size keeps its
digits; the frame model still forms F from the positions: a static motion below their round-off is refused with
a message that says so.  The tolerance 1e-6 is a digit count (float64 keeps 15-16).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from robust import beam

import voxflex as vf
from voxflex.result import Result
from voxflex.scene import Scene

DROP = Path(__file__).resolve().parents[1] / "examples" / "drop.toml"


def _drop(kind: str, model: str, dt: float) -> Scene:
    text = DROP.read_text().replace("dt = 0.01", f"dt = {dt!r}").replace("steps = 10", "steps = 2")
    text = text.replace('"neo-hookean"', f'"{model}"')
    if kind == "affine":
        text = text.replace('kind = "voxel"', 'kind = "affine"\ncount = 8')
    return Scene.from_toml_text(text)


@pytest.mark.parametrize("kind", ["voxel", "affine"])
@pytest.mark.parametrize("model", ["neo-hookean", "hooke"])
def test_a_free_fall_at_dt_1e_9_moves_by_the_exact_discrete_fall(kind, model, tmp_path):
    """Backward Euler, 2 steps: the fall is g dt^2 (1 + 2) exactly (a rigid translation, no strain)."""
    dt = 1e-9
    r = vf.simulate(_drop(kind, model, dt), progress=False, cache=False)
    exact = -9.81 * dt**2 * 3
    u = r.probe_displacements()["centre"]
    assert u[2] == pytest.approx(exact, rel=1e-6)
    assert abs(u[0]) < 1e-6 * abs(exact) and abs(u[1]) < 1e-6 * abs(exact)
    # the positions cannot hold it (the ball's centre is at z = 1.5 m): the displacement group does
    assert r.probes["centre"][-1][2] == pytest.approx(1.5, abs=1e-15)
    # and the file keeps it
    back = Result.load(r.save(tmp_path / "fall.h5"))
    assert back.probe_displacements()["centre"][2] == pytest.approx(exact, rel=1e-6)


def _tip(kind, g, *, origin=0.0, **kw):
    text = beam(kind, gravity=f"[0.0, 0.0, {-g!r}]", nodes="count = 6" if kind == "affine" else "", **kw)
    if origin:  # the same beam, clamp and probe moved by `origin` along every axis
        o = f"{origin!r}"
        text = (text.replace("origin = [0.0, 0.0, 0.0]", f"origin = [{o}, {o}, {o}]")
                .replace("max = [1.0e-6, 1.0e9, 1.0e9]", f"max = [{origin + 1e-6!r}, 1.0e9, 1.0e9]")
                .replace("point = [4.0, 0.5, 0.5]", f"point = [{origin + 4.0!r}, {origin + 0.5!r}, {origin + 0.5!r}]"))
    r = vf.simulate(Scene.from_toml_text(text), progress=False, cache=False)
    return r.probe_displacements()["tip"], r


def test_a_static_motion_below_the_strains_round_off_is_refused_and_named():
    """A neo-Hookean material reads F = I + H, which rounds H to eps: a cantilever under 1e-11 of its gravity
    (strains ~1e-13) stops at relative residual ~1; the refusal names the round-off of the forces and a fix
    that works (raise the loads), not a stiff layer.  Between 1e-3 and 1e-6 of the load the sag still scales
    (measured 4.4e-9 apart: the nonlinearity's share, 0.47 % at the full load, goes with the load squared;
    asserted to 1e-7; the axial shortening, quadratic in the sag, is not compared)."""
    nh = {"model": "neo-hookean", "elasticity": ""}
    ref = _tip("voxel", 9.81e-3, **nh)[0]
    assert ref[2] < 0
    assert _tip("voxel", 9.81e-6, **nh)[0][2] == pytest.approx(1e-3 * ref[2], rel=1e-7)
    with pytest.raises(vf.ConvergenceError, match=r"below what the elastic forces resolve .* raise the loads"):
        _tip("voxel", 9.81e-11, **nh)


@pytest.mark.parametrize("kind", ["voxel", "affine"])
@pytest.mark.parametrize("scale", [1e-6, 1e-12, 1e-20])
def test_a_linear_model_keeps_the_digits_of_any_static_motion(kind, scale):
    """Its forces are K u of the displacement: 1e-12 of the gravity (refused before: the positions rounded the
    1e-13 m tip away) and 1e-20 scale the tip exactly (a linear answer; 1e-12 relative, where the sideways
    components, zero by symmetry, are round-off of the sag's)."""
    ref = _tip(kind, 9.81)[0]
    np.testing.assert_allclose(_tip(kind, 9.81 * scale)[0], scale * ref, rtol=1e-12, atol=1e-12 * scale * abs(ref[2]))


@pytest.mark.parametrize("kind", ["voxel", "affine"])
def test_a_neo_hookean_body_far_from_the_origin_gets_the_answer_it_gets_at_the_origin(kind):
    """The beam moved 1 km and 1000 km away: the strains come from the displacement, so the tip is the one at
    the origin in as many Newton iterations, to 1e-12 of the sag for voxels (0.0 measured) and, for frames,
    to the round-off of their weights, computed from positions: 4 eps |x| / h (1.6e-10 measured at 1000 km).
    Before, the forces' round-off (eps |x| / h of strain) moved the tip by 1.3e-7 (voxels) and 7.3e-8
    (frames) at 1000 km and let Newton stop at its round-off floor one (voxels) and two (frames) iterations early."""
    ref, r0 = _tip(kind, 9.81, model="neo-hookean", elasticity="")
    assert ref[2] < -0.2
    for origin in (1e3, 1e6):
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # no round-off-floor warning
            tip, r = _tip(kind, 9.81, model="neo-hookean", elasticity="", origin=origin)
        tol = 1e-12 if kind == "voxel" else max(1e-12, 4 * np.finfo(float).eps * origin / 0.5)
        np.testing.assert_allclose(tip, ref, rtol=0, atol=tol * abs(ref[2]))
        assert list(r.newton_iterations) == list(r0.newton_iterations)


def test_results_without_the_displacement_group_read_the_positions():
    """Files that predate ``/probe_displacements`` (and rigid frames) answer from the positions."""
    T = 2
    r = Result(time=np.arange(T, dtype=float), probes={"p": np.array([[0.0, 0, 1], [0.0, 0, 0.5]])},
               surface_rest=np.zeros((1, 3)), surface_faces=np.zeros((0, 3), dtype=np.int64),
               surface_positions=np.zeros((T, 1, 3)), nodes_rest=np.zeros((1, 3)), nodes_state=np.zeros((T, 1, 3)),
               energy_elastic=np.zeros(T), energy_kinetic=np.zeros(T), newton_iterations=np.zeros(T, np.int64),
               step_seconds=np.zeros(T), image_labels=np.ones((1, 1, 1), np.uint8), image_spacing=np.ones(3),
               image_origin=np.zeros(3))
    np.testing.assert_allclose(r.probe_displacements()["p"], [0, 0, -0.5])
    with pytest.raises(vf.InputError, match="name a probe"):
        Result(**{**r.__dict__, "probe_displacement": {"q": np.zeros((T, 3))}})


CABLE = """
[[cable]]
anchor = [5.0, 0.5, 0.5]
points = [[1.0, 0.5, 0.5], [2.0, 0.5, 0.5], [3.9, 0.5, 0.5]]
stiffness = 100.0
shorten = 0.01
"""

PLANE = """
[[obstacle]]
kind = "plane"
point = [0.0, 0.0, -0.3]
normal = [0.0, 0.0, 1.0]
"""


@pytest.mark.parametrize("kind", ["voxel", "affine"])
@pytest.mark.parametrize("extra", [CABLE, PLANE, CABLE + PLANE], ids=["cable", "plane", "both"])
def test_layers_form_the_wrapped_models_strains_from_the_displacement(kind, extra):
    """A cable or an obstacle wrapping a model with the displacement form has it too: the wrapped model's
    strains from u, the layer's own term at rest + u.  Its (energy, gradient, Hessian) equal the position
    form's at strains ~1e-2 (1e-12 relative: round-off), and the layer's term is in it (a layer that
    forwarded the wrapped model's form dropped a cable's pull from the solve)."""
    from voxflex.deform.models.protocol import FromDisplacement

    text = beam(kind, model="neo-hookean", elasticity="", nodes="count = 6" if kind == "affine" else "", extra=extra)
    model = vf.model(Scene.from_toml_text(text), cache=False)
    model.set_time(1.0)  # the cable shortened: it pulls
    assert isinstance(model, FromDisplacement) and isinstance(model.inner, FromDisplacement)
    rng = np.random.default_rng(0)
    u = (1e-2 if kind == "affine" else 1e-3) * rng.standard_normal(np.shape(model.rest))
    E1, g1, H1 = model.energy_gradient_hessian_u(u)
    E0, g0, H0 = model.energy_gradient_hessian(np.asarray(model.rest) + u)
    dense = [np.asarray(H.toarray() if hasattr(H, "toarray") else H) for H in (H1, H0)]
    assert E1 == pytest.approx(E0, rel=1e-12)
    assert np.abs(g1 - g0).max() <= 1e-12 * np.abs(g0).max()
    assert np.abs(dense[0] - dense[1]).max() <= 1e-12 * np.abs(dense[1]).max()
    inner = model.inner.energy_gradient_hessian_u(u)
    if "cable" in extra:
        assert np.abs(g1 - inner[1]).max() > 1e-6 * np.abs(g1).max()  # the cable's pull is in the form


def test_plasticity_passes_the_displacement_form_on():
    """Plasticity adds no energy (its materials are the wrapped model's): its displacement form is the
    wrapped model's own."""
    from voxflex.deform.layers.plasticity import PlasticModel

    scene = Scene.from_toml(Path(__file__).resolve().parents[1] / "examples" / "plastic_bar.toml")
    model = vf.model(scene, cache=False)
    assert isinstance(model, PlasticModel) and model.adds_energy is False
    assert model.energy_gradient_hessian_u == model.inner.energy_gradient_hessian_u
    assert model.strain_lengths == model.inner.strain_lengths


@pytest.mark.parametrize("kind", ["voxel", "affine"])
def test_a_body_with_a_layer_far_from_the_origin_gets_the_answer_it_gets_at_the_origin(kind):
    """The neo-Hookean beam above a plane 10 m below (never touched: the layer adds nothing but its presence)
    moved 1000 km away gets its tip at the origin to the tolerance of the bare beam's test (the strains come
    from the displacement through the contact layer; before, the layered model formed them from the
    positions: 1.3e-7 and 7.3e-8 of the sag off)."""
    plane = PLANE.replace("[0.0, 0.0, -0.3]", "[0.0, 0.0, -10.0]")
    ref, r0 = _tip(kind, 9.81, model="neo-hookean", elasticity="", extra=plane)
    assert ref[2] < -0.2
    origin = 1e6
    moved = plane.replace("[0.0, 0.0, -10.0]", f"[{origin!r}, {origin!r}, {origin - 10.0!r}]")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no round-off-floor warning
        tip, r = _tip(kind, 9.81, model="neo-hookean", elasticity="", origin=origin, extra=moved)
    tol = 1e-12 if kind == "voxel" else 4 * np.finfo(float).eps * origin / 0.5
    np.testing.assert_allclose(tip, ref, rtol=0, atol=tol * abs(ref[2]))


@pytest.mark.parametrize("kind", ["voxel", "affine"])
def test_a_nearly_incompressible_body_is_solved_at_its_round_off_floor(kind):
    """At nu = 0.49999999 (lambda / mu = 5e7) the forces are sums of volumetric terms 5e7 times larger than what
    they add up to: the linear cantilever's residual stalled at 2.4e-7 (voxels) and 1.3e-7 (frames) of the load for
    50 iterations and 8 load cuts, and the run was refused with "use more load steps".  Newton's floor now has
    BULK_FLOOR eps lambda / mu of the forces' scale (7e-7 here): one iteration, and the tip of nu = 0.4999999 (whose
    floor, 7e-8, is below what it reaches) to 1e-5."""
    def tip(nu):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the locking advice at nu > 0.49
            r = vf.simulate(Scene.from_toml_text(beam(kind, poisson=nu)), progress=False)
        return r, r.probes["tip"][-1] - r.probes["tip"][0]

    r, u = tip("0.49999999")
    assert list(r.newton_iterations) == [0, 1]
    np.testing.assert_allclose(u, tip("0.4999999")[1], rtol=0, atol=1e-5 * np.abs(u).max())


MM_BEAM = """
[object]
shape = "box"
size = [0.04, 0.01, 0.01]
voxel_size = 0.002
origin = [{o!r}, 0.0, 0.0]

[[material]]
model = "neo-hookean"
young = 1.0e5
poisson = 0.3
density = 1000.0

[nodes]
{nodes}

[[fixed]]
min = [{o!r}, -1.0, -1.0]
max = [{clamp!r}, 1.0, 1.0]

[[load]]
kind = "gravity"

[[probe]]
name = "tip"
point = [{tip!r}, 0.005, 0.005]
"""


@pytest.mark.parametrize("nodes", ['kind = "voxel"', "count = 10", 'count = 10\nshape_function = "natural-neighbour"'])
def test_a_millimetre_body_far_from_the_origin_gets_the_verdict_and_the_answer_it_gets_at_the_origin(nodes):
    """A 4 cm beam of 2 mm voxels, its probe on the end face, moved 1 km, 100 km and 1000 km along x (issue 27,
    round 27): the voxel size is no binary fraction, so a coordinate far away carries eps |x| / h of a voxel.
    Before, at 1000 km the probe on the face was refused as "outside the material" (1e-9 voxel of slack, 2.4e-8
    of round-off; voxels and frames), and the frames' answer moved with the origin: -0.07 % at 1 km and +1.1 % of
    the sag, with the tip 1.9 % sideways, at 100 km (the elaston regions' splits and centroids compared world
    coordinates; natural-neighbour weights snapped their frames to the voxel grid only within 1.5e-11 voxel)."""
    def tip(o):
        text = MM_BEAM.format(o=o, nodes=nodes, clamp=o + 1e-4, tip=o + 0.04)
        return vf.simulate(Scene.from_toml_text(text), progress=False, cache=False).probe_displacements()["tip"]

    ref = tip(0.0)
    assert -0.005 < ref[2] < -0.002
    for origin in (1e3, 1e5, 1e6):
        np.testing.assert_allclose(tip(origin), ref, rtol=0, atol=1e-7 * abs(ref[2]))


@pytest.mark.parametrize("kind", ["voxel", "affine"])
def test_a_clamp_moved_rigidly_1000_km_reaches_its_round_off_floor_and_names_the_motion(kind):
    """A 4 cm beam whose clamp is translated 1e6 m (2.5e7 body sizes) in one step: its forces come from a
    displacement of 1e6 m and carry eps |u| / h of round-off, but Newton's floor was set at the step's start
    (u = 0): the line search failed after 14 iterations and advised more load steps, which failed the same way.
    The floor now includes the prescribed motion: the step is accepted at it, the sag is the one the beam gets
    unmoved to 0.1 % (the round-off of forces known to eps 1e6 m / 2 mm), and the round-off warning names the
    motion as the cause instead of a stiffness contrast."""
    def text(shift):
        return beam(kind, size=(0.04, 0.01, 0.01), h=0.002, model="neo-hookean", young="1.0e5", density="1000.0",
                    nodes="count = 10" if kind == "affine" else "", elasticity="",
                    fixed_max="[0.0001, 1.0, 1.0]\ntransform = [[1.0, 0.0, 0.0, %r], [0.0, 1.0, 0.0, 0.0], "
                              "[0.0, 0.0, 1.0, 0.0]]" % shift)
    ref = vf.simulate(Scene.from_toml_text(text(0.0)), progress=False).probe_displacements()["tip"]
    with pytest.warns(UserWarning, match=r"round-off floor .* the fixed regions move the body 2\.5e\+07 body sizes"):
        r = vf.simulate(Scene.from_toml_text(text(1e6)), progress=False)
    u = r.probe_displacements()["tip"]
    assert u[0] == pytest.approx(1e6 + ref[0], abs=1e-3 * abs(ref[2]) + 1e-9)
    assert u[2] == pytest.approx(ref[2], rel=1e-3)


@pytest.mark.parametrize("h", [2e-6, 2e-3, 2.0])
def test_a_body_too_far_from_the_origin_is_refused_with_the_same_verdict_at_every_unit(h, tmp_path, monkeypatch,
                                                                                        capfd):
    """A beam 5e11 voxel sizes from the origin (1e9 m at 2 mm voxels): coordinates carry 1.8e-3 of a voxel, the
    frames' answer moved 1 % and at 5e14 the end-face probe was 'outside the material'.  Refused before anything is
    built, naming the distance and the fix, at 2 um, 2 mm and 2 m voxels alike; 1e7 voxel sizes out runs."""
    from robust import assert_refused

    from voxflex.cli import main

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("VOXFLEX_PROGRESS", "0")

    def text(out):
        x0 = out * h
        # the modulus scales with the size (rho g L / E fixed): the same scene at every unit
        return beam("voxel", size=(20 * h, 5 * h, 5 * h), h=h, young=repr(1.0e5 * h / 2e-3), density="1000.0",
                    fixed_max=f"[{x0 + 0.05 * h!r}, 1.0e12, 1.0e12]").replace(
            "origin = [0.0, 0.0, 0.0]", f"origin = [{x0!r}, 0.0, 0.0]").replace(
            "min = [-1.0e9, -1.0e9, -1.0e9]", "min = [-1.0e15, -1.0e15, -1.0e15]").replace(
            f"point = [{20 * h!r},", f"point = [{x0 + 20 * h!r},")

    (tmp_path / "far.toml").write_text(text(5e11))
    status = main(["simulate", "far.toml", "-o", "far.h5", "--quiet"])
    assert_refused(status, capfd.readouterr()[1], "simulate",
                   ["the object lies", "5e+11 voxel sizes", "move it near the origin"])
    (tmp_path / "near.toml").write_text(text(1e7))
    assert main(["simulate", "near.toml", "-o", "near.h5", "--quiet"]) == 0
