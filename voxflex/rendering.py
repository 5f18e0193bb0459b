"""Offscreen pictures and animations of a :class:`~voxflex.result.Result`.

A picture is composed of two layers:

* the 3-D view, drawn by VTK (pyvista) offscreen into the plot area: the
  deformed boundary surface coloured by displacement magnitude (or by a result
  field) and, behind it, the rest shape as a faint grey silhouette (drawn only
  where the deformed surface is not).  The camera is orthographic and
  fitted to the deformed and rest shapes of every step together, so nothing
  leaves the picture and an animation does not jump;
* the 2-D annotations, drawn with Pillow around it: the title and step above
  the plot area, for affine frame models the frames as small black dots
  (visible even inside the object), the cables of a result that has them as
  red polylines through their deformed eyelets (anchor first; also drawn over
  the object), the colour bar with its ticks on the right, and under it an
  axes triad and a gravity arrow (when the scene has gravity) seen from the
  camera.  Text is measured before it is placed, so labels stay inside the
  picture at any window size.

The view: a named ``view`` (``iso``, ``front``, ``side``, ``top``) or an
``azimuth`` / ``elevation`` in degrees, about the world axis ``up`` that is
drawn vertical.  Azimuth 0 and elevation 0 is the front view: with ``up = "z"``
the camera looks along +y (x to the right); with ``up = "y"`` it looks along
-z (x to the right, the usual frame of y-up meshes); with ``up = "x"`` it
looks along +z (y to the right).  A positive azimuth turns the camera towards
the right-hand side, a positive elevation raises it.  ``side`` is azimuth 90,
``top`` elevation 90, ``iso`` azimuth 45 and elevation 35.26 (the isometric
view).

This module draws the 3-D view, refuses what cannot be drawn and writes the pictures; the camera and the
style one call's pictures share are in :mod:`voxflex._render_style`, the 2-D annotations in
:mod:`voxflex._render_annotations`.

No display is needed: pyvista is imported lazily, inside the functions, with
``PYVISTA_OFF_SCREEN=true`` and EGL as the default OpenGL window (EGL works
headless; forcing OSMesa without libosmesa segfaults).

Example
-------
>>> import voxflex as vf
>>> vf.render(vf.Result.load("beam.h5"), "beam.png")                 # doctest: +SKIP
>>> vf.render(result, "cow.png", view="side", up="y")                 # doctest: +SKIP
>>> vf.render(result, "frames/", azimuth=30, elevation=10)            # one PNG per step  # doctest: +SKIP
>>> vf.render(result, "beam.gif")                                      # animation         # doctest: +SKIP
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ._atomic import atomic_path
from ._render_annotations import CABLE_COLOUR as CABLE_COLOUR
from ._render_annotations import _Layout
from ._render_style import UP_AXES, VIEWS, _colormap, _place_camera, _style, camera_axes
from .errors import InputError

__all__ = ["render", "render_frames", "VIEWS", "UP_AXES", "camera_axes"]

_STILL = (".png",)
_MOVIES = (".gif", ".mp4")

_DISPLACEMENT = "displacement"
_REST_GREY = (0.62, 0.64, 0.68)
_REST_FAINT = 0.3  # the rest silhouette keeps this fraction of its shading over white
_ZERO_COLOUR = (0.80, 0.84, 0.90)  # the surface colour when nothing moved (no colour range)


def _offscreen_env() -> None:
    os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    _check_offscreen_gl()


# a tiny render in a child process: a machine without the GL libraries makes VTK
# segfault, which must not take the caller (and its unsaved work) down
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


# ---------------------------------------------------------------------------
# what is drawn
# ---------------------------------------------------------------------------
def _gravity(result):
    """The run's gravity (3,) in m/s^2 (the result's ``/problem``), or None (no gravity, or not recorded)."""
    g = result.problem.get("gravity")
    if g is None:
        return None
    g = np.asarray(g, dtype=float).reshape(3)
    if not np.all(np.isfinite(g)) or not np.any(g):
        return None
    return g


def _frame_positions(result, step=None):
    """The drawn point of each node ``(n, 3)`` at ``step`` (all steps ``(s, n, 3)`` when None), or None for
    models whose nodes are not drawn (the result's ``/nodes/points``: a frame's origin)."""
    points = result.node_points
    if points is None:
        return None
    return np.asarray(points if step is None else points[step])


def _cable_polylines(result, step=None) -> list:
    """Each cable's polyline at ``step``: a list of ``(k, 3)`` world positions (anchor first), or of
    ``(T, k, 3)`` over every state when ``step`` is None; [] when the result has no cable points."""
    points = getattr(result, "cable_points", None)
    owner = getattr(result, "cable_point_cable", None)
    if points is None or owner is None or len(owner) == 0:
        return []
    states = points if step is None else points[step]
    return [np.asarray(states[..., owner == c, :]) for c in np.unique(owner)]


OBSTACLE_COLOUR = (0.55, 0.50, 0.45)
"""RGB (0..1) of the obstacles, drawn translucent (:data:`OBSTACLE_OPACITY`) so that they never hide the body."""
OBSTACLE_OPACITY = 0.35


def _run_fraction(result, step: int) -> float:
    """The run fraction of state ``step`` that places moving obstacles: the load factor (statics) or
    t / t_end (implicit Euler), as the solver used it (``/stats/fraction``; the time where not recorded)."""
    if result.fraction is not None:
        return float(result.fraction[step])
    return float(result.time[step]) / float(result.problem.get("end_time", 1.0))


def _obstacles(result) -> list:
    """The run's obstacles as (obstacle, pyvista mesh at rest) pairs, built once per render: planes as a
    square patch under the body (1.5 times the body's largest extent over the run, centred on the body's
    rest centre projected onto the plane), spheres and boxes as they are; [] without obstacles.  ``sdf``
    obstacles are not drawn (their surface is an image's level set, not a shape here)."""
    specs = [o for o in result.problem.get("obstacles", []) if o.get("kind") in ("plane", "sphere", "box")]
    if not specs:
        return []
    import pyvista as pv

    from .deform.layers.obstacles import obstacle

    every = np.concatenate([result.surface_rest, result.surface_positions.reshape(-1, 3)])
    size = 1.5 * float((every.max(axis=0) - every.min(axis=0)).max())
    centre = result.surface_rest.mean(axis=0)
    out = []
    for spec in specs:
        ob = obstacle(spec["kind"], **{k: v for k, v in spec.items() if k != "kind"})
        if ob.kind == "plane":
            foot = centre - float((centre - ob.point) @ ob.normal) * ob.normal
            mesh = pv.Plane(center=foot, direction=ob.normal, i_size=size, j_size=size)
        elif ob.kind == "sphere":
            mesh = pv.Sphere(radius=ob.radius, center=ob.center, theta_resolution=64, phi_resolution=32)
        else:
            mesh = pv.Box(bounds=(ob.min[0], ob.max[0], ob.min[1], ob.max[1], ob.min[2], ob.max[2]))
        out.append((ob, mesh))
    return out


def _posed(obstacles, result, step: int) -> list:
    """The meshes of :func:`_obstacles` moved by each obstacle's motion to state ``step`` (copies)."""
    fraction = _run_fraction(result, step)
    meshes = []
    for ob, rest in obstacles:
        R, t = ob.pose(fraction)
        mesh = rest.copy()
        mesh.points = np.asarray(rest.points) @ R.T + t
        meshes.append(mesh)
    return meshes


def _obstacle_meshes(result, step: int) -> list:
    """The scene's obstacles at state ``step`` as pyvista meshes in world coordinates (see :func:`_obstacles`)."""
    return _posed(_obstacles(result), result, step)


def _field_names(result) -> list[str]:
    fields = getattr(result, "fields", None)
    return sorted(str(k) for k in fields) if isinstance(fields, dict) else []


def _colour_values(result, color: str):
    """Per-state values to colour by: ``(values (T, V) or (T, F), on "points" or "cells", bar title)``.

    ``displacement`` is the magnitude of the surface displacement.  Any other
    name must be a field the result carries with one value per surface vertex
    (T, V) or per surface triangle (T, F).
    """
    if not isinstance(color, str) or not color:
        raise InputError(f"color must be a name such as 'displacement', got {color!r}")
    if color == _DISPLACEMENT:
        u = result.surface_positions - result.surface_rest[None]
        return np.linalg.norm(u, axis=2), "points", "|u| (m)"
    fields = getattr(result, "fields", None)
    names = _field_names(result)
    key = next((k for k in (color, color.replace("-", "_"), color.replace("_", "-")) if k in names), None)
    if key is None:
        have = ", ".join(names) if names else "none"
        raise InputError(
            f"cannot colour by '{color}': this result carries no field '{color}' (fields in it: {have}); "
            f"ask for it with [output] fields = [\"{color}\"] and run again, or colour by 'displacement'"
        )
    values = np.asarray(fields[key], dtype=float)
    T, V, F = result.n_states, result.surface_rest.shape[0], result.surface_faces.shape[0]
    if values.shape == (T, V):
        return values, "points", key
    if values.shape == (T, F):
        return values, "cells", key
    raise InputError(
        f"cannot colour by '{color}': the field has shape {values.shape}, but a render needs one value per "
        f"surface vertex ({T}, {V}) or per surface triangle ({T}, {F})"
    )


# ---------------------------------------------------------------------------
# rendering
# ---------------------------------------------------------------------------
def render_frames(
    result,
    steps,
    *,
    window_size=(800, 450),
    title=None,
    cmap: str = "viridis",
    view: str = "iso",
    azimuth=None,
    elevation=None,
    up: str = "z",
    color: str = _DISPLACEMENT,
    show_rest: bool = True,
    axes: bool = True,
    gravity: bool = True,
    frames: bool = True,
):
    """Render the given steps offscreen; returns a list of (H, W, 3) uint8 images.

    The camera and the colour range are the same for every picture: fitted to
    the rest shape and to the deformed shapes of all the result's states, so
    that an animation does not jump and a single step is coloured on the
    scale of the whole run.  See :func:`render` for the keywords.
    """
    result = _as_result(result)
    _check_drawable(result)
    steps = [result.step_index(s) for s in steps]
    style = _style(result, window_size=window_size, title=title, cmap=cmap, view=view, azimuth=azimuth,
                   elevation=elevation, up=up, color=color, show_rest=show_rest, axes=axes, gravity=gravity,
                   frames=frames)
    values, where, bar_title = _colour_values(result, color)
    finite = values[np.isfinite(values)]
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 0.0)
    if color == _DISPLACEMENT:
        lo = 0.0
    g = _gravity(result) if style.show_gravity else None
    _offscreen_env()
    import pyvista as pv

    cam = style.camera
    pts = [result.surface_rest, result.surface_positions.reshape(-1, 3)]
    if style.show_frames and _frame_positions(result, 0) is not None:
        pts.append(_frame_positions(result).reshape(-1, 3))
    pts += [line.reshape(-1, 3) for line in _cable_polylines(result)]  # anchors outside the body stay in view
    pts = np.concatenate(pts)
    layout = _Layout.make(style, result, (lo, hi), bar_title, g is not None)
    faces = np.hstack([np.full((result.surface_faces.shape[0], 1), 3), result.surface_faces]).ravel()
    rest = pv.PolyData(np.array(result.surface_rest), faces=faces)
    cmap_obj = _colormap(style.cmap)

    obstacles = _obstacles(result)
    images = []
    plotter = pv.Plotter(off_screen=True, window_size=layout.plot_size)
    try:
        plotter.set_background("white")
        plotter.enable_parallel_projection()
        silhouette = None
        if style.show_rest:
            # the rest shape alone, once (the camera is fixed): later drawn faint, and only where the
            # deformed surface is not, so it never veils the object
            plotter.add_mesh(rest, color=_REST_GREY, smooth_shading=False, show_edges=False)
            _place_camera(plotter, cam, pts, layout.plot_size)
            rest_rgb = np.asarray(plotter.screenshot(return_img=True))[..., :3].astype(float)
            rest_mask = np.isfinite(plotter.get_image_depth(fill_value=np.nan))
            silhouette = (rest_mask, (255.0 - _REST_FAINT * (255.0 - rest_rgb)).round().astype(np.uint8))
        for s in steps:
            plotter.clear()
            mesh = pv.PolyData(np.array(result.surface_positions[s]), faces=faces)
            if hi > lo:
                data = mesh.point_data if where == "points" else mesh.cell_data
                data["value"] = values[s]
                plotter.add_mesh(mesh, scalars="value", cmap=cmap_obj, clim=(lo, hi), show_scalar_bar=False,
                                 smooth_shading=False, show_edges=False, nan_color="lightgray")
            else:
                plotter.add_mesh(mesh, color=_ZERO_COLOUR, smooth_shading=False, show_edges=False)
            for ob_mesh in _posed(obstacles, result, s):  # not in the camera fit: a big obstacle is cut by the frame
                plotter.add_mesh(ob_mesh, color=OBSTACLE_COLOUR, opacity=OBSTACLE_OPACITY, smooth_shading=True,
                                 show_edges=False)
            to_pixels = _place_camera(plotter, cam, pts, layout.plot_size)
            view_image = np.asarray(plotter.screenshot(return_img=True))[..., :3].copy()
            if silhouette is not None:
                empty = ~np.isfinite(plotter.get_image_depth(fill_value=np.nan))
                show = empty & silhouette[0]
                view_image[show] = silhouette[1][show]
            frame_pts = _frame_positions(result, s) if style.show_frames else None
            dots = None if frame_pts is None else to_pixels(frame_pts)
            lines = [to_pixels(line) for line in _cable_polylines(result, s)]
            images.append(layout.compose(view_image, style, result, s, cmap_obj, (lo, hi), g, dots, lines))
    finally:
        plotter.close()
    return images


DRAWABLE = 1e6
"""A render refuses a result with a drawn point farther than this many body sizes (the rest surface's
bounding-box diagonal) from the body's rest centre: a picture of it would be a dot, or VTK's garbage."""


def _check_drawable(result) -> None:
    """InputError when the result's surface or frames are not finite or lie absurdly far (:data:`DRAWABLE`)."""
    rest = np.asarray(result.surface_rest, dtype=float)
    if not np.all(np.isfinite(rest)) or len(rest) == 0:
        raise InputError("the result's rest surface is empty or not finite; nothing can be drawn")
    centre = 0.5 * (rest.min(axis=0) + rest.max(axis=0))
    size = max(float(np.linalg.norm(rest.max(axis=0) - rest.min(axis=0))), 1e-300)
    series = [("surface", np.asarray(result.surface_positions, dtype=float))]
    if result.node_points is not None:
        series.append(("frames", np.asarray(result.node_points, dtype=float)))
    for what, x in series:
        bad = ~np.all(np.isfinite(x), axis=-1)
        with np.errstate(over="ignore", invalid="ignore"):
            far = np.abs(x - centre).max(axis=-1) > DRAWABLE * size
        wrong = bad | far
        if np.any(wrong):
            s = int(np.flatnonzero(wrong.reshape(len(x), -1).any(axis=1))[0])
            how = "not finite (NaN or inf)" if np.any(bad[s]) else (
                f"up to {float(np.nanmax(np.abs(x[s] - centre))):.3g} m from the body (more than {DRAWABLE:g} times "
                f"its size, {size:.3g} m)")
            raise InputError(f"the result's {what} at state {s} is {how}: there is nothing meaningful to draw; "
                             "check the run (voxflex info) and simulate it again")



def render(
    result,
    path,
    *,
    step: int = -1,
    window_size=(800, 450),
    title=None,
    cmap: str = "viridis",
    fps: int = 8,
    view: str = "iso",
    azimuth=None,
    elevation=None,
    up: str = "z",
    color: str = _DISPLACEMENT,
    show_rest: bool = True,
    axes: bool = True,
    gravity: bool = True,
    frames: bool = True,
):
    """Picture of the deformed surface, offscreen.

    Parameters
    ----------
    result : Result or path to a result file
    path : path
        ``.png`` -- one picture of ``step``; a folder (an existing directory or a
        path without suffix) -- one PNG per step (``step_0000.png`` ...);
        ``.gif`` / ``.mp4`` -- an animation of all steps (``.mp4`` needs
        imageio-ffmpeg).
    step : int
        Which state for a single picture (negative counts from the end).
    window_size : (width, height) pixels
        Size of the whole picture (annotations included).
    title : str, optional
        First line above the object (default: the scene's title or "voxflex").
    cmap : str
        Matplotlib colour map name.
    fps : int
        Frames per second of an animation.
    view : {"iso", "front", "side", "top"}
        Named camera direction (see the module docstring).
    azimuth, elevation : float, optional, degrees
        Override the named view's angles (elevation in [-90, 90]).
    up : {"x", "y", "z"}
        World axis drawn vertical (``"y"`` for meshes made y-up).
    color : str
        ``"displacement"`` (magnitude, metres; the default) or the name of a
        field the result carries with one value per surface vertex or
        triangle (e.g. ``"von-mises"``); a missing field is an error that names it.
    show_rest : bool
        Draw the rest shape as a faint translucent silhouette.
    axes : bool
        Draw the axes triad (x red, y green, z blue) as seen by the camera.
    gravity : bool
        Draw the gravity arrow when the result's scene has gravity.
    frames : bool
        Draw the frames of a frame model as dots (affine: the origins t, ``/nodes/state`` columns 9:12;
        rigid: the frames' mass centres, columns 0:3).

    Returns
    -------
    Path
        What was written (the file or the folder).
    """
    result = _as_result(result)
    _check_drawable(result)
    path = Path(path)
    suffix = path.suffix.lower()
    if isinstance(fps, bool) or not isinstance(fps, (int, np.integer)) or fps < 1:
        raise InputError(f"fps must be a positive integer, got {fps!r}")
    opts = dict(window_size=window_size, title=title, cmap=cmap, view=view, azimuth=azimuth, elevation=elevation,
                up=up, color=color, show_rest=show_rest, axes=axes, gravity=gravity, frames=frames)
    # validate every option before the GL probe and any work
    _style(result, **{k: v for k, v in opts.items() if k != "color"}, color=color)
    _colour_values(result, color)
    if suffix in _STILL:
        index = result.step_index(step)
        (image,) = render_frames(result, [index], **opts)
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
        pictures = render_frames(result, range(result.n_states), **opts)
        _write_movie(pictures, path, fps=int(fps))
        return path
    if suffix and not path.is_dir():
        raise InputError(
            f"cannot render to '{path}': give a .png, a folder, a .gif or a .mp4 (unknown extension '{suffix}')"
        )
    pictures = render_frames(result, range(result.n_states), **opts)
    path.mkdir(parents=True, exist_ok=True)
    for i, image in enumerate(pictures):
        _write_png(image, path / f"step_{i:04d}.png")
    return path


def _write_png(image: np.ndarray, path: Path) -> None:
    from PIL import Image

    with atomic_path(path) as tmp:
        Image.fromarray(image).save(tmp, format="PNG", optimize=True)


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
