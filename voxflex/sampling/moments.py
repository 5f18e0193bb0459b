"""Volume moments of simple regions about sample points (the elastons' V, M1, M2).

An elaston (:mod:`voxflex.deform.materials.elaston`) integrates a strain field that
varies linearly over its region from the region's volume ``V``, first moment
``M1 = int (x - x0) dV`` and second moment ``M2 = int (x - x0)(x - x0)^T dV``.

>>> V, M1, M2 = box_moments([[0, 0, 0]], [[1, 1, 1]], [[0.5, 0.5, 0.5]])
>>> float(V[0]), float(M2[0, 0, 0])
(1.0, 0.08333333333333333)
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError

__all__ = ["box_moments"]


def box_moments(lower, upper, x0):
    """Volume moments (V, M1, M2) of axis-aligned boxes about points x0.

    Parameters
    ----------
    lower, upper : arrays (n, 3)
        Box corners [m], ``upper > lower``.
    x0 : array (n, 3)
        Sample points [m] (anywhere).

    Returns
    -------
    V (n,) [m^3], M1 (n, 3) [m^4], M2 (n, 3, 3) [m^5].
    """
    lo = np.asarray(lower, dtype=np.float64)
    hi = np.asarray(upper, dtype=np.float64)
    x0 = np.asarray(x0, dtype=np.float64)
    if lo.ndim != 2 or lo.shape[1] != 3 or hi.shape != lo.shape or x0.shape != lo.shape:
        raise InputError(f"box corners and x0 must all have shape (n, 3); got {lo.shape}, {hi.shape}, {x0.shape}")
    if not np.all(hi > lo):
        raise InputError("box upper corners must exceed the lower corners on every axis")
    length = hi - lo
    V = np.prod(length, axis=1)
    c = 0.5 * (lo + hi) - x0  # centroid offset
    M1 = V[:, None] * c
    M2 = V[:, None, None] * (c[:, :, None] * c[:, None, :] + np.einsum("ni,ij->nij", length**2 / 12.0, np.eye(3)))
    return V, M1, M2
