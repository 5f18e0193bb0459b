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

import contextlib
import csv
import dataclasses
import io
import math
import os
import platform
import statistics
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .deform.models.kinds import default_kind, node_kind, reference_kind
from .errors import ConvergenceError, InputError, VoxflexError, check_choice
from .sampling.quadrature import REGION_RULES
from .scene import OutputSpec, Scene

__all__ = ["tradeoff", "TradeoffTable", "Configuration", "COLUMNS", "REFERENCES"]

REFERENCES = ("scene", "finer")
METRICS = ("probe_error", "surface_error", "energy_error")

COLUMNS = (
    "role", "kind", "count", "shape_function", "quadrature", "samples", "voxel_size", "dofs", "steps",
    "precompute_seconds", "solve_seconds", "total_seconds", "newton_iterations",
    "probe_error", "surface_error", "energy_error", "reference_error", "below_reference", "pareto",
    "probe_ux", "probe_uy", "probe_uz", "note",
)
"""Columns of ``tradeoff.csv`` (documented in docs/tradeoff.md, see :class:`TradeoffTable`)."""

_TIMES = ("precompute_seconds", "solve_seconds", "total_seconds")
_SHORT_RUN = 1.0  # seconds: shorter runs are timed 3 times and the median reported


# ---------------------------------------------------------------------------
# configurations
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Configuration:
    """One model of the sweep.

    ``kind`` names a :class:`~voxflex.deform.models.kinds.NodeKind`: the reference kind (the voxel
    model on the image of grid ``level``: 0 the scene's image, 1 every voxel split in 2x2x2, -1 / -2
    ... 2x / 4x coarser) or a reduced kind (frames on the scene's image).
    """

    kind: str
    role: str = "reduced"  # "reference", "refinement" (coarser voxel grids) or "reduced"
    level: int = 0
    count: int | None = None
    shape_function: str | None = None
    quadrature: str = "gauss-legendre"
    samples: int | None = None

    def label(self) -> str:
        kind = node_kind(self.kind)
        if kind.reference:
            return f"{kind.name} level {self.level:+d}"
        extra = f" {self.samples} samples" if self.samples is not None else ""
        return f"{self.count} frames {self.shape_function} {self.quadrature}{extra}"

    def scene(self, scene: Scene) -> Scene:
        """``scene`` set up for this configuration (no output file: a sweep writes no result)."""
        nodes, elasticity = scene.nodes, scene.elasticity
        if node_kind(self.kind).reference:
            nodes = dataclasses.replace(nodes, kind=self.kind, shape_function=None, count=None, positions=None)
            elasticity = dataclasses.replace(elasticity, quadrature=self.quadrature, samples=None)
        else:
            nodes = dataclasses.replace(nodes, kind=self.kind, count=self.count, shape_function=self.shape_function)
            samples = self.samples if self.samples is not None else elasticity.samples
            elasticity = dataclasses.replace(elasticity, quadrature=self.quadrature,  # no region count for points
                                             samples=samples if self.quadrature in REGION_RULES else None)
        return dataclasses.replace(scene, nodes=nodes, elasticity=elasticity, output=OutputSpec())


# ---------------------------------------------------------------------------
# the table
# ---------------------------------------------------------------------------
@dataclass
class TradeoffTable:
    """The measured sweep: one row (a dict keyed by :data:`COLUMNS`) per configuration.

    Attributes
    ----------
    rows : list of dict
        Reference first, then the coarser voxel grids, then the reduced
        configurations in sweep order.  Times in seconds, errors relative
        (dimensionless, NaN where not measurable).
    reference_error : dict
        The reference's refinement error per metric (``probe_error``,
        ``surface_error``, ``energy_error``): the floor below which errors are
        flagged.
    metric : str
        The error the ranking uses: ``probe_error`` when the scene has probes,
        else ``surface_error``.
    skipped : list of (str, str)
        Configurations that could not run and why (e.g. samples that leave
        a soft mode, a solver that did not converge).
    choice : dict or None
        With ``max_error``: the cheapest row (least ``total_seconds``) whose
        ranked error is within the budget, or None.
    max_error : float or None
    machine : str
        Platform, CPU count and thread pinning of the timings.
    scene_title : str
    """

    rows: list
    reference_error: dict
    metric: str
    skipped: list = field(default_factory=list)
    choice: dict | None = None
    max_error: float | None = None
    machine: str = ""
    scene_title: str = ""

    # -- ranking -------------------------------------------------------------------
    def ranked_error(self, row: dict, metric: str | None = None) -> float:
        """The row's error as the ranking sees it: never below the reference's refinement error."""
        metric = metric or self.metric
        if row["role"] == "reference":
            return float(self.reference_error.get(metric, math.nan))
        value, floor = float(row[metric]), float(self.reference_error.get(metric, math.nan))
        return max(value, floor) if math.isfinite(floor) else value

    def pareto_rows(self) -> list:
        return [r for r in self.rows if r["pareto"]]

    # -- output --------------------------------------------------------------------
    @classmethod
    def read_csv(cls, path) -> "TradeoffTable":
        """A table back from its ``tradeoff.csv`` (to replot or re-rank it); ``skipped`` and ``machine``
        are not in the CSV and come back empty."""
        path = Path(path)
        try:
            with open(path, newline="", encoding="utf-8") as fh:
                raw = list(csv.DictReader(fh))
        except (OSError, UnicodeDecodeError) as exc:
            raise InputError(f"cannot read '{path}': {exc}") from None
        if not raw or list(raw[0]) != list(COLUMNS) or raw[0]["role"] != "reference":
            raise InputError(f"'{path}' is not a tradeoff.csv written by voxflex tradeoff (columns or first row)")
        ints = {"count", "samples", "dofs", "steps", "newton_iterations"}
        text = {"role", "kind", "shape_function", "quadrature", "below_reference", "note"}
        rows = []
        for r in raw:
            row = {}
            for k, v in r.items():
                if k in text:
                    row[k] = v
                elif k == "pareto":
                    row[k] = v == "true"
                elif k in ints:
                    row[k] = int(v)
                else:
                    row[k] = float(v) if v != "" else math.nan
            rows.append(row)
        refine = next((r for r in rows if r["role"] == "refinement"), None)
        ref_err = {m: (refine[m] if refine is not None else math.nan) for m in METRICS}
        metric = "probe_error" if math.isfinite(rows[0]["probe_ux"]) else "surface_error"
        return cls(rows=rows, reference_error=ref_err, metric=metric)

    def to_csv(self, path) -> Path:
        """Write ``path`` (CSV, the :data:`COLUMNS`), atomically."""
        from ._atomic import atomic_path

        path = Path(path)
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=list(COLUMNS), lineterminator="\n")
        writer.writeheader()
        for row in self.rows:
            writer.writerow({k: _csv_value(row[k]) for k in COLUMNS})
        with atomic_path(path) as tmp:
            tmp.write_text(buf.getvalue(), encoding="utf-8")
        return path

    def plot(self, path) -> Path:
        """Error against total time, log-log: every configuration, the Pareto front, the reference and the band
        below its refinement error (where errors cannot be told apart)."""
        return _plot(self, Path(path))

    def save(self, folder) -> tuple[Path, Path]:
        """Write ``folder/tradeoff.csv`` and ``folder/tradeoff.png`` (the folder is created if missing)."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        return self.to_csv(folder / "tradeoff.csv"), self.plot(folder / "tradeoff.png")

    def format(self) -> str:
        """The table as fixed-width text (what ``voxflex tradeoff`` prints)."""
        head = ["", "model", "DOF", "pre s", "solve s", "total s", "Newton", "probe", "surface", "energy"]
        lines = []
        body = []
        for r in self.rows:
            flags = set(filter(None, str(r["below_reference"]).split(";")))
            mark = "*" if r["pareto"] else " "
            if r["role"] == "reference":
                name = f"reference voxel h={r['voxel_size']:.4g}"
            elif node_kind(r["kind"]).reference:
                name = f"{r['kind']} h={r['voxel_size']:.4g}"
            else:
                name = (f"{r['count']} {r['shape_function']} {r['quadrature']}"
                        + (f" {r['samples']}" if r["quadrature"] != "gauss-legendre" else " (per voxel)"))
            errs = [_fmt_err(r[m], m.split("_")[0] in flags) for m in METRICS]
            body.append([mark, name, str(r["dofs"]), _fmt_time(r["precompute_seconds"]),
                         _fmt_time(r["solve_seconds"]), _fmt_time(r["total_seconds"]),
                         str(r["newton_iterations"]), *errs])
        widths = [max(len(x[i]) for x in [head] + body) for i in range(len(head))]
        fmt = lambda cells: "  ".join(c.ljust(w) if i < 2 else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths)))  # noqa: E731
        lines.append(fmt(head))
        lines.append("  ".join("-" * w for w in widths))
        lines += [fmt(b) for b in body]
        ref = self.reference_error
        lines.append("")
        lines.append("reference refinement error (2x coarser grid against the reference): "
                     + ", ".join(f"{m.split('_')[0]} {_fmt_err(ref.get(m, math.nan), False)}" for m in METRICS))
        lines.append("* Pareto front (by total time and " + self.metric.replace("_", " ") + "); '<' errors below "
                     "the reference's refinement error (ranked as that error)")
        for what, why in self.skipped:
            lines.append(f"skipped {what}: {why}")
        if self.max_error is not None:
            if self.choice is None:
                lines.append(f"no configuration has {self.metric.replace('_', ' ')} <= {self.max_error:g}")
            else:
                lines.append(f"cheapest within {self.metric.replace('_', ' ')} <= {self.max_error:g}: "
                             + _describe_row(self.choice))
        lines.append(f"machine: {self.machine}")
        return "\n".join(lines)


def _describe_row(r: dict) -> str:
    kind = node_kind(r["kind"])
    if kind.reference:
        what = f"{kind.name} model h={r['voxel_size']:.4g} ({r['dofs']} DOF)"
    else:
        what = (f"{kind.count(r['count'])}, {r['shape_function']}, {r['quadrature']}"
                + (f", {r['samples']} samples" if r["quadrature"] != "gauss-legendre" else "")
                + f" ({r['dofs']} DOF)")
    return f"{what}: {r['total_seconds']:.3g} s, {r['probe_error']:.3g} probe error"


def _csv_value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if v is None:
        return ""
    if isinstance(v, float):
        return "" if math.isnan(v) else repr(v)
    return v


def _fmt_time(t) -> str:
    return f"{t:.3g}" if math.isfinite(t) else "-"


def _fmt_err(e, below) -> str:
    if not math.isfinite(e):
        return "-"
    return ("<" if below else "") + (f"{e:.2%}" if e >= 1e-4 else f"{e:.1e}")


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


def _warm_key(c: Configuration):
    return (c.kind, c.quadrature, c.shape_function)


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
def _run_all(tasks, workers, scheduler, bar) -> list:
    if workers is None and scheduler is None:
        out = []
        for task in tasks:
            out.append(_task(*task))
            if bar is not None:
                bar.update(1)
        return out
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise InputError('distributed sweeps need Dask: pip install "voxflex[dask]" (or dask[distributed]); '
                         "or run without workers/scheduler") from None
    with contextlib.ExitStack() as stack:
        if scheduler is not None:
            try:
                client = stack.enter_context(Client(scheduler, timeout=10))
            except (OSError, TimeoutError, ValueError) as exc:
                raise InputError(f"cannot reach the Dask scheduler at '{scheduler}' ({exc}); check the address "
                                 "and that the scheduler runs") from None
        else:
            # dashboard on a free port (None means the default 8787 here, and a warning when it is taken)
            cluster = stack.enter_context(LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True,
                                                       dashboard_address=":0"))
            client = stack.enter_context(Client(cluster))
        futures = [client.submit(_task, *task, pure=False) for task in tasks]
        for _ in as_completed(futures):
            if bar is not None:
                bar.update(1)
        return client.gather(futures)


_WARMED: set = set()  # warm-up keys already run in this process (one per worker process under Dask)


@contextlib.contextmanager
def _pinned():
    """BLAS and OpenMP at one thread, numba at one thread: timings of one core, results independent of threads."""
    import numba
    from threadpoolctl import threadpool_limits

    before = numba.get_num_threads()
    with threadpool_limits(limits=1):
        numba.set_num_threads(1)
        try:
            yield
        finally:
            numba.set_num_threads(before)


def _task(scene, image, config, warm, warm_image) -> dict:
    """Run one configuration (after its warm-up, once per process): raw measurements, or ``{"error": why}``."""
    key = (_warm_key(warm), warm.level, warm.count, warm.samples)
    if key not in _WARMED:
        _WARMED.add(key)
        try:
            _measure(scene, warm_image, warm, repeat=False)  # untimed
        except Exception:  # noqa: BLE001 - a failure shows in the configuration's own run
            pass
    return _measure(scene, image, config, repeat=True)


def _measure(scene, image, config, *, repeat: bool) -> dict:
    from .build import model as build_model
    from .simulation import simulate

    s = config.scene(scene)
    with warnings.catch_warnings(record=True) as caught, _pinned():
        warnings.simplefilter("always")
        try:
            pre, solve = [], []
            first = None
            while True:
                t0 = time.perf_counter()
                # never from the on-disk precompute cache: the column is what building the model costs (the
                # repeats, and a sweep run before, would otherwise time a cache load: 5 ms for 0.3 s)
                m = build_model(s, image=image, cache=False)
                t1 = time.perf_counter()
                result = simulate(s, model=m, progress=False)
                t2 = time.perf_counter()
                pre.append(t1 - t0)
                solve.append(t2 - t1)
                if first is None:
                    first = (m, result)
                if not repeat or len(pre) >= 3 or (len(pre) == 1 and pre[0] + solve[0] >= _SHORT_RUN):
                    break
        except (InputError, ConvergenceError, NotImplementedError) as exc:
            return {"error": str(exc).splitlines()[0]}
        except Exception as exc:  # noqa: BLE001 - one broken configuration must not lose the sweep
            if config.role == "reference":
                raise
            return {"error": f"failed with {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''} "
                             "(an error in voxflex, please report it)"}
    m, result = first
    notes = list(dict.fromkeys(str(w.message).splitlines()[0] for w in caught))
    describe = m.describe()
    steps = max(len(result.time) - 1, 1)
    dynamic = scene.solver.kind == "implicit-euler"
    solve_s = statistics.median(solve)
    return {
        "dofs": int(describe.get("dofs", np.asarray(m.rest).size)),
        "samples": int(describe.get("samples", 0)),
        "voxel_size": float(np.max(image.spacing)),
        "precompute_seconds": statistics.median(pre),
        "solve_seconds": solve_s / steps if dynamic else solve_s,
        "total_seconds": statistics.median(pre) + solve_s,
        "steps": steps,
        "newton_iterations": int(np.sum(result.newton_iterations)),
        "probes": {k: np.asarray(v) for k, v in result.probes.items()},
        "surface_rest": np.asarray(result.surface_rest),
        "surface_positions": np.asarray(result.surface_positions),
        "energy": np.asarray(result.energy_elastic) + np.asarray(result.energy_kinetic),
        "notes": notes,
    }


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


# -- plot -----------------------------------------------------------------------
def _plot(table: TradeoffTable, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    from ._atomic import atomic_path

    metric = table.metric
    floor = table.reference_error.get(metric, math.nan)
    fig, ax = plt.subplots(figsize=(7.5, 5.0), dpi=110)
    groups = {}
    for r in table.rows:
        if r["role"] == "reference":
            continue
        key = (f"{r['kind']} model (coarser grids)" if node_kind(r["kind"]).reference
               else f"{r['shape_function']}, {r['quadrature']}")
        groups.setdefault(key, []).append(r)
    markers = iter("so^vD<>phX*")
    errs = [table.ranked_error(r) for r in table.rows if math.isfinite(table.ranked_error(r))]
    cands = [e for e in errs if e > 0] + [r[metric] for r in table.rows if r[metric] > 0]
    lo = (min(cands) if cands else 1e-3) / 3
    for key, rows in groups.items():
        t = np.array([r["total_seconds"] for r in rows])
        e = np.array([r[metric] for r in rows], dtype=float)
        ok = np.isfinite(e) & (e > 0)
        ax.scatter(t[ok], e[ok], marker=next(markers, "o"), s=36, label=key, zorder=3)
        for r in rows:
            if not node_kind(r["kind"]).reference and math.isfinite(r[metric]) and r[metric] > 0:
                ax.annotate(str(r["count"]), (r["total_seconds"], r[metric]), textcoords="offset points",
                            xytext=(4, 3), fontsize=7, color="0.3")
    ref = table.rows[0]
    if math.isfinite(floor) and floor > 0:
        ax.axhspan(lo, floor, color="0.85", zorder=0, label="below the reference's refinement error")
        ax.errorbar([ref["total_seconds"]], [floor], fmt="*", ms=14, color="k", zorder=4,
                    label=f"reference ({ref['dofs']} DOF), at its refinement error {floor:.2%}")
    else:
        ax.axvline(ref["total_seconds"], color="k", ls=":", label="reference (refinement error unknown)")
    front = sorted(table.pareto_rows(), key=lambda r: r["total_seconds"])
    if front:
        ft = [r["total_seconds"] for r in front]
        fe = [table.ranked_error(r) for r in front]
        ax.step(ft, fe, where="post", color="C3", lw=1.2, zorder=2)
        ax.scatter(ft, fe, s=110, facecolors="none", edgecolors="C3", lw=1.4, zorder=5, label="Pareto front")
    if table.max_error is not None:
        ax.axhline(table.max_error, color="C2", ls="--", lw=1, label=f"budget {table.max_error:g}")
    ax.set_xscale("log")
    ax.set_yscale("log")
    times = [r["total_seconds"] for r in table.rows if r["total_seconds"] > 0]
    if times and max(times) / min(times) > 10:  # labelled decades suffice; minor labels would overlap
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set_ylim(bottom=lo)
    ax.set_xlabel("precompute + solve time (s, one thread)")
    ax.set_ylabel(metric.replace("_", " ") + " (relative to the reference)")
    ax.set_title(table.scene_title or "speed against accuracy", fontsize=10)
    ax.grid(True, which="both", lw=0.3, alpha=0.6)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    with atomic_path(path) as tmp:
        tmp.write_bytes(buf.getvalue())
    return path
