"""End-to-end time of the bundled default scene: ``voxflex simulate --quiet``, warm.

What a user waits for when typing ``voxflex simulate --quiet``: interpreter
start, imports, loading the cached numba kernels, voxelizing the mesh, the
frame model's precompute (from the on-disk cache), the static solve and
writing ``result.h5``.  Each version of the package (``--after``, default this
checkout; ``--before``, default ``/work/main`` when it exists, only read) runs
in fresh subprocesses, the two interleaved run by run so that they share the
machine's noise, after one untimed warm-up run each (which fills the numba,
bytecode and precompute caches).  Nothing is written into either tree: numba's
cache goes to ``--cache-dir`` (``NUMBA_CACHE_DIR``) and the result files to a
temporary folder.

Two measures, min and median of ``--repeat`` (>= 5) runs each:

* **end to end**: wall-clock time of ``python -m voxflex simulate --quiet -o
  FILE`` measured around the subprocess;
* **split**: the same run through a small driver (``--driver``) that counts,
  inside the process, the time spent in imports (outermost imports only,
  including the ones numba makes when it loads its first kernel), in numba's
  loading of cached kernels (less the imports inside it) and in the rest (the
  computation, voxelizing to writing the file); "start + exit" is the rest of
  the wall-clock time: interpreter start-up and ``site``, and the end of the
  process (the interpreter's teardown, or the program's quick exit).

Two bytecode settings: ``--bytecode env`` (default) runs with this process's
environment; where ``PYTHONDONTWRITEBYTECODE`` is set (as on the project's
shared machine) voxflex's own sources, which no installer compiled, are
compiled again by every run (~0.3 s for the ~20k lines the default scene
imports).  ``--bytecode cached`` unsets it and points ``PYTHONPYCACHEPREFIX``
into ``--cache-dir``: every module's bytecode is cached, as after a normal
install.  ``--bytecode both`` runs the two.

A last row, "floor", times a process that only imports the third-party
modules the run needs (numpy, scipy's sparse, linalg and ndimage, numba, h5py,
threadpoolctl) and calls one cached numba kernel: what the run pays before any
of voxflex's own code, the limit of what import work in voxflex can reach.

The answer must not change: the final node states of the two versions'
result files are compared bitwise (printed as "same answer").

    python benchmarks/bench_startup.py [--repeat 5] [--before merge-base|REV|FOLDER] [--bytecode both]

Measured on the shared 2-core x86_64 Xeon with other engineers' work running
(load average 1.8-2.4 throughout), 9 runs, seconds (min / median); before =
6b879e1 (where the start-up work left main), after = the start-up branch
(binary STL without pyvista, the program's quick exit):

| bytecode | version | end to end | start + exit | imports | numba kernel loads | compute |
|---|---|---|---|---|---|---|
| env (none cached) | before | 1.78 / 2.34 | 0.31 / 0.35 | 1.41 / 1.51 | 0.13 / 0.14 | 0.38 / 0.42 |
| env (none cached) | after | 1.43 / 1.62 | 0.05 / 0.06 | 0.95 / 1.13 | 0.11 / 0.12 | 0.35 / 0.39 |
| env (none cached) | floor | 1.01 / 1.22 | | | | |
| cached | before | 1.87 / 2.20 | 0.27 / 0.37 | 1.10 / 1.22 | 0.11 / 0.13 | 0.35 / 0.46 |
| cached | after | 1.29 / 1.47 | 0.05 / 0.06 | 0.85 / 0.93 | 0.11 / 0.12 | 0.33 / 0.36 |
| cached | floor | 0.99 / 1.09 | | | | |

An earlier run at load average 3.1-4.1, before the quick exit, read 2.27 / 2.86
(before) against 1.84 / 2.19 s (after) end to end.  The same answer (bitwise)
in both settings.  What is left above the floor is voxflex's own modules (~67
of them, ~21k lines, compiled again by every run without a bytecode cache)
and the computation; the floor itself is mostly
numba (import and the set-up of its compiler on the first kernel, ~0.6 s
quiet) and scipy (its array-API layer imports numpy.f2py, numpy.testing,
numpy.ma and numpy.random, ~0.2 s; scipy.ndimage decorates its functions at
import, ~0.1 s).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

_DRIVER = r"""
import json, sys, time
t_in = time.perf_counter()
import importlib._bootstrap as _b
acc = {"imports": 0.0, "numba": 0.0, "numba_imports": 0.0}
state = {"depth": 0, "in_numba": False, "patched": False}
_find = _b._find_and_load


def _patch_numba():
    # numba's dispatcher is wrapped as soon as it is imported (by voxflex, not earlier)
    state["patched"] = True
    d = sys.modules["numba.core.dispatcher"]
    orig = d.Dispatcher._compile_for_args

    def timed(self, *a, **k):
        if state["in_numba"]:
            return orig(self, *a, **k)
        state["in_numba"] = True
        t = time.perf_counter()
        try:
            return orig(self, *a, **k)
        finally:
            acc["numba"] += time.perf_counter() - t
            state["in_numba"] = False

    d.Dispatcher._compile_for_args = timed


def _find_and_load(name, import_):
    outer = state["depth"] == 0
    state["depth"] += 1
    t = time.perf_counter()
    try:
        return _find(name, import_)
    finally:
        state["depth"] -= 1
        if outer:
            dt = time.perf_counter() - t
            acc["imports"] += dt
            if state["in_numba"]:
                acc["numba_imports"] += dt
        if name == "numba.core.dispatcher" and not state["patched"] and name in sys.modules:
            _patch_numba()  # the module has just finished loading


_b._find_and_load = _find_and_load


def _report():
    # run as an atexit handler: after the command, before the process ends (either way it ends)
    inside = time.perf_counter() - t_in
    heavy = sorted({m.split(".")[0] for m in sys.modules} & {"pyvista", "vtkmodules", "vtk", "tqdm", "matplotlib"})
    print(json.dumps({"inside": inside, "imports": acc["imports"], "numba": acc["numba"] - acc["numba_imports"],
                      "heavy_modules": heavy}), flush=True)


import atexit

atexit.register(_report)
import voxflex.cli

sys.argv = ["voxflex", *sys.argv[1:]]
if hasattr(voxflex.cli, "entry"):
    voxflex.cli.entry()  # what `voxflex` and `python -m voxflex` run
else:
    raise SystemExit(voxflex.cli.main())
"""


# The floor under any change to voxflex's own start-up: the third-party modules the default scene's run
# imports (numpy; scipy.sparse, .linalg and .ndimage; numba; h5py; threadpoolctl) and numba's first call
# of one cached kernel (its compiler's set-up), in a fresh process, without voxflex.
_FLOOR = r"""
import numpy, scipy.sparse, scipy.sparse.linalg, scipy.linalg, scipy.ndimage, numba, h5py, threadpoolctl, tomllib


@numba.njit(cache=True)
def one(x):
    return x + 1.0


one(1.0)
"""


def _env(root: Path, bytecode: str, cache_dir: Path) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(root)  # this version's voxflex before the installed (editable) one
    env["NUMBA_CACHE_DIR"] = str(cache_dir / "numba")
    if bytecode == "cached":
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        env["PYTHONPYCACHEPREFIX"] = str(cache_dir / "pycache")
    return env


def _run(root: Path, env: dict, out: Path, work: Path, driver: Path | None):
    cmd = [sys.executable]
    cmd += [str(driver)] if driver is not None else ["-m", "voxflex"]
    cmd += ["simulate", "--quiet", "-o", str(out), "--force"]
    t = time.perf_counter()
    proc = subprocess.run(cmd, env=env, cwd=work, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if proc.returncode != 0:
        raise SystemExit(f"{root}: {' '.join(cmd[1:])} failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    split = json.loads(proc.stdout.strip().splitlines()[-1]) if driver is not None else None
    return wall, split


def _git(root: Path, *args: str) -> str:
    proc = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True)
    return proc.stdout.strip() if proc.returncode == 0 else ""


def _before_tree(before: str, after: Path, cache_dir: Path) -> Path:
    """The 'before' package: a folder as given, or a revision of the 'after' repository exported (read only)."""
    if Path(before, "voxflex").is_dir():
        return Path(before).resolve()
    rev = _git(after, "merge-base", "HEAD", "main") if before == "merge-base" else _git(after, "rev-parse", before)
    if not rev:
        raise SystemExit(f"--before {before!r}: neither a checkout folder nor a revision of {after}")
    tree = cache_dir / f"tree-{rev[:12]}"
    if not (tree / "voxflex").is_dir():
        tree.mkdir(parents=True, exist_ok=True)
        archive = subprocess.run(["git", "-C", str(after), "archive", rev], capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
    return tree


def _run_floor(script: Path, env: dict, work: Path) -> float:
    t = time.perf_counter()
    proc = subprocess.run([sys.executable, str(script)], env=env, cwd=work, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if proc.returncode != 0:
        raise SystemExit(f"the floor script failed:\n{proc.stderr[-2000:]}")
    return wall


def _states(path: Path):
    import h5py

    with h5py.File(path, "r") as f:
        return f["nodes/state"][()]


def _machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            names = [line.split(":", 1)[1].strip() for line in fh if line.startswith("model name")]
        cpu = names[0] if names else cpu
    except OSError:
        pass
    import numba
    import numpy
    import scipy

    return (f"{platform.system()} {platform.machine()}, {cpu}, {os.cpu_count()} cores; Python "
            f"{platform.python_version()}, numpy {numpy.__version__}, scipy {scipy.__version__}, "
            f"numba {numba.__version__}")


def _load() -> str:
    try:
        return "load average %.2f %.2f %.2f" % os.getloadavg()
    except OSError:
        return "load average unknown"


def _fmt(values) -> str:
    return f"{min(values):6.3f} {statistics.median(values):6.3f}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=5, help="timed runs per version and measure (>= 5)")
    parser.add_argument("--after", default=str(ROOT), help="checkout to time as 'after' (default: this one)")
    parser.add_argument("--before", default="merge-base",
                        help="what to time as 'before': a checkout folder (read only), a git revision of the "
                        "'after' repository (exported with git archive into --cache-dir), 'merge-base' (default: "
                        "where this branch left main) or '' to skip")
    parser.add_argument("--bytecode", choices=("env", "cached", "both"), default="env")
    parser.add_argument("--cache-dir", default=str(Path(tempfile.gettempdir()) / "voxflex-bench-startup"),
                        help="numba and bytecode caches of the timed runs (kept between benchmark runs)")
    args = parser.parse_args(argv)
    if args.repeat < 5:
        parser.error("--repeat must be >= 5")
    versions = [("after", Path(args.after).resolve())]
    cache_dir = Path(args.cache_dir)
    if args.before:
        versions.insert(0, ("before", _before_tree(args.before, versions[0][1], cache_dir)))
    modes = ("env", "cached") if args.bytecode == "both" else (args.bytecode,)

    print(f"# voxflex simulate --quiet (the bundled default scene), warm\n\nmachine: {_machine()}")
    print(f"PYTHONDONTWRITEBYTECODE={os.environ.get('PYTHONDONTWRITEBYTECODE', '')!r} in this environment; "
          f"{_load()} at start")
    for label, root in versions:
        if (root / ".git").exists():
            rev = _git(root, "rev-parse", "--short", "HEAD") or "?"
            dirty = " (with uncommitted changes)" if _git(root, "status", "--porcelain", "--untracked-files=no") else ""
            print(f"{label}: {root} at {rev}{dirty}")
        else:
            print(f"{label}: {root} (exported revision {root.name[5:]})")
    scene = subprocess.run([sys.executable, "-c", "from voxflex.scene import default_scene_path as p; print(p())"],
                           env=_env(versions[-1][1], "env", cache_dir), capture_output=True, text=True)
    print(f"default scene: {scene.stdout.strip() or scene.stderr.strip()[-200:]}")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        driver = work / "driver.py"
        driver.write_text(_DRIVER)
        floor = work / "floor.py"
        floor.write_text(_FLOOR)
        for mode in modes:
            envs = {label: _env(root, mode, cache_dir) for label, root in versions}
            for label, root in versions:  # warm-up: fills numba's, the bytecode's and the precompute's caches
                _run(root, envs[label], work / f"{label}.h5", work, None)
            _run_floor(floor, envs[versions[-1][0]], work)
            walls = {label: [] for label, _ in versions}
            splits = {label: [] for label, _ in versions}
            floors = []
            for _ in range(args.repeat):  # interleaved, so that both versions share the machine's noise
                for label, root in versions:
                    walls[label].append(_run(root, envs[label], work / f"{label}.h5", work, None)[0])
                floors.append(_run_floor(floor, envs[versions[-1][0]], work))
                for label, root in versions:
                    wall, split = _run(root, envs[label], work / f"{label}-split.h5", work, driver)
                    split["start"] = wall - split["inside"]
                    split["wall"] = wall
                    splits[label].append(split)
            what = "as this environment runs" if mode == "env" else "cached, as after an install"
            print(f"\n## bytecode: {mode} ({what}); {args.repeat} runs; {_load()} at end\n")
            print("| version | end to end (min median) s | start + exit | imports | numba kernel loads | compute "
                  "| pyvista/vtk/tqdm imported |")
            print("|---|---|---|---|---|---|---|")
            for label, _ in versions:
                s = splits[label]
                compute = [x["inside"] - x["imports"] - x["numba"] for x in s]
                heavy = ", ".join(s[-1]["heavy_modules"]) or "no"
                print(f"| {label} | {_fmt(walls[label])} | {_fmt([x['start'] for x in s])} | "
                      f"{_fmt([x['imports'] for x in s])} | {_fmt([x['numba'] for x in s])} | {_fmt(compute)} | "
                      f"{heavy} |")
            print(f"| floor: the third-party imports and numba's set-up alone | {_fmt(floors)} | | | | | |")
            if len(versions) == 2:
                a, b = (_states(work / f"{label}.h5") for label, _ in versions)
                same = a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()
                print(f"\nsame answer (final /nodes/state of the two result files, bitwise): {'yes' if same else 'NO'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
