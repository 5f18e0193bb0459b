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

# measured on the voxel reference (peak resident memory per DOF of a solve, linear and nonlinear materials)
_VOXEL_BYTES_PER_DOF = {True: 1.2e3, False: 2.9e3}


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


def image_estimate(image, node_kind: str):
    """(DOFs, text) of the model about to be built on ``image``; the DOFs of voxel nodes are
    estimated from the occupied voxels (about one node per voxel plus the surface layer)."""
    import numpy as np

    voxels = int(np.count_nonzero(np.asarray(image.labels)))
    if node_kind != "voxel":
        return 0, f"building a {node_kind} model over {voxels} voxels"
    dofs = 3 * voxels
    return dofs, (f"building the voxel model: {voxels} voxels, about {dofs} DOF; solve memory about "
                  f"{_megabytes(dofs * _VOXEL_BYTES_PER_DOF[True])} (linear) to "
                  f"{_megabytes(dofs * _VOXEL_BYTES_PER_DOF[False])} (nonlinear materials)")


def model_estimate(model, steps: int):
    """(DOFs, text): the model's size and an estimate of the solve's memory."""
    dofs = int(model.rest.size)
    samples = getattr(model, "n_samples", None)
    if model.node_kind == "voxel":
        nbytes = dofs * _VOXEL_BYTES_PER_DOF[bool(model.constant_tangent)]
        basis = "measured per DOF on the voxel reference"
    else:
        # the dense Hessian, its free block and its factor (3 x 8 N^2 bytes); per sample the 9x9 tangent
        # block twice (1296 B) and the Jacobian's 9 rows x 12 k columns in CSR (12 B each, k = 4 parents)
        m = samples or 0
        nbytes = 3 * 8.0 * dofs**2 + m * (2 * 81 * 8 + 9 * 12 * 4 * 12)
        basis = "dense stiffness of the frames, tangents and Jacobian of the samples"
    text = (f"model: {model.n_nodes} {model.node_kind} nodes, {dofs} DOF"
            + (f", {samples} samples" if samples else "")
            + f"; {steps} step(s); memory about {_megabytes(nbytes)} ({basis})")
    return dofs, text


def announce(estimate, *, force: bool = False, quiet: bool = False) -> None:
    """Log ``estimate`` (DOFs, text) when ``force``, or when the model is large (:data:`LARGE_DOFS`) unless ``quiet``."""
    dofs, text = estimate
    if force or (dofs >= LARGE_DOFS and not quiet):
        log(text)
