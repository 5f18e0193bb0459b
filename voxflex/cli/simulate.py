"""``voxflex simulate``: run a scene (or the bundled default) and write the result file."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

_EPILOG = """\
examples:
  voxflex simulate                                  # the bundled default scene -> result.h5
  voxflex simulate beam.toml -o beam.h5 --render beam.png
  voxflex simulate beam.toml --vtk beam_vtk/        # ParaView series (open beam_vtk/result.pvd)

Scenes to start from: examples/ in the source tree (a cantilever, a stretch, a twist,
a drop, a ball on a plane, one example per object source: shape, mesh, image);
every key is described in docs/scene.md.  [nodes] kind = "voxel" is the
full-resolution reference, "affine" a reduced model of a few frames.

The result file goes to -o, else to the scene's [output] file, else to result.h5
in the current folder.  The summary goes to stdout, the progress bar (step,
Newton iteration and residual) and --verbose logs to stderr.  Stress, strain
and reactions are written when the scene asks: [output] fields = ["von-mises", ...].
When a later step fails, the steps that converged are still written (the file
marked incomplete) and the exit status is 2.

The states are written to the result file step by step (memory does not grow
with the steps); --every K records every K-th step only, for long runs.  The
file replaces an existing one only when the run ends.  Before the run, the
model's memory and the result file's size are estimated; a run that would not
fit in memory or on the disk is refused with what would fit.

Every output is checked before the run starts (folder exists and is writable,
extension known); an existing file is replaced only when it is a voxflex result
(for -o) or a picture of the same kind (for --render), and never when it is an
input of the run (the scene, its mesh or image): --force lifts both refusals.
SIGINT or SIGTERM during the run or the save stops it (within the step under
way) with exit status 130 and leaves the previous file as it was.
"""


def register(sub) -> None:
    parser = sub.add_parser(
        "simulate",
        help="run a scene file (default: the bundled demo) and write the result",
        description="Run a simulation scene (TOML) and write the result file (HDF5). "
        "With no SCENE, runs the bundled default scene.",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("scene", nargs="?", metavar="SCENE.toml", help="scene file (default: the bundled demo)")
    parser.add_argument("-o", "--output", metavar="RESULT.h5", help="result file to write")
    parser.add_argument("--render", metavar="OUT.png", help="also render the final state (.png, folder, .gif)")
    parser.add_argument("--vtk", metavar="FOLDER", help="also export a ParaView time series (.vtp + .pvd)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar and no summary")
    parser.add_argument("--every", metavar="K", type=_positive_int, default=None,
                        help="record every K-th step (and the rest state and the last step); default: the scene's "
                             "[output] every, else 1")
    parser.add_argument("--keep", metavar="all|last|N", type=_keep, default=None,
                        help="recorded states held in memory during the run (the file has them all): all, last, "
                             "or the last N; default: the scene's [output] keep, else all while they need at most "
                             "256 MiB, else last "
                             "(--render and --vtk then read the file)")
    parser.add_argument(
        "--no-cache",
        action="store_true",
        help="recompute a frame model's precompute (frames, weights, samples) instead of loading it from the "
        "on-disk cache (~/.cache/voxflex or $VOXFLEX_CACHE_DIR)",
    )
    parser.add_argument(
        "--verbose",
        action="store_true",
        help="log the model size and memory estimate and one line per Newton iteration (residual, step length, "
        "linear solver and its iterations, seconds) on stderr",
    )
    parser.add_argument(
        "--force",
        action="store_true",
        help="overwrite existing outputs even when they are not voxflex results or are inputs of the run",
    )
    parser.set_defaults(func=run)


def run(args) -> int:
    from ..scene import Scene, default_scene_path
    from ..simulation import simulate

    path = Path(args.scene) if args.scene else default_scene_path()
    scene = Scene.from_toml(path)
    output = Path(args.output) if args.output else Path(scene.output.file or "result.h5")
    check_outputs(args, scene, path if args.scene else None, output)
    t0 = time.perf_counter()
    try:
        result = simulate(scene, progress=not args.quiet, output=output, verbose=args.verbose,
                          cache=not args.no_cache, keep=args.keep, every=args.every, force=args.force)
    except NotImplementedError as exc:
        from ..errors import VoxflexError

        raise VoxflexError(str(exc)) from None
    wall = time.perf_counter() - t0
    if args.vtk or args.render:
        full = _every_state(result, output)
    if args.vtk:
        full.export_vtk(args.vtk)
    if args.render:
        from ..errors import VoxflexError
        from ..rendering import render

        try:
            render(full, args.render)
        except VoxflexError as exc:
            raise VoxflexError(f"{exc} (the result itself was saved to {output})") from None
    if not args.quiet:
        print(summary(result, scene_path=path, output=output, wall=wall, extras=[args.render, args.vtk]))
    return 0


def _scene_value(check, text, *, names=()):
    """A command-line value checked by the scene's own validator (one definition of what is valid)."""
    from ..errors import InputError

    value = text if text in names else (int(text) if text.lstrip("+-").isdigit() else text)
    try:
        return check(value, "value")
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc).strip()) from None


def _positive_int(text):
    from ..scene import check_every

    return _scene_value(check_every, text)


def _keep(text):
    from ..scene import KEEP_CHOICES, check_keep

    return _scene_value(check_keep, text, names=KEEP_CHOICES)


def _every_state(result, output):
    """The result with every recorded state: ``result`` when it holds them all, else the file read back."""
    import h5py

    from ..result import Result

    with h5py.File(output, "r") as f:
        recorded = f["time"].shape[0]
    return result if recorded == result.n_states else Result.load(output)


def check_outputs(args, scene, scene_path, output) -> None:
    """Validate -o (or the scene's [output] file), --render and --vtk before the run starts."""
    from ._outputs import check_render_output, check_result_output, check_vtk_output, run_inputs

    inputs = run_inputs(scene_path, scene)
    option = "-o" if args.output else "[output] file"
    check_result_output(output, inputs=inputs, force=args.force, option=option)
    if args.vtk:
        check_vtk_output(args.vtk, inputs=inputs, force=args.force)
    if args.render:
        check_render_output(args.render, force=args.force, option="--render", probe_gl=True)


def summary(result, *, scene_path, output, wall, extras=()) -> str:
    """The short report printed after a run."""
    import numpy as np

    from ..result_text import field_lines

    totals = result.run_totals()
    lines = [
        f"scene: {scene_path}",
        f"model: {result.n_nodes} nodes, {result.n_dofs} DOF, {result.n_voxels} voxels",
        f"steps: {totals['steps']}, Newton iterations: {totals['newton_iterations']}, wall time: {wall:.2f} s",
    ]
    moved = result.probe_displacements(-1)
    for name, pos in result.probes.items():
        u = moved[name]
        lines.append(
            f"probe {name}: final position [{', '.join(f'{x:.6g}' for x in pos[-1])}] "
            f"displacement [{', '.join(f'{x:.6g}' for x in u)}]"
        )
    lines += field_lines(result)
    if result.n_states > 1 and result.complete and not np.any(result.displacement(-1)):
        # exactly zero everywhere drawn: a scene whose loads were forgotten looked like a result
        lines.append("note: nothing moved: the scene applies no load, prescribed motion, cable pull or moving obstacle, "
                     "so the result is its rest state")
    written = [str(output)] + [str(e) for e in extras if e]
    lines.append(f"wrote: {', '.join(written)}")
    return "\n".join(lines)


