"""Scale-free tie-breaking for the placement of frames and samples.

A scene and the same scene in other units (every length times ``s``) must
place the same frames and regions: symmetric bodies have exactly equal
distances, which round differently at each scale, so an ``argmax`` or a sort
on raw distances picks a different one of the tied voxels (a 1 cm beam put its
clamp frame on the other of two voxels equidistant from the clamp's centre and
its tip moved 1.5 % from the 1 m beam's).  Values within :data:`TIE` of each
other, relative to the largest magnitude compared, tie; the lowest index wins.
"""

from __future__ import annotations

import numpy as np

__all__ = ["TIE", "first_extreme", "tie_key"]

TIE = 1e-9
"""Relative tolerance under which compared distances tie (far above round-off, far below any real gap)."""


def first_extreme(values, which: str, *, floor: float | None = None) -> int:
    """Index of the first of ``values`` within :data:`TIE` (relative to the largest finite magnitude) of
    the largest (``which="max"``) or smallest (``"min"``); infinities compare as themselves.

    ``floor``: values beyond it on the far side (below it for ``"max"``, above for ``"min"``) are sentinels
    that never win, left out of the magnitude: an array of distances with -1 for the excluded entries would
    otherwise make the tolerance ``TIE`` metres (not relative) whenever the distances are below 1, so that
    the same scene at 1 nm and at 1 m broke ties differently."""
    v = np.asarray(values, dtype=float)
    i = int(np.argmax(v) if which == "max" else np.argmin(v))
    best = float(v[i])
    if not np.isfinite(best) or i == 0:
        return i  # the first infinity, or already the first index
    other = float(v.min() if which == "max" else v.max())
    if floor is not None:
        other = max(other, float(floor)) if which == "max" else min(other, float(floor))
    if np.isfinite(other):
        mag = max(abs(best), abs(other))
    else:  # infinities at the other end: the largest finite magnitude by a masked pass
        finite = np.abs(v[np.isfinite(v)])
        mag = float(finite.max()) if finite.size else 0.0
    tol = TIE * mag
    head = v[:i]
    near = np.flatnonzero(head >= best - tol) if which == "max" else np.flatnonzero(head <= best + tol)
    return int(near[0]) if near.size else i


def tie_key(values, scale: float) -> np.ndarray:
    """``values / scale`` rounded to :data:`TIE`: a sort key on which equal distances at any unit compare
    equal (``scale`` a length or area of the same unit as ``values``, e.g. the voxel size squared)."""
    return np.round(np.asarray(values, dtype=float) / scale / TIE) * TIE
