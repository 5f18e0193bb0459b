"""Speed against accuracy: a sweep of reduced models measured against the voxel reference.

:func:`tradeoff` runs a scene with the full-resolution voxel model (the
reference), with the same voxel model on coarser grids, and with every
reduced (affine-frame) configuration of a sweep — frame counts, shape-function
kinds, quadratures and sample counts — and measures each one:

* **time**: precompute (building the model: placement, shape functions,
  samples, assembly; what :func:`voxflex.build.model` does) and solve (what
  :func:`voxflex.simulate` does; per step for dynamic scenes), with BLAS,
  OpenMP and numba pinned to one thread, after an untimed warm-up run of the
  smallest configuration of each kind, as the median of 3 runs when a run
  takes less than a second;
* **error** against the reference, relative:

  - ``probe_error``: ``max_t |u_p(t) - u_ref(t)| / max_t |u_ref(t)|`` for every
    probe (displacements from the rest state, every recorded state), the
    largest over the probes;
  - ``surface_error``: the RMS over the boundary-surface vertices of the
    displacement difference, divided by the largest reference surface
    displacement, the largest over the recorded states.  Models on the same
    image share the voxelized boundary vertex for vertex (checked); voxel
    models on another grid are compared at the vertices both surfaces share;
  - ``energy_error``: ``max_t |E(t) - E_ref(t)| / max_t |E_ref(t)|`` with
    ``E`` the elastic plus kinetic energy.

The reference is known only to within its own **refinement error**
(``reference_error``): the errors of the voxel model one grid coarser (2x the
voxel size) measured against it.  Errors below that floor are kept as
measured but flagged (column ``below_reference``) and, for ranking (the
Pareto front, ``max_error``), count as the floor: no configuration is ranked
as more accurate than the reference can tell.

``reference="finer"`` makes the reference the voxel model on the scene's image
with every voxel split into 2x2x2 (same geometry, half the voxel size), so
the scene's own voxel model becomes the first coarser row.

The configurations and how each one runs (pinned, warmed up, here or on Dask) are in
:mod:`voxflex.sweep_runs`, the table (ranking, CSV, text, plot) in :mod:`voxflex.sweep_table`; this module
validates the sweep, runs it and measures the errors.

Example
-------
>>> import voxflex as vf
>>> from voxflex.sweep import tradeoff
>>> table = tradeoff("examples/cantilever.toml", frames=(5, 10), samples=(100,),
...                  quadratures=("midpoint",), progress=False)       # doctest: +SKIP
>>> print(table.format())                                             # doctest: +SKIP
>>> table.save("sweep/")           # sweep/tradeoff.csv, sweep/tradeoff.png   # doctest: +SKIP
"""

from __future__ import annotations

import dataclasses
import math
import os
import platform
import time
from pathlib import Path

import numpy as np

from .deform.models.kinds import default_kind, node_kind, reference_kind
from .errors import InputError, VoxflexError, check_choice
from .sampling.quadrature import REGION_RULES
from .scene import Scene
from .sweep_runs import Configuration, _run_all, _warm_key
from .sweep_table import COLUMNS, METRICS, TradeoffTable

__all__ = ["tradeoff", "TradeoffTable", "Configuration", "COLUMNS", "REFERENCES"]

REFERENCES = ("scene", "finer")
_TIMES = ("precompute_seconds", "solve_seconds", "total_seconds")


# ---------------------------------------------------------------------------
# the public function
# ---------------------------------------------------------------------------
def tradeoff(scene, *, frames=(5, 10, 20, 40), samples=(100, 400), shape_functions=("natural-neighbour",),
             quadratures=("elaston", "gauss-legendre"), reference: str = "scene", voxel_levels: int = 1,
             max_error: float | None = None, workers: int | None = None, scheduler: str | None = None,
             progress: bool = True) -> TradeoffTable:
    """Measure error against time for a sweep of reduced models on ``scene``.

    Parameters
    ----------
    scene : Scene or path to a scene file
        Its object, materials, fixed regions, loads, solver and probes are
        used as they are; ``[nodes]`` ``parents``, ``distance`` and ``seed``
        apply to every frame configuration.
    frames : sequence of int
        Frame counts to sweep.
    samples : sequence of int
        Sample counts for the ``"midpoint"`` and ``"elaston"`` quadratures
        (``"gauss-legendre"`` uses 2x2x2 points in every voxel).
    shape_functions : sequence of str
        Shape-function kinds (``natural-neighbour``, the default, ``reproducing-kernel``,
        ``eigenmode``, ``sibson``, ``laplace``, ``distance-ratio``, ``shepard``).
    quadratures : sequence of str
        ``"elaston"``, ``"gauss-legendre"`` (the default pair: the frames' default rule beside
        the exact one, so that a figure is never a cancellation of integration against kinematics)
        and ``"midpoint"`` (every material with each).
    reference : {"scene", "finer"}
        The voxel model on the scene's image, or on the image with every voxel
        split into 2x2x2 (about 8x the cost of the scene's own voxel model).
    voxel_levels : int
        How many coarser voxel grids (2x, 4x, ... the reference's voxel size)
        to run beside the reference, at least 1 (the first gives the
        reference's refinement error).
    max_error : float, optional
        Budget on the ranked error (relative, e.g. 0.02): the table's
        ``choice`` is the cheapest row within it, or None.
    workers : int, optional
        Run the configurations on a local Dask cluster of this many worker
        processes (needs ``pip install "voxflex[dask]"``).
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``) instead.
    progress : bool
        A progress bar over the configurations on stderr.

    Returns
    -------
    TradeoffTable

    Raises
    ------
    InputError
        A bad option, a reference that cannot run, Dask missing or unreachable.
    """
    if not isinstance(scene, Scene):
        if isinstance(scene, (str, Path)):
            scene = Scene.from_toml(scene)
        else:
            raise InputError(f"tradeoff needs a Scene or a scene file path, got {type(scene).__name__}")
    from .sampling.quadrature import QUADRATURES
    from .voronoi.families import FRAME_SHAPE_FUNCTIONS

    frames = _positive_ints("frames", frames)
    samples = _positive_ints("samples", samples)
    shape_functions = _names("shape function", shape_functions, FRAME_SHAPE_FUNCTIONS)
    quadratures = _names("quadrature", quadratures, QUADRATURES)
    check_choice("reference", reference, REFERENCES)
    if isinstance(voxel_levels, bool) or not isinstance(voxel_levels, (int, np.integer)) or voxel_levels < 1:
        raise InputError(f"voxel_levels must be an integer >= 1 (coarser voxel grids to run), got {voxel_levels!r}")
    if max_error is not None:
        if isinstance(max_error, bool) or not isinstance(max_error, (int, float)) or not (
                math.isfinite(max_error) and max_error > 0):
            raise InputError(f"max_error must be a positive relative error such as 0.02, got {max_error!r}")
    if workers is not None and scheduler is not None:
        raise InputError("give workers (a local Dask cluster) or scheduler (an existing one), not both")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, (int, np.integer))
                                or workers < 1):
        raise InputError(f"workers must be a positive number of worker processes, got {workers!r}")
    if scheduler is not None and (not isinstance(scheduler, str) or not scheduler.strip()):
        raise InputError(f"scheduler must be a Dask scheduler address such as tcp://host:8786, got {scheduler!r}")
    if scheduler is not None:
        probe_scheduler(scheduler)  # before the reference runs: a wrong address fails in seconds, not after it
    return _tradeoff_impl(scene, frames, samples, shape_functions, quadratures, reference, int(voxel_levels),
                          max_error, workers, scheduler, progress)


def _positive_ints(name, values) -> tuple:
    if isinstance(values, (int, np.integer)) and not isinstance(values, bool):
        values = (values,)
    try:
        out = tuple(values)
    except TypeError:
        raise InputError(f"{name} must be a list of positive integers, got {values!r}") from None
    if not out or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 1 for v in out):
        raise InputError(f"{name} must be a non-empty list of positive integers, e.g. 5,10,20; got {values!r}")
    return tuple(dict.fromkeys(int(v) for v in out))


def _names(name, values, choices) -> tuple:
    if isinstance(values, str):
        values = (values,)
    out = tuple(values)
    if not out:
        raise InputError(f"give at least one {name}; valid: {', '.join(choices)}")
    for v in out:
        check_choice(name, v, choices)
    return tuple(dict.fromkeys(out))


# ---------------------------------------------------------------------------
# implementation
# ---------------------------------------------------------------------------
def _tradeoff_impl(scene, frames, samples, shape_functions, quadratures, reference, voxel_levels, max_error,
                   workers, scheduler, progress) -> TradeoffTable:
    from .build import build_image

    base = build_image(scene)
    ref_level = 1 if reference == "finer" else 0
    _check_levels(base, voxel_levels - ref_level, voxel_levels)
    ref_kind, swept = reference_kind(), default_kind()
    voxel_q = scene.elasticity.quadrature if scene.nodes.kind == ref_kind.name else ref_kind.default_quadrature
    configs = [Configuration(ref_kind.name, role="reference", level=ref_level, quadrature=voxel_q)]
    configs += [Configuration(ref_kind.name, role="refinement", level=ref_level - i, quadrature=voxel_q)
                for i in range(1, voxel_levels + 1)]
    for sf in shape_functions:
        for q in quadratures:
            for n in frames:
                for m in (samples if q in REGION_RULES else (None,)):
                    configs.append(Configuration(swept.name, count=n, shape_function=sf, quadrature=q, samples=m))
    images = {0: base}
    for c in configs:
        if c.level not in images:
            images[c.level] = _image_at_level(base, c.level)
    # the smallest configuration of each kind runs once untimed first (kernels compile or load)
    warm = {}
    for c in sorted(configs, key=lambda c: (c.level, c.count or 0, c.samples or 0)):
        warm.setdefault(_warm_key(c), dataclasses.replace(c, role="warm-up"))
    tasks = [(scene, images[c.level], c, warm[_warm_key(c)], images[warm[_warm_key(c)].level]) for c in configs]
    from ._progress import progress as _bar

    bar = _bar(total=len(tasks), desc="tradeoff", unit="model", delay=0.0) if progress else None
    try:
        runs = _run_all(tasks, workers, scheduler, bar)
    finally:
        if bar is not None:
            bar.close()
    ref_run = runs[0]
    if "error" in ref_run:
        raise VoxflexError(f"the voxel reference did not run: {ref_run['error']}")
    metric = "probe_error" if scene.probes else "surface_error"
    rows, skipped, seen = [], [], {}
    for c, run in zip(configs, runs):
        if "error" in run:
            skipped.append((c.label(), run["error"]))
            continue
        reference = node_kind(c.kind).reference
        if not reference:  # a sampler makes at most one mid-point sample per voxel: requests may coincide
            key = (c.count, c.shape_function, c.quadrature, run["samples"])
            if key in seen:
                skipped.append((c.label(), f"the sampler made {run['samples']} samples, as for {seen[key]} "
                                           "(the same model; shown once)"))
                continue
            seen[key] = f"{c.samples} requested"
        same_image = ref_level == 0 and (not reference or c.level == 0)
        rows.append(_row(c, run, ref_run, same_image=same_image, scene=scene))
    refine = next((r for r in rows if r["role"] == "refinement" and r["voxel_size"] == _level_size(base, ref_level - 1)),
                  None)
    ref_err = {m: (float(refine[m]) if refine is not None else math.nan) for m in METRICS}
    if refine is None:
        skipped.append(("reference refinement error", "the 2x coarser voxel model did not run (see above)"))
    rows[0]["reference_error"] = ref_err[metric]
    table = TradeoffTable(rows=rows, reference_error=ref_err, metric=metric, skipped=skipped,
                          max_error=max_error, machine=_machine(), scene_title=scene.title or "")
    for r in rows:
        flags = []
        if r["role"] == "reduced" or (r["role"] == "refinement" and r is not refine):
            flags = [m.split("_")[0] for m in METRICS
                     if math.isfinite(r[m]) and math.isfinite(ref_err[m]) and r[m] < ref_err[m]]
        r["below_reference"] = ";".join(flags)
    _mark_pareto(table)
    if max_error is not None:
        fits = [r for r in rows if math.isfinite(table.ranked_error(r)) and table.ranked_error(r) <= max_error]
        table.choice = min(fits, key=lambda r: r["total_seconds"]) if fits else None
    return table


def _check_levels(image, merges: int, voxel_levels: int) -> None:
    """InputError when merging 2x2x2 blocks ``merges`` times leaves no material (or less than a voxel along
    an axis) in the image; the message names the largest ``voxel_levels`` that works."""
    from .image.levels import merge_blocks

    out, done = image, 0
    while done < merges:
        labels = np.asarray(out.labels)
        if min(labels.shape) < 2:
            break
        merged = merge_blocks(out)
        if not np.any(np.asarray(merged.labels) > 0):
            break
        out, done = merged, done + 1
    if done == merges:
        return
    shape = " x ".join(map(str, np.asarray(image.labels).shape))
    last = " x ".join(map(str, np.asarray(out.labels).shape))
    allowed = voxel_levels - (merges - done)
    fix = f"use voxel_levels <= {allowed}" if allowed >= 1 else "use a finer voxel size or --reference finer"
    raise InputError(f"voxel_levels = {voxel_levels} asks for grids down to 2^{merges} times coarser than the image "
                     f"({shape} voxels), but {done} halving(s) leave {last} voxels and another leaves no material; "
                     f"{fix}")


def _level_size(image, level) -> float:
    return float(np.max(image.spacing)) * 2.0 ** (-level)


def _image_at_level(image, level: int):
    """The scene's image on grid ``level`` (:func:`voxflex.image.levels.image_at_level`)."""
    from .image.levels import image_at_level

    return image_at_level(image, level)


# -- running --------------------------------------------------------------------
SCHEDULER_WAIT = 5.0
"""Seconds to wait for a Dask scheduler's greeting (it sends its handshake as soon as a client connects)."""


def probe_scheduler(address: str, wait: float = SCHEDULER_WAIT) -> None:
    """InputError unless a Dask scheduler answers at ``address`` within ``wait`` seconds.

    A ``tcp://host:port`` address (or ``host:port``) is probed with a plain socket: a Dask scheduler
    greets every connection with its handshake (msgpack naming ``compression`` and ``pickle-protocol``);
    anything else -- nothing listening, a server that says nothing, a web server -- is refused, where
    the Dask client would wait for a handshake that never comes.  Other schemes (``tls://``, ``ucx://``)
    are left to the client.
    """
    import socket

    scheme, sep, rest = address.strip().partition("://")
    if not sep:
        scheme, rest = "tcp", address.strip()
    if scheme != "tcp":
        return
    host, colon, port = rest.rstrip("/").rpartition(":")
    if not colon or not port.isdigit() or not host:
        raise InputError(f"scheduler address '{address}' must be tcp://HOST:PORT (e.g. tcp://head:8786)")
    host = host.strip("[]")
    try:
        with socket.create_connection((host, int(port)), timeout=wait) as sock:
            sock.settimeout(wait)
            greeting = b""
            deadline = time.monotonic() + wait
            while b"pickle-protocol" not in greeting and time.monotonic() < deadline and len(greeting) < 4096:
                chunk = sock.recv(4096)
                if not chunk:
                    break
                greeting += chunk
    except socket.timeout:
        raise InputError(f"'{address}' accepted the connection but sent no Dask handshake within {wait:g} s: it is "
                         "not a Dask scheduler; check the address and the port") from None
    except OSError as exc:
        raise InputError(f"cannot reach the Dask scheduler at '{address}' ({exc.strerror or exc}); check the address "
                         "and that the scheduler runs") from None
    if b"compression" not in greeting or b"pickle-protocol" not in greeting:
        raise InputError(f"'{address}' answered, but not with a Dask scheduler's handshake: it is not a Dask "
                         "scheduler; check the address and the port")
# -- errors ---------------------------------------------------------------------
def _row(config, run, ref, *, same_image: bool, scene) -> dict:
    probe = _probe_error(run["probes"], ref["probes"])
    surface, of_ref, of_model = _surface_error(run, ref)
    notes = list(run["notes"])
    if same_image and (of_ref < 1.0 or of_model < 1.0):
        notes.append(f"surfaces differ although the image is the reference's: {of_ref:.1%} of its vertices matched")
    elif of_model < 1.0:
        notes.append(f"surface compared at the {of_model:.1%} of this model's vertices on the reference's surface")
    energy = _energy_error(run["energy"], ref["energy"])
    u = np.full(3, math.nan)
    if run["probes"]:
        p = run["probes"][scene.probes[0].name]
        u = p[-1] - p[0]
    is_ref = config.role == "reference"
    kind = node_kind(config.kind)
    return {
        "role": config.role,
        "kind": config.kind,
        "count": run["dofs"] // kind.dofs_per_node if kind.reference else config.count,
        "shape_function": kind.default_shape_function if kind.reference else config.shape_function,
        "quadrature": config.quadrature,
        "samples": run["samples"],
        "voxel_size": run["voxel_size"],
        "dofs": run["dofs"],
        "steps": run["steps"],
        "precompute_seconds": run["precompute_seconds"],
        "solve_seconds": run["solve_seconds"],
        "total_seconds": run["total_seconds"],
        "newton_iterations": run["newton_iterations"],
        "probe_error": 0.0 if is_ref else probe,
        "surface_error": 0.0 if is_ref else surface,
        "energy_error": 0.0 if is_ref else energy,
        "reference_error": math.nan,
        "below_reference": "",
        "pareto": False,
        "probe_ux": float(u[0]),
        "probe_uy": float(u[1]),
        "probe_uz": float(u[2]),
        "note": "; ".join(notes),
    }


def _probe_error(probes, ref_probes) -> float:
    if not ref_probes:
        return math.nan
    worst = 0.0
    for name, ref in ref_probes.items():
        du_ref = ref - ref[0]
        du = probes[name] - probes[name][0]
        scale = np.max(np.linalg.norm(du_ref, axis=1))
        worst = max(worst, float(np.max(np.linalg.norm(du - du_ref, axis=1)) / scale) if scale > 0 else math.nan)
    return worst


def _surface_error(run, ref) -> tuple[float, float, float]:
    """RMS surface displacement error over the shared vertices / max reference surface displacement; and the
    fractions of the reference's and of the model's vertices compared."""
    from scipy.spatial import cKDTree

    Vr, Xr = ref["surface_rest"], ref["surface_positions"]
    Vm, Xm = run["surface_rest"], run["surface_positions"]
    tol = 1e-6 * min(ref["voxel_size"], run["voxel_size"])
    if Vm.shape == Vr.shape and np.max(np.abs(Vm - Vr), initial=0.0) <= tol:
        im = ir = np.arange(len(Vr))
    else:
        d, idx = cKDTree(Vr).query(Vm, distance_upper_bound=tol)
        im = np.flatnonzero(np.isfinite(d))
        ir = idx[im]
    if len(ir) == 0:
        return math.nan, 0.0, 0.0
    ur = Xr - Vr[None]
    scale = float(np.max(np.linalg.norm(ur, axis=2)))
    diff = (Xm[:, im] - Vm[None, im]) - ur[:, ir]
    rms = np.sqrt(np.mean(np.sum(diff ** 2, axis=2), axis=1))
    return (float(np.max(rms)) / scale if scale > 0 else math.nan), len(np.unique(ir)) / len(Vr), len(im) / len(Vm)


def _energy_error(energy, ref_energy) -> float:
    scale = float(np.max(np.abs(ref_energy)))
    return float(np.max(np.abs(energy - ref_energy))) / scale if scale > 0 else math.nan


def _mark_pareto(table: TradeoffTable) -> None:
    """Pareto front over (total time, ranked error): no other row is both faster and more accurate."""
    pts = [(r["total_seconds"], table.ranked_error(r), i) for i, r in enumerate(table.rows)
           if math.isfinite(table.ranked_error(r))]
    best = math.inf
    for t, e, i in sorted(pts):
        if e < best:
            table.rows[i]["pareto"] = True
            best = e


def _machine() -> str:
    return (f"{platform.machine()} {platform.system()} {platform.release()}, {os.cpu_count()} CPUs, "
            f"{platform.processor() or platform.python_implementation()}, Python {platform.python_version()}; "
            "timings on one thread (BLAS, OpenMP, numba pinned)")
