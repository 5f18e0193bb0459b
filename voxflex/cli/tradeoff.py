"""``voxflex tradeoff``: reduced models against the voxel reference (planned).

The command is reserved by the SPEC; the reduced models it sweeps (affine
frames with natural-neighbour weights and elaston samples) are not built yet,
so it stops with a clear message instead of pretending.
"""

from __future__ import annotations

import argparse

from ..errors import VoxflexError


def register(sub) -> None:
    parser = sub.add_parser(
        "tradeoff",
        help="sweep reduced models against the voxel reference (not implemented yet)",
        description="Run a scene with the full-resolution voxel model and with a sweep of reduced "
        "models, and print the error-versus-time table. Not implemented yet: the reduced "
        "(affine-frame) models it compares are still to be built.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("scene", metavar="SCENE.toml", help="the scene to sweep")
    parser.set_defaults(func=run)


def run(args) -> int:
    raise VoxflexError(
        "tradeoff is not implemented yet: reduced affine-frame models do not exist in this version; "
        "run 'voxflex simulate SCENE.toml' for the voxel reference"
    )
