"""Tracebacks that became one-line errors, and messages that name the right cause (issue 27): damaged
files (obstacle SDFs, result files), output names at the file-name limit, outputs the system refuses, a disk
that fills during the run, sweeps asked for impossible grids, renders of garbage or failed runs, folders
given as files, flat membranes, frame counts the object cannot hold."""

from __future__ import annotations

import errno
import random
import shutil
from pathlib import Path

import numpy as np
import pytest
import robust
from robust import assert_refused, beam

import voxflex as vf
from voxflex.cli import main
from voxflex.errors import VoxflexError
from voxflex.scene import Scene


@pytest.fixture(scope="module")
def result_file(tmp_path_factory):
    folder = tmp_path_factory.mktemp("result")
    vf.simulate(Scene.from_toml_text(beam()), progress=False, output=folder / "good.h5")
    return folder / "good.h5"


@pytest.fixture
def folder(tmp_path, monkeypatch, result_file):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("VOXFLEX_PROGRESS", "0")
    shutil.copy(result_file, tmp_path / "good.h5")
    (tmp_path / "beam.toml").write_text(beam())
    return tmp_path


def _run(capfd, *argv):
    status = main(list(argv))
    return status, capfd.readouterr().err


# ---------------------------------------------------------------------------
# damaged result files in info and render
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("command", ["info", "render"])
def test_a_byte_damaged_result_is_one_line(folder, capfd, seed, command):
    data = bytearray((folder / "good.h5").read_bytes())
    rng = random.Random(seed)
    for _ in range(200):
        i = rng.randrange(512, len(data))
        data[i] = rng.randrange(256)
    (folder / "bad.h5").write_bytes(bytes(data))
    argv = ["info", "bad.h5"] if command == "info" else ["render", "bad.h5", "-o", "bad.png"]
    status, err = _run(capfd, *argv)
    if status == 0:  # the damage missed everything read: then the answer read is what was written
        assert "Traceback" not in err
        return
    assert_refused(status, err, command, "bad.h5")
    assert not (folder / "bad.png").exists()


@pytest.mark.parametrize("command", ["info", "render"])
def test_a_truncated_result_is_called_damaged(folder, capfd, command):
    data = (folder / "good.h5").read_bytes()
    (folder / "cut.h5").write_bytes(data[: len(data) // 2])
    argv = ["info", "cut.h5"] if command == "info" else ["render", "cut.h5", "-o", "cut.png"]
    status, err = _run(capfd, *argv)
    line = assert_refused(status, err, command, "cut.h5")
    assert "truncated" in line or "damaged" in line


@pytest.mark.parametrize("value, expected", [(np.nan, "not finite"), (1e300, "times its size")])
def test_render_refuses_garbage_positions(folder, capfd, value, expected):
    import h5py

    shutil.copy(folder / "good.h5", folder / "g.h5")
    with h5py.File(folder / "g.h5", "r+") as f:
        a = f["surface/positions"][()]
        a[-1, 3] = value
        f["surface/positions"][...] = a
    status, err = _run(capfd, "render", "g.h5", "-o", "g.png")
    assert_refused(status, err, "render", ["state 1", expected])
    assert not (folder / "g.png").exists()
    status = main(["info", "g.h5"])  # info describes the file (exit 0), and says when it is not finite
    out, err = capfd.readouterr()
    assert status == 0 and "Traceback" not in err and "RuntimeWarning" not in err
    assert ("DAMAGED" in out) == (value != value)


def test_a_failed_run_is_titled_with_its_failure(result_file):
    """The title band of a picture of an incomplete result names the failure (it said 'step 1/1')."""
    import dataclasses

    from voxflex import _render_annotations, _render_style

    r = vf.Result.load(result_file)
    failed = dataclasses.replace(r, complete=False, error="static step 2/5: Newton did not converge")
    texts = []

    class _Draw:
        def text(self, xy, text, **kw):
            texts.append(text)

    layout = _render_annotations._Layout((800, 450), 12, 40, 700, 100, None, "", None, None)
    style = _render_style._style(failed, window_size=(800, 450), title=None, cmap="viridis", view="iso",
                                 azimuth=None, elevation=None, up="z", color="displacement", show_rest=True, axes=True,
                                 gravity=True, frames=True)
    layout._title(_Draw(), style, failed, 1)
    assert any("FAILED after step 1" in t for t in texts), texts
    texts.clear()
    layout._title(_Draw(), style, r, 1)
    assert not any("FAILED" in t for t in texts)


# ---------------------------------------------------------------------------
# output names and places the system refuses
# ---------------------------------------------------------------------------
def test_an_output_name_at_the_limit_leaves_a_short_enough_temporary(folder):
    name = "a" * 252 + ".h5"  # 255 bytes: its temporary '.STEM.XXXXXXXX.h5' used to be 266
    r = vf.simulate(Scene.from_toml(folder / "beam.toml"), progress=False, output=folder / name)
    assert (folder / name).is_file() and np.all(np.isfinite(r.surface_positions))
    assert not [p for p in folder.iterdir() if p.name.startswith(".")]


@pytest.mark.parametrize("argv, command", [
    (["simulate", "beam.toml", "-o", "c" * 260 + ".h5", "--quiet"], "simulate"),
    (["render", "good.h5", "-o", "c" * 260 + ".png"], "render"),
    (["render", "c" * 260 + ".h5", "-o", "x.png"], "render"),
    (["info", "c" * 260 + ".h5"], "info"),
    (["render", "good.h5", "-o", "c" * 260], "render"),
])
def test_a_name_beyond_the_limit_is_one_line(folder, capfd, argv, command):
    status, err = _run(capfd, *argv)
    line = assert_refused(status, err, command, "")
    assert "bytes long" in line or "too long" in line.lower() or "File name too long" in line


@pytest.mark.parametrize("argv, command", [
    (["render", "good.h5", "-o", "/proc/x.png"], "render"),
    (["render", "good.h5", "-o", "/proc/"], "render"),
    (["render", "good.h5", "-o", "/proc/frames/"], "render"),
    (["tradeoff", "beam.toml", "-o", "/proc/sweep", "--quiet"], "tradeoff"),
    (["simulate", "beam.toml", "-o", "/proc/r.h5", "--quiet"], "simulate"),
    (["simulate", "beam.toml", "--vtk", "/proc/", "--quiet"], "simulate"),
])
def test_outputs_under_proc_are_refused_before_any_work(folder, capfd, argv, command):
    status, err = _run(capfd, *argv)
    assert_refused(status, err, command, "/proc")


# ---------------------------------------------------------------------------
# a disk that fills during the run
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("where, exc", [
    ("append", OSError(errno.ENOSPC, "No space left on device")),
    ("close", RuntimeError("Can't decrement id ref count (file write failed: errno = 28, error message = "
                           "'No space left on device')")),
])
def test_a_disk_that_fills_during_the_run_is_one_line_and_keeps_the_old_file(folder, capfd, monkeypatch, where, exc):
    from voxflex.result import ResultWriter

    (folder / "r.h5").write_bytes((folder / "good.h5").read_bytes())
    before = (folder / "r.h5").read_bytes()
    original = getattr(ResultWriter, where)

    def full(self, *a, **k):
        if where == "close":
            original(self, *a, **k)
        raise exc

    monkeypatch.setattr(ResultWriter, where, full)
    (folder / "s.toml").write_text(beam(solver="steps = 3"))
    status, err = _run(capfd, "simulate", "s.toml", "-o", "r.h5", "--quiet")
    assert_refused(status, err, "simulate", ["the disk is full", "nothing was replaced"])
    assert (folder / "r.h5").read_bytes() == before
    assert not [p for p in folder.iterdir() if p.name.startswith(".")]


def test_another_writer_error_is_not_disguised(folder, monkeypatch):
    """A bug in the writer (not an I/O failure) still raises as itself."""
    from voxflex.result import ResultWriter

    def broken(self, row):
        raise KeyError("a bug")

    monkeypatch.setattr(ResultWriter, "append", broken)
    with pytest.raises(KeyError):
        vf.simulate(Scene.from_toml(folder / "beam.toml"), progress=False, output=folder / "r2.h5")


# ---------------------------------------------------------------------------
# obstacle files
# ---------------------------------------------------------------------------
def _sdf_files(folder):
    d = np.linspace(-1, 1, 512).reshape(8, 8, 8)
    np.savez(folder / "good_sdf.npz", distance=d, spacing=np.full(3, 0.5), origin=np.array([-2.0, -2, -5]))
    data = (folder / "good_sdf.npz").read_bytes()
    (folder / "trunc.npz").write_bytes(data[: len(data) // 2])
    b = bytearray(data)
    for i in range(200, len(b), 97):
        b[i] ^= 0x5A
    (folder / "bytes.npz").write_bytes(bytes(b))
    (folder / "text.npz").write_text("not a zip file at all")
    np.savez(folder / "nokey.npz", foo=d)
    np.savez(folder / "strings.npz", distance=np.array(["a", "b"]), spacing=np.ones(3), origin=np.zeros(3))
    np.savez(folder / "nan.npz", distance=np.full((8, 8, 8), np.nan), spacing=np.full(3, 0.5), origin=np.zeros(3))
    (folder / "adir.npz").mkdir()


@pytest.mark.parametrize("name, expected", [
    ("trunc.npz", "cannot be read"), ("bytes.npz", "holds neither"), ("text.npz", "cannot be read"),
    ("nokey.npz", "holds neither 'distance'"), ("strings.npz", "must be numbers"), ("nan.npz", "finite"),
    ("adir.npz", "is a folder"), ("missing.npz", "not found"),
])
def test_a_bad_obstacle_file_is_one_line(folder, capfd, name, expected):
    _sdf_files(folder)
    text = beam("voxel", extra=f'\n[[obstacle]]\nkind = "sdf"\nfile = "{name}"\n')
    (folder / "s.toml").write_text(text)
    status, err = _run(capfd, "simulate", "s.toml", "-o", "r.h5", "--quiet")
    assert_refused(status, err, "simulate", expected)


# ---------------------------------------------------------------------------
# sweeps, folders, membranes, counts
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("levels", [3, 50])
def test_voxel_levels_beyond_the_image_name_the_largest_that_works(folder, capfd, levels):
    status, err = _run(capfd, "tradeoff", "beam.toml", "-o", "sweep", "--voxel-levels", str(levels), "--frames", "4",
                       "--quiet")
    assert_refused(status, err, "tradeoff", [f"voxel_levels = {levels}", "use voxel_levels <= 1"])


@pytest.mark.parametrize("argv, command, expected", [
    (["simulate", "adir", "-o", "r.h5", "--quiet"], "simulate", "scene file 'adir' is a folder"),
    (["info", "adir"], "info", "'adir' is a folder"),
    (["render", "adir", "-o", "x.png"], "render", "result file 'adir' is a folder"),
    (["render", "adir.h5", "-o", "x.png"], "render", "'adir.h5' is a folder"),
    (["voxelize", "adir.stl", "-o", "x.nrrd", "--voxel-size", "0.1"], "voxelize", "is a folder"),
    (["info", "adir.nrrd"], "info", "is a folder"),
])
def test_a_folder_given_as_a_file_is_named_as_a_folder(folder, capfd, argv, command, expected):
    for name in ("adir", "adir.h5", "adir.stl", "adir.nrrd"):
        (folder / name).mkdir()
    status, err = _run(capfd, *argv)
    line = assert_refused(status, err, command, expected)
    assert "extension" not in line and "not found" not in line


def test_a_scene_mesh_that_is_a_folder(folder, capfd):
    (folder / "part.stl").mkdir()
    text = beam().replace('shape = "box"\nsize = [4.0, 1.0, 1.0]\nvoxel_size = 0.5\norigin = [0.0, 0.0, 0.0]',
                          'mesh = "part.stl"\nvoxel_size = 0.5')
    (folder / "m.toml").write_text(text)
    status, err = _run(capfd, "simulate", "m.toml", "-o", "r.h5", "--quiet")
    assert_refused(status, err, "simulate", "is a folder")


def _flat_obj(folder):
    V = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 0]]
    F = [[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]]
    (folder / "flat.obj").write_text("".join(f"v {a} {b} {c}\n" for a, b, c in V)
                                     + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F))


def test_a_flat_membrane_mesh_runs(folder):
    _flat_obj(folder)
    text = """\
[object]
mesh = "flat.obj"
voxel_size = 0.1

[[material]]
model = "stvk"
young = 2.0e9
poisson = 0.3
density = 1400.0

[nodes]
kind = "membrane"

[membrane]
thickness = 5.0e-5
rim = "clamped"

[[load]]
kind = "pressure"
pressure = 100.0

[[probe]]
name = "centre"
point = [0.5, 0.5, 0.0]
"""
    r = vf.simulate(Scene.from_toml_text(text, base_dir=folder), progress=False)
    u = robust.tip(r, "centre")
    assert u[2] > 0 and u[2] < 0.5  # the pressure pushes the free centre along +z, by less than the sheet's size


def test_a_flat_solid_mesh_names_the_membrane_kind(folder, capfd):
    _flat_obj(folder)
    text = beam("affine").replace('shape = "box"\nsize = [4.0, 1.0, 1.0]\nvoxel_size = 0.5\norigin = [0.0, 0.0, 0.0]',
                                  'mesh = "flat.obj"\nvoxel_size = 0.1')
    (folder / "m.toml").write_text(text)
    status, err = _run(capfd, "simulate", "m.toml", "-o", "r.h5", "--quiet")
    assert_refused(status, err, "simulate", ["flat", 'kind = "membrane"'])


@pytest.mark.parametrize("count, output", [(100_000_000, "r.h5"), (100_000, "r.h5"), (100_000_000, None)])
def test_too_many_frames_blame_the_count_not_the_disk_or_memory(folder, capfd, count, output):
    (folder / "c.toml").write_text(beam("affine", nodes=f"count = {count}"))
    argv = ["simulate", "c.toml", "--quiet"] + (["-o", output] if output else [])
    status, err = _run(capfd, *argv)
    line = assert_refused(status, err, "simulate", ["[nodes] count", "use [nodes] count <= 32"])
    assert "free space" not in line and "available" not in line


def test_a_voxflex_error_from_the_api_is_one_line(folder):
    with pytest.raises(VoxflexError) as info:
        vf.simulate(Scene.from_toml_text(beam("affine", nodes="count = 100000000")), progress=False)
    assert "\n" not in str(info.value)


# ---------------------------------------------------------------------------
# results through the Python API (round 27b)
# ---------------------------------------------------------------------------
def test_result_save_protects_files_and_checks_what_was_edited(folder):
    """Result.save wrote over any file (a scene became HDF5), a folder was an IsADirectoryError, and an edited
    probes dict a ValueError from inside the writer."""
    r = vf.Result.load(folder / "good.h5")
    (folder / "notes.h5").write_text("precious\n")
    for target, expected in [("beam.toml", "must end in .h5"), ("notes.h5", "is not a voxflex result file"),
                             (".", "is a folder"), (5, "must be a path")]:
        with pytest.raises(vf.InputError, match=expected):
            r.save(target)
    assert (folder / "notes.h5").read_text() == "precious\n" and (folder / "beam.toml").read_text() == beam()
    r.save("notes.h5", force=True)
    assert vf.Result.load("notes.h5").n_states == r.n_states
    r.probes["tip"] = np.zeros((1, 3))  # the dataclass is frozen, its dicts are not
    with pytest.raises(vf.InputError, match="probe 'tip' must have shape"):
        r.save("edited.h5")
    with pytest.raises(vf.InputError, match="must be an integer state index"):
        r.displacement(1.0)


def test_export_vtk_into_odd_targets(folder):
    r = vf.Result.load(folder / "good.h5")
    (folder / "plain").write_text("x")
    with pytest.raises(vf.InputError, match="is a file"):
        r.export_vtk("plain")  # was FileExistsError
    (folder / "series.pvd").mkdir()
    assert r.export_vtk("series.pvd") == Path("series.pvd") / "result.pvd"  # was IsADirectoryError
    positions = np.array(r.surface_positions)
    positions[-1, 0, 0] = np.nan
    broken = vf.Result(**{**{k: getattr(r, k) for k in r.__dataclass_fields__}, "surface_positions": positions})
    with pytest.raises(vf.InputError, match="not finite"):
        broken.export_vtk("nan_series")  # was a series of NaN surfaces
    assert not (folder / "nan_series").exists() or not any((folder / "nan_series").iterdir())


@pytest.mark.parametrize("path, value, expected", [
    ("time", np.nan, "DAMAGED: the times"),
    ("energy/elastic", np.inf, "DAMAGED: the elastic energies"),
    ("probes/tip", np.nan, "DAMAGED: the probe tip's positions"),
])
def test_info_names_every_non_finite_series(folder, capfd, path, value, expected):
    import h5py

    with h5py.File(folder / "good.h5", "r+") as f:
        a = f[path][()]
        a.reshape(len(a), -1)[-1, 0] = value
        f[path][...] = a
    assert main(["info", "good.h5"]) == 0
    assert expected in capfd.readouterr().out


def test_a_result_with_an_impossible_image_geometry_is_refused_and_unknown_model_arrays_ignored(folder, capfd):
    import h5py

    with h5py.File(folder / "good.h5", "r+") as f:
        f["model"].attrs["future_array"] = np.arange(4)  # readers ignore what they do not know
    assert vf.Result.load(folder / "good.h5").n_states >= 2
    with h5py.File(folder / "good.h5", "r+") as f:
        f["image/labels"].attrs["spacing"] = [np.nan, 0.5, 0.5]
    status, err = _run(capfd, "info", "good.h5")
    assert_refused(status, err, "info", "image_spacing must be 3 finite lengths > 0")


@pytest.mark.parametrize("value, complete", [(True, True), (False, False), (1, True), (np.int8(0), False),
                                             ("no", None), (0.5, None)])
def test_the_complete_flag_reads_only_booleans(folder, capfd, value, complete):
    """A result's ``complete`` attribute edited to "no" read as True (round 27b): a flag is a boolean (or the
    integers 1 / 0 h5py may hand back); anything else is a damaged file, said in one line by info."""
    import h5py

    with h5py.File(folder / "good.h5", "r+") as f:
        f.attrs["complete"] = value
    if complete is not None:
        assert vf.Result.load(folder / "good.h5").complete is complete
        return
    status, err = _run(capfd, "info", "good.h5")
    assert_refused(status, err, "info", ["'complete' attribute is", "not a boolean: the file is damaged"])
