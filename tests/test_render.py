"""Offscreen rendering, checked with tolerant measures on the picture (never bytes)."""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import paths
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
    """Render once in a subprocess: a missing GL library segfaults instead of raising."""
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
    # 2 mm voxels (about 470 instead of 3736), 10 frames and two load steps keep the test short;
    # the picture is the same capsule with a similar sag
    scene = replace(scene, object=replace(scene.object, voxel_size=0.002), solver=replace(scene.solver, steps=2),
                    nodes=replace(scene.nodes, count=10), elasticity=replace(scene.elasticity, samples=200))
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
    # ... and is elongated (a long capsule, bent): along its principal axis longer than a third of the
    # frame and more than twice as long as across (the sag tilts it, so not along the picture's axes)
    xy = np.stack([cols, rows]).astype(float)
    ev, vec = np.linalg.eigh(np.cov(xy))
    along = vec[:, -1] @ xy
    assert along.max() - along.min() > 800 / 3 and ev[-1] > 4 * ev[0], (along.max() - along.min(), ev)
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
    from results import hand_result

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
    from results import hand_result

    from voxflex.rendering import render

    with pytest.raises(InputError, match="imageio-ffmpeg.*gif"):
        render(hand_result(), tmp_path / "a.mp4")
    assert not (tmp_path / "a.mp4").exists()


def test_render_cli(tmp_path, capsys):
    from results import hand_result

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


# ---------------------------------------------------------------------------
# views, fitting, annotations (issue 15)
# ---------------------------------------------------------------------------
SHARED_MESHES = paths.MESHES


def _dark(image: np.ndarray) -> np.ndarray:
    """Mask of text-dark pixels (labels, arrows): every channel below 110."""
    return np.all(image[..., :3] < 110, axis=2)


def _plot_area(image: np.ndarray, layout) -> np.ndarray:
    return image[layout.title_h:, : layout.band_x]


def _layout_for(result, size):
    from voxflex import _render_annotations, _render_style, rendering

    style = _render_style._style(result, window_size=size, title=None, cmap="viridis", view="iso", azimuth=None,
                                 elevation=None, up="z", color="displacement", show_rest=True, axes=True,
                                 gravity=True, frames=True)
    values, _, title = rendering._colour_values(result, "displacement")
    return _render_annotations._Layout.make(style, result, (0.0, float(values.max())), title,
                                            rendering._gravity(result) is not None)


@pytest.mark.parametrize("size", [(800, 450), (320, 200), (400, 800), (1600, 900)])
def test_labels_and_object_stay_inside_the_frame_at_any_size(default_result, size):
    from voxflex.rendering import render_frames

    (image,) = render_frames(default_result, [-1], window_size=size)
    assert image.shape == (size[1], size[0], 3)
    dark = _dark(image)
    # no text, tick or arrow pixel touches the picture's border: nothing is clipped
    border = np.concatenate([dark[0], dark[-1], dark[:, 0], dark[:, -1]])
    assert not border.any(), size
    layout = _layout_for(default_result, size)
    # the colour bar's tick labels are drawn (dark pixels right of the gradient) ...
    x1 = layout.bar_box[2]
    assert dark[layout.bar_box[1]: layout.bar_box[3], x1 + 1:].sum() > 20
    # ... the title sits above the plot area, and the object (coloured pixels) lies inside the plot area
    assert dark[: layout.title_h].sum() > 20
    obj = _coloured(image)
    obj[:, layout.band_x:] = False  # the gradient of the colour bar is coloured too
    rows, cols = np.nonzero(obj)
    assert rows.min() >= layout.title_h and rows.max() < size[1] - 1 and cols.min() > 0
    # zoom to fit: the object (with its rest shape) spans most of the plot area's width or height
    pw, ph = layout.plot_size
    assert (cols.max() - cols.min()) > 0.5 * pw or (rows.max() - rows.min()) > 0.5 * ph


def test_camera_axes_are_right_handed_and_named_views_look_as_documented():
    from voxflex.rendering import VIEWS, camera_axes

    for up in "xyz":
        for view in VIEWS:
            t, r, u = camera_axes(view, up=up)
            # an orthonormal right-handed screen frame: right x up = towards the camera (1e-12: round-off)
            np.testing.assert_allclose(np.cross(r, u), t, atol=1e-12)
            np.testing.assert_allclose([t @ t, r @ r, u @ u, t @ r, t @ u, r @ u], [1, 1, 1, 0, 0, 0], atol=1e-12)
        e_up = np.eye(3)["xyz".index(up)]
        np.testing.assert_allclose(camera_axes("front", up=up)[2], e_up, atol=1e-12)  # up is drawn up
        np.testing.assert_allclose(camera_axes("top", up=up)[0], e_up, atol=1e-12)  # top looks down
    # y-up models: the front view looks along -z with x to the right (their own modelling frame)
    t, r, _ = camera_axes("front", up="y")
    np.testing.assert_allclose(t, [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(r, [1, 0, 0], atol=1e-12)
    # azimuth/elevation override the named view; iso is the isometric direction (1, -1, 1)/sqrt(3)
    np.testing.assert_allclose(camera_axes("iso")[0], np.array([1, -1, 1]) / np.sqrt(3), atol=1e-12)
    np.testing.assert_allclose(camera_axes("front", azimuth=90)[0], camera_axes("side")[0], atol=1e-12)
    with pytest.raises(InputError, match="elevation"):
        camera_axes("iso", elevation=91)
    with pytest.raises(InputError, match="unknown view"):
        camera_axes("back")


def test_front_side_and_top_views_of_the_capsule(default_result):
    """The capsule (5 cm along x, 1 cm thick, sagging by s in z) seen from the front, the top and the
    side: the drawn extents follow the deformed bounding box (ratios within 30 %: voxel staircase,
    the rounded ends and the outline's pixels)."""
    from voxflex.rendering import render_frames

    pos = default_result.surface_positions[-1]
    ext = pos.max(axis=0) - pos.min(axis=0)  # deformed extents along x, y, z
    shapes = {}
    for view in ("front", "side", "top"):
        (image,) = render_frames(default_result, [-1], window_size=(800, 450), view=view)
        layout = _layout_for(default_result, (800, 450))
        obj = _coloured(_plot_area(image, layout))
        rows, cols = np.nonzero(obj)
        shapes[view] = (cols.max() - cols.min(), rows.max() - rows.min())
    expected = {"front": ext[0] / ext[2], "top": ext[0] / ext[1], "side": ext[1] / ext[2]}  # width / height
    for view, (w, h) in shapes.items():
        assert w / h == pytest.approx(expected[view], rel=0.3), (view, shapes, expected)
    assert ext[2] > 1.3 * ext[1]  # it sags: taller than thick


def test_rest_silhouette_is_faint_and_behind(default_result):
    from voxflex.rendering import render_frames

    (with_rest,) = render_frames(default_result, [-1], view="front")
    (without,) = render_frames(default_result, [-1], view="front", show_rest=False)
    differ = np.any(with_rest != without, axis=2)
    # the silhouette adds pixels (the strip's rest position above the sagging tip) ...
    assert differ.mean() > 0.01
    # ... all of them light grey (faint, 200..255 in every channel), never over the coloured object
    assert np.all(with_rest[differ] >= 200)
    assert not _coloured(without)[differ].any()


def test_gravity_arrow_and_triad_are_drawn(default_result):
    from voxflex.rendering import render_frames

    layout = _layout_for(default_result, (800, 450))
    (image,) = render_frames(default_result, [-1])
    (bare,) = render_frames(default_result, [-1], gravity=False, axes=False)
    for box in (layout.gravity_box, layout.triad_box):
        x0, y0, x1, y1 = box
        assert _dark(image[y0:y1, x0:x1]).sum() + (_coloured(image[y0:y1, x0:x1])).sum() > 30
    # without them nothing is drawn below the colour bar's last label
    bare_bar_bottom = np.nonzero(_coloured(bare[:, layout.band_x:]).any(axis=1))[0].max()
    assert np.all(bare[bare_bar_bottom + layout.font + 2:, layout.band_x:] == 255)
    # the gravity arrow (-z, drawn vertical in the iso view) is taller than wide
    x0, y0, x1, y1 = layout.gravity_box
    rows, cols = np.nonzero(_dark(image[y0 + layout.font + 2: y1, x0:x1]))
    assert rows.max() - rows.min() > 2 * (cols.max() - cols.min())


def test_a_result_without_gravity_has_no_arrow(tmp_path):
    from results import hand_result

    from voxflex import rendering

    r = hand_result()
    assert rendering._gravity(r) is None
    layout = _layout_for(r, (800, 450))
    assert layout.gravity_box is None and layout.triad_box is not None


def test_affine_frames_are_drawn_as_dots():
    from results import hand_result

    from voxflex.rendering import render_frames
    from voxflex.result import Result

    r = hand_result(T=2)
    # two affine frames (A = I, t = frame origin) inside the cube, moving with it
    t = np.array([[0.3, 0.5, 0.5], [0.7, 0.5, 0.5]])
    rest = np.hstack([np.tile(np.eye(3).ravel(), (2, 1)), t])
    state = np.stack([rest, rest + np.r_[[0] * 11, -0.1]])
    fields = {k: getattr(r, k) for k in Result.__dataclass_fields__}
    # what a frame model records per node: its origin (/nodes/points)
    fields.update(nodes_rest=rest, nodes_state=state, node_kind="affine", node_points=state[..., 9:12])
    r = Result(**fields)
    kwargs = dict(window_size=(400, 300), show_rest=False, view="front")
    (dots,) = render_frames(r, [-1], **kwargs)
    (plain,) = render_frames(r, [-1], frames=False, **kwargs)
    layout = _layout_for(r, (400, 300))
    black = lambda im: np.all(_plot_area(im, layout) < 40, axis=2)  # noqa: E731 - viridis never goes below 40
    assert black(dots).sum() > 10 and black(plain).sum() == 0


def test_colour_by_a_field(tmp_path):
    from results import hand_result

    from voxflex.rendering import render, render_frames

    r = hand_result(T=2)
    with pytest.raises(InputError, match="no field 'von-mises' .*fields in it: none"):
        render(r, tmp_path / "vm.png", color="von-mises")
    assert not (tmp_path / "vm.png").exists()
    # a per-vertex field (T, V): the picture is coloured by it (constant per state here -> one colour)
    values = np.stack([np.zeros(8), np.linspace(0.0, 1.0, 8)])
    object.__setattr__(r, "fields", {"von_mises": values})
    (image,) = render_frames(r, [-1], color="von-mises", window_size=(400, 300))
    assert _coloured(image).mean() > 0.02
    object.__setattr__(r, "fields", {"von_mises": np.zeros((2, 5))})
    with pytest.raises(InputError, match="one value per surface vertex"):
        render_frames(r, [-1], color="von-mises")


def test_bad_view_options_are_one_line_errors(default_result, tmp_path):
    from voxflex.rendering import render

    for kwargs, match in (
        (dict(view="back"), "unknown view"),
        (dict(up="w"), "unknown up axis"),
        (dict(azimuth="left"), "azimuth"),
        (dict(elevation=120), "elevation"),
        (dict(cmap="nope"), "colour map"),
        (dict(fps=0), "fps"),
    ):
        with pytest.raises(InputError, match=match) as exc:
            render(default_result, tmp_path / "x.png", **kwargs)
        assert "\n" not in str(exc.value)
    assert not list(tmp_path.iterdir())


def test_render_cli_view_options(tmp_path):
    from PIL import Image
    from results import hand_result

    from voxflex.cli import main

    hand_result().save(tmp_path / "r.h5")
    out = tmp_path / "top.png"
    argv = ["render", str(tmp_path / "r.h5"), "-o", str(out), "--view", "top", "--up", "y", "--size", "300", "200",
            "--no-axes", "--no-rest", "--azimuth", "10", "--elevation", "20"]
    assert main(argv) == 0
    with Image.open(out) as im:
        assert im.size == (300, 200)
    assert main(["render", str(tmp_path / "r.h5"), "-o", str(tmp_path / "f.png"), "--color", "von-mises"]) == 2


def _mesh_result(name: str, voxel_size: float, young: float):
    """A y-up mesh from ../shared/meshes, voxelized coarsely (about 1300 voxels), hooves/base held,
    sagging under gravity along -y; linear strain keeps the solve to one Newton iteration."""
    import voxflex as vf
    from voxflex.scene import Scene

    path = SHARED_MESHES / f"{name}.obj"
    if not path.is_file():
        pytest.skip(f"{path} is absent (the shared test meshes are not here)")
    from voxflex.rasterize import load_mesh

    lo, hi = load_mesh(path).bounds()
    base = lo[1] + 0.25 * (hi[1] - lo[1])
    text = f"""
title = "{name} (y-up mesh)"
[object]
mesh = "{path}"
voxel_size = {voxel_size}
keep = "largest"
[[material]]
model = "hooke"
strain = "linear"
young = {young}
poisson = 0.3
density = 100.0
[[fixed]]
min = [-1e9, -1e9, -1e9]
max = [1e9, {base}, 1e9]
[[load]]
kind = "gravity"
vector = [0.0, -9.81, 0.0]
[solver]
linear_solver = "direct"
"""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # islands of the coarse voxelization are dropped
        return vf.simulate(Scene.from_toml_text(text), progress=False)


@pytest.mark.parametrize("name, voxel_size, young", [("cow", 0.35, 3e5), ("stanford-bunny", 0.008, 3e4)])
def test_y_up_meshes_are_seen_upright(name, voxel_size, young, tmp_path):
    from PIL import Image

    from voxflex.rendering import render, render_frames

    result = _mesh_result(name, voxel_size, young)
    out = render(result, tmp_path / f"{name}.png", up="y", window_size=(800, 450))
    image = np.asarray(Image.open(out))
    layout = _layout_for(result, (800, 450))
    obj = _coloured(image)
    obj[:, layout.band_x:] = False
    assert 0.05 < obj.mean() < 0.6
    rows, cols = np.nonzero(obj)
    assert rows.min() >= layout.title_h and rows.max() < 449 and cols.min() > 0 and cols.max() < layout.band_x
    dark = _dark(image)
    assert not np.concatenate([dark[0], dark[-1], dark[:, 0], dark[:, -1]]).any()
    # upright: the held base (|u| = 0, the darkest colour) is at the bottom of the object, the
    # gravity arrow (along -y) points down the picture
    low = np.all(np.abs(image[..., :3].astype(int) - (68, 1, 84)) < 30, axis=2) & obj
    assert low.any()
    assert np.nonzero(low)[0].mean() > rows.mean()
    if name == "cow":
        # from the side (along -x) an upright cow is taller (6.4) than wide (3.4); with z up it would lie flat
        sizes = {}
        for up in ("y", "z"):
            (im,) = render_frames(result, [-1], up=up, view="side")
            r_, c_ = np.nonzero(_coloured(_plot_area(im, layout)))
            sizes[up] = (c_.max() - c_.min(), r_.max() - r_.min())
        assert sizes["y"][1] > 1.3 * sizes["y"][0] and sizes["z"][0] > 1.3 * sizes["z"][1], sizes


def test_cables_are_drawn_through_their_deformed_eyelets(tmp_path):
    """examples/cable_bar.toml at 1 cm voxels: the result's cable polyline is the anchor then the
    eyelets at their deformed positions (the probe on the first eyelet, mapped independently by
    the probe layer, agrees to round-off), and the picture has the cable's red pixels, which the
    same result without cable points lacks (no colour map reaches that red)."""
    import voxflex as vf
    from voxflex.rendering import CABLE_COLOUR, _cable_polylines, render_frames
    from voxflex.result import Result
    from voxflex.scene import Scene

    scene = Scene.from_toml(paths.ROOT / "examples" / "cable_bar.toml")
    scene = replace(scene, object=replace(scene.object, voxel_size=0.01), solver=replace(scene.solver, steps=1),
                    cables=(replace(scene.cables[0], shorten=0.004),))
    result = vf.simulate(scene, progress=False)
    (line,) = _cable_polylines(result, -1)
    assert line.shape == (1 + len(scene.cables[0].points), 3)
    np.testing.assert_array_equal(line[0], scene.cables[0].anchor)
    np.testing.assert_allclose(line[1], result.probes["eyelet_1"][-1], rtol=0, atol=1e-12)
    assert line[-1, 2] > scene.cables[0].points[-1][2] + 1e-3  # the tied end rose with the bending bar
    kwargs = dict(window_size=(480, 320), show_rest=False, view="front")
    (with_cable,) = render_frames(result, [-1], **kwargs)
    fields = {k: getattr(result, k) for k in Result.__dataclass_fields__}
    fields.update(cable_points=None, cable_point_cable=None)
    (without,) = render_frames(Result(**fields), [-1], **kwargs)
    red = lambda im: np.all(np.abs(im[..., :3].astype(int) - CABLE_COLOUR) < 30, axis=2)  # noqa: E731
    # the polyline spans ~0.18 m of a ~0.2 m wide view, 2+ pixels thick: hundreds of pixels
    added = red(with_cable) & ~red(without)
    assert added.sum() > 200
    rows = np.flatnonzero(added.any(axis=1))
    cols = np.flatnonzero(added.any(axis=0))
    assert cols.max() - cols.min() > 0.5 * 480 and rows.max() - rows.min() < 0.5 * 320  # a long, nearly level line


def test_plastic_bar_renders(tmp_path):
    """examples/plastic_bar.toml (1 cm voxels) renders: a coloured object in the picture."""
    import voxflex as vf
    from voxflex.rendering import render_frames
    from voxflex.scene import Scene

    scene = Scene.from_toml(paths.ROOT / "examples" / "plastic_bar.toml")
    result = vf.simulate(replace(scene, object=replace(scene.object, voxel_size=0.01)), progress=False)
    (image,) = render_frames(result, [-1], window_size=(480, 320), show_rest=False, view="front")
    assert _coloured(image).mean() > 0.02  # the bar: a thin strip across the picture


def test_obstacles_are_drawn_where_the_scene_puts_them():
    """The pushed-block example (coarse): the sphere drawn at each state is the obstacle moved by its
    motion to that state's load factor (every vertex at the radius from the moved centre, 1e-9 m: the
    mesh's float32-free vertices), and the rendered picture shows it, translucent brown, above the block
    where the body is not (the picture's upper left, white without obstacles)."""
    import voxflex as vf
    from voxflex.rendering import OBSTACLE_COLOUR, _obstacle_meshes, render_frames
    from voxflex.scene import Scene

    scene = Scene.from_toml(paths.ROOT / "examples" / "pushed_block.toml")
    scene = replace(scene, object=replace(scene.object, voxel_size=0.1), solver=replace(scene.solver, steps=2))
    result = vf.simulate(scene, progress=False)
    ob = scene.obstacles[0]
    for step, fraction in ((0, 0.0), (2, 1.0)):
        (sphere,) = _obstacle_meshes(result, step)
        centre = np.array(ob.center) + fraction * np.array(ob.motion)[:, 3]
        r = np.linalg.norm(np.asarray(sphere.points) - centre, axis=1)
        assert np.abs(r - ob.radius).max() < 1e-6 * ob.radius  # pyvista stores float32 points
    (image,) = render_frames(result, [-1], window_size=(480, 320), show_rest=False, axes=False, gravity=False)
    corner = image[60:100, 10:60].reshape(-1, 3).astype(float)  # beside the block, under the sphere's cap
    assert np.all(corner.mean(axis=0) < 250)  # not the white background
    # a blend of the obstacle's brown with white: red >= green >= blue, as the colour
    rgb = corner.mean(axis=0)
    assert rgb[0] >= rgb[1] >= rgb[2] and OBSTACLE_COLOUR[0] > OBSTACLE_COLOUR[2]


def test_a_plane_obstacle_is_a_patch_under_the_body():
    """ball_on_plane (3 steps): the plane is drawn as a square in the obstacle's plane, centred on the
    body's rest centre projected onto it, 1.5 times the body's extent."""
    import voxflex as vf
    from voxflex.rendering import _obstacle_meshes
    from voxflex.scene import Scene

    scene = Scene.from_toml(paths.ROOT / "examples" / "ball_on_plane.toml")
    result = vf.simulate(replace(scene, solver=replace(scene.solver, steps=3)), progress=False)
    (plane,) = _obstacle_meshes(result, 3)
    ob = scene.obstacles[0]
    pts = np.asarray(plane.points, dtype=float)
    n = np.asarray(ob.normal, dtype=float) / np.linalg.norm(ob.normal)
    assert np.abs((pts - np.asarray(ob.point)) @ n).max() < 1e-6
    centre = result.surface_rest.mean(axis=0)
    foot = centre - ((centre - np.asarray(ob.point)) @ n) * n
    assert np.allclose(pts.mean(axis=0), foot, atol=1e-6)
    every = np.concatenate([result.surface_rest, result.surface_positions.reshape(-1, 3)])
    extent = (every.max(axis=0) - every.min(axis=0)).max()
    assert np.ptp(pts, axis=0).max() == pytest.approx(1.5 * extent, rel=1e-6)
    # and the picture has it: in the iso view the patch is a band of grey-brown under the coloured ball
    import voxflex.rendering as rendering
    from voxflex.rendering import render_frames

    def grey(image):  # neither white background nor colour-mapped: the patch (and the title's text)
        rgb = image.reshape(-1, 3).astype(int)
        return ((rgb.max(axis=1) < 250) & (rgb.max(axis=1) - rgb.min(axis=1) <= 40)).mean()

    kw = dict(window_size=(480, 320), show_rest=False, axes=False, gravity=False)
    (image,) = render_frames(result, [-1], **kw)
    real = rendering._obstacles
    try:
        rendering._obstacles = lambda result: []
        (bare,) = render_frames(result, [-1], **kw)
    finally:
        rendering._obstacles = real
    assert _coloured(image).mean() > 0.02 and grey(image) > grey(bare) + 0.05


def test_a_result_whose_scene_text_was_removed_renders_the_same(tmp_path):
    """The renderer reads the result's typed groups (/problem: obstacles, gravity, title, solver; /nodes/points;
    /stats/fraction), never the scene TOML, kept only for provenance: erase it from the file and the picture
    of the ball dropped on a plane (dynamics: the plane, the gravity arrow, the title, the frames) is unchanged
    pixel for pixel."""
    import h5py

    import voxflex as vf
    from voxflex.rendering import render_frames
    from voxflex.result import Result
    from voxflex.scene import Scene

    scene = Scene.from_toml(paths.ROOT / "examples" / "ball_on_plane.toml")
    scene = replace(scene, solver=replace(scene.solver, steps=3))
    assert scene.gravity is not None and scene.solver.kind == "implicit-euler" and scene.title
    path = tmp_path / "r.h5"
    vf.simulate(scene, progress=False, output=path)
    kwargs = dict(window_size=(480, 320))
    (before,) = render_frames(Result.load(path), [-1], **kwargs)
    with h5py.File(path, "r+") as f:
        assert f.attrs["scene"] and "obstacles" in f["problem"] and len(f["problem/obstacles"]) == 1
        f.attrs["scene"] = ""
    bare = Result.load(path)
    assert bare.scene == "" and bare.problem["obstacles"][0]["kind"] == "plane"
    assert bare.problem["title"] == scene.title and bare.problem["solver_kind"] == "implicit-euler"
    assert np.allclose(bare.problem["gravity"], scene.gravity)
    (after,) = render_frames(bare, [-1], **kwargs)
    assert np.array_equal(before, after)
