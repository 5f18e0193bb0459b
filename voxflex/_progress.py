"""Progress bars on stderr for long work.

A bar appears only when the work outlasts ``delay`` seconds (so quick calls
stay silent) and only when stderr is a terminal or ``VOXFLEX_PROGRESS=1``.
``VOXFLEX_PROGRESS=0`` silences every bar.
"""

from __future__ import annotations

import os
import sys


def _enabled() -> bool:
    flag = os.environ.get("VOXFLEX_PROGRESS")
    if flag is not None:
        return flag.lower() not in {"0", "false", "no", "off"}
    return sys.stderr.isatty()


def progress(iterable=None, *, total=None, desc: str = "", unit: str = "it", delay: float = 2.0):
    """Wrap ``iterable`` (or count to ``total``) with a tqdm bar on stderr."""
    from tqdm.auto import tqdm

    return tqdm(
        iterable,
        total=total,
        desc=desc,
        unit=unit,
        delay=delay,
        file=sys.stderr,
        disable=not _enabled(),
        leave=False,
        dynamic_ncols=True,
    )
