"""User-facing errors.

Every problem caused by the user's input (a missing file, a nonsense parameter,
an empty image) is raised as a :class:`VoxflexError` whose message is one line
naming the problem and the fix.  The command line prints that line on stderr
and exits non-zero without a traceback; library callers can catch it.
"""

from __future__ import annotations


class VoxflexError(Exception):
    """Bad input or an unrecoverable condition, described in one line."""


class InputError(VoxflexError, ValueError):
    """An argument, file or scene entry is invalid."""


class ConvergenceError(VoxflexError, RuntimeError):
    """A solver did not converge; the message says what was tried."""


def did_you_mean(name: str, choices) -> str:
    """Return ``" (did you mean 'x'?)"`` for the closest choice, or ``""``."""
    import difflib

    close = difflib.get_close_matches(str(name), [str(c) for c in choices], n=1)
    return f" (did you mean '{close[0]}'?)" if close else ""


def check_choice(name: str, value: str, choices) -> str:
    """Validate a named choice; raise :class:`InputError` listing the valid ones."""
    if value not in choices:
        raise InputError(
            f"unknown {name} '{value}'{did_you_mean(value, choices)}; "
            f"valid: {', '.join(sorted(choices))}"
        )
    return value


def missing_file(path, what: str) -> InputError:
    """The error for a ``what`` file (``"scene file"``, ``"mesh file"`` ...) that is not a readable file:
    a folder is named as a folder (not "not found" or "bad extension"), anything else as not found."""
    import os

    try:
        os.stat(path)
    except OSError as exc:
        if exc.strerror and exc.errno not in (2, 20):  # not ENOENT / ENOTDIR: a name too long, a loop ...
            return InputError(f"{what} '{str(path)[:80]}' cannot be read ({exc.strerror}); check the path")
        return InputError(f"{what} '{path}' not found; check the path")
    if os.path.isdir(path):
        return InputError(f"{what} '{path}' is a folder, not a file; give a file inside it")
    return InputError(f"{what} '{path}' is not a regular file; give a file")
