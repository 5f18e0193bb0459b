"""``voxflex render``: offscreen pictures and animations of a result file."""

from __future__ import annotations

import argparse

_EPILOG = """\
examples:
  voxflex render result.h5 -o result.png            # the final state
  voxflex render result.h5 -o first.png --step 0    # the rest state
  voxflex render result.h5 -o frames/               # one PNG per step
  voxflex render result.h5 -o result.gif            # animation (.mp4 needs imageio-ffmpeg)

No display is needed (offscreen EGL rendering).
"""


def register(sub) -> None:
    parser = sub.add_parser(
        "render",
        help="render a result file to a picture, a folder of pictures or an animation",
        description="Offscreen picture of the deformed surface coloured by displacement magnitude.",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("result", metavar="RESULT.h5", help="result file written by 'voxflex simulate'")
    parser.add_argument("-o", "--output", required=True, metavar="OUT", help=".png, a folder, .gif or .mp4")
    parser.add_argument("--step", type=int, default=-1, help="state to draw for a .png (default: -1, the last)")
    parser.add_argument(
        "--size", type=int, nargs=2, default=(800, 450), metavar=("W", "H"), help="picture size in pixels"
    )
    parser.add_argument("--title", help="title text (default: the scene's title)")
    parser.add_argument(
        "--force", action="store_true", help="overwrite OUT even when it is not a picture of its kind"
    )
    parser.set_defaults(func=run)


def run(args) -> int:
    from ..rendering import render
    from ..result import Result
    from ._outputs import check_render_output

    check_render_output(args.output, force=args.force)
    result = Result.load(args.result)
    out = render(result, args.output, step=args.step, window_size=tuple(args.size), title=args.title)
    print(f"wrote {out}")
    return 0
