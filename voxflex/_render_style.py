"""The look of a render, validated once: the camera and the style every picture of one call shares.

The camera turns a named ``view`` (or an ``azimuth`` / ``elevation`` about the world axis ``up``) into the
world directions towards the camera, screen right and screen up (:func:`camera_axes`; the conventions are in
:mod:`voxflex.rendering`'s docstring), and fits the orthographic view of a plotter to the drawn points
(:func:`_place_camera`).  :func:`_style` validates a call's options into a :class:`_Style` (camera, window,
title, colour map, what to show).  Used by :mod:`voxflex.rendering`; the 2-D annotations read the style
(:mod:`voxflex._render_annotations`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import InputError, check_choice

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
_MARGIN = 0.04  # empty fraction of the plot area on each side of the object


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
    >>> (t.round(12) + 0.0).tolist(), r.tolist(), (u.round(12) + 0.0).tolist()  # + 0.0: no -0.0
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
# the style
# ---------------------------------------------------------------------------
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


MAX_PIXELS = 8192
"""The largest picture side (pixels): 8192 x 8192 RGB is 200 MB; 100000 x 100000 made VTK abort the process."""


def _style(result, *, window_size, title, cmap, view, azimuth, elevation, up, color, show_rest, axes, gravity,
           frames) -> _Style:
    try:
        w, h = (int(v) for v in window_size)
    except (TypeError, ValueError):
        raise InputError(f"window_size must be (width, height) in pixels, got {window_size!r}") from None
    if min(w, h) < 16:
        raise InputError(f"window_size must be (width, height) of at least 16 pixels, got {window_size!r}")
    if max(w, h) > MAX_PIXELS:
        raise InputError(f"window_size must be (width, height) of at most {MAX_PIXELS} pixels a side, got {window_size!r}")
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


def _scene_title(result) -> str:
    title = result.problem.get("title")
    return str(title) if title else "voxflex"
