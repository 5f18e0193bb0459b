"""``voxflex info FILE``: describe a label image, a scene or a result file.

Images (any extension :mod:`voxflex.image.io` reads) are loaded and described
by :meth:`voxflex.LabelImage.describe`; ``.toml`` scenes by
``voxflex.scene.describe_scene``; HDF5 files holding ``/time`` (result files)
by ``voxflex.result_text.describe_result``.  The last two are imported lazily.
"""

from __future__ import annotations

import argparse
import importlib
from pathlib import Path

from ..errors import VoxflexError

_EPILOG = """\
supported image files: .npy (+ NAME.npy.json) .npz .nii .nii.gz .nrrd .mha .mhd
                       .tif .tiff .h5 .hdf5 .vti
examples:
  voxflex info scan.nii.gz
  voxflex info scan.nii.gz --connectivity vertex --largest 10
  voxflex info stack.tif --spacing 1e-5 1e-5 2e-5     # a TIFF that records no voxel size
  voxflex info beam.toml                              # a scene
  voxflex info result.h5                              # a simulation result
"""


def register(sub) -> None:
    parser = sub.add_parser(
        "info",
        help="describe an image, a scene or a result file",
        description="Describe a label image (shape, spacing, origin, direction, labels with their "
        "voxel counts, volumes and parts, the connected components of the material by face "
        "connectivity with the largest listed, memory), a scene file (.toml) or a "
        "result file (.h5 holding /time). Lengths are in metres; the world frame is LPS for "
        "medical formats (see voxflex.image.io).",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("file", metavar="FILE", help="image, scene (.toml) or result (.h5) file")
    parser.add_argument(
        "--spacing",
        nargs=3,
        type=float,
        metavar=("SX", "SY", "SZ"),
        help="voxel size in metres for image files that record none (a bare .npy, a plain TIFF)",
    )
    parser.add_argument(
        "--connectivity",
        default="face",
        choices=("face", "edge", "vertex"),
        help="neighbourhood for connected parts and components: voxels sharing a face (6 neighbours, "
        "default: what holds a body together mechanically), a face or an edge (18), or touching at all (26)",
    )
    parser.add_argument(
        "--largest",
        type=int,
        default=5,
        metavar="N",
        help="list the N largest components with their voxel count, labels and box (default 5)",
    )
    parser.set_defaults(func=run)


def _describer(module_name: str, function: str, what: str):
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name not in (module_name, None):
            raise
        module = None
    func = getattr(module, function, None)
    if func is None:
        raise VoxflexError(f"describing {what} files is not available in this build; 'voxflex info' reads images only")
    return func


def _is_result_file(path: Path) -> bool:
    import h5py

    try:
        with h5py.File(str(path), "r") as f:
            try:
                return "time" in f or "voxflex_version" in f.attrs
            except (RuntimeError, KeyError, ValueError):
                return "voxflex_version" in f.attrs or f.attrs.get("format") is not None  # damaged: Result.load says so
    except (OSError, RuntimeError, KeyError, ValueError):
        return False  # not HDF5: the image reader reports it


def run(args) -> int:
    path = Path(args.file)
    if not path.is_file():
        from ..errors import missing_file

        raise missing_file(path, "file")
    name = path.name.lower()
    if name.endswith(".toml"):
        text = _describer("voxflex.scene", "describe_scene", "scene")(path)
    elif name.endswith((".h5", ".hdf5")) and _is_result_file(path):
        text = _describer("voxflex.result_text", "describe_result", "result")(path)
    else:
        from ..image import LabelImage

        image = LabelImage.load(path, spacing=args.spacing)
        text = f"{path}\n" + image.describe(connectivity=args.connectivity, largest=args.largest)
    print(text)
    return 0
