"""Checks on a command's outputs, done before any work starts.

A run must not fail after minutes of work because its output cannot be
written, and it must never destroy a file it was not meant to replace.  Each
``check_*`` function raises :class:`voxflex.errors.InputError` with one line
naming the problem and the fix:

* the folder exists and is writable, the target is not a folder
  (:func:`voxflex._atomic.check_output_path`), its extension is one the
  writer knows;
* an existing file is replaced only when it is what the command writes there
  (a voxflex result for ``simulate -o``, an image of the named format for
  ``voxelize -o``, a picture or animation for ``render -o``) and is not an
  input of the run (the scene file, its mesh or image); ``--force`` lifts
  both refusals.
"""

from __future__ import annotations

import importlib.util
import os
import re
from pathlib import Path

from ._atomic import check_name_length, check_output_path, probe_folder
from ._result_target import (  # noqa: F401 - importable from here as before
    _FORCE, RESULT_EXTENSIONS, _refuse_inputs, _same_file, _system_folder, check_result_output, is_result_file,
)
from .errors import InputError

RENDER_FILES = (".png", ".gif", ".mp4")


def run_inputs(scene_path, scene) -> list[tuple[str, Path]]:
    """The files a scene run reads: ``[(description, path)]`` (the scene file, its mesh or image)."""
    inputs = []
    if scene_path is not None:
        inputs.append(("the scene file", Path(scene_path)))
    obj = scene.object
    for key in ("mesh", "image"):
        source = getattr(obj, key, None)
        if source is not None:
            inputs.append((f"the scene's {key}", Path(source)))
            if key == "image" and str(source).lower().endswith(".npy"):
                inputs.append(("the scene image's sidecar", Path(str(source) + ".json")))
    return inputs




def check_image_output(path, *, inputs=(), force: bool = False, option: str = "-o") -> Path:
    """Validate the image file target of ``voxflex voxelize`` (and its ``.npy`` sidecar)."""
    from .image.io import image_format, looks_like_image

    path = check_name_length(path, "image file")
    fmt = image_format(path)  # unknown extensions are refused here, with the supported list
    check_output_path(path, what="image file", example="image" + "".join(path.suffixes))
    _refuse_inputs(path, inputs, "image file", option, force)
    if path.exists() and not force:
        if is_result_file(path):
            raise InputError(
                f"'{path}' is a simulation result and would be replaced by an image; "
                f"choose another {option}, or {_FORCE}"
            )
        if not looks_like_image(path):
            raise InputError(
                f"'{path}' exists and is not a {fmt} image, so it would be lost; choose another {option}, or {_FORCE}"
            )
    if fmt == "NumPy":
        side = path.with_name(path.name + ".json")
        check_output_path(side, what="sidecar")
        if side.exists() and not force and not _is_sidecar(side):
            raise InputError(
                f"'{side}' exists and is not a voxflex sidecar, so writing '{path.name}' would replace it; "
                f"choose another {option}, or {_FORCE}"
            )
    return path


def _is_sidecar(path: Path) -> bool:
    import json

    try:
        return json.loads(path.read_text()).get("kind") == "voxflex-label-image-geometry"
    except (OSError, ValueError, AttributeError):
        return False


_SIGNATURES = {
    ".png": lambda head: head.startswith(b"\x89PNG\r\n\x1a\n"),
    ".gif": lambda head: head[:6] in (b"GIF87a", b"GIF89a"),
    ".mp4": lambda head: head[4:8] == b"ftyp",
}


def check_render_output(path, *, force: bool = False, option: str = "-o", probe_gl: bool = False) -> Path:
    """Validate a render target: a ``.png``, ``.gif`` or ``.mp4`` file, or a folder of PNGs.

    ``probe_gl`` also checks that offscreen OpenGL works here (a child process,
    about a second), for runs that render only after a long computation.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    what = f"{option} target"
    check_name_length(path, what)
    if suffix in RENDER_FILES:
        check_output_path(path, what=what)
        if path.exists() and not force:
            with open(path, "rb") as fh:
                head = fh.read(16)
            if not _SIGNATURES[suffix](head):
                raise InputError(
                    f"'{path}' exists and is not a {suffix} file, so it would be lost; choose another {option}, "
                    f"or {_FORCE}"
                )
        if suffix == ".mp4" and importlib.util.find_spec("imageio_ffmpeg") is None:
            raise InputError(
                f"writing {path.name} needs imageio-ffmpeg (pip install imageio-ffmpeg); or render a .gif instead"
            )
    elif path.is_dir():
        if not os.access(path, os.W_OK | os.X_OK):
            raise InputError(f"folder '{path}' ({what}) is not writable; choose another or fix its permissions")
        probe_folder(path, what, path)
    elif suffix or path.exists():
        why = f"unknown extension '{suffix}'" if suffix else "it is an existing file, not a folder"
        raise InputError(f"cannot render to '{path}': give a .png, a .gif, a .mp4 or a folder ({why})")
    else:  # a folder to be created: its parent must exist
        check_output_path(path, what=what)
    if probe_gl:
        from . import rendering

        probe = getattr(rendering, "_check_offscreen_gl", None)
        if probe is not None:
            probe()
    return path


def check_vtk_output(path, *, inputs=(), force: bool = False, option: str = "--vtk") -> Path:
    """Validate a ParaView export target: a folder (existing, or created in an existing one) or a ``.pvd`` file."""
    path = check_name_length(path, option)
    if path.suffix.lower() == ".pvd":
        check_output_path(path, what=f"{option} target")
        folder, stem = (path.parent if str(path.parent) else Path(".")), path.stem
        if path.exists() and not force:
            with open(path, "rb") as fh:
                head = fh.read(512)
            if b"<VTKFile" not in head or b"Collection" not in head:
                raise InputError(
                    f"'{path}' exists and is not a ParaView collection, so it would be lost; "
                    f"choose another {option}, or {_FORCE}"
                )
    elif path.is_dir():
        if not os.access(path, os.W_OK | os.X_OK):
            raise InputError(f"{option} folder '{path}' is not writable; choose another or fix its permissions")
        probe_folder(path, f"{option} folder", path)
        folder, stem = path, "result"
    elif path.exists():
        raise InputError(
            f"{option} target '{path}' is an existing file; give a folder (created if missing) or a .pvd file"
        )
    elif path.suffix:
        raise InputError(
            f"{option} target '{path}' must be a folder (created if missing) or a .pvd file, "
            f"not a '{path.suffix}' file; e.g. {option} {path.with_suffix('')}/"
        )
    else:
        check_output_path(path, what=f"{option} folder")
        folder, stem = path, "result"
    pattern = re.compile(rf"{re.escape(stem)}_\d{{4}}\.vtp")
    if not force:
        for name, source in inputs:
            source = Path(source)
            if pattern.fullmatch(source.name) and _same_file(source.parent, folder):
                raise InputError(
                    f"{option} would write over {name} '{source}'; choose another {option}, or {_FORCE}"
                )
    return path
