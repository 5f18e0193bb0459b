"""On-disk cache of a frame model's precompute (frames, shape functions, samples).

The precompute of a frame model depends only on the label image and a few
scene settings; a second run of the same scene loads it instead of
recomputing it.  Entries are ``.npz`` files named by the SHA-256 of
everything the precompute reads (the image's labels, geometry and occupancy,
the ``[nodes]`` and ``[elasticity]`` settings that matter, the fixed boxes,
the compliance moduli, the source code of the whole package), in ``$VOXFLEX_CACHE_DIR`` or
``~/.cache/voxflex``.  Writes are atomic.  An entry can only give back what a
fresh build would:

* the key covers the source of every module of the package (:func:`code_fingerprint`),
  so a changed algorithm anywhere never reads an entry of the old one;
* each entry carries the SHA-256 of its own arrays (names, dtypes, shapes,
  bytes); :func:`load` recomputes it and treats any difference as damage;
* an entry that is unreadable, damaged, or that the builder finds
  inconsistent (:class:`CacheMismatch`, :func:`discard`) is removed and
  recomputed with a one-line :class:`CacheWarning`; it is never trusted and
  never reported as a fault of the scene.

``VOXFLEX_CACHE=0`` or ``voxflex simulate --no-cache`` turn the cache off.

>>> key_of(b"abc", {"a": 1})[:12]
'c64b5a1b4a8d'
"""

from __future__ import annotations

import hashlib
import json
import os
import warnings
from pathlib import Path

import numpy as np

from .errors import InputError

__all__ = ["code_fingerprint", "key_of", "load", "save", "discard", "cache_dir", "enabled", "CacheWarning",
           "CacheMismatch", "CHECKSUM"]

CHECKSUM = "__checksum__"
"""The array of an entry that holds the SHA-256 of all its other arrays."""


class CacheWarning(UserWarning):
    """A cache entry could not be read or written, or was damaged (the work is redone; nothing else changes)."""


class CacheMismatch(Exception):
    """Raised by a builder that finds a cache entry inconsistent with what it needs (the entry is then
    discarded and recomputed: :func:`discard`)."""


def enabled() -> bool:
    """False when ``VOXFLEX_CACHE`` is 0/false/no/off, True when unset or 1/true/yes/on; InputError for anything
    else (``maybe`` was taken as on without a word)."""
    value = os.environ.get("VOXFLEX_CACHE", "1").strip().lower()
    if value in {"0", "false", "no", "off"}:
        return False
    if value in {"1", "true", "yes", "on", ""}:
        return True
    raise InputError(f"VOXFLEX_CACHE={os.environ['VOXFLEX_CACHE']!r} is not a switch; set it to 0 (off) or 1 (on), "
                     "or unset it")


def cache_dir() -> Path:
    """``$VOXFLEX_CACHE_DIR``, else ``~/.cache/voxflex``."""
    env = os.environ.get("VOXFLEX_CACHE_DIR")
    return Path(env) if env else Path.home() / ".cache" / "voxflex"


def code_fingerprint() -> str:
    """SHA-256 of the version and the source of every module of the package (each file's path in the
    package and its bytes): a change of code anywhere (the frame model, its builder, the weights, the
    samples, a material) never reads an entry of the old code, whatever the version says.  About 10 ms
    for the package's ~1.5 MB of source, once per process."""
    global _FINGERPRINT
    if _FINGERPRINT is None:
        _FINGERPRINT = source_fingerprint(Path(__file__).resolve().parent)
    return _FINGERPRINT


def source_files(root) -> list:
    """Every module of the package at ``root`` (``*.py`` below it, caches left out), sorted."""
    return sorted(p for p in Path(root).rglob("*.py") if "__pycache__" not in p.parts)


def source_fingerprint(root) -> str:
    """SHA-256 of the version and of each module's path (relative to ``root``) and bytes."""
    from ._version import __version__

    root = Path(root)
    h = hashlib.sha256(__version__.encode())
    for f in source_files(root):
        h.update(f.relative_to(root).as_posix().encode() + b"\x00")
        h.update(f.read_bytes())
        h.update(b"\x00")
    return h.hexdigest()


_FINGERPRINT = None


def key_of(*parts) -> str:
    """SHA-256 (hex) of bytes, arrays (dtype, shape and data) and JSON-able settings, in order."""
    h = hashlib.sha256()
    for p in parts:
        if isinstance(p, bytes):
            h.update(p)
        elif isinstance(p, np.ndarray):
            a = np.ascontiguousarray(p)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(a.tobytes())
        else:
            h.update(json.dumps(p, sort_keys=True, default=str).encode())
        h.update(b"\x00")
    return h.hexdigest()


def checksum(arrays: dict) -> str:
    """SHA-256 (hex) of named arrays: each name, dtype, shape and bytes, in name order (``CHECKSUM`` left out)."""
    return key_of(*[part for name in sorted(arrays) if name != CHECKSUM
                    for part in (name, np.asarray(arrays[name]))])


def _path(kind: str, key: str) -> Path:
    return cache_dir() / kind / f"{key}.npz"


def discard(kind: str, key: str, reason: str, *, stacklevel: int = 2) -> None:
    """Remove the entry ``kind``/``key`` (it is then recomputed) with a one-line :class:`CacheWarning`."""
    path = _path(kind, key)
    warnings.warn(f"cache entry {path} {reason}; recomputing it", CacheWarning, stacklevel=stacklevel + 1)
    try:
        path.unlink()
    except OSError:
        pass  # gone already, or a read-only cache: the fresh entry replaces it if it can


def load(kind: str, key: str) -> dict | None:
    """The arrays stored under ``kind``/``key``, or None: missing; unreadable or damaged (its checksum
    differs, or it has none) -- then removed with a one-line warning so that it is recomputed."""
    path = _path(kind, key)
    if not path.is_file():
        return None
    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as data:  # fh: closed even when np.load fails
            arrays = {k: data[k] for k in data.files}
    except Exception as exc:  # a damaged entry must never stop a run: recompute it
        reason = " ".join(str(exc).split())[:200] or type(exc).__name__
        discard(kind, key, f"is unreadable ({reason})", stacklevel=2)
        return None
    stored = arrays.pop(CHECKSUM, None)
    if stored is None or str(stored) != checksum(arrays):
        discard(kind, key, "has no checksum" if stored is None else "is damaged (its checksum does not match)",
                stacklevel=2)
        return None
    return arrays


def save(kind: str, key: str, arrays: dict) -> None:
    """Store the arrays atomically with their checksum; a cache that cannot be written only warns."""
    from ._atomic import atomic_path

    folder = cache_dir() / kind
    arrays = {name: np.asarray(a) for name, a in arrays.items()}
    arrays[CHECKSUM] = np.array(checksum(arrays))
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with atomic_path(folder / f"{key}.npz") as tmp:
            with open(tmp, "wb") as f:
                np.savez(f, **arrays)
    except OSError as exc:
        warnings.warn(f"cannot write the cache in {folder} ({exc}); set VOXFLEX_CACHE_DIR or VOXFLEX_CACHE=0",
                      CacheWarning, stacklevel=2)
