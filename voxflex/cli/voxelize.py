"""``voxflex voxelize``: surface meshes and primitives -> a label image file."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import InputError

_EPILOG = """\
inputs:
  a surface mesh (.stl .obj .ply .vtk .vtp; need not be watertight: holes and
  duplicated seams are handled by the generalized winding number), or a
  primitive spec with its bounding box's lower corner at the origin:
    box:LX,LY,LZ   cylinder:R,L (axis z)   sphere:R        (metres)

grid:
  origin = lower corner of the inputs' bounding box minus PADDING voxels;
  voxels per axis = ceil(extent / H) (+ 2 PADDING); a voxel is material when
  its centre is inside (with --occupancy: when any part of it is, and the
  fraction is stored where the format can hold it: .npz .h5 .vti).

examples:
  voxflex voxelize box:4,1,1 -o beam.nii.gz --voxel-size 0.125      # 32x8x8, all ones
  voxflex voxelize part.stl -o part.nrrd --voxel-size 0.002 --padding 1
  voxflex voxelize bunny.obj -o bunny.npz --voxel-size 1e-3 --occupancy
  voxflex voxelize cow.obj -o cow.nii.gz --voxel-size 0.1 --up y    # a y-up mesh stands on z
  voxflex voxelize box:2,2,2 sphere:0.5 -o two.nii.gz --voxel-size 0.05
        (two labels: 1 = the box, 2 = the ball; later inputs overwrite earlier ones)
  voxflex voxelize shell.stl core.stl -o parts.h5 --voxel-size 0.01 --labels 3 7
"""


def register(sub) -> None:
    parser = sub.add_parser(
        "voxelize",
        help="turn surface meshes or primitives into a label image",
        description="Rasterize one or more surface meshes or primitives into ONE label image "
        "(label 0 = empty). OUT's extension picks the format: .npy .npz .nii .nii.gz .nrrd .mha "
        ".tif .h5 .vti. Prints a one-line summary (shape, voxels per label, volume).",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("inputs", nargs="+", metavar="INPUT", help="mesh file or primitive spec (several: multi-label)")
    parser.add_argument("-o", "--output", required=True, metavar="OUT", help="image file to write (atomic)")
    parser.add_argument(
        "--voxel-size",
        required=True,
        nargs="+",
        type=float,
        metavar="H",
        help="voxel edge length in metres: one value, or three (x y z)",
    )
    parser.add_argument(
        "--occupancy",
        action="store_true",
        help="also compute the fraction of each voxel inside (partial volume); boundary voxels "
        "holding any material become material",
    )
    parser.add_argument(
        "--up",
        choices=("x", "y", "z"),
        default="z",
        help="the inputs' axis that should point up: they are turned about the origin so that it becomes +z "
        "(y for y-up meshes such as most OBJ models; default z, no turn)",
    )
    parser.add_argument("--padding", type=int, default=0, metavar="N", help="empty voxels on every side (default 0)")
    parser.add_argument(
        "--labels",
        nargs="+",
        type=int,
        metavar="L",
        help="label of each input, in order (default 1 2 3 ...); 1..65535",
    )
    parser.add_argument(
        "--max-memory",
        type=float,
        default=None,
        metavar="GIB",
        help="refuse grids needing more working memory (default: min(4 GiB, half the free memory))",
    )
    parser.add_argument(
        "--force",
        action="store_true",
        help="overwrite OUT even when it is not an image of its format, or is a simulation result",
    )
    parser.set_defaults(func=run)


def run(args) -> int:
    from ..rasterize import voxelize

    if len(args.voxel_size) not in (1, 3):
        raise InputError(f"--voxel-size takes 1 or 3 values, got {len(args.voxel_size)}; e.g. --voxel-size 0.01")
    labels = args.labels or list(range(1, len(args.inputs) + 1))
    if len(labels) != len(args.inputs):
        raise InputError(
            f"--labels gives {len(labels)} label(s) for {len(args.inputs)} input(s); give one label per input"
        )
    if len(set(labels)) != len(labels):
        raise InputError(f"--labels repeats a label ({' '.join(map(str, labels))}); give each input its own label")
    if args.padding < 0:
        raise InputError(f"--padding must be >= 0, got {args.padding}")
    max_bytes = None
    if args.max_memory is not None:
        if not args.max_memory > 0:
            raise InputError(f"--max-memory must be > 0 GiB, got {args.max_memory}")
        max_bytes = int(args.max_memory * 1024**3)
    from ._outputs import check_image_output

    inputs = [(f"input {src}", Path(src)) for src in args.inputs if Path(src).exists()]
    check_image_output(args.output, inputs=inputs, force=args.force)
    sources = [(src, lab) for src, lab in zip(args.inputs, labels)]
    image = voxelize(
        sources if len(sources) > 1 else sources[0][0],
        args.voxel_size[0] if len(args.voxel_size) == 1 else args.voxel_size,
        occupancy=args.occupancy,
        label=labels[0],
        padding=args.padding,
        max_bytes=max_bytes,
        progress=True,
        up=args.up,
    )
    image.save(args.output)
    print(summary(image, args.output))
    return 0


def summary(image, path) -> str:
    """One line: file, shape, voxel size, voxels (and volume) per label, total volume."""
    import numpy as np

    counts = np.bincount(image.labels.ravel())
    vv = image.voxel_volume
    parts = []
    total = 0.0
    for lab in np.flatnonzero(counts[1:]) + 1:
        mask = image.labels == lab
        vol = float(image.occupancy[mask].sum()) * vv if image.occupancy is not None else counts[lab] * vv
        total += vol
        parts.append(f"label {lab}: {counts[lab]} voxels ({vol:.4g} m^3)")
    shape = "x".join(str(s) for s in image.shape)
    h = image.spacing
    size = f"{h[0]:.4g}" if np.all(h == h[0]) else "x".join(f"{x:.4g}" for x in h)
    kind = "occupancy-weighted " if image.occupancy is not None else ""
    return f"wrote {path}: {shape} voxels of {size} m; {'; '.join(parts)}; {kind}volume {total:.6g} m^3"
