"""``voxflex tradeoff``: a sweep of reduced models measured against the voxel reference."""

from __future__ import annotations

import argparse
from pathlib import Path

_EPILOG = """\
examples:
  voxflex tradeoff beam.toml -o beam_sweep/                      # default sweep
  voxflex tradeoff beam.toml --frames 5,10,20 --samples 100,400 --quadratures midpoint,elaston
  voxflex tradeoff beam.toml --reference finer --voxel-levels 3  # reference on a 2x finer grid
  voxflex tradeoff beam.toml --max-error 0.02                    # exit 1 when nothing fits
  voxflex tradeoff beam.toml --workers 4                         # local Dask cluster
  voxflex tradeoff beam.toml --scheduler tcp://head:8786         # an existing Dask cluster

Writes DIR/tradeoff.csv (one row per configuration) and DIR/tradeoff.png (error
against time, log-log, Pareto front marked, the reference with its refinement
error band).  Errors are relative to the reference: probe displacement, RMS
surface displacement over the largest reference displacement, energy.  The
reference's own refinement error (the voxel model 2x coarser against it) is a
floor: errors below it are flagged '<' and ranked as that floor.  Timings run
on one thread (BLAS, OpenMP and numba pinned), after an untimed warm-up, as the
median of 3 runs when a run is under a second.  See docs/tradeoff.md.

The table goes to stdout, the progress bar to stderr.  Existing tradeoff.csv
and tradeoff.png in DIR are replaced only when they are what this command
writes (--force lifts that).
"""


def register(sub) -> None:
    parser = sub.add_parser(
        "tradeoff",
        help="sweep reduced models against the voxel reference: error against time",
        description="Run a scene with the full-resolution voxel model (the reference) and with a sweep "
        "of reduced affine-frame models; print the error-versus-time table and write tradeoff.csv and "
        "tradeoff.png.",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("scene", metavar="SCENE.toml", help="the scene to sweep")
    parser.add_argument("-o", "--output", metavar="DIR", default="tradeoff",
                        help="folder for tradeoff.csv and tradeoff.png (default: ./tradeoff, created if missing)")
    parser.add_argument("--frames", metavar="N,N,...", default="5,10,20,40", help="frame counts (default 5,10,20,40)")
    parser.add_argument("--samples", metavar="N,N,...", default="100,400",
                        help="sample counts for midpoint and elaston quadratures (default 100,400)")
    parser.add_argument("--shape-functions", metavar="KIND,...", default="natural-neighbour",
                        help="shape-function kinds (default natural-neighbour; also reproducing-kernel (linearly "
                        "precise), eigenmode, sibson, laplace, distance-ratio, shepard)")
    parser.add_argument("--quadratures", metavar="KIND,...", default="elaston,gauss-legendre",
                        help="quadratures (default elaston,gauss-legendre: the default rule beside the exact one; "
                        "also midpoint)")
    parser.add_argument("--reference", choices=("scene", "finer"), default="scene",
                        help="the voxel model on the scene's image, or with every voxel split in 2x2x2")
    parser.add_argument("--voxel-levels", metavar="N", type=int, default=1,
                        help="coarser voxel grids run beside the reference (default 1)")
    parser.add_argument("--max-error", metavar="E", type=float,
                        help="name the cheapest configuration within this relative error; exit 1 when none is")
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--workers", metavar="N", type=int, help="run on a local Dask cluster of N processes")
    group.add_argument("--scheduler", metavar="ADDRESS", help="run on the Dask scheduler at ADDRESS")
    parser.add_argument("--quiet", action="store_true", help="no progress bar and no table")
    parser.add_argument("--force", action="store_true",
                        help="overwrite tradeoff.csv / tradeoff.png even when they are not this command's outputs")
    parser.set_defaults(func=run)


def run(args) -> int:
    from ..scene import Scene
    from ..sweep import tradeoff

    scene_path = Path(args.scene)
    scene = Scene.from_toml(scene_path)
    folder = check_outputs(args, scene, scene_path)
    kwargs = dict(
        frames=_int_list("--frames", args.frames),
        samples=_int_list("--samples", args.samples),
        shape_functions=_name_list(args.shape_functions),
        quadratures=_name_list(args.quadratures),
        reference=args.reference,
        voxel_levels=args.voxel_levels,
        max_error=args.max_error,
        workers=args.workers,
        scheduler=args.scheduler,
        progress=not args.quiet,
    )
    table = tradeoff(scene, **kwargs)
    csv_path, png_path = table.save(folder)
    if not args.quiet:
        print(f"scene: {scene_path}")
        print(table.format())
        print(f"wrote: {csv_path}, {png_path}")
    if args.max_error is not None and table.choice is None:
        return 1
    return 0


def _int_list(option: str, text: str) -> tuple:
    from ..errors import InputError

    try:
        values = tuple(int(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise InputError(f"{option} must be comma-separated positive integers such as 5,10,20; got '{text}'") from None
    return values


def _name_list(text: str) -> tuple:
    return tuple(x.strip() for x in text.split(",") if x.strip())


def check_outputs(args, scene, scene_path) -> Path:
    """Validate -o before the sweep starts: a folder (existing and writable, or creatable), whose
    tradeoff.csv / tradeoff.png are replaced only when they are this command's outputs."""
    from .._atomic import check_output_path
    from ..errors import InputError
    from ._outputs import run_inputs

    folder = Path(args.output)
    if folder.exists() and not folder.is_dir():
        raise InputError(f"-o '{folder}' is an existing file; give a folder (created if missing)")
    if not folder.exists():
        check_output_path(folder, what="-o folder", example="sweep")  # its parent exists and is writable
        return folder
    inputs = run_inputs(scene_path, scene)
    for name, check in (("tradeoff.csv", _is_tradeoff_csv), ("tradeoff.png", _is_png)):
        target = folder / name
        check_output_path(target, what=f"-o target {name}")
        if args.force:
            continue
        for what, source in inputs:
            if target.exists() and source.exists() and target.resolve() == source.resolve():
                raise InputError(f"'{target}' is {what} of this run and would be destroyed; choose another -o, "
                                 "or pass --force to overwrite it")
        if target.exists() and not check(target):
            raise InputError(f"'{target}' exists and is not a {name} written by voxflex tradeoff, so it would be "
                             "lost; choose another -o, or pass --force to overwrite it")
    return folder


def _is_tradeoff_csv(path: Path) -> bool:
    try:
        with open(path, encoding="utf-8") as fh:
            head = fh.readline()
    except (OSError, UnicodeDecodeError):
        return False
    return head.startswith("role,kind,count,")


def _is_png(path: Path) -> bool:
    try:
        with open(path, "rb") as fh:
            return fh.read(8) == b"\x89PNG\r\n\x1a\n"
    except OSError:
        return False
