"""Compiled kernels of the voxel stencil: Gauss-Seidel sweeps and products applied from per-pattern 3x81 rows."""

from __future__ import annotations

import numpy as np

from ...._jit import njit


@njit(fastmath={"reassoc", "contract"})
def _stencil_gather(x, nbr, t, xl):
    for o in range(27):
        base = nbr[t, o]
        for c in range(3):
            xl[3 * o + c] = x[base + c]


@njit(fastmath={"reassoc", "contract"})
def _stencil_rows(S, row0, xl):
    """The products of stencil rows ``row0``, ``row0 + 1``, ``row0 + 2`` with the gathered values (one pass)."""
    p0 = 0.0
    p1 = 0.0
    p2 = 0.0
    for m in range(81):
        xm = xl[m]
        p0 += S[row0, m] * xm
        p1 += S[row0 + 1, m] * xm
        p2 += S[row0 + 2, m] * xm
    return p0, p1, p2


@njit(fastmath={"reassoc", "contract"})
def stencil_sweep(x, b, node_of_row, nbr, kind, scale, S, b_row, b_ptr, b_idx, b_val, forward):
    """One pointwise Gauss-Seidel sweep on ``A x = b`` with A's rows given two ways, in place on x.

    Rows of an interior node (``node_of_row[k] = t >= 0``; its 3 rows are consecutive):
    ``A[k, :] x = scale[t] * S[kind[t], a] . x[nbr[t]]`` (the node's 27 neighbours' 3
    DOFs each, ``S[3 kind[t] + a]`` (81,) the voxel stencil of a unit material); other rows
    (``b_row[k] = r``): stored, ``b_ptr[r]:b_ptr[r + 1]`` of ``b_idx``, ``b_val``.
    Rows are visited in increasing order (``forward``) or decreasing, each updated
    with the current values of all others, as Gauss-Seidel on the assembled matrix.
    Plain twin: pyamg's ``gauss_seidel`` on the assembled matrix (the tests compare).
    """
    F = len(x)
    xl = np.empty(81, dtype=np.float64)
    k = 0 if forward else F - 1
    while 0 <= k < F:
        t = node_of_row[k]
        if t >= 0:  # a whole node: rows k0, k0 + 1, k0 + 2
            k0 = k if forward else k - 2
            _stencil_gather(x, nbr, t, xl)
            s_t = scale[t]
            row0 = 3 * kind[t]
            # the 3 rows' products with the values before this node (independent of each other) ...
            p0, p1, p2 = _stencil_rows(S, row0, xl)
            # ... then the node's own components in sweep order, each seeing the earlier updates
            if forward:
                u0 = (b[k0] - s_t * p0) / (s_t * S[row0, 39])
                u1 = (b[k0 + 1] - s_t * (p1 + S[row0 + 1, 39] * u0)) / (s_t * S[row0 + 1, 40])
                u2 = (b[k0 + 2] - s_t * (p2 + S[row0 + 2, 39] * u0 + S[row0 + 2, 40] * u1)) / (s_t * S[row0 + 2, 41])
            else:
                u2 = (b[k0 + 2] - s_t * p2) / (s_t * S[row0 + 2, 41])
                u1 = (b[k0 + 1] - s_t * (p1 + S[row0 + 1, 41] * u2)) / (s_t * S[row0 + 1, 40])
                u0 = (b[k0] - s_t * (p0 + S[row0, 40] * u1 + S[row0, 41] * u2)) / (s_t * S[row0, 39])
            x[k0] += u0
            x[k0 + 1] += u1
            x[k0 + 2] += u2
            k = k0 + 3 if forward else k0 - 1
        else:
            r = b_row[k]
            s = 0.0
            d = 0.0
            for e in range(b_ptr[r], b_ptr[r + 1]):
                c = b_idx[e]
                s += b_val[e] * x[c]
                if c == k:
                    d = b_val[e]
            x[k] += (b[k] - s) / d
            k = k + 1 if forward else k - 1


@njit(fastmath={"reassoc", "contract"})
def stencil_matvec(x, node_of_row, nbr, kind, scale, S, b_row, b_ptr, b_idx, b_val, y):
    """``y = A x`` with A's rows as in :func:`stencil_sweep`."""
    F = len(x)
    xl = np.empty(81, dtype=np.float64)
    k = 0
    while k < F:
        t = node_of_row[k]
        if t >= 0:
            _stencil_gather(x, nbr, t, xl)
            p0, p1, p2 = _stencil_rows(S, 3 * kind[t], xl)
            y[k] = scale[t] * p0
            y[k + 1] = scale[t] * p1
            y[k + 2] = scale[t] * p2
            k += 3
        else:
            r = b_row[k]
            s = 0.0
            for e in range(b_ptr[r], b_ptr[r + 1]):
                s += b_val[e] * x[b_idx[e]]
            y[k] = s
            k += 1
    return y
