"""``glove pattern``: the printable glove pattern (palm and back, with a legend)."""

from __future__ import annotations

import argparse


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "pattern",
        help="picture of the glove pattern for painting a real glove",
        description="Write the glove pattern as seen on the back and the palm of the open "
        "right hand, with a legend of the ten colors and the patches they cover.",
    )
    parser.add_argument(
        "--out", default="glove_pattern.png", help="output PNG (default: %(default)s)"
    )
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from builder.figures import check_image_path, pattern_sheet, save_rgb
    from builder.render import GloveRenderer
    from glovedb.camera import KINECT_V1

    check_image_path(args.out)
    with GloveRenderer(KINECT_V1) as renderer:
        path = save_rgb(args.out, pattern_sheet(renderer))
    print(f"wrote {path}")
    return 0
