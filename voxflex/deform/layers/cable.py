"""A cable: its polyline through material points, its rest length over the run and its tension law.

The data of one ``[[cable]]`` table, validated once; the layer that adds the
cables' energy to a model is :mod:`voxflex.deform.layers.cables`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import InputError

__all__ = ["Cable", "cable_law"]


# ---------------------------------------------------------------------------
# the scalar law
# ---------------------------------------------------------------------------
def cable_law(delta, stiffness, *, tension_only: bool = True):
    """Energy, tension and tangent of elastic cables of excess lengths ``delta``.

    Parameters
    ----------
    delta : (c,) float, metres
        Length minus rest length ``l - L``.
    stiffness : (c,) float, N/m (> 0)
    tension_only : bool
        True: ``E = k/2 max(delta, 0)^2`` (slack cables carry nothing); False: ``k/2 delta^2``.

    Returns
    -------
    energy : (c,) float, J
    tension : (c,) float, N (``dE/dl``; >= 0 when tension_only)
    tangent : (c,) float, N/m (``d2E/dl2``: k where taut, 0 where slack)
    """
    delta = np.asarray(delta, dtype=float)
    k = np.broadcast_to(np.asarray(stiffness, dtype=float), delta.shape)
    taut = delta > 0 if tension_only else np.ones(delta.shape, dtype=bool)
    d = np.where(taut, delta, 0.0)
    return 0.5 * k * d * d, k * d, np.where(taut, k, 0.0)


# ---------------------------------------------------------------------------
# a cable's description
# ---------------------------------------------------------------------------
def _finite(name, value, *, positive=False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputError(f"cable {name} must be a number, got {value!r}")
    v = float(value)
    if not np.isfinite(v) or (positive and v <= 0):
        raise InputError(f"cable {name} must be a finite number{' > 0' if positive else ''}, got {value!r}")
    return v


@dataclass(frozen=True, eq=False)
class Cable:
    """One cable: a polyline through material points (see the module docstring).

    Parameters
    ----------
    points : (k, 3) float, metres
        Rest positions of the material points it runs through, in order
        (k >= 2, or k >= 1 with an anchor).
    anchor : (3,) float, metres, optional
        A fixed point in the world: the cable's first end (then its first
        segment runs from the anchor to ``points[0]``).
    stiffness : float, N/m, optional
        The whole cable's axial stiffness ``k = EA / L_0``; required unless ``pull`` is given.
    rest_length : float, metres, optional
        ``L_0``; default the rest polyline length (taut, no tension, at rest).
    shorten : float, metres
        Length reduction reached at the end of the run (``L(s) = L_0 - s * shorten``;
        negative lets the cable out).
    pull : float, N, optional
        A prescribed tension reached at the end of the run (``T = s * pull``) instead of
        an elastic cable: no stiffness, rest length or shortening then.
    tension_only : bool
        False makes an elastic cable a two-sided spring (it pushes when compressed).
    """

    points: np.ndarray
    anchor: np.ndarray | None = None
    stiffness: float | None = None
    rest_length: float | None = None
    shorten: float = 0.0
    pull: float | None = None
    tension_only: bool = True

    def __post_init__(self):
        s = object.__setattr__
        try:
            P = np.array(self.points, dtype=float)
        except (TypeError, ValueError):
            raise InputError("cable points must be a list of [x, y, z] rest positions (m)") from None
        if P.ndim != 2 or P.shape[1] != 3 or not np.all(np.isfinite(P)):
            raise InputError(f"cable points must be a finite (k, 3) list of [x, y, z] (m), got shape {P.shape}")
        A = None
        if self.anchor is not None:
            A = np.array(self.anchor, dtype=float)
            if A.shape != (3,) or not np.all(np.isfinite(A)):
                raise InputError(f"cable anchor must be a finite [x, y, z] (m), got {self.anchor!r}")
        if len(P) < (1 if A is not None else 2):
            raise InputError(f"a cable needs at least 2 points, or 1 point and an anchor; got {len(P)} point(s)")
        P.setflags(write=False)
        s(self, "points", P)
        if A is not None:
            A.setflags(write=False)
        s(self, "anchor", A)
        seg = np.linalg.norm(np.diff(self.polyline, axis=0), axis=1)
        if np.any(seg <= 0):
            e = int(np.argmin(seg))
            raise InputError(f"cable segment {e} has zero length (two equal consecutive points "
                             f"{self.polyline[e].tolist()}); remove the repeated point")
        if not isinstance(self.tension_only, (bool, np.bool_)):
            raise InputError(f"cable tension_only must be true or false, got {self.tension_only!r}")
        s(self, "shorten", _finite("shorten", self.shorten))
        if self.pull is not None:
            s(self, "pull", _finite("pull", self.pull, positive=True))
            given = [k for k in ("stiffness", "rest_length") if getattr(self, k) is not None]
            if self.shorten != 0:
                given.append("shorten")
            if given:
                raise InputError(f"a cable with pull (a prescribed tension) takes no {' or '.join(given)}; "
                                 "give either pull or stiffness (with rest_length / shorten)")
            return
        if self.stiffness is None:
            raise InputError("a cable needs a stiffness (N/m) or a pull (N)")
        s(self, "stiffness", _finite("stiffness", self.stiffness, positive=True))
        if self.rest_length is not None:
            s(self, "rest_length", _finite("rest_length", self.rest_length, positive=True))
        L0 = self.length_at(0.0)
        if L0 - self.shorten <= 0:
            raise InputError(f"cable shorten = {self.shorten:g} m leaves no length (rest length {L0:g} m); "
                             "give a shortening below the rest length")

    @property
    def polyline(self) -> np.ndarray:
        """(k or k+1, 3): the anchor (if any) then the points, at rest (m)."""
        return self.points if self.anchor is None else np.vstack([self.anchor, self.points])

    @property
    def rest_polyline_length(self) -> float:
        """Length of the polyline at rest (m)."""
        return float(np.sum(np.linalg.norm(np.diff(self.polyline, axis=0), axis=1)))

    def length_at(self, fraction: float) -> float:
        """Rest length ``L(s) = L_0 - s * shorten`` (m) at run fraction s (elastic cables)."""
        L0 = self.rest_polyline_length if self.rest_length is None else self.rest_length
        return L0 - float(fraction) * self.shorten
