"""The single JIT entry point of voxflex.

Every compiled kernel is declared with :func:`njit` from this module, so that
compilation options live in one place:

* ``VOXFLEX_NUMBA_CACHE=0`` disables numba's on-disk cache (it is on by
  default; numba falls back to a per-user cache directory when the package
  folder is read-only, and ``NUMBA_CACHE_DIR`` redirects it);
* ``VOXFLEX_DISABLE_JIT=1`` runs the kernels as plain Python, for debugging.

Each kernel has a plain numpy twin, used by the tests as the reference.
"""

from __future__ import annotations

import os

# numba's OpenMP threads busy-wait after each parallel kernel and starve
# OpenBLAS's threads on small machines (a 243x243 Cholesky measured 0.37 s
# instead of 0.5 ms on 2 cores); passive waiting removes the contention.  The
# OpenMP runtime reads this when it loads, at the first parallel kernel, so
# setting it here (before any kernel runs) is enough; a user's setting wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numba  # noqa: E402

CACHE = os.environ.get("VOXFLEX_NUMBA_CACHE", "1").lower() not in {"0", "false", "no", "off"}
DISABLED = os.environ.get("VOXFLEX_DISABLE_JIT", "0").lower() in {"1", "true", "yes", "on"}


def njit(*args, parallel: bool = False, **kwargs):
    """``numba.njit`` with voxflex's defaults (cache switchable, no fastmath).

    Use as ``@njit`` or ``@njit(parallel=True)``.
    """
    options = dict(cache=CACHE, fastmath=False, parallel=parallel, nogil=True)
    options.update(kwargs)
    if DISABLED:
        if args and callable(args[0]):
            return args[0]
        return lambda f: f
    if args and callable(args[0]):
        return numba.njit(**options)(args[0])
    return numba.njit(*args, **options)


prange = numba.prange


@njit
def chunk_bounds(n, chunks, c):  # pragma: no cover - compiled
    """(start, stop) of chunk ``c`` of ``chunks`` near-equal slices of ``range(n)``: the cut every parallel
    kernel uses (fixed by ``n`` and ``chunks`` alone, so results do not depend on the thread count)."""
    step = (n + chunks - 1) // chunks
    return min(n, c * step), min(n, (c + 1) * step)
