"""On-disk cache of a frame model's precompute (frames, shape functions, samples).

The precompute of a frame model depends only on the label image and a few
scene settings; a second run of the same scene loads it instead of
recomputing it.  Entries are ``.npz`` files named by the SHA-256 of
everything the precompute reads (the image's labels, geometry and occupancy,
the ``[nodes]`` and ``[elasticity]`` settings that matter, the fixed boxes,
the compliance moduli, the source code of the precompute), in ``$VOXFLEX_CACHE_DIR`` or
``~/.cache/voxflex``.  Writes are atomic; an unreadable entry is recomputed
(and replaced) with a warning, never trusted.  ``VOXFLEX_CACHE=0`` or
``voxflex simulate --no-cache`` turn the cache off.

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

__all__ = ["code_fingerprint", "key_of", "load", "save", "cache_dir", "enabled", "CacheWarning"]


class CacheWarning(UserWarning):
    """A cache entry could not be read or written (the work is redone; nothing else changes)."""


def enabled() -> bool:
    """False when ``VOXFLEX_CACHE`` is 0/false/no/off."""
    return os.environ.get("VOXFLEX_CACHE", "1").lower() not in {"0", "false", "no", "off"}


def cache_dir() -> Path:
    """``$VOXFLEX_CACHE_DIR``, else ``~/.cache/voxflex``."""
    env = os.environ.get("VOXFLEX_CACHE_DIR")
    return Path(env) if env else Path.home() / ".cache" / "voxflex"


def code_fingerprint() -> str:
    """SHA-256 of the source of the stages a frame model's precompute runs (voronoi, sampling, the
    builders and the frames' region tables): a changed algorithm never reads an entry of the old one,
    whatever the version."""
    global _FINGERPRINT
    if _FINGERPRINT is None:
        root = Path(__file__).resolve().parent
        frames = root / "deform" / "models" / "frames"
        files = sorted([*root.glob("voronoi/*.py"), *root.glob("sampling/*.py"), root / "build.py",
                        *(frames / f for f in ("build.py", "quadrature.py", "stabilise.py"))])
        h = hashlib.sha256()
        for f in files:
            h.update(f.name.encode())
            h.update(f.read_bytes())
        _FINGERPRINT = h.hexdigest()
    return _FINGERPRINT


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


def load(kind: str, key: str) -> dict | None:
    """The arrays stored under ``kind``/``key``, or None (missing, unreadable: then a warning)."""
    path = cache_dir() / kind / f"{key}.npz"
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            return {k: data[k] for k in data.files}
    except Exception as exc:  # a damaged entry must never stop a run: recompute it
        warnings.warn(f"cache entry {path} is unreadable ({exc}); recomputing it", CacheWarning, stacklevel=2)
        return None


def save(kind: str, key: str, arrays: dict) -> None:
    """Store the arrays atomically; a cache that cannot be written only warns."""
    from ._atomic import atomic_path

    folder = cache_dir() / kind
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with atomic_path(folder / f"{key}.npz") as tmp:
            with open(tmp, "wb") as f:
                np.savez(f, **arrays)
    except OSError as exc:
        warnings.warn(f"cannot write the cache in {folder} ({exc}); set VOXFLEX_CACHE_DIR or VOXFLEX_CACHE=0",
                      CacheWarning, stacklevel=2)
