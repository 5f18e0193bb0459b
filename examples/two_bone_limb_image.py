"""Make ``two_bone_limb.npz``, the label image of ``two_bone_limb.toml`` (deterministic).

A limb of soft flesh, a box 0.3 x 0.06 x 0.06 m with its lower corner at the origin
(label 1), holding two stiff bones (label 2), boxes 0.02 x 0.02 m in section on the
limb's axis (y = z = 0.03): bone 1 from x = 0 to 0.13, bone 2 from x = 0.17 to 0.30.
The 4 cm of flesh between them is the joint, centred at (0.15, 0.03, 0.03).  Later
labels overwrite earlier ones.  At the default 5 mm voxels the image is 60 x 12 x 12
(8,640 voxels; the .npz is under 1 kB).

    python examples/two_bone_limb_image.py            # writes two_bone_limb.npz next to this script
    python examples/two_bone_limb_image.py 0.01 -o coarse.npz
"""

from __future__ import annotations

import argparse
from pathlib import Path

LENGTH, WIDTH, BONE, GAP = 0.3, 0.06, 0.02, 0.04
JOINT = (LENGTH / 2, WIDTH / 2, WIDTH / 2)
"""Dimensions (m) and the joint centre (world, m)."""


def limb_image(voxel_size: float = 0.005):
    """The two-label limb as a :class:`voxflex.LabelImage` at ``voxel_size`` (m; 0.3, 0.06 and 0.02 m
    should be whole multiples of it for the bones and joint to be sharp)."""
    from voxflex.rasterize import Box, voxelize

    c = (WIDTH - BONE) / 2
    half = (LENGTH - GAP) / 2
    flesh = Box((LENGTH, WIDTH, WIDTH))
    bone1 = Box((half, BONE, BONE), origin=(0.0, c, c))
    bone2 = Box((half, BONE, BONE), origin=(LENGTH - half, c, c))
    return voxelize([(flesh, 1), (bone1, 2), (bone2, 2)], voxel_size, progress=False)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("voxel_size", nargs="?", type=float, default=0.005, help="voxel edge (m), default 0.005")
    parser.add_argument("-o", "--output", type=Path, default=Path(__file__).resolve().parent / "two_bone_limb.npz")
    args = parser.parse_args(argv)
    limb_image(args.voxel_size).save(args.output)
    print(args.output)


if __name__ == "__main__":
    main()
