"""Atomic file output: write to a temporary file beside the target, then rename.

A failed or interrupted write leaves any existing file untouched and no
partial output behind.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path


@contextlib.contextmanager
def atomic_path(path, *, suffix: str | None = None):
    """Yield a temporary path in the target's folder; move it onto ``path`` on success.

    ``suffix`` defaults to the target's full suffix (``.nii.gz`` stays
    ``.nii.gz``) so that writers which pick the format from the extension work.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.exists():
        from .errors import InputError

        raise InputError(f"output folder '{folder}' does not exist; create it or choose another path")
    if suffix is None:
        suffix = "".join(path.suffixes) or path.suffix
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=suffix, dir=folder)
    os.close(fd)
    tmp = Path(tmp)
    # mkstemp creates 0600; give the output the permissions a plain open() would
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
