"""Progress on stderr for long work: bars, log lines and size estimates.

A bar appears only when the work outlasts ``delay`` seconds (so quick calls
stay silent) and only when stderr is a terminal or ``VOXFLEX_PROGRESS=1``.
``VOXFLEX_PROGRESS=0`` silences every bar.  :func:`log` writes a line on
stderr without breaking a bar; :func:`announce` prints a size estimate when
the work is large (or when asked), before the precompute or solve starts.
"""

from __future__ import annotations

import os
import sys

LARGE_DOFS = 200_000
"""Models with at least this many DOFs (estimated) announce their size before they are built and solved."""



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


def log(line: str) -> None:
    """Write one line on stderr (through tqdm, so an open bar is redrawn below it)."""
    from tqdm.auto import tqdm

    tqdm.write(line, file=sys.stderr)


def newton_line(info: dict) -> str:
    """The ``--verbose`` line of one Newton iterate (the solver's ``newton_callback`` dict)."""
    lin = info["linear_solver"] or "-"
    if info["linear_iterations"]:
        lin += f", {info['linear_iterations']} iterations"
    return (f"{info['label']}: Newton {info['iteration']}: residual {info['residual']:.3e}, "
            f"step length {info['step_length']:.3g}, linear solver {lin}, {info['seconds']:.3f} s")


def _megabytes(nbytes: float) -> str:
    return f"{nbytes / 2**20:.3g} MB" if nbytes < 2**30 else f"{nbytes / 2**30:.3g} GB"






def announce(estimate, *, force: bool = False, quiet: bool = False) -> None:
    """Log ``estimate`` (DOFs, text) when ``force``, or when the model is large (:data:`LARGE_DOFS`) unless ``quiet``."""
    dofs, text = estimate
    if force or (dofs >= LARGE_DOFS and not quiet):
        log(text)
