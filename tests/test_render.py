"""Offscreen rendering, checked with tolerant measures on the picture (never bytes)."""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from voxflex.errors import InputError

pytestmark = pytest.mark.render

_PROBE = """
import os
os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
import pyvista as pv
p = pv.Plotter(off_screen=True, window_size=(64, 48))
p.add_mesh(pv.Sphere())
img = p.screenshot(return_img=True)
p.close()
assert img.shape[:2] == (48, 64)
"""


@pytest.fixture(scope="module", autouse=True)
def offscreen_gl():
    """Render once in a subprocess: a missing GL library segfaults instead of raising (NOTES)."""
    proc = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=120)
    if proc.returncode != 0:
        pytest.skip(
            f"offscreen OpenGL is not available here (probe exited {proc.returncode}); "
            "install libegl1 libegl-mesa0 libgl1-mesa-dri"
        )


@pytest.fixture(scope="module")
def default_result():
    import voxflex as vf
    from voxflex.scene import Scene, default_scene_path

    scene = Scene.from_toml(default_scene_path())
    # 10 mm voxels (270 instead of 1250) and two load steps instead of four keep the test
    # short; the picture is the same strip with the same sag to within the discretization
    scene = replace(scene, object=replace(scene.object, voxel_size=0.01), solver=replace(scene.solver, steps=2))
    return vf.simulate(scene, progress=False)


def _coloured(image: np.ndarray) -> np.ndarray:
    """Mask of saturated (colour-mapped) pixels: the deformed surface, not the white
    background, the black text or the grey rest outline."""
    rgb = image[..., :3].astype(int)
    return (rgb.max(axis=2) - rgb.min(axis=2)) > 40


def test_render_of_the_default_scene(default_result, tmp_path):
    from PIL import Image

    from voxflex.rendering import render

    out = render(default_result, tmp_path / "strip.png", window_size=(800, 450))
    image = np.asarray(Image.open(out))
    assert image.shape[:2] == (450, 800)
    obj = _coloured(image)
    obj[:, int(0.85 * 800):] = False  # the scalar bar lives on the right edge
    # the strip (30 cm x 3 cm) seen at an angle covers a few percent of the frame: a
    # blank or a filled frame would be far outside [1 %, 40 %]
    fraction = obj.mean()
    assert 0.01 < fraction < 0.40, fraction
    rows, cols = np.nonzero(obj)
    # the object's bounding box lies inside the picture, not touching its border ...
    assert rows.min() > 0 and rows.max() < 449 and cols.min() > 0
    # ... and is elongated (a long strip): wider than a third of the frame, wider than tall
    width, height = cols.max() - cols.min(), rows.max() - rows.min()
    assert width > 800 / 3 and width > height, (width, height)
    # the background is white and dominates
    white = np.all(image[..., :3] > 245, axis=2).mean()
    assert white > 0.5


def test_step_zero_has_no_displacement_colour_range(default_result, tmp_path):
    from PIL import Image

    from voxflex.rendering import render

    out = render(default_result, tmp_path / "rest.png", step=0, window_size=(400, 240))
    image = np.asarray(Image.open(out))
    assert image.shape[:2] == (240, 400)
    assert 0.01 < _coloured(image)[:, :340].mean() < 0.40


def test_animation_and_folder_outputs(tmp_path):
    from PIL import Image

    from test_result import hand_result
    from voxflex.rendering import render

    r = hand_result(T=3)
    gif = render(r, tmp_path / "anim.gif", window_size=(160, 120))
    with Image.open(gif) as im:
        assert im.n_frames == 3 and im.size == (160, 120)
    folder = render(r, tmp_path / "frames", window_size=(160, 120))
    assert sorted(p.name for p in Path(folder).iterdir()) == ["step_0000.png", "step_0001.png", "step_0002.png"]
    with pytest.raises(InputError, match="out of range"):
        render(r, tmp_path / "x.png", step=3)
    with pytest.raises(InputError, match="give a .png, a folder"):
        render(r, tmp_path / "x.jpg")


def test_mp4_without_ffmpeg_says_what_to_do(tmp_path):
    pytest.importorskip("imageio")
    try:
        import imageio_ffmpeg  # noqa: F401

        pytest.skip("imageio-ffmpeg is installed here; the error path cannot be exercised")
    except ImportError:
        pass
    from test_result import hand_result
    from voxflex.rendering import render

    with pytest.raises(InputError, match="imageio-ffmpeg.*gif"):
        render(hand_result(), tmp_path / "a.mp4")
    assert not (tmp_path / "a.mp4").exists()


def test_render_cli(tmp_path, capsys):
    from test_result import hand_result
    from voxflex.cli import main

    hand_result().save(tmp_path / "r.h5")
    assert main(["render", str(tmp_path / "r.h5"), "-o", str(tmp_path / "r.png"), "--step", "1"]) == 0
    assert (tmp_path / "r.png").stat().st_size > 1000
    assert main(["render", str(tmp_path / "missing.h5"), "-o", str(tmp_path / "r.png")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not found" in err[0]
    assert os.environ.get("PYVISTA_OFF_SCREEN") == "true"


def test_missing_opengl_is_a_one_line_error(monkeypatch, tmp_path, default_result):
    # a machine without GL libraries makes VTK crash; the probe in a child process turns that
    # into an InputError naming the packages to install, and the caller survives
    from voxflex import rendering

    monkeypatch.setattr(rendering, "_PROBE_CODE", "import os\nos.abort()\n")
    monkeypatch.setattr(rendering, "_probe_status", None)
    with pytest.raises(InputError, match="libegl1") as exc:
        rendering.render(default_result, tmp_path / "x.png")
    assert "\n" not in str(exc.value)
    assert not list(tmp_path.iterdir())
