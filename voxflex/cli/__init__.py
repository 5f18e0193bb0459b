"""The ``voxflex`` command line: a thin shell over the library.

Each sub-command lives in its own module of this package and exposes
``register(subparsers)``, which adds its parser and sets ``func`` to a function
``run(args) -> int``.  Results go to stdout, progress and logs to stderr; a
:class:`voxflex.VoxflexError` becomes a one-line message on stderr and exit
status 2, with no traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys

from .._atomic import Interrupted
from .._version import __version__
from ..errors import VoxflexError

# sub-command modules, in the order --help lists them
_COMMANDS = ["voxelize", "simulate", "render", "info", "tradeoff"]

_EPILOG = """\
quick start:
  voxflex voxelize sphere:0.5 -o ball.nii.gz --voxel-size 0.05
  voxflex info ball.nii.gz
  voxflex simulate                   # the bundled default scene
  voxflex render result.h5 -o result.png

Run 'voxflex COMMAND --help' for the options of each command.
"""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="voxflex",
        description="Image-based voxel elastic simulation: voxelize shapes into label images, "
        "simulate deformable solids on them, render and inspect the results.",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"voxflex {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _COMMANDS:
        try:
            module = importlib.import_module(f"voxflex.cli.{name}")
        except ModuleNotFoundError as exc:  # command not built yet
            if exc.name != f"voxflex.cli.{name}":
                raise
            continue
        module.register(sub)
    return parser


def main(argv=None) -> int:
    os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2  # a usage error, as argparse's own
    import warnings

    previous = warnings.formatwarning
    _one_line_warnings(args.command)
    try:
        return int(args.func(args) or 0)
    except VoxflexError as exc:
        print(f"voxflex {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except Interrupted as exc:
        print(
            f"voxflex {args.command}: interrupted by {signal.Signals(exc.signum).name} while saving "
            f"'{exc.path}'; that file was left as it was and no partial file remains",
            file=sys.stderr,
        )
        return 130
    except KeyboardInterrupt:
        print(f"voxflex {args.command}: interrupted", file=sys.stderr)
        return 130
    except MemoryError:
        print(
            f"voxflex {args.command}: error: out of memory; use a coarser voxel size or fewer nodes",
            file=sys.stderr,
        )
        return 2
    except OSError as exc:  # the system refused a read or a write the checks could not foresee
        where = f" '{str(exc.filename)[:120]}'" if exc.filename else ""
        print(f"voxflex {args.command}: error: the system refused{where}: {exc.strerror or exc}; check the path, "
              "its permissions and the free space", file=sys.stderr)
        return 2
    finally:
        warnings.formatwarning = previous


def _one_line_warnings(command: str) -> None:
    """Warnings print as one line on stderr, ``voxflex COMMAND: warning: MESSAGE (Category)``, without the
    source location and line Python adds (which name voxflex's internals, not the user's input)."""
    import warnings

    def one_line(message, category, filename, lineno, line=None):
        text = " ".join(str(message).split())
        return f"voxflex {command}: warning: {text} ({category.__name__})\n"

    warnings.formatwarning = one_line


def entry() -> None:
    """The ``voxflex`` program (console script and ``python -m voxflex``): :func:`main`, then exit.

    Once a command has returned, the process ends without the interpreter's
    teardown, which destroys every module and object one by one: with numba,
    scipy and h5py loaded that took 0.2-0.3 s, a tenth of a warm default-scene
    run, after the work was done.  What the teardown would do that matters is
    done first: stdout and stderr are flushed and the ``atexit`` handlers run
    (logging, temporary files, h5py, Dask).  When that cannot be done safely
    (another non-daemon thread is alive, a stream cannot be flushed, no
    ``atexit._run_exitfuncs``) the interpreter exits the usual way.  An
    exception from :func:`main` (a ``SystemExit`` from ``--help`` or
    ``--version``, a bug's traceback) also takes the usual way.
    """
    code = main()
    _exit_now(code)


def _exit_now(code: int) -> None:
    import atexit
    import threading

    run_exitfuncs = getattr(atexit, "_run_exitfuncs", None)
    others = [t for t in threading.enumerate() if t is not threading.main_thread() and not t.daemon and t.is_alive()]
    if run_exitfuncs is None or others:
        raise SystemExit(code)
    if not _flushed():  # a closed pipe or stream: let the interpreter report it as usual
        raise SystemExit(code)
    run_exitfuncs()
    if not _flushed():
        code = code or 120  # what the interpreter returns when it cannot flush stdout at exit
    os._exit(code)


def _flushed() -> bool:
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError, AttributeError):  # broken pipe, closed stream, no stream at all
        return False
    return True
