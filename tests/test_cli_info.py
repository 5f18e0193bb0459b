"""``voxflex info``: images, scenes and result files, and its errors."""

from __future__ import annotations

import sys
import types

import h5py
import numpy as np
import pytest

from voxflex.cli import main
from voxflex.image import LabelImage


@pytest.fixture
def image_file(tmp_path):
    labels = np.zeros((6, 4, 2), dtype=np.uint8)
    labels[0:2, 0:2, :] = 3  # 8 voxels
    labels[4:6, 2:4, :] = 5  # 8 voxels
    labels[5, 0, 0] = 5  # a second part of label 5
    path = tmp_path / "part.nii.gz"
    LabelImage(labels, spacing=[0.5, 0.25, 0.125], origin=[1.0, 2.0, 3.0]).save(path)
    return path


def test_info_on_an_image(image_file, capsys):
    assert main(["info", str(image_file)]) == 0
    out = capsys.readouterr().out
    assert "6 x 4 x 2" in out
    assert "[0.5, 0.25, 0.125] m" in out
    assert "[1, 2, 3] m" in out
    lines = out.splitlines()
    table = lines[next(i for i, line in enumerate(lines) if "volume m^3" in line) + 1 :]
    table = table[: next(i for i, line in enumerate(table) if line.strip().startswith("total"))]
    rows = {line.split()[0]: line.split() for line in table}
    # label, voxels, volume (count x 1/64 m^3), share, parts
    assert rows["3"][1:3] == ["8", "0.125"] and rows["3"][4] == "1"
    assert rows["5"][1:3] == ["9", "0.140625"] and rows["5"][4] == "2"
    # material components by face connectivity (the default): the two 2x2x2 blocks and the
    # stray voxel (5, 0, 0), which shares no face with either; largest first
    assert "components 3 (face connectivity" in out
    comps = lines[next(i for i, line in enumerate(lines) if line.strip().startswith("#")) + 1 :][:3]
    assert [c.split()[:3] for c in comps] == [["1", "8", "3"], ["2", "8", "5"], ["3", "1", "5"]]
    assert comps[2].endswith("[5, 0, 0] to [5, 0, 0]")


def test_info_connectivity_option(image_file, capsys):
    # touching at all (26 neighbours), (5, 0, 0) still touches nothing: the blocks are 2 voxels apart
    assert main(["info", str(image_file), "--connectivity", "vertex", "--largest", "1"]) == 0
    out = capsys.readouterr().out
    assert "components 3 (vertex connectivity" in out
    assert "... and 2 smaller component(s) with 9 voxels in all" in out


def test_info_on_an_all_zero_image(tmp_path, capsys):
    LabelImage(np.zeros((3, 2, 2), dtype=np.uint8), spacing=0.1).save(tmp_path / "empty.nrrd")
    assert main(["info", str(tmp_path / "empty.nrrd")]) == 0
    out = capsys.readouterr().out
    assert "none: all 12 voxels are 0 (empty); the image holds no material" in out


def test_info_with_spacing_for_a_bare_npy(tmp_path, capsys):
    np.save(tmp_path / "raw.npy", np.ones((2, 3, 4), dtype=np.uint8))
    assert main(["info", str(tmp_path / "raw.npy"), "--spacing", "0.1", "0.2", "0.3"]) == 0
    out = capsys.readouterr().out
    assert "[0.1, 0.2, 0.3] m" in out and "2 x 3 x 4" in out


def test_info_on_a_missing_file(tmp_path, capsys):
    status = main(["info", str(tmp_path / "missing.nii.gz")])
    err = capsys.readouterr().err.strip().splitlines()
    assert status != 0
    assert len(err) == 1 and "not found" in err[0]


def test_info_on_a_corrupt_file_is_one_line(tmp_path, capsys):
    (tmp_path / "bad.vti").write_text("not VTK")
    status = main(["info", str(tmp_path / "bad.vti")])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and "cannot read" in err[0]


def test_info_help(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["info", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "--spacing" in out and ".nii.gz" in out


def test_info_on_a_scene_calls_describe_scene(tmp_path, capsys, monkeypatch):
    scene = tmp_path / "beam.toml"
    scene.write_text("[object]\nshape = 'box'\n")
    fake = types.ModuleType("voxflex.scene")
    fake.describe_scene = lambda path: f"scene at {path.name}"
    monkeypatch.setitem(sys.modules, "voxflex.scene", fake)
    assert main(["info", str(scene)]) == 0
    assert capsys.readouterr().out.strip() == "scene at beam.toml"


def test_info_on_a_result_calls_describe_result(tmp_path, capsys, monkeypatch):
    path = tmp_path / "result.h5"
    with h5py.File(path, "w") as f:
        f["time"] = np.zeros(2)
    fake = types.ModuleType("voxflex.result_text")
    fake.describe_result = lambda p: f"result at {p.name}"
    monkeypatch.setitem(sys.modules, "voxflex.result_text", fake)
    assert main(["info", str(path)]) == 0
    assert capsys.readouterr().out.strip() == "result at result.h5"


def test_info_without_the_scene_module(tmp_path, capsys, monkeypatch):
    scene = tmp_path / "beam.toml"
    scene.write_text("")
    monkeypatch.setitem(sys.modules, "voxflex.scene", None)  # import fails as if the module were absent
    status = main(["info", str(scene)])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and "not available in this build" in err[0]
