"""``voxflex render``: offscreen pictures and animations of a result file."""

from __future__ import annotations

import argparse

_EPILOG = """\
examples:
  voxflex render result.h5 -o result.png            # the final state
  voxflex render result.h5 -o first.png --step 0    # the rest state
  voxflex render result.h5 -o frames/               # one PNG per step
  voxflex render result.h5 -o result.gif            # animation (.mp4 needs imageio-ffmpeg)
  voxflex render cow.h5 -o cow.png --view side --up y          # a y-up model seen from its side
  voxflex render beam.h5 -o beam.png --azimuth 20 --elevation 10
  voxflex render beam.h5 -o vm.png --color von-mises  # a field the result carries

views (about the --up axis): iso (azimuth 45, elevation 35.26), front (0, 0),
side (90, 0), top (0, 90); --azimuth/--elevation override the named view's angles.
The camera fits the rest and deformed shapes of every step; the colour range
spans the whole run.

No display is needed (offscreen EGL rendering).
"""


def register(sub) -> None:
    parser = sub.add_parser(
        "render",
        help="render a result file to a picture, a folder of pictures or an animation",
        description="Offscreen picture of the deformed surface coloured by displacement magnitude (or a result field), "
        "with the faint rest shape, an axes triad and the gravity direction.",
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
    parser.add_argument("--view", choices=("iso", "front", "side", "top"), default="iso",
                        help="named camera direction (default: iso)")
    parser.add_argument("--azimuth", type=float, metavar="DEG", help="camera azimuth about the up axis, degrees")
    parser.add_argument("--elevation", type=float, metavar="DEG", help="camera elevation, degrees in [-90, 90]")
    parser.add_argument("--up", choices=("x", "y", "z"), default="z",
                        help="world axis drawn vertical (default: z; y for y-up models)")
    parser.add_argument("--color", default="displacement", metavar="NAME",
                        help="colour by 'displacement' (magnitude, the default) or by a field of the result "
                        "(e.g. von-mises)")
    parser.add_argument("--cmap", default="viridis", metavar="NAME", help="matplotlib colour map (default: viridis)")
    parser.add_argument("--fps", type=int, default=8, help="frames per second of an animation (default: 8)")
    parser.add_argument("--no-rest", action="store_true", help="do not draw the faint rest silhouette")
    parser.add_argument("--no-axes", action="store_true", help="do not draw the axes triad")
    parser.add_argument("--no-gravity", action="store_true", help="do not draw the gravity arrow")
    parser.add_argument("--no-frames", action="store_true", help="do not draw the frames of an affine model")
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
    out = render(
        result,
        args.output,
        step=args.step,
        window_size=tuple(args.size),
        title=args.title,
        view=args.view,
        azimuth=args.azimuth,
        elevation=args.elevation,
        up=args.up,
        color=args.color,
        cmap=args.cmap,
        fps=args.fps,
        show_rest=not args.no_rest,
        axes=not args.no_axes,
        gravity=not args.no_gravity,
        frames=not args.no_frames,
    )
    print(f"wrote {out}")
    return 0
