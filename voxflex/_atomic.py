"""Atomic file output: write to a temporary file beside the target, then rename.

A failed or interrupted write leaves any existing file untouched and no
partial output behind:

* an exception inside the ``with`` block removes the temporary file;
* SIGINT and SIGTERM received while the block runs (in the main thread) are
  recorded, and the block ends with :class:`Interrupted` (a
  ``KeyboardInterrupt``) instead of the rename: the temporary file is removed
  and the old target stays in place.  The first signal does not raise inside
  the writer, because libraries (h5py, VTK) may swallow an exception raised in
  their callbacks or print "Exception ignored" noise; the writer finishes its
  temporary file, which is then discarded.  A second signal raises at once
  (for a write that hangs).  The command line turns :class:`Interrupted` into
  exit status 130.  Outside a save the process's own signal handling applies
  unchanged.  A long write inside the block (a result streamed over a whole
  run) calls :func:`check_interrupted` between its parts, so the first signal
  stops it there.

:func:`check_output_path` validates a target before any work is done (the
folder exists and is writable, the target is not a folder).

Testing hook: when the environment variable ``VOXFLEX_TEST_SAVE_PAUSE`` holds a
number of seconds, every atomic write sleeps that long after its temporary file
is written and before the rename, so that a test can signal a process that is
deterministically inside a save.
"""

from __future__ import annotations

import contextlib
import os
import signal
import tempfile
import threading
import time
from pathlib import Path

from .errors import InputError

_PAUSE_ENV = "VOXFLEX_TEST_SAVE_PAUSE"
_SIGNALS = tuple(s for s in (getattr(signal, "SIGINT", None), getattr(signal, "SIGTERM", None)) if s is not None)


class Interrupted(KeyboardInterrupt):
    """A save was stopped by SIGINT or SIGTERM; the temporary file is gone and the old target untouched."""

    def __init__(self, signum: int, path):
        self.signum = signum
        self.path = Path(path)
        super().__init__(f"{signal.Signals(signum).name} during the save of '{path}'")


def check_output_path(path, *, what: str = "output", example: str = "out") -> Path:
    """Check that ``path`` can be written as a file, before any work is done.

    Parameters
    ----------
    path : str or Path
        The file to be written.
    what : str
        How messages name it (``"result file"``, ``"--render target"`` ...).
    example : str
        A file name suggested inside ``path`` when ``path`` is a folder.

    Returns
    -------
    Path

    Raises
    ------
    InputError
        The folder does not exist or is not writable, or ``path`` is a folder.
    """
    path = check_name_length(path, what)
    folder = path.parent if str(path.parent) else Path(".")
    if path.is_dir():
        raise InputError(f"{what} '{path}' is a folder; give a file name inside it, e.g. '{path / example}'")
    if not folder.exists():
        raise InputError(
            f"output folder '{folder}' of {what} '{path}' does not exist; create it or choose another path"
        )
    if not folder.is_dir():
        raise InputError(
            f"'{folder}' is a file, not a folder, so {what} '{path}' cannot be written; choose another path"
        )
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InputError(f"output folder '{folder}' is not writable; choose another path or fix its permissions")
    if path.exists() and not os.access(path, os.W_OK):
        raise InputError(f"{what} '{path}' exists and is read-only; choose another path or fix its permissions")
    probe_folder(folder, what, path)
    return path


def check_name_length(path, what: str = "output") -> Path:
    """InputError when a part of ``path`` is longer than file names may be (before anything stats it: the
    system's own error, ENAMETOOLONG, is not a one-line message)."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    for part in path.parts:
        size = len(os.fsencode(part))
        limit = _name_max(folder if part == path.name else Path("."))
        if size > limit:
            raise InputError(f"{what} '{part[:32]}...' is a name {size} bytes long, more than the {limit} the file "
                             "system allows; choose a shorter name")
    return path


def _name_max(folder: Path) -> int:
    """The longest file name (bytes) the file system of ``folder`` takes (255 where it does not say)."""
    try:
        return int(os.pathconf(folder, "PC_NAME_MAX"))
    except (OSError, ValueError, AttributeError):
        return 255


def probe_folder(folder: Path, what: str, path: Path) -> None:
    """Create and remove a file in ``folder``: a folder that says it is writable but is not (/proc, a
    read-only mount) is refused now, not after the run."""
    try:
        fd, name = tempfile.mkstemp(prefix=".voxflex-probe.", dir=folder)
        os.close(fd)
        os.unlink(name)
    except OSError as exc:
        raise InputError(f"cannot create files in folder '{folder}' for {what} '{path}' ({exc.strerror or exc}); "
                         "choose another path") from None


def _temporary_name(path: Path, suffix: str, folder: Path) -> tuple[str, str]:
    """(prefix, suffix) of :func:`tempfile.mkstemp` for ``path``: ``.STEM.XXXXXXXX.SUFFIX`` shortened (the stem
    first, then the suffix to its last part) so that the hidden name fits the file system's name limit."""
    limit = _name_max(folder)
    random_part = 8  # mkstemp's random characters
    stem = path.stem
    fixed = 2 + random_part  # the leading and the separating dots
    if len(os.fsencode(suffix)) + fixed + 1 > limit:
        suffix = path.suffix  # the last suffix still names the format
    room = limit - fixed - len(os.fsencode(suffix))
    encoded = os.fsencode(stem)
    if len(encoded) > room:
        stem = encoded[:max(room, 0)].decode(errors="ignore")
    return f".{stem}.", suffix


class _Guard:
    """SIGINT/SIGTERM handling for the outermost active save (main thread only).

    Nested saves (an ``.npy`` and its sidecar) hand their renames to the
    outermost one, which commits them all at once with the signals blocked, so
    a signal leaves either every old file or every new one.
    """

    depth = 0
    received: int | None = None
    previous: dict = {}
    path: Path | None = None
    pending: list = []

    @classmethod
    def enter(cls, path: Path) -> bool:
        """Start guarding; True when this is the guarded outermost save."""
        if threading.current_thread() is not threading.main_thread():
            return False
        if cls.depth == 0:
            cls.received = None
            cls.path = path
            cls.pending = []
            cls.previous = {s: signal.getsignal(s) for s in _SIGNALS}
            for s in _SIGNALS:
                signal.signal(s, cls._handler)
        cls.depth += 1
        return cls.depth == 1

    @classmethod
    def leave(cls) -> None:
        cls.depth -= 1
        if cls.depth == 0:
            for s, handler in cls.previous.items():
                signal.signal(s, handler if handler is not None else signal.SIG_DFL)
            cls.previous = {}

    @classmethod
    def _handler(cls, signum, frame):
        again = cls.received is not None
        cls.received = signum
        if again:  # a second signal: stop now, wherever the writer is
            raise Interrupted(signum, cls.path)

    @classmethod
    def check(cls) -> None:
        """Raise :class:`Interrupted` when a signal arrived during the save."""
        if cls.received is not None:
            raise Interrupted(cls.received, cls.path)


def check_interrupted() -> None:
    """Raise :class:`Interrupted` when SIGINT or SIGTERM arrived during the active save.

    A writer that works for long inside :func:`atomic_path` (a result streamed
    state by state over a whole run) calls this between states, so that the
    first signal stops it within a state instead of at the end; the temporary
    file is then removed and the old target kept.  Does nothing outside a save
    or off the main thread.
    """
    if _Guard.depth and threading.current_thread() is threading.main_thread():
        _Guard.check()


def _pause(seconds: float, guarded: bool) -> None:
    """The testing hook's sleep, cut short by a signal recorded meanwhile."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if guarded:
            _Guard.check()
        time.sleep(min(0.01, max(end - time.monotonic(), 0.0)))


def _block():
    """Block SIGINT/SIGTERM; returns the previous mask for :func:`_restore` (None where unsupported)."""
    if hasattr(signal, "pthread_sigmask"):
        return signal.pthread_sigmask(signal.SIG_BLOCK, _SIGNALS)
    return None


def _restore(mask) -> None:
    if mask is not None:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)


@contextlib.contextmanager
def atomic_path(path, *, suffix: str | None = None):
    """Yield a temporary path in the target's folder; move it onto ``path`` on success.

    ``suffix`` defaults to the target's full suffix (``.nii.gz`` stays
    ``.nii.gz``) so that writers which pick the format from the extension work.
    On any exception, SIGINT or SIGTERM the temporary file is removed and
    ``path`` is left as it was.  Nested blocks are committed together when the
    outermost one ends.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.exists():
        raise InputError(f"output folder '{folder}' does not exist; create it or choose another path")
    if suffix is None:
        suffix = "".join(path.suffixes) or path.suffix
    guarded = threading.current_thread() is threading.main_thread()
    outermost = _Guard.enter(path)
    tmp = None
    handed_over = False
    blocked = None
    try:
        mask = _block() if guarded else None  # no signal between creating the file and knowing its name
        try:
            prefix, short = _temporary_name(path, suffix, folder)
            fd, name = tempfile.mkstemp(prefix=prefix, suffix=short, dir=folder)
            tmp = Path(name)
            os.close(fd)
        finally:
            _restore(mask)
        # mkstemp creates 0600; give the output the permissions a plain open() would
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        yield tmp
        pause = os.environ.get(_PAUSE_ENV)
        if pause:
            _pause(float(pause), guarded)
        if not guarded:
            os.replace(tmp, path)
        elif not outermost:
            _Guard.pending.append((tmp, path))  # the outermost save renames it
            handed_over = True
        else:
            blocked = _block()
            _Guard.check()
            for t, p in [*_Guard.pending, (tmp, path)]:
                os.replace(t, p)
    finally:
        try:
            leftovers = [] if handed_over else [tmp]
            if outermost:
                leftovers += [t for t, _ in _Guard.pending]
                _Guard.pending = []
            for t in leftovers:
                if t is not None and t.exists():
                    t.unlink()
        finally:
            if guarded:
                _Guard.leave()
            _restore(blocked)  # a signal now pending meets the process's own handler
