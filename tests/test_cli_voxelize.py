"""``voxflex voxelize`` through voxflex.cli.main: files written, summary, multi-label, errors."""

from __future__ import annotations

import numpy as np
import paths
import pytest

from voxflex import LabelImage
from voxflex.cli import main


def test_box_to_npz(tmp_path, capsys):
    out = tmp_path / "beam.npz"
    assert main(["voxelize", "box:4,1,1", "-o", str(out), "--voxel-size", "0.125"]) == 0
    line = capsys.readouterr().out.strip()
    assert line.count("\n") == 0 and "32x8x8" in line and "label 1: 2048 voxels" in line and "volume 4 m^3" in line
    image = LabelImage.load(out)
    assert image.shape == (32, 8, 8) and np.all(image.labels == 1)
    np.testing.assert_allclose(image.spacing, 0.125)
    np.testing.assert_allclose(image.origin, 0.0)


def test_two_inputs_to_nifti_with_labels(tmp_path, capsys):
    out = tmp_path / "two.nii.gz"
    status = main(
        ["voxelize", "box:2,2,2", "sphere:0.5", "-o", str(out), "--voxel-size", "0.1", "--labels", "3", "7", "--padding", "1"]
    )
    assert status == 0
    image = LabelImage.load(out)
    assert image.shape == (22, 22, 22)
    assert set(np.unique(image.labels)) == {0, 3, 7}
    # the ball (label 7, written last) replaces box voxels: exactly the voxels of the ball alone
    # (same grid alignment: both lower corners at the origin)
    from voxflex.rasterize import voxelize

    n7 = int((image.labels == 7).sum())
    assert n7 == int((voxelize("sphere:0.5", 0.1, progress=False).labels > 0).sum())
    assert (image.labels == 3).sum() + n7 == 20**3
    assert "label 3:" in capsys.readouterr().out


def test_occupancy_written_to_npz(tmp_path):
    out = tmp_path / "ball.npz"
    assert main(["voxelize", "sphere:1", "-o", str(out), "--voxel-size", "0.1", "--occupancy"]) == 0
    image = LabelImage.load(out)
    assert image.occupancy is not None
    vol = image.occupancy.sum() * image.voxel_volume
    assert abs(vol / (4 / 3 * np.pi) - 1) < 0.005  # measured 5e-5 (see test_voxelize)


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["box:1,2", "--voxel-size", "0.1"], "box needs 3"),
        (["box:1,1,1", "--voxel-size", "0"], "voxel size"),
        (["box:1,1,1", "--voxel-size", "0.1", "0.1"], "1 or 3 values"),
        (["box:1,1,1", "sphere:1", "--voxel-size", "0.1", "--labels", "1"], "one label per input"),
        (["missing.stl", "--voxel-size", "0.1"], "not found"),
        (["box:1,1,1", "--voxel-size", "1e-4"], "voxel size of at least"),
    ],
)
def test_errors_are_one_line_exit_2(tmp_path, capsys, argv, fragment):
    out = tmp_path / "x.npz"
    status = main(["voxelize", *argv, "-o", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and fragment in err[0]
    assert not out.exists()


def test_help_teaches(capsys):
    with pytest.raises(SystemExit):
        main(["voxelize", "--help"])
    text = capsys.readouterr().out
    assert "examples:" in text and "box:LX,LY,LZ" in text and "--occupancy" in text


def test_bundled_bar_and_phantom(tmp_path, capsys):

    data = paths.ROOT / "data"
    out = tmp_path / "bar.npz"
    assert main(["voxelize", str(data / "bar.stl"), "-o", str(out), "--voxel-size", "0.0005", "--occupancy"]) == 0
    image = LabelImage.load(out)
    # capsule r = 5 mm, body 40 mm; the 32-gon polyhedron holds 1 - sin(2pi/32)/(2pi/32) = 0.64 % less
    exact = np.pi * 0.005**2 * 0.04 + 4 / 3 * np.pi * 0.005**3
    vol = image.occupancy.sum() * image.voxel_volume
    assert abs(vol / exact - 1) < 0.015  # polygon deficit 0.64 % + occupancy error (< 0.5 % at R/h = 10)
    phantom = LabelImage.load(data / "phantom.nii.gz")
    assert phantom.shape == (80, 40, 40)
    counts = np.bincount(phantom.labels.ravel(), minlength=4)
    assert counts[0] == 0 and counts[1:].sum() == 80 * 40 * 40
    # ball r = 5 mm at 0.5 mm voxels: 4/3 pi 10^3 = 4189 voxels, staircase error measured 0.8 % (R/h = 10)
    assert abs(counts[2] / 4188.8 - 1) < 0.02


@pytest.mark.parametrize("argv, fixed", [
    (["box:1e30,1,1", "--voxel-size", "0.1"], "--voxel-size"),
    (["box:1,1,1", "--voxel-size", "0.5", "--padding", "1000000000"], "--padding"),
])
def test_a_grid_too_large_names_a_fix_that_works(tmp_path, capfd, argv, fixed):
    """Round 27: a 1e30 m box gave numpy cast warnings and "no voxel centre lies inside ... use a smaller voxel
    size" (the grid's counts overflowed int64); --padding 1e9 was told "use a voxel size of at least 2.9e10",
    which still pads 2e9 voxels per axis.  Now one line naming a voxel size or a padding, and that one fits."""
    out = tmp_path / "x.npz"
    status = main(["voxelize", *argv, "-o", str(out), "--max-memory", "0.01"])
    err = capfd.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and "Warning" not in err[0], err
    value = err[0].split("use a voxel size of at least " if fixed == "--voxel-size" else "use --padding ")[1].split()[0]
    args = list(argv)
    args[args.index(fixed) + 1] = value
    assert main(["voxelize", *args, "-o", str(out), "--max-memory", "0.01"]) in (0, 2)
    assert "grid needs" not in capfd.readouterr().err  # the named fix fits (its voxels may then hold no centre)
