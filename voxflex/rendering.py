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

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ._atomic import atomic_path
from .errors import InputError, check_choice

__all__ = ["render", "render_frames", "VIEWS", "UP_AXES", "camera_axes"]

_STILL = (".png",)
_MOVIES = (".gif", ".mp4")

#: named views: (azimuth, elevation) in degrees
VIEWS = {
    "iso": (45.0, math.degrees(math.atan(1.0 / math.sqrt(2.0)))),
    "front": (0.0, 0.0),
    "side": (90.0, 0.0),
    "top": (0.0, 90.0),
}
UP_AXES = ("x", "y", "z")
# (right, back) world axes of the front view for each up axis; right x back = up (right-handed)
_FRONT = {
    "z": ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
    "y": ((1.0, 0.0, 0.0), (0.0, 0.0, -1.0)),
    "x": ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
}
_UP = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}
_DISPLACEMENT = "displacement"
_REST_GREY = (0.62, 0.64, 0.68)
_REST_FAINT = 0.3  # the rest silhouette keeps this fraction of its shading over white
_ZERO_COLOUR = (0.80, 0.84, 0.90)  # the surface colour when nothing moved (no colour range)
_AXIS_COLOURS = {"x": (205, 40, 40), "y": (30, 150, 40), "z": (40, 80, 220)}
_TEXT = (20, 20, 20)
_MARGIN = 0.04  # empty fraction of the plot area on each side of the object


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
# the camera
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class _Camera:
    toward: np.ndarray  # (3,) unit vector from the object to the camera
    right: np.ndarray  # (3,) world direction drawn to the right
    up: np.ndarray  # (3,) world direction drawn upwards


def camera_axes(view: str = "iso", *, azimuth=None, elevation=None, up: str = "z"):
    """World directions of a view: towards the camera, screen right, screen up.

    Parameters
    ----------
    view : {"iso", "front", "side", "top"}
        Named view; ``azimuth`` / ``elevation`` override its angles.
    azimuth, elevation : float, optional, degrees
        Camera angles about the ``up`` axis (elevation in [-90, 90]).
    up : {"x", "y", "z"}
        World axis drawn vertical.

    Returns
    -------
    toward, right, screen_up : (3,) float each
        Orthonormal, right-handed (``right x screen_up = toward``).

    Examples
    --------
    >>> t, r, u = camera_axes("front")
    >>> t.round(12).tolist(), r.tolist(), u.round(12).tolist()
    ([0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    """
    cam = _camera(view, azimuth, elevation, up)
    return cam.toward.copy(), cam.right.copy(), cam.up.copy()


def _angle(name: str, value, lo: float, hi: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputError(f"{name} must be a number of degrees, got {value!r}")
    value = float(value)
    if not math.isfinite(value) or not lo <= value <= hi:
        raise InputError(f"{name} must be a number of degrees in [{lo:g}, {hi:g}], got {value!r}")
    return value


def _camera(view, azimuth, elevation, up) -> _Camera:
    check_choice("view", view, VIEWS)
    check_choice("up axis", up, UP_AXES)
    az, el = VIEWS[view]
    if azimuth is not None:
        az = _angle("azimuth", azimuth, -360.0, 360.0)
    if elevation is not None:
        el = _angle("elevation", elevation, -90.0, 90.0)
    R, B = (np.asarray(v) for v in _FRONT[up])
    U = np.asarray(_UP[up])
    a, e = math.radians(az), math.radians(el)
    toward = math.cos(e) * (math.sin(a) * R - math.cos(a) * B) + math.sin(e) * U
    right = math.cos(a) * R + math.sin(a) * B
    screen_up = np.cross(toward, right)
    return _Camera(toward / np.linalg.norm(toward), right, screen_up / np.linalg.norm(screen_up))


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


CABLE_COLOUR = (214, 39, 40)
"""RGB of the cable polylines (no colour map of the renders reaches it: red, far from viridis)."""


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


@dataclass(frozen=True)
class _Style:
    """Everything the pictures of one call share (validated once)."""

    camera: _Camera
    window: tuple[int, int]
    title: str
    cmap: str
    color: str
    show_rest: bool
    show_axes: bool
    show_gravity: bool
    show_frames: bool


def _style(result, *, window_size, title, cmap, view, azimuth, elevation, up, color, show_rest, axes, gravity,
           frames) -> _Style:
    try:
        w, h = (int(v) for v in window_size)
    except (TypeError, ValueError):
        raise InputError(f"window_size must be (width, height) in pixels, got {window_size!r}") from None
    if min(w, h) < 16:
        raise InputError(f"window_size must be (width, height) of at least 16 pixels, got {window_size!r}")
    _colormap(cmap)
    for name, flag in (("show_rest", show_rest), ("axes", axes), ("gravity", gravity), ("frames", frames)):
        if not isinstance(flag, (bool, np.bool_)):
            raise InputError(f"{name} must be true or false, got {flag!r}")
    return _Style(
        camera=_camera(view, azimuth, elevation, up),
        window=(w, h),
        title=_scene_title(result) if title is None else str(title),
        cmap=cmap,
        color=color,
        show_rest=bool(show_rest),
        show_axes=bool(axes),
        show_gravity=bool(gravity),
        show_frames=bool(frames),
    )


def _colormap(name):
    import matplotlib

    if not isinstance(name, str) or name not in matplotlib.colormaps:
        raise InputError(f"unknown colour map {name!r}; use a matplotlib colour map name such as 'viridis'")
    return matplotlib.colormaps[name]


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


def _place_camera(plotter, cam: _Camera, pts: np.ndarray, size):
    """Orthographic camera along ``cam`` whose view holds every point of ``pts`` with a margin.

    Returns the projection: a function of world points (n, 3) -> pixel positions (n, 2) in the view.
    """
    w, h = size
    x, y, z = pts @ cam.right, pts @ cam.up, pts @ cam.toward
    xmid, ymid = 0.5 * (x.min() + x.max()), 0.5 * (y.min() + y.max())
    span = max(float(x.max() - x.min()), float(y.max() - y.min()), float(z.max() - z.min()))
    if not span > 0:  # every point in one place: any scale draws it (an absolute 1e-12 m floor was not unit-free)
        span = max(float(np.abs(pts).max()), 1.0)
    per_pixel = max((x.max() - x.min()) / (w * (1 - 2 * _MARGIN)), (y.max() - y.min()) / (h * (1 - 2 * _MARGIN)))
    per_pixel = max(float(per_pixel), span * 1e-6)
    centre = xmid * cam.right + ymid * cam.up + float(z.mean()) * cam.toward
    camera = plotter.camera
    camera.focal_point = tuple(centre)
    camera.position = tuple(centre + cam.toward * 4.0 * span)
    camera.up = tuple(cam.up)
    camera.parallel_scale = per_pixel * h / 2.0
    plotter.reset_camera_clipping_range()

    def to_pixels(p):
        p = np.asarray(p, dtype=float)
        return np.column_stack([w / 2 + (p @ cam.right - xmid) / per_pixel, h / 2 - (p @ cam.up - ymid) / per_pixel])

    return to_pixels


# ---------------------------------------------------------------------------
# 2-D annotations
# ---------------------------------------------------------------------------
def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=max(int(size), 6))
    except (TypeError, OSError, AttributeError):  # Pillow without FreeType: the fixed bitmap font
        return ImageFont.load_default()


def _text_size(font, text: str) -> tuple[int, int]:
    left, top, right, bottom = font.getbbox(text)
    return int(math.ceil(right - min(left, 0))), int(math.ceil(bottom - min(top, 0)))


def _fit_text(text: str, size: int, width: int, minimum: int = 7):
    """A font (shrunk down to ``minimum`` px) and the text (ellipsized if need be) that fit in ``width``."""
    while True:
        font = _font(size)
        if _text_size(font, text)[0] <= width or size <= minimum:
            break
        size -= 1
    if _text_size(font, text)[0] > width:
        while len(text) > 1 and _text_size(font, text + "…")[0] > width:
            text = text[:-1]
        text = text + "…" if text else ""
    return font, text


def _ticks(lo: float, hi: float, count: int = 5) -> list[float]:
    return [lo + (hi - lo) * i / (count - 1) for i in range(count)]


def _tick_text(v: float) -> str:
    return "0" if v == 0 else f"{v:.3g}"


@dataclass(frozen=True)
class _Layout:
    """Where each part of the picture goes (pixels)."""

    window: tuple[int, int]
    font: int
    title_h: int
    band_x: int  # left edge of the right band (colour bar, triad)
    band_w: int
    bar_box: tuple[int, int, int, int] | None  # x0, y0, x1, y1 of the colour gradient
    bar_title: str
    triad_box: tuple[int, int, int, int] | None
    gravity_box: tuple[int, int, int, int] | None

    @property
    def plot_size(self) -> tuple[int, int]:
        w, h = self.window
        return max(self.band_x, 8), max(h - self.title_h, 8)

    @classmethod
    def make(cls, style: _Style, result, clim, bar_title: str, has_gravity: bool) -> "_Layout":
        W, H = style.window
        f = int(np.clip(round(min(H * 0.04, W * 0.024)), 7, 28))
        pad = max(2, f // 3)
        title_h = int(2 * f * 1.25 + 2 * pad)
        font = _font(f)
        labels = [_tick_text(v) for v in _ticks(*clim)] if clim[1] > clim[0] else ["|u| = 0"]
        label_w = max(_text_size(font, t)[0] for t in labels)
        bar_w = max(6, int(0.8 * f))
        title_w = _text_size(font, bar_title)[0]
        band_w = 2 * pad + max(bar_w + pad + label_w, title_w)
        band_w = min(band_w, W // 3)
        legend = int(np.clip(4.5 * f, 24, H * 0.3))
        band_w = max(band_w, legend + 2 * pad) if style.show_axes or has_gravity else band_w
        band_w = min(band_w, W // 3)
        band_x = W - band_w
        y = title_h
        triad = gravity = None
        free = H - y - pad
        # the colour bar needs its title, a gradient at least 3 labels tall; the legends come below it
        bar_need = 2 * f + 3 * f
        if style.show_axes and free - legend >= bar_need:
            triad = (band_x + (band_w - legend) // 2, H - pad - legend, band_x + (band_w + legend) // 2, H - pad)
            free -= legend + pad
        if has_gravity and free - legend >= bar_need:
            top = (triad[1] if triad else H - pad) - pad - legend
            gravity = (band_x + (band_w - legend) // 2, top, band_x + (band_w + legend) // 2, top + legend)
            free -= legend + pad
        bar_top = y + int(1.9 * f)
        bar_bottom = min(y + free - f // 2, bar_top + max(10 * f, int(0.45 * H)))
        bar = None
        if bar_bottom - bar_top >= f:
            bar = (band_x + pad, bar_top, band_x + pad + bar_w, bar_bottom)
        return cls((W, H), f, title_h, band_x, band_w, bar, bar_title, triad, gravity)

    # -- drawing ----------------------------------------------------------
    def compose(self, view_image, style: _Style, result, step: int, cmap, clim, gravity, dots=None,
                cables=()) -> np.ndarray:
        from PIL import Image, ImageDraw

        W, H = self.window
        canvas = Image.new("RGB", (W, H), "white")
        canvas.paste(Image.fromarray(view_image), (0, self.title_h))
        draw = ImageDraw.Draw(canvas)
        width = max(2, round(self.font / 6))
        for line in cables:  # cables: polylines through the eyelets (pixels), always visible
            xy = [(float(x), float(y) + self.title_h) for x, y in line]
            if len(xy) >= 2:
                draw.line(xy, fill=CABLE_COLOUR, width=width, joint="curve")
        if dots is not None:  # affine frames: always visible, even inside the object
            r = max(2.0, self.font / 4)
            for x, y in dots:
                y = y + self.title_h
                draw.ellipse([x - r - 1, y - r - 1, x + r + 1, y + r + 1], fill="white")
                draw.ellipse([x - r, y - r, x + r, y + r], fill=(0, 0, 0))
        self._title(draw, style, result, step)
        self._colour_bar(draw, cmap, clim)
        if self.triad_box is not None:
            self._triad(draw, style.camera)
        if self.gravity_box is not None and gravity is not None:
            self._gravity(draw, style.camera, gravity)
        return np.asarray(canvas)

    def _title(self, draw, style, result, step):
        W = self.window[0]
        pad = max(2, self.font // 3)
        if _solver_kind(result) == "static":
            when = f"load factor {result.time[step]:.4g}"
        else:
            when = f"t = {result.time[step]:.4g} s"
        number = int(result.step[step]) if getattr(result, "step", None) is not None else step  # --every skips steps
        state = f"step {number}/{result.n_steps}, {when}"
        if not result.complete:  # a failed run's picture says so (it is not the answer the scene asked for)
            reason = " ".join(str(result.error).split()) or "no reason recorded"
            state = f"FAILED after step {result.n_steps}: {reason} | {state}"
        lines = [style.title, state]
        y = pad
        for text, size in zip(lines, (self.font + 1, self.font - 1)):
            font, text = _fit_text(text, size, W - 2 * pad)
            draw.text((pad, y), text, fill=_TEXT, font=font)
            y += int(self.font * 1.25)

    def _colour_bar(self, draw, cmap, clim):
        if self.bar_box is None:
            return
        x0, y0, x1, y1 = self.bar_box
        pad = max(2, self.font // 3)
        room = self.window[0] - x0 - pad
        font, title = _fit_text(self.bar_title, self.font, room)
        draw.text((x0, y0 - int(1.7 * self.font)), title, fill=_TEXT, font=font)
        lo, hi = clim
        if not hi > lo:
            font, text = _fit_text("|u| = 0" if self.bar_title.startswith("|u|") else "constant", self.font, room)
            draw.text((x0, y0), text, fill=_TEXT, font=font)
            return
        n = max(y1 - y0, 2)
        colours = (np.asarray(cmap(np.linspace(1.0, 0.0, n)))[:, :3] * 255).round().astype(int)
        for i, c in enumerate(colours):
            draw.line([(x0, y0 + i), (x1, y0 + i)], fill=tuple(int(v) for v in c))
        draw.rectangle([x0, y0, x1, y1], outline=(90, 90, 90))
        font = _font(self.font)
        room = self.window[0] - (x1 + pad) - 1
        for v in _ticks(lo, hi):
            yy = y1 - (v - lo) / (hi - lo) * (y1 - y0)
            draw.line([(x1, yy), (x1 + pad // 2 + 1, yy)], fill=(90, 90, 90))
            f, text = _fit_text(_tick_text(v), self.font, room)
            tw, th = _text_size(f, text)
            ty = int(np.clip(yy - th / 2 - 1, 0, self.window[1] - th - 1))
            draw.text((x1 + pad, ty), text, fill=_TEXT, font=f)

    def _arrow(self, draw, start, end, colour, width):
        draw.line([start, end], fill=colour, width=width)
        d = np.subtract(end, start).astype(float)
        length = float(np.hypot(*d))
        if length < 1:
            return
        d /= length
        n = np.array([-d[1], d[0]])
        head = min(0.35 * length, 3.0 * width + 4)
        base = np.asarray(end) - d * head
        draw.polygon([tuple(end), tuple(base + n * head * 0.45), tuple(base - n * head * 0.45)], fill=colour)

    def _triad(self, draw, cam: _Camera):
        x0, y0, x1, y1 = self.triad_box
        c = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
        arm = 0.34 * (x1 - x0)
        font = _font(max(self.font - 2, 7))
        width = max(1, self.font // 8)
        axes = []
        for name, e in _UP.items():
            e = np.asarray(e)
            axes.append((float(e @ cam.toward), name, np.array([e @ cam.right, -(e @ cam.up)])))
        for _, name, d in sorted(axes):  # the axis pointing away first, the one towards the camera last
            end = c + arm * d
            self._arrow(draw, tuple(c), tuple(end), _AXIS_COLOURS[name], width)
            tw, th = _text_size(font, name)
            length = float(np.hypot(*d))
            lab = c + (arm + 0.6 * self.font) * (d / length if length > 0.2 else np.array([0.7, -0.7]))
            lx = int(np.clip(lab[0] - tw / 2, x0, x1 - tw))
            ly = int(np.clip(lab[1] - th / 2, y0, y1 - th))
            draw.text((lx, ly), name, fill=_AXIS_COLOURS[name], font=font)

    def _gravity(self, draw, cam: _Camera, g):
        x0, y0, x1, y1 = self.gravity_box
        c = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
        d_unit = g / np.linalg.norm(g)
        d = np.array([d_unit @ cam.right, -(d_unit @ cam.up)])
        arm = 0.32 * (x1 - x0)
        width = max(2, self.font // 6)
        length = float(np.hypot(*d))
        colour = (40, 40, 40)
        if length > 0.25:
            self._arrow(draw, tuple(c - arm * d), tuple(c + arm * d), colour, width)
        else:  # gravity along the line of sight: a dot (towards the viewer) or a cross (away)
            r = 0.18 * (x1 - x0)
            draw.ellipse([c[0] - r, c[1] - r, c[0] + r, c[1] + r], outline=colour, width=width)
            if float(d_unit @ cam.toward) > 0:
                draw.ellipse([c[0] - r / 4, c[1] - r / 4, c[0] + r / 4, c[1] + r / 4], fill=colour)
            else:
                k = r * 0.7
                draw.line([(c[0] - k, c[1] - k), (c[0] + k, c[1] + k)], fill=colour, width=width)
                draw.line([(c[0] - k, c[1] + k), (c[0] + k, c[1] - k)], fill=colour, width=width)
        text = f"g = {np.linalg.norm(g):.3g} m/s^2"
        f, text = _fit_text(text, max(self.font - 2, 7), x1 - x0 + (self.window[0] - x1) - 2)
        tw, th = _text_size(f, text)
        draw.text((int(max(x0, min(c[0] - tw / 2, self.window[0] - tw - 1))), y0), text, fill=colour, font=f)


def _solver_kind(result) -> str:
    """``static`` or ``implicit-euler``: the run's solver (``/problem``; static where not recorded)."""
    return str(result.problem.get("solver_kind", "static"))


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


def _scene_title(result) -> str:
    title = result.problem.get("title")
    return str(title) if title else "voxflex"


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
