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


def first_extreme(values, which: str) -> int:
    """Index of the first of ``values`` within :data:`TIE` (relative to the largest finite magnitude) of
    the largest (``which="max"``) or smallest (``"min"``); infinities compare as themselves."""
    values = np.asarray(values, dtype=float)
    finite = np.abs(values[np.isfinite(values)])
    tol = TIE * (float(finite.max()) if finite.size else 0.0)
    if which == "max":
        top = float(values.max())
        return int(np.flatnonzero(values >= top - tol)[0])
    low = float(values.min())
    return int(np.flatnonzero(values <= low + tol)[0])


def tie_key(values, scale: float) -> np.ndarray:
    """``values / scale`` rounded to :data:`TIE`: a sort key on which equal distances at any unit compare
    equal (``scale`` a length or area of the same unit as ``values``, e.g. the voxel size squared)."""
    return np.round(np.asarray(values, dtype=float) / scale / TIE) * TIE
