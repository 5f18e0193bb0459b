"""Outputs that cannot destroy inputs: atomic writes under signals, and the checks done before a run.

Oracles: byte-for-byte comparison of files before and after, directory
listings (no temporary ``.NAME.*`` file left), exit statuses.  Signals are sent
in-process (``os.kill`` of our own pid inside an atomic block, delivered
before ``kill`` returns).  The command line under signals (a child process held
inside its save) is covered by ``tests/test_bad_input.py``.
"""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path

import numpy as np
import paths
import pytest

from voxflex._atomic import Interrupted, atomic_path, check_output_path
from voxflex.cli import main
from voxflex.cli._outputs import (
    check_image_output,
    check_render_output,
    check_result_output,
    check_vtk_output,
    is_result_file,
)
from voxflex.errors import InputError
from voxflex.image import LabelImage
from voxflex.image.io import looks_like_image

EXAMPLES = paths.ROOT / "examples"


def _listing(folder: Path) -> dict:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


# -- atomic_path ------------------------------------------------------------------------------
def test_atomic_write_replaces_on_success_and_keeps_on_error(tmp_path):
    target = tmp_path / "a.txt"
    target.write_text("old")
    with atomic_path(target) as tmp:
        tmp.write_text("new")
    assert target.read_text() == "new"
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("writer failed")
    assert _listing(tmp_path) == {"a.txt": b"new"}


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_inside_a_save_removes_the_temp_and_keeps_the_old_file(tmp_path, signum):
    target = tmp_path / "a.txt"
    target.write_text("old")
    before = signal.getsignal(signum)
    with pytest.raises(Interrupted) as info:
        with atomic_path(target) as tmp:
            tmp.write_text("new")
            os.kill(os.getpid(), signum)  # recorded; the writer is not interrupted mid-call
            tmp.write_text("newer")
    assert info.value.signum == signum and isinstance(info.value, KeyboardInterrupt)
    assert _listing(tmp_path) == {"a.txt": b"old"}
    assert signal.getsignal(signum) is before  # the process's own handling is back


def test_a_second_signal_stops_the_writer_at_once(tmp_path):
    """For a write that hangs: the second signal raises inside the block, which never finishes."""
    target = tmp_path / "a.txt"
    target.write_text("old")
    reached = []
    with pytest.raises(Interrupted):
        with atomic_path(target) as tmp:
            tmp.write_text("new")
            os.kill(os.getpid(), signal.SIGINT)
            os.kill(os.getpid(), signal.SIGINT)
            reached.append(True)  # not reached
    assert reached == [] and _listing(tmp_path) == {"a.txt": b"old"}


def test_nested_saves_commit_together(tmp_path):
    """An .npy and its sidecar: both new after success, both old after a signal in either block."""
    image = LabelImage(np.ones((2, 2, 2), dtype=np.uint8), spacing=0.5)
    image.save(tmp_path / "a.npy")
    old = _listing(tmp_path)
    with pytest.raises(Interrupted):
        with atomic_path(tmp_path / "a.npy") as outer:
            np.save(outer, np.zeros((2, 2, 2), dtype=np.uint8))
            with atomic_path(tmp_path / "a.npy.json") as inner:
                inner.write_text("{}")
            # the inner block is over but its file must not be in place yet
            assert (tmp_path / "a.npy.json").read_bytes() == old["a.npy.json"]
            os.kill(os.getpid(), signal.SIGTERM)
    assert _listing(tmp_path) == old
    LabelImage(np.full((2, 2, 2), 3, dtype=np.uint8), spacing=0.25).save(tmp_path / "a.npy")
    assert set(_listing(tmp_path)) == {"a.npy", "a.npy.json"}
    assert json.loads((tmp_path / "a.npy.json").read_text())["spacing"] == [0.25] * 3
    assert LabelImage.load(tmp_path / "a.npy").labels.max() == 3


# -- checks before a run ----------------------------------------------------------------------
def test_check_output_path(tmp_path):
    assert check_output_path(tmp_path / "x.h5") == tmp_path / "x.h5"
    with pytest.raises(InputError, match="does not exist"):
        check_output_path(tmp_path / "missing" / "x.h5")
    with pytest.raises(InputError, match="is a folder"):
        check_output_path(tmp_path)
    (tmp_path / "f").write_text("")
    with pytest.raises(InputError, match="is a file, not a folder"):
        check_output_path(tmp_path / "f" / "x.h5")


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root writes anywhere; needs a normal user")
def test_unwritable_folder_is_refused(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        with pytest.raises(InputError, match="not writable"):
            check_output_path(locked / "x.h5")
    finally:
        locked.chmod(0o700)


@pytest.fixture(scope="module")
def result_file(tmp_path_factory):
    folder = tmp_path_factory.mktemp("result")
    out = folder / "r.h5"
    assert main(["simulate", str(EXAMPLES / "cantilever.toml"), "-o", str(out), "--quiet"]) == 0
    return out


def test_is_result_file(tmp_path, result_file):
    assert is_result_file(result_file)
    image = tmp_path / "image.h5"
    LabelImage(np.ones((2, 2, 2), dtype=np.uint8)).save(image)
    assert not is_result_file(image)  # a voxflex image file is HDF5 but not a result
    (tmp_path / "text.h5").write_text("hello")
    assert not is_result_file(tmp_path / "text.h5") and not is_result_file(tmp_path / "missing.h5")


def test_looks_like_image(tmp_path, result_file):
    image = LabelImage(np.ones((2, 2, 2), dtype=np.uint8), spacing=0.5)
    for ext in (".npy", ".npz", ".nii", ".nii.gz", ".nrrd", ".mha", ".tif", ".h5", ".vti"):
        image.save(tmp_path / f"a{ext}")
        assert looks_like_image(tmp_path / f"a{ext}"), ext
        (tmp_path / f"b{ext}").write_text("not an image at all")
        assert not looks_like_image(tmp_path / f"b{ext}"), ext
    assert not looks_like_image(result_file)  # a result holds /image/labels but is not an image file


def test_result_target_rules(tmp_path, result_file):
    scene = tmp_path / "s.toml"
    scene.write_text("")
    inputs = [("the scene file", scene)]
    assert check_result_output(tmp_path / "new.h5", inputs=inputs) == tmp_path / "new.h5"
    assert check_result_output(result_file, inputs=inputs) == result_file  # a result may be replaced
    with pytest.raises(InputError, match="is the scene file of this run"):
        check_result_output(scene, inputs=inputs)
    with pytest.raises(InputError, match=r"must end in \.h5 or \.hdf5.*-o .*new\.h5"):
        check_result_output(tmp_path / "new.txt", inputs=inputs)
    (tmp_path / "notes.h5").write_text("precious")
    with pytest.raises(InputError, match="not a voxflex result file.*--force"):
        check_result_output(tmp_path / "notes.h5", inputs=inputs)
    assert check_result_output(tmp_path / "notes.h5", inputs=inputs, force=True)


def test_image_target_rules(tmp_path, result_file):
    LabelImage(np.ones((2, 2, 2), dtype=np.uint8)).save(tmp_path / "old.nrrd")
    assert check_image_output(tmp_path / "old.nrrd")
    (tmp_path / "fake.nrrd").write_text("precious")
    with pytest.raises(InputError, match="not a NRRD image"):
        check_image_output(tmp_path / "fake.nrrd")
    with pytest.raises(InputError, match="is a simulation result"):
        check_image_output(result_file)
    (tmp_path / "a.npy.json").write_text('{"mine": 1}')
    with pytest.raises(InputError, match="not a voxflex sidecar"):
        check_image_output(tmp_path / "a.npy")
    assert check_image_output(tmp_path / "a.npy", force=True)
    with pytest.raises(InputError, match="unknown image file extension"):
        check_image_output(tmp_path / "a.bmp")


def test_render_and_vtk_target_rules(tmp_path):
    assert check_render_output(tmp_path / "a.png") and check_render_output(tmp_path / "frames")
    (tmp_path / "fake.gif").write_text("precious")
    with pytest.raises(InputError, match="not a .gif file"):
        check_render_output(tmp_path / "fake.gif")
    with pytest.raises(InputError, match="unknown extension '.bmp'"):
        check_render_output(tmp_path / "a.bmp")
    (tmp_path / "plain").write_text("")
    with pytest.raises(InputError, match="existing file, not a folder"):
        check_render_output(tmp_path / "plain")
    assert check_vtk_output(tmp_path / "vtk") and check_vtk_output(tmp_path / "series.pvd")
    with pytest.raises(InputError, match="existing file"):
        check_vtk_output(tmp_path / "plain")
    with pytest.raises(InputError, match="must be a folder .* or a .pvd file"):
        check_vtk_output(tmp_path / "x.vtp")
    (tmp_path / "series.pvd").write_text("precious")
    with pytest.raises(InputError, match="not a ParaView collection"):
        check_vtk_output(tmp_path / "series.pvd")
    mesh = tmp_path / "result_0001.vtp"
    mesh.write_text("")
    with pytest.raises(InputError, match="would write over the scene's mesh"):
        check_vtk_output(tmp_path, inputs=[("the scene's mesh", mesh)])


def test_force_overwrites_a_foreign_file_through_the_cli(tmp_path, capsys):
    target = tmp_path / "notes.h5"
    target.write_text("not a result")
    assert main(["simulate", str(EXAMPLES / "cantilever.toml"), "-o", str(target), "--quiet"]) == 2
    assert "pass --force" in capsys.readouterr().err and target.read_text() == "not a result"
    assert main(["simulate", str(EXAMPLES / "cantilever.toml"), "-o", str(target), "--quiet", "--force"]) == 0
    assert is_result_file(target)
