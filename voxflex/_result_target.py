"""The result file target: what :func:`voxflex.simulate`, ``voxflex simulate -o`` and :meth:`Result.save`
refuse to write over (below :mod:`voxflex.result` and :mod:`voxflex.outputs`, which re-exports it)."""

from __future__ import annotations

import os
from pathlib import Path

from ._atomic import check_output_path
from ._result_layout import _FORMAT as _RESULT_FORMAT  # the root attribute a result file carries
from .errors import InputError

RESULT_EXTENSIONS = (".h5", ".hdf5")
_FORCE = "pass --force to overwrite it"


def is_result_file(path) -> bool:
    """Whether ``path`` is a voxflex result file: HDF5 whose root says ``format = "voxflex-result"``
    (or, for files written before that attribute, carries ``voxflex_version`` and ``/time``)."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            if fh.read(8) != b"\x89HDF\r\n\x1a\n":
                return False
    except OSError:
        return False
    import h5py

    try:
        with h5py.File(str(path), "r") as f:
            fmt = f.attrs.get("format")
            if isinstance(fmt, bytes):
                fmt = fmt.decode("utf-8", "replace")
            return fmt == _RESULT_FORMAT or ("voxflex_version" in f.attrs and "time" in f)
    except (OSError, RuntimeError, KeyError, ValueError):  # a damaged file is not known to be a result
        return False


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _refuse_inputs(path: Path, inputs, what: str, option: str, force: bool, hint: str = _FORCE) -> None:
    if force:
        return
    for name, source in inputs:
        if source is not None and _same_file(path, Path(source)):
            raise InputError(
                f"{what} '{path}' is {name} of this run and would be destroyed; choose another {option}, or {hint}"
            )


def _system_folder(folder: Path) -> bool:
    """Whether ``folder`` is one of the system's device or kernel folders (/dev, /proc, /sys), where no result
    belongs even when the process may write there (root)."""
    try:
        parts = Path(folder).resolve().parts
    except OSError:
        return False
    return len(parts) > 1 and parts[0] == "/" and parts[1] in {"dev", "proc", "sys"}


def check_result_output(path, *, inputs=(), force: bool = False, option: str = "-o", hint: str = _FORCE) -> Path:
    """Validate the result file target of ``voxflex simulate`` and of :func:`voxflex.simulate` (``output=``).

    ``option`` and ``hint`` are how messages name the target and the way to force it (``"-o"`` and
    "pass --force to overwrite it" on the command line, ``"output"`` and "pass force=True ..." in Python).
    """
    path = Path(path)
    what = "result file"
    check_output_path(path, what=what, example="result.h5")
    _refuse_inputs(path, inputs, what, option, force, hint)
    if path.suffix.lower() not in RESULT_EXTENSIONS:
        stem = path.stem if path.suffix else path.name
        alt = path.with_name(stem + ".h5")
        if _system_folder(alt.parent) or not os.access(alt.parent, os.W_OK):
            alt = Path(stem + ".h5")  # beside /dev/null is no place for a result: the current folder
        raise InputError(f"{what} '{path}' must end in .h5 or .hdf5 (it is HDF5); e.g. {option} {alt}")
    if path.exists() and not force and not is_result_file(path):
        raise InputError(
            f"'{path}' exists and is not a voxflex result file, so it would be lost; "
            f"choose another {option}, or {hint}"
        )
    return path
