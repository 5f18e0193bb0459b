"""BLAS on one thread, through a threadpoolctl controller made once.

``threadpoolctl.threadpool_limits`` re-scans the loaded shared libraries on
every call (0.6-1.5 ms: it reads ``/proc/self/maps``); a Newton loop that pins
BLAS around every linear solve paid that each iteration (62 calls, 0.1 s in a
31-iteration voxel run).  :func:`one_thread` reuses one controller.  On a busy
2-core machine threaded OpenBLAS stalled small dense factorisations for
hundreds of milliseconds, hence the pin around the solvers' dense kernels.
"""

from __future__ import annotations

_CONTROLLER = []


def one_thread():
    """A context manager limiting BLAS to one thread (restored on exit)."""
    from threadpoolctl import ThreadpoolController

    if not _CONTROLLER:
        _CONTROLLER.append(ThreadpoolController())
    return _CONTROLLER[0].limit(limits=1, user_api="blas")
