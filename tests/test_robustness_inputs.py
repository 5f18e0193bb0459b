"""Inputs and accepted states at the extremes (issue 27): the Python API protects files as the command line
does; magnitudes double precision cannot carry, and loads no solid carries, are refused; every accepted
state is finite, in balance and of plausible size, or the run says so."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import robust
from robust import assert_refused, beam

import voxflex as vf
from voxflex.cli import main
from voxflex.errors import ConvergenceError, InputError, VoxflexError
from voxflex.guards import GROWTH_REFUSE, RESIDUAL_REFUSE, ImplausibleStateWarning, StateCheck
from voxflex.scene import Scene
from voxflex.simulation import InversionWarning


@pytest.fixture
def folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("VOXFLEX_PROGRESS", "0")
    (tmp_path / "beam.toml").write_text(beam())
    return tmp_path


# ---------------------------------------------------------------------------
# the API protects files like the command line
# ---------------------------------------------------------------------------
def _precious(folder):
    (folder / "notes.h5").write_text("precious notes\n")
    (folder / "picture.png").write_bytes(b"\x89PNG\r\n\x1a\nprecious")
    return {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()}


@pytest.mark.parametrize("target, expected", [
    ("beam.toml", "is the scene file of this run"),
    ("notes.h5", "is not a voxflex result file"),
    ("picture.png", "must end in .h5"),
    ("adir", "is a folder"),
    ("missing/r.h5", "does not exist"),
])
def test_simulate_refuses_to_destroy_a_file(folder, target, expected):
    (folder / "adir").mkdir()
    before = _precious(folder)
    scene = Scene.from_toml(folder / "beam.toml")
    with pytest.raises(InputError, match=expected) as info:
        vf.simulate(scene, progress=False, output=folder / target)
    assert "\n" not in str(info.value)
    assert {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()} == before
    assert not list(folder.glob(".*"))  # no temporary left


def test_simulate_refuses_the_scene_file_given_as_a_path(folder):
    with pytest.raises(InputError, match="scene file of this run.*force=True"):
        vf.simulate(folder / "beam.toml", progress=False, output=folder / "beam.toml")


def test_simulate_refuses_the_scene_image(folder):
    from voxflex.image import LabelImage

    LabelImage(np.ones((4, 2, 2), dtype=np.uint8), spacing=0.5).save(folder / "img.h5")
    (folder / "img.toml").write_text(robust.image_scene("img.h5", probe="[2.0, 0.5, 0.5]"))
    with pytest.raises(InputError, match="the scene's image"):
        vf.simulate(Scene.from_toml(folder / "img.toml"), progress=False, output=folder / "img.h5")


def test_force_lets_the_api_overwrite_a_foreign_file(folder):
    _precious(folder)
    r = vf.simulate(Scene.from_toml(folder / "beam.toml"), progress=False, output=folder / "notes.h5", force=True)
    assert vf.Result.load(folder / "notes.h5").n_states == r.n_states == 2


def test_the_scene_output_file_is_checked_too(folder):
    _precious(folder)
    (folder / "out.toml").write_text(beam() + '\n[output]\nfile = "notes.h5"\n')
    with pytest.raises(InputError, match=r"\[output\] file"):
        vf.simulate(Scene.from_toml(folder / "out.toml"), progress=False)


# ---------------------------------------------------------------------------
# magnitudes
# ---------------------------------------------------------------------------
REFUSED = [
    ("gravity_1e200", dict(gravity="[0.0, 0.0, -1e200]"), "outside 1e-100 .. 1e+100"),
    ("gravity_1e30", dict(gravity="[0.0, 0.0, -1e30]"), "the load would strain the body 4e+26 times"),
    ("gravity_1e8", dict(gravity="[0.0, 0.0, -1e8]"), "the load would strain the body 4e+04 times"),
    ("young_1e-300", dict(young="1e-300"), "young = 1e-300 is outside"),
    ("young_5e-324", dict(young="5e-324"), "young = 5e-324 is outside"),
    ("young_1e-3", dict(young="1e-3"), "the load would strain the body"),
    ("density_1e300", dict(density="1e300"), "density = 1e+300 is outside"),
    ("density_1e-120", dict(density="1e-120"), "density = 1e-120 is outside"),
    ("voxel_1e-120", dict(h=1e-120, size=(4e-120, 1e-120, 1e-120)), "voxel size along x = 1e-120 is outside"),
    ("gravity_tiny", dict(gravity="[0.0, 0.0, -1e-150]"), "vector magnitude = 1e-150 is outside"),
]


@pytest.mark.parametrize("kind", ["voxel", "affine"])
@pytest.mark.parametrize("name, kw, expected", REFUSED, ids=[c[0] for c in REFUSED])
def test_absurd_magnitudes_are_refused(folder, capfd, kind, name, kw, expected):
    nodes = "count = 4" if kind == "affine" else ""
    (folder / "s.toml").write_text(beam(kind, nodes=nodes, **kw))
    status = main(["simulate", "s.toml", "-o", "r.h5", "--quiet"])
    assert_refused(status, capfd.readouterr().err, "simulate", expected)
    assert not (folder / "r.h5").exists()


def _damped(kind, rayleigh):
    text = beam(kind, nodes="count = 4" if kind == "affine" else "", solver=f"steps = 2\ndt = 0.05\n{rayleigh}")
    return text.replace('kind = "static"', 'kind = "implicit-euler"')


@pytest.mark.parametrize("kind", ["voxel", "affine"])
def test_stiffness_proportional_damping_runs_and_absurd_damping_is_refused(folder, capfd, kind):
    """Round 27: ``rayleigh_stiffness`` with frames (the default model) was a numpy ``ValueError`` traceback at
    the first step (the sparse mass plus the frames' dense stiffness is an ``np.matrix``); 1e300 with voxels ran
    to a tip of -7.6e-305 m, exit 0.  Now the frames run, damping slows the fall as it does for voxels, and a
    coefficient double precision cannot carry is refused like dt."""
    tip = {}
    for beta in ("0.0", "0.01"):
        r = vf.simulate(Scene.from_toml_text(_damped(kind, f"rayleigh_stiffness = {beta}")), progress=False)
        tip[beta] = r.probe_displacements()["tip"][2]
    assert np.isfinite(tip["0.01"]) and tip["0.0"] < tip["0.01"] < 0
    (folder / "s.toml").write_text(_damped(kind, "rayleigh_stiffness = 1e300"))
    status = main(["simulate", "s.toml", "-o", "r.h5", "--quiet"])
    assert_refused(status, capfd.readouterr().err, "simulate", "rayleigh_stiffness = 1e+300 is outside")


def test_traction_and_force_loads_are_measured_against_the_stiffness(folder):
    for load, expected in (('kind = "traction"\nvector = [0.0, 0.0, -1e9]\nmin = [3.9, -1.0, -1.0]', "|t| / E"),
                           ('kind = "force"\nvector = [0.0, 0.0, -1e12]\nmin = [3.9, -1.0, -1.0]', "|F| / (E A)")):
        text = beam().replace('[[load]]\nkind = "gravity"\nvector = [0.0, 0.0, -9.81]', "[[load]]\n" + load)
        with pytest.raises(InputError, match=expected.replace("|", r"\|").replace("(", r"\(").replace(")", r"\)")):
            vf.simulate(Scene.from_toml_text(text), progress=False)


@pytest.mark.parametrize("kind", ["voxel", "affine"])
def test_large_but_physical_loads_run_and_are_plausible(kind):
    """rho g L / E = 0.04 (a soft jelly under its weight): accepted, finite, and no warning."""
    scene = Scene.from_toml_text(beam(kind, model="neo-hookean", elasticity="", young="1.0e3",
                                      nodes="count = 6" if kind == "affine" else "", solver="steps = 4"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = vf.simulate(scene, progress=False)
    u = robust.tip(r)
    assert -4.0 < u[2] < -0.5  # sags a lot (large deformation), less than its length
    assert np.all(np.isfinite(r.surface_positions)) and r.totals["inverted_samples"] == 0


def test_no_numpy_overflow_warning_leaks(folder, capfd):
    """A load at the edge of what is accepted on a very soft linear body: whatever the solver meets inside,
    the user sees voxflex's own lines only."""
    (folder / "s.toml").write_text(beam(young="1.0", gravity="[0.0, 0.0, -200.0]"))
    main(["simulate", "s.toml", "-o", "r.h5", "--quiet"])
    err = capfd.readouterr().err
    assert "RuntimeWarning" not in err and "overflow" not in err.lower()


# ---------------------------------------------------------------------------
# every accepted state
# ---------------------------------------------------------------------------
def test_a_non_finite_state_is_refused():
    check = StateCheck(np.zeros((2, 3)) + [[0, 0, 0], [1, 1, 1]])
    for bad in (np.nan, np.inf, -np.inf):
        q = np.ones((4, 3))
        q[1, 2] = bad
        with pytest.raises(ConvergenceError, match="not finite"):
            check(3, q, np.ones((2, 3)), 0.0)


def test_a_non_finite_drawn_surface_is_refused():
    check = StateCheck(np.array([[0, 0, 0], [1, 1, 1]], dtype=float))
    for bad in (np.nan, np.inf, -np.inf):
        for where in ((0, 0), (1, 2)):
            surface = np.ones((2, 3))
            surface[where] = bad
            with pytest.raises(ConvergenceError, match="drawn surface is not finite"):
                check(3, np.zeros(3), surface, 0.0)
    check(3, np.zeros(3), np.ones((2, 3)), 0.0)


def test_a_step_accepted_out_of_balance_is_refused():
    check = StateCheck(np.array([[0, 0, 0], [1, 1, 1]], dtype=float))
    check(1, np.zeros(3), np.zeros((2, 3)), RESIDUAL_REFUSE / 2)
    with pytest.raises(ConvergenceError, match="relative residual 1.00e\\+00"):
        check(2, np.zeros(3), np.zeros((2, 3)), 1.0)


def test_a_body_grown_a_thousandfold_is_refused_and_tenfold_warned():
    rest = np.array([[0, 0, 0], [1, 1, 1]], dtype=float)
    check = StateCheck(rest)
    check(1, np.zeros(3), rest * 20, 0.0)
    with pytest.warns(ImplausibleStateWarning, match="20 times its rest size"):
        check.warn()
    with pytest.raises(ConvergenceError, match="times its rest size"):
        check(2, np.zeros(3), rest * 2 * GROWTH_REFUSE, 0.0)


def test_a_linear_run_far_beyond_small_strains_is_warned_about():
    """A one-voxel-thick linear plate sagging 3.5 times its length under gravity x 10: the run says the
    state is implausible and that samples inverted (linear strain does not stop it)."""
    scene = Scene.from_toml_text(beam(size=(4.0, 1.0, 0.25), h=0.25, gravity="[0.0, 0.0, -300.0]"))
    with pytest.warns(Warning) as caught:
        r = vf.simulate(scene, progress=False)
    kinds = {w.category for w in caught}
    assert ImplausibleStateWarning in kinds or InversionWarning in kinds, [str(w.message) for w in caught]
    assert np.all(np.isfinite(r.surface_positions))


def test_inverted_samples_of_any_material_are_warned_about():
    from voxflex.simulation import _warn_inversion

    class _Rec:
        first_inverted = (2, 5)
        totals = {"min_det_F": -0.3}

    class _Model:
        materials = {1: vf.material("neo-hookean", young=1e4, poisson=0.3)}

    with pytest.warns(InversionWarning, match="5 samples inverted.*not physical"):
        _warn_inversion(_Model(), _Rec())


def test_friction_1e12_is_not_accepted_at_relative_residual_1(folder, capfd, monkeypatch):
    """A sliding ball on a plane with friction 1e12: the round-off floor of the friction stiffness let Newton
    accept residual 1.0.  The scene refuses it (no Coulomb coefficient, a one-line message naming the
    range); past that check (the bound lifted), the run stops at that step with the reason (earlier steps
    kept, marked)."""
    import pathlib

    import voxflex.scene_tables as scene_module

    text = pathlib.Path(robust.__file__).resolve().parents[2].joinpath("examples", "ball_on_plane.toml").read_text()
    text = text.replace("normal = [0.0, 0.0, 1.0]", "normal = [0.0, 0.0, 1.0]\nfriction = 1e12")
    text = text.replace("vector = [0.0, 0.0, -9.81]", "vector = [3.0, 0.0, -9.81]").replace("steps = 50", "steps = 6")
    (folder / "f.toml").write_text(text)
    status = main(["simulate", "f.toml", "-o", "r.h5", "--quiet"])
    assert_refused(status, capfd.readouterr().err, "simulate", ["friction = 1e+12", "no Coulomb coefficient", "[0, 100]"])
    assert not (folder / "r.h5").exists()
    monkeypatch.setattr(scene_module, "FRICTION_MAX", float("inf"))
    status = main(["simulate", "f.toml", "-o", "r.h5", "--quiet"])
    line = assert_refused(status, capfd.readouterr().err, "simulate", ["relative residual", "not an equilibrium"])
    assert "marked incomplete" in line
    r = vf.Result.load(folder / "r.h5")
    assert not r.complete and np.all(np.isfinite(r.surface_positions))


def test_the_state_check_error_reaches_the_api_as_a_voxflex_error(monkeypatch):
    """A model whose solve yields NaN (a stand-in for an overflow) ends in a VoxflexError, not exit 0."""
    from voxflex import simulation

    original = simulation._Recorder.__call__

    def poisoned(self, rec):
        if self.count == 1:
            rec.q = np.full_like(np.asarray(rec.q, dtype=float), np.nan)
        return original(self, rec)

    monkeypatch.setattr(simulation._Recorder, "__call__", poisoned)
    with pytest.raises(VoxflexError, match="not finite"):
        vf.simulate(Scene.from_toml_text(beam()), progress=False)


# ---------------------------------------------------------------------------
# wrong types through the Python API (round 27b: notebook users): one InputError, no traceback from inside
# ---------------------------------------------------------------------------
def _image():
    return vf.voxelize("box:4,1,1", 0.5)


API_REFUSED = [
    ("simulate TOML text", lambda: vf.simulate(beam(), progress=False), "vf.Scene.from_toml_text"),
    ("simulate output=5", lambda: vf.simulate(Scene.from_toml_text(beam()), progress=False, output=5),
     "output must be a result file path"),
    ("simulate model='voxel'", lambda: vf.simulate(Scene.from_toml_text(beam()), progress=False, model="voxel"),
     "[nodes] kind"),
    ("model of a dict", lambda: vf.model({"object": {}}), "vf.model needs a Scene"),
    ("model image=array", lambda: vf.model(Scene.from_toml_text(beam()), image=np.ones((8, 2, 2))),
     "must be the scene's LabelImage"),
    ("place_frames of an array", lambda: vf.place_frames(np.ones((8, 2, 2)), 3), "image must be a LabelImage"),
    ("shape_function of None", lambda: vf.shape_function(None, [[0.25, 0.25, 0.25]]), "image must be a LabelImage"),
    ("geodesic_distance of an array", lambda: vf.geodesic_distance(np.ones((8, 2, 2)), [[0.25, 0.25, 0.25]]),
     "image must be a LabelImage"),
    ("place_frames seed='a'", lambda: vf.place_frames(_image(), 3, seed="a"), "seed must be an integer >= 0"),
    ("voxelize voxel_size=True", lambda: vf.voxelize("box:4,1,1", True), "voxel size must be a number"),
    ("from_toml_text bytes", lambda: Scene.from_toml_text(beam().encode()), ".decode('utf-8')"),
    ("from_toml_text None", lambda: Scene.from_toml_text(None), "vf.Scene.from_toml(path)"),
    ("from_toml_text base_dir=5", lambda: Scene.from_toml_text(beam(), base_dir=5), "base_dir must be a folder"),
    ("Scene fixed=None", lambda: __import__("dataclasses").replace(Scene.from_toml_text(beam()), fixed=None),
     "Scene.fixed must be a sequence of FixedSpec"),
    ("a NUL in the title", lambda: Scene.from_toml_text('title = "a\\u0000b"\n' + beam()), "NUL character"),
    ("a lone surrogate in the title",
     lambda: __import__("dataclasses").replace(Scene.from_toml_text(beam()), title="a\udc80"), "lone surrogate"),
]


@pytest.mark.parametrize("name, call, expected", API_REFUSED, ids=[c[0] for c in API_REFUSED])
def test_wrong_types_through_the_api_are_one_input_error(folder, name, call, expected):
    with pytest.raises(InputError) as info:
        call()
    assert expected in str(info.value) and "\n" not in str(info.value), str(info.value)


def test_a_scene_with_a_byte_order_mark_and_control_characters_reads_back(folder):
    """A BOM (Windows editors) was 'Invalid statement (at line 1, column 1)'; a control character in a title
    was written raw by to_toml (TOML refuses it: the result's scene text did not read back)."""
    import dataclasses

    (folder / "bom.toml").write_text("\ufeff" + beam(), encoding="utf-8")
    scene = Scene.from_toml(folder / "bom.toml")
    titled = dataclasses.replace(scene, title="tab\there, bell\x07, del\x7f")
    assert Scene.from_toml_text(titled.to_toml()) == titled


def test_a_model_built_for_another_scene_is_refused_naming_the_tables():
    """vf.simulate(S, model=vf.model(S2)) with S2 another Young's modulus returned S2's answer (a sag 100x too
    small) under S's title and scene text (round 27b).  A model built by vf.model carries its scene's model tables;
    simulate names the ones that differ.  Another load or solver on the same model is the run's own: taken."""
    from dataclasses import replace

    from voxflex.errors import InputError
    from voxflex.scene import Scene

    scene = Scene.from_toml_text(beam("voxel", young="1.0e4"))
    other = Scene.from_toml_text(beam("voxel", young="1.0e6"))
    model = vf.model(other, cache=False)
    with pytest.raises(InputError, match=r"the model was built for another scene: its \[materials\] differ"):
        vf.simulate(scene, model=model, progress=False)
    heavier = replace(other, loads=tuple(replace(ld, vector=(0.0, 0.0, -19.62)) for ld in other.loads))
    u1 = vf.simulate(other, model=model, progress=False).probe_displacements()["tip"][2]
    u2 = vf.simulate(heavier, model=model, progress=False).probe_displacements()["tip"][2]
    assert u2 == pytest.approx(2.0 * u1, rel=1e-9)  # linear strain: twice the load, twice the sag
