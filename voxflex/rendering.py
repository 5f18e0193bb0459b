"""Offscreen pictures and animations of a :class:`~voxflex.result.Result`.

The deformed boundary surface is coloured by displacement magnitude, the rest
shape is drawn as a faint outline (its feature edges), with a scalar bar and a
title.  No display is needed: pyvista is imported lazily, inside the
functions, with ``PYVISTA_OFF_SCREEN=true`` and EGL as the default OpenGL
window (see NOTES: EGL works headless; forcing OSMesa without libosmesa
segfaults).

Example
-------
>>> import voxflex as vf
>>> vf.render(vf.Result.load("beam.h5"), "beam.png")        # doctest: +SKIP
>>> vf.render(result, "frames/")                              # one PNG per step  # doctest: +SKIP
>>> vf.render(result, "beam.gif")                             # animation         # doctest: +SKIP
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ._atomic import atomic_path
from .errors import InputError

__all__ = ["render", "render_frames"]

_STILL = (".png",)
_MOVIES = (".gif", ".mp4")


def _offscreen_env() -> None:
    os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    _check_offscreen_gl()


# a tiny render in a child process: a machine without the GL libraries makes VTK
# segfault (NOTES), which must not take the caller (and its unsaved work) down
_PROBE_CODE = (
    "import pyvista as pv\n"
    "p = pv.Plotter(off_screen=True, window_size=(32, 24))\n"
    "p.add_mesh(pv.Cube())\n"
    "p.screenshot(return_img=True)\n"
    "p.close()\n"
)
_probe_status: int | None = None


def _check_offscreen_gl() -> None:
    """Raise a one-line InputError when offscreen OpenGL cannot work here (probed once per process)."""
    global _probe_status
    if _probe_status is None:
        import subprocess
        import sys

        try:
            proc = subprocess.run(
                [sys.executable, "-c", _PROBE_CODE], capture_output=True, timeout=300, env=dict(os.environ)
            )
            _probe_status = proc.returncode
        except subprocess.TimeoutExpired:
            _probe_status = -1
    if _probe_status != 0:
        raise InputError(
            f"offscreen rendering is not available on this machine (OpenGL probe exited {_probe_status}); "
            "install EGL (apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri) or OSMesa (libosmesa6 with "
            "VTK_DEFAULT_OPENGL_WINDOW=vtkOSOpenGLRenderWindow)"
        )


def _as_result(result):
    from .result import Result

    if isinstance(result, Result):
        return result
    if isinstance(result, (str, Path)):
        return Result.load(result)
    raise InputError(f"render needs a Result or a result file path, got {type(result).__name__}")


def render_frames(result, steps, *, window_size=(800, 450), title=None, cmap="viridis", show_rest=True):
    """Render the given steps offscreen; returns a list of (H, W, 3) uint8 images.

    The camera and the colour range are the same for every frame (fitted to
    all the requested states) so that an animation does not jump.
    """
    _offscreen_env()
    import pyvista as pv

    result = _as_result(result)
    steps = [result.step_index(s) for s in steps]
    faces = np.hstack([np.full((result.surface_faces.shape[0], 1), 3), result.surface_faces]).ravel()
    mags = [np.linalg.norm(result.displacement(s), axis=1) for s in steps]
    top = max(float(m.max()) for m in mags) if mags else 0.0
    clim = (0.0, top if top > 0 else 1.0)
    pts = np.concatenate([result.surface_rest] + [result.surface_positions[s] for s in steps])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    bounds = (lo[0], hi[0], lo[1], hi[1], lo[2], hi[2])
    rest = pv.PolyData(np.array(result.surface_rest), faces=faces)
    edges = rest.extract_feature_edges(
        feature_angle=60, boundary_edges=True, non_manifold_edges=False, manifold_edges=False
    )

    static = _solver_kind(result) == "static"
    images = []
    plotter = pv.Plotter(off_screen=True, window_size=tuple(int(v) for v in window_size))
    try:
        plotter.set_background("white")
        for s, mag in zip(steps, mags):
            plotter.clear()
            if show_rest and edges.n_points:
                plotter.add_mesh(edges, color="gray", opacity=0.35, line_width=1)
            mesh = pv.PolyData(np.array(result.surface_positions[s]), faces=faces)
            mesh.point_data["|u| (m)"] = mag
            plotter.add_mesh(
                mesh,
                scalars="|u| (m)",
                cmap=cmap,
                clim=clim,
                smooth_shading=False,
                show_edges=False,
                scalar_bar_args=dict(title="u (m)", color="black", vertical=True, fmt="%.3g"),
            )
            if static:
                when = f"load factor {result.time[s]:.4g}"
            else:
                when = f"t = {result.time[s]:.4g} s"
            plotter.add_text(
                f"{title or 'voxflex'}   step {s}/{result.n_steps - 1}, {when}",
                font_size=10,
                color="black",
                position="upper_left",
            )
            plotter.view_vector((0.45, -1.0, 0.55), viewup=(0.0, 0.0, 1.0))
            plotter.reset_camera(bounds=bounds)
            plotter.camera.zoom(1.05)
            images.append(np.asarray(plotter.screenshot(return_img=True))[..., :3].copy())
    finally:
        plotter.close()
    return images


def _scene_table(result) -> dict:
    """The result's scene as parsed TOML; {} when the result carries no scene (built in code).

    A scene text that is not valid TOML means a damaged result: InputError, not a guess.
    """
    import tomllib

    if not result.scene.strip():
        return {}
    try:
        return tomllib.loads(result.scene)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"the result's scene attribute is not valid TOML ({exc}); the result file is damaged") from None


def _solver_kind(result) -> str:
    """``static`` or ``implicit-euler``: the scene's solver (a result without a scene is static)."""
    return str(_scene_table(result).get("solver", {}).get("kind", "static"))


def render(result, path, *, step: int = -1, window_size=(800, 450), title=None, cmap="viridis", fps: int = 8):
    """Picture of the deformed surface, offscreen.

    Parameters
    ----------
    result : Result or path to a result file
    path : path
        ``.png`` — one picture of ``step``; a folder (an existing directory or a
        path without suffix) — one PNG per step (``step_0000.png`` ...);
        ``.gif`` / ``.mp4`` — an animation of all steps (``.mp4`` needs
        imageio-ffmpeg).
    step : int
        Which state for a single picture (negative counts from the end).
    window_size : (width, height) pixels
    title : str, optional
        Text in the upper-left corner (default: the scene's title or "voxflex").
    cmap : str
        Matplotlib colour map name for |u|.
    fps : int
        Frames per second of an animation.

    Returns
    -------
    Path
        What was written (the file or the folder).
    """
    result = _as_result(result)
    path = Path(path)
    suffix = path.suffix.lower()
    if title is None:
        title = _scene_title(result)
    if len(tuple(window_size)) != 2 or min(int(v) for v in window_size) < 16:
        raise InputError(f"window_size must be (width, height) of at least 16 pixels, got {window_size!r}")
    if suffix in _STILL:
        index = result.step_index(step)
        (image,) = render_frames(result, [index], window_size=window_size, title=title, cmap=cmap)
        _write_png(image, path)
        return path
    if suffix in _MOVIES:
        if suffix == ".mp4":
            try:
                import imageio_ffmpeg  # noqa: F401
            except ImportError:
                raise InputError(
                    "writing .mp4 needs imageio-ffmpeg (pip install imageio-ffmpeg); or write a .gif instead"
                ) from None
        frames = render_frames(result, range(result.n_steps), window_size=window_size, title=title, cmap=cmap)
        _write_movie(frames, path, fps=fps)
        return path
    if suffix and not path.is_dir():
        raise InputError(
            f"cannot render to '{path}': give a .png, a folder, a .gif or a .mp4 (unknown extension '{suffix}')"
        )
    path.mkdir(parents=True, exist_ok=True)
    frames = render_frames(result, range(result.n_steps), window_size=window_size, title=title, cmap=cmap)
    for i, image in enumerate(frames):
        _write_png(image, path / f"step_{i:04d}.png")
    return path


def _scene_title(result) -> str:
    title = _scene_table(result).get("title")
    return str(title) if title else "voxflex"


def _write_png(image: np.ndarray, path: Path) -> None:
    from PIL import Image

    with atomic_path(path) as tmp:
        Image.fromarray(image).save(tmp, format="PNG")


def _write_movie(frames, path: Path, *, fps: int) -> None:
    if path.suffix.lower() == ".gif":
        from PIL import Image

        pics = [Image.fromarray(f) for f in frames]
        with atomic_path(path) as tmp:
            pics[0].save(
                tmp, format="GIF", save_all=True, append_images=pics[1:], duration=int(1000 / max(fps, 1)), loop=0
            )
        return
    import imageio.v2 as imageio

    with atomic_path(path) as tmp:
        with imageio.get_writer(tmp, fps=fps, format="FFMPEG") as writer:  # pragma: no cover - optional dependency
            for f in frames:
                writer.append_data(f)
