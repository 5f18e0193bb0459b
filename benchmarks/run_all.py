"""Run every stage benchmark and write one Markdown report with tables, plots and the machine.

Stages: every ``bench_*.py`` script in this folder (voxelize, Voronoi, sampling,
strains, materials, mappings, the frame model against its flop bound and
against the voxel model, the voxel model against scikit-fem and warp.fem,
locking, resources, contact, and any script added later), in pipeline order,
each in a fresh process so that one's compiled kernels and memory do not
colour the next; then a ``voxflex tradeoff`` sweep of the neo-Hooke
cantilever (16x4x4 voxels, about a minute) for the error-against-time plot.

    python benchmarks/run_all.py [-o benchmark-report] [--quick] [--only voxelize,strains] [--timeout 1800]

``--quick`` passes each script its small-problem options (minutes in all on 2
cores, for checking that the report builds; the figures are then not the
published ones).  The report is ``DIR/report.md`` with ``DIR/stage_times.png``
and ``DIR/tradeoff.png``; each stage's full output (stdout, then stderr) is
in ``DIR/logs/``.  A stage that fails or runs out of time is reported as such
and the others still run.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

# Every benchmarks/bench_*.py is a stage: the order below follows the pipeline, scripts not listed
# run after them in name order.  Options for --quick (small problems) per script; none otherwise.
ORDER = ["voxelize", "voronoi", "sampling", "strains", "materials", "mappings", "frames", "frames_accuracy",
         "voxel_model", "locking", "resources", "contact"]
QUICK = {
    "voxelize": ["--sizes", "64"],
    "voronoi": ["--sizes", "32", "--frames", "10,50"],
    "sampling": ["--sizes", "32", "--counts", "200,1000"],
    "strains": ["--n", "20000"],
    "materials": ["--n", "20000"],
    "mappings": ["--m", "20000", "--nodes", "500", "--repeat", "3"],
    "frames": ["--counts", "10,50", "--repeat", "3"],
    "frames_accuracy": ["--part", "2", "--counts", "5,10"],
    "voxel_model": ["--quick", "--no-series", "--repeat", "1"],
    "locking": ["--quick"],
    "resources": ["--quick"],
    "contact": ["--quick"],
    "robust_newton": ["--contrasts", "1e2,1e3", "--repeat", "1"],
    "weights_convergence": ["--part", "bending", "--counts", "10,20", "--repeat", "1"],
    "precompute": ["--repeat", "1", "--kinds", "natural-neighbour"],
}


def stages() -> list[tuple[str, str, list[str], str]]:
    """(name, script, quick options, first docstring line) of every stage benchmark here."""
    import ast

    found = {p.stem[len("bench_"):]: p for p in HERE.glob("bench_*.py")}
    names = [n for n in ORDER if n in found] + sorted(set(found) - set(ORDER))
    out = []
    for name in names:
        try:
            doc = ast.get_docstring(ast.parse(found[name].read_text(encoding="utf-8"))) or ""
        except (OSError, SyntaxError):
            doc = ""
        out.append((name, found[name].name, QUICK.get(name, []), doc.strip().split("\n")[0]))
    return out


def machine() -> list[tuple[str, str]]:
    """(item, value) rows describing this machine and the software."""
    rows = [
        ("platform", platform.platform()),
        ("processor", _cpu_model()),
        ("CPUs (os.cpu_count)", str(os.cpu_count())),
        ("memory", _memory()),
        ("Python", f"{platform.python_implementation()} {platform.python_version()}"),
    ]
    for name in ("numpy", "scipy", "numba", "voxflex"):
        try:
            module = __import__(name)
            rows.append((name, getattr(module, "__version__", "?")))
        except ImportError:
            rows.append((name, "not installed"))
    try:
        from threadpoolctl import threadpool_info

        blas = [f"{i.get('internal_api')} {i.get('version')} ({i.get('num_threads')} threads)" for i in threadpool_info()
                if i.get("user_api") == "blas"]
        rows.append(("BLAS", ", ".join(blas) or "unknown"))
    except ImportError:
        pass
    rows.append(("load average at start (1, 5, 15 min)", ", ".join(f"{x:.2f}" for x in os.getloadavg())))
    return rows


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _memory() -> str:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                return f"{int(line.split()[1]) / 2**20:.1f} GiB"
    except OSError:
        pass
    return "unknown"


def run_stage(script: str, options: list[str], logs: Path, name: str, timeout: float) -> dict:
    """Run one benchmark script; return its status, wall time and output."""
    cmd = [sys.executable, str(HERE / script), *options]
    env = dict(os.environ, VOXFLEX_PROGRESS="0", PYVISTA_OFF_SCREEN="true")
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout)
        status = "ok" if proc.returncode == 0 else f"failed (exit {proc.returncode})"
        out, err = proc.stdout, proc.stderr
    except subprocess.TimeoutExpired as exc:
        status = f"timed out after {timeout:g} s"
        out = exc.stdout.decode() if isinstance(exc.stdout, bytes) else (exc.stdout or "")
        err = exc.stderr.decode() if isinstance(exc.stderr, bytes) else (exc.stderr or "")
    wall = time.perf_counter() - t0
    log = logs / f"{name.replace(' ', '_')}.log"
    log.write_text(f"$ {' '.join(cmd)}\n\n{out}\n--- stderr ---\n{err}", encoding="utf-8")
    return {"status": status, "wall": wall, "stdout": out, "stderr": err, "command": " ".join(
        ["python", f"benchmarks/{script}", *options]), "log": log}


def run_tradeoff(folder: Path, quick: bool) -> dict:
    """A tradeoff sweep for the plot: the neo-Hooke cantilever of docs/tradeoff.md on 16x4x4 voxels (about a
    minute), or with --quick the linear cantilever of examples/ on 8x2x2 (seconds)."""
    if quick:
        scene, options = "examples/cantilever.toml", ["--frames", "5,8", "--samples", "32",
                                                       "--quadratures", "midpoint,elaston"]
    else:
        scene, options = "docs/tradeoff/cantilever_16x4x4.toml", ["--frames", "10,20,40", "--samples", "100,200",
                                                                   "--quadratures", "midpoint,gauss-legendre"]
    cmd = [sys.executable, "-m", "voxflex", "tradeoff", str(ROOT / scene), "-o", str(folder / "tradeoff_sweep"),
           *options, "--force"]
    env = dict(os.environ, VOXFLEX_PROGRESS="0")
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    png = folder / "tradeoff_sweep" / "tradeoff.png"
    if proc.returncode == 0 and png.exists():
        (folder / "tradeoff.png").write_bytes(png.read_bytes())
    return {"status": "ok" if proc.returncode == 0 else f"failed (exit {proc.returncode})", "wall": wall,
            "stdout": proc.stdout, "stderr": proc.stderr,
            "command": " ".join(["voxflex tradeoff", scene, *options])}


def plot_stage_times(results: dict, path: Path) -> bool:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    names = list(results)
    walls = [results[n]["wall"] for n in names]
    colors = ["C0" if results[n]["status"] == "ok" else "C3" for n in names]
    fig, ax = plt.subplots(figsize=(7, 0.45 * len(names) + 1.2), dpi=110)
    ax.barh(names[::-1], walls[::-1], color=colors[::-1])
    ax.set_xlabel("wall time of the whole benchmark script (s; red: failed or timed out)")
    ax.set_title("benchmark scripts", fontsize=10)
    ax.grid(True, axis="x", lw=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return True


def report(results: dict, trade: dict | None, machine_rows, folder: Path, quick: bool, started: str) -> str:
    lines = [
        "# voxflex benchmark report",
        "",
        f"Generated by `python benchmarks/run_all.py{' --quick' if quick else ''}` on {started}"
        + (" with the scripts' small-problem options (not the published figures)." if quick else "."),
        "",
        "## Machine",
        "",
        "| item | value |",
        "|---|---|",
        *[f"| {k} | {v} |" for k, v in machine_rows],
        f"| load average at end (1, 5, 15 min) | {', '.join(f'{x:.2f}' for x in os.getloadavg())} |",
        "",
        "Other work on the machine slows the timings; the load averages above say how busy it was.",
        "",
        "## Summary",
        "",
        "| stage | what | command | status | wall s |",
        "|---|---|---|---|---|",
    ]
    what = {name: text for name, _, _, text in stages()}
    for name, r in results.items():
        lines.append(f"| {name} | {what.get(name, '')} | `{r['command']}` | {r['status']} | {r['wall']:.1f} |")
    if trade is not None:
        lines.append(f"| tradeoff | error against time of reduced models | `{trade['command']}` | {trade['status']} | "
                     f"{trade['wall']:.1f} |")
    lines.append("")
    if (folder / "stage_times.png").exists():
        lines += ["![wall time per benchmark script](stage_times.png)", ""]
    for name, r in results.items():
        lines += [f"## {name}", "", f"`{r['command']}` — {r['status']}, {r['wall']:.1f} s "
                  f"(full output: `logs/{r['log'].name}`)", "", "```", r["stdout"].rstrip() or "(no output)", "```", ""]
        if r["status"] != "ok":
            tail = "\n".join(r["stderr"].rstrip().splitlines()[-15:])
            lines += ["stderr (last lines):", "", "```", tail, "```", ""]
    if trade is not None:
        lines += ["## Speed against accuracy (tradeoff)", "", f"`{trade['command']}` — {trade['status']}", "",
                  "```", trade["stdout"].rstrip(), "```", ""]
        if (folder / "tradeoff.png").exists():
            lines += ["![error against time](tradeoff.png)", ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-o", "--output", default="benchmark-report", help="report folder (default: benchmark-report)")
    ap.add_argument("--quick", action="store_true", help="small problems: check that the report builds")
    ap.add_argument("--only", default="", help="comma-separated stage names (default: all, and the tradeoff sweep)")
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds per stage (default 1800)")
    args = ap.parse_args(argv)
    folder = Path(args.output)
    logs = folder / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    only = {s.strip() for s in args.only.split(",") if s.strip()}
    unknown = only - {name for name, *_ in stages()} - {"tradeoff"}
    if unknown:
        ap.error(f"unknown stage(s) {', '.join(sorted(unknown))}; valid: "
                 f"{', '.join(name for name, *_ in stages())}, tradeoff")
    started = datetime.datetime.now().strftime("%Y-%m-%d %H:%M")
    machine_rows = machine()
    results = {}
    for name, script, quick, _ in stages():
        if only and name not in only:
            continue
        print(f"[run_all] {name}: {script} ...", file=sys.stderr, flush=True)
        results[name] = run_stage(script, quick if args.quick else [], logs, name, args.timeout)
        print(f"[run_all] {name}: {results[name]['status']} in {results[name]['wall']:.1f} s", file=sys.stderr)
    trade = None
    if not only or "tradeoff" in only:
        print("[run_all] tradeoff sweep ...", file=sys.stderr, flush=True)
        trade = run_tradeoff(folder, args.quick)
    if results:
        plot_stage_times(results, folder / "stage_times.png")
    text = report(results, trade, machine_rows, folder, args.quick, started)
    (folder / "report.md").write_text(text, encoding="utf-8")
    print(f"wrote {folder / 'report.md'}")
    failed = [n for n, r in results.items() if r["status"] != "ok"] + ([] if trade is None or trade["status"] == "ok"
                                                                      else ["tradeoff"])
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
