"""The table of a trade-off sweep: its rows, their ranking, and the table written out.

:class:`TradeoffTable` holds one row (a dict keyed by :data:`COLUMNS`) per configuration that
:func:`voxflex.sweep.tradeoff` measured; it ranks the rows (never below the reference's refinement error),
reads and writes ``tradeoff.csv``, formats the fixed-width text that ``voxflex tradeoff`` prints and plots
error against time (``tradeoff.png``).  The columns are documented in docs/tradeoff.md.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .deform.models.kinds import node_kind
from .errors import InputError

METRICS = ("probe_error", "surface_error", "energy_error")

COLUMNS = (
    "role", "kind", "count", "shape_function", "quadrature", "samples", "voxel_size", "dofs", "steps",
    "precompute_seconds", "solve_seconds", "total_seconds", "newton_iterations",
    "probe_error", "surface_error", "energy_error", "reference_error", "below_reference", "pareto",
    "probe_ux", "probe_uy", "probe_uz", "note",
)
"""Columns of ``tradeoff.csv`` (documented in docs/tradeoff.md, see :class:`TradeoffTable`)."""


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