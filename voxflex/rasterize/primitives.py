"""Analytic primitives (box, cylinder, sphere) and their spec strings.

Each primitive is a frozen dataclass with an exact signed distance
(negative inside, metres) and an axis-aligned bounding box.  ``origin`` is the
LOWER CORNER of the bounding box (docs/conventions.md), so ``Box((4, 1, 1))`` fills
``[0, 4] x [0, 1] x [0, 1]``.

Spec strings (command line, scene files)::

    box:LX,LY,LZ      cylinder:R,L      sphere:R

>>> parse_spec("box:4,1,1").bounds()
(array([0., 0., 0.]), array([4., 1., 1.]))
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError, check_choice, did_you_mean

SPEC_FORMS = "box:LX,LY,LZ, cylinder:R,L, sphere:R"
_AXES = {"x": 0, "y": 1, "z": 2}


def _positive(name: str, values, count: int) -> tuple[float, ...]:
    try:
        arr = np.asarray(values, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be {count} positive number(s), got {values!r}") from None
    if arr.size == 1 and count > 1:
        arr = np.repeat(arr, count)
    if arr.size != count:
        raise InputError(f"{name} must be {count} positive number(s), got {arr.size}")
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise InputError(f"{name} must be finite and > 0, got {arr.tolist()}; give positive lengths in metres")
    return tuple(float(v) for v in arr)


def _vector(name: str, values) -> tuple[float, float, float]:
    try:
        arr = np.broadcast_to(np.asarray(values, dtype=float), (3,))
    except (TypeError, ValueError):
        raise InputError(f"{name} must be 3 numbers, got {values!r}") from None
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name} must be finite, got {arr.tolist()}")
    return tuple(float(v) for v in arr)


def _points(points) -> np.ndarray:
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(f"points must have shape (n, 3), got {pts.shape}")
    return pts


@dataclass(frozen=True)
class Box:
    """Axis-aligned box.

    Parameters
    ----------
    size : (3,) float, metres
        Edge lengths along x, y, z (> 0).
    origin : (3,) float, metres
        Lower corner.
    """

    size: tuple[float, float, float]
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        object.__setattr__(self, "size", _positive("box size", self.size, 3))
        object.__setattr__(self, "origin", _vector("box origin", self.origin))

    @property
    def volume(self) -> float:
        """Exact volume, m^3."""
        return float(np.prod(self.size))

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper corners (3,), (3,) of the bounding box."""
        lo = np.asarray(self.origin)
        return lo.copy(), lo + np.asarray(self.size)

    def signed_distance(self, points) -> np.ndarray:
        """Exact signed distance (n,) of ``points`` (n, 3); negative inside."""
        return _box_sd(_points(points), self)


@dataclass(frozen=True)
class Cylinder:
    """Solid circular cylinder with flat caps.

    Parameters
    ----------
    radius, length : float, metres
        Radius (> 0) and length along ``axis`` (> 0).
    origin : (3,) float, metres
        Lower corner of the bounding box.
    axis : {"x", "y", "z"}
        Direction of the cylinder's axis.
    """

    radius: float
    length: float
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    axis: str = "z"

    def __post_init__(self):
        object.__setattr__(self, "radius", _positive("cylinder radius", self.radius, 1)[0])
        object.__setattr__(self, "length", _positive("cylinder length", self.length, 1)[0])
        object.__setattr__(self, "origin", _vector("cylinder origin", self.origin))
        check_choice("cylinder axis", self.axis, _AXES)

    @property
    def volume(self) -> float:
        """Exact volume, m^3."""
        return math.pi * self.radius**2 * self.length

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper corners (3,), (3,) of the bounding box."""
        ext = np.full(3, 2.0 * self.radius)
        ext[_AXES[self.axis]] = self.length
        lo = np.asarray(self.origin)
        return lo.copy(), lo + ext

    def signed_distance(self, points) -> np.ndarray:
        """Exact signed distance (n,) of ``points`` (n, 3); negative inside."""
        return _cylinder_sd(_points(points), self)


@dataclass(frozen=True)
class Sphere:
    """Solid ball.

    Parameters
    ----------
    radius : float, metres
    origin : (3,) float, metres
        Lower corner of the bounding box (the centre is ``origin + radius``).
    """

    radius: float
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        object.__setattr__(self, "radius", _positive("sphere radius", self.radius, 1)[0])
        object.__setattr__(self, "origin", _vector("sphere origin", self.origin))

    @property
    def volume(self) -> float:
        """Exact volume, m^3."""
        return 4.0 / 3.0 * math.pi * self.radius**3

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper corners (3,), (3,) of the bounding box."""
        lo = np.asarray(self.origin)
        return lo.copy(), lo + 2.0 * self.radius

    def signed_distance(self, points) -> np.ndarray:
        """Exact signed distance (n,) of ``points`` (n, 3); negative inside."""
        return _sphere_sd(_points(points), self)


PRIMITIVES = {"box": (Box, 3, "LX,LY,LZ"), "cylinder": (Cylinder, 2, "R,L"), "sphere": (Sphere, 1, "R")}
Primitive = Box | Cylinder | Sphere


def parse_spec(spec: str, origin=(0.0, 0.0, 0.0)) -> Primitive:
    """Build a primitive from a spec string such as ``"box:4,1,1"``.

    Parameters
    ----------
    spec : str
        One of ``box:LX,LY,LZ``, ``cylinder:R,L`` (axis along z), ``sphere:R``; lengths in metres.
    origin : (3,) float
        Lower corner of the primitive's bounding box.
    """
    text = str(spec).strip()
    kind, sep, rest = text.partition(":")
    kind = kind.strip().lower()
    if kind not in PRIMITIVES:
        raise InputError(
            f"unknown primitive '{kind}'{did_you_mean(kind, PRIMITIVES)} in '{text}'; accepted forms: {SPEC_FORMS}"
        )
    cls, count, form = PRIMITIVES[kind]
    try:
        values = [float(v) for v in rest.split(",")] if sep and rest.strip() else []
    except ValueError:
        values = None
    if values is None or len(values) != count:
        raise InputError(
            f"malformed primitive spec '{text}': {kind} needs {count} number(s) ({kind}:{form}); "
            f"accepted forms: {SPEC_FORMS}"
        )
    if not all(math.isfinite(v) and v > 0 for v in values):
        raise InputError(f"primitive spec '{text}' has a non-positive or non-finite length; all lengths must be > 0")
    if kind == "box":
        return Box(tuple(values), origin=origin)
    if kind == "cylinder":
        return Cylinder(values[0], values[1], origin=origin)
    return Sphere(values[0], origin=origin)



# -- private implementations (trust their inputs) --------------------------
def _box_sd(points: np.ndarray, box: Box) -> np.ndarray:
    half = 0.5 * np.asarray(box.size)
    q = np.abs(points - (np.asarray(box.origin) + half)) - half
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    return outside + np.minimum(q.max(axis=1), 0.0)


def _cylinder_sd(points: np.ndarray, cyl: Cylinder) -> np.ndarray:
    a = _AXES[cyl.axis]
    lo, hi = cyl.bounds()
    centre = 0.5 * (lo + hi)
    rel = points - centre
    axial = np.abs(rel[:, a]) - 0.5 * cyl.length
    others = [b for b in range(3) if b != a]
    radial = np.hypot(rel[:, others[0]], rel[:, others[1]]) - cyl.radius
    outside = np.hypot(np.maximum(axial, 0.0), np.maximum(radial, 0.0))
    return outside + np.minimum(np.maximum(axial, radial), 0.0)


def _sphere_sd(points: np.ndarray, sph: Sphere) -> np.ndarray:
    centre = np.asarray(sph.origin) + sph.radius
    return np.linalg.norm(points - centre, axis=1) - sph.radius
