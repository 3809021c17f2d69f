"""``glove render``: a picture of the glove hand in a named posture."""

from __future__ import annotations

import argparse
import math

from glovedb.views import NAMED_VIEWS


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "render",
        help="render the glove hand in a posture (color, labels, depth side by side)",
        description="Render the glove hand in a named posture and write color, class "
        "labels and depth side by side to a PNG.",
    )
    parser.add_argument("--posture", required=True, help="named posture, e.g. open, pinch, power")
    parser.add_argument(
        "--out", default="glove_render.png", help="output PNG (default: %(default)s)"
    )
    parser.add_argument(
        "--view", default="back", choices=sorted(NAMED_VIEWS), help="direction to look from"
    )
    parser.add_argument(
        "--azimuth",
        type=float,
        help="degrees about the hand's y axis from the back (overrides --view)",
    )
    parser.add_argument(
        "--elevation",
        type=float,
        help="degrees toward the fingertips (with --azimuth; default 0)",
    )
    parser.add_argument(
        "--distance", type=float, default=0.35, help="camera distance in metres (0.1 to 5)"
    )
    parser.add_argument("--hand-length", type=float, default=0.19, help="hand length in metres")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from builder.figures import check_image_path, rendering_panels, save_rgb, title_bar
    from builder.render import GloveRenderer
    from glovedb.camera import KINECT_V1
    from glovedb.hand_model import make_skeleton
    from glovedb.mesh import make_hand_mesh
    from glovedb.postures import named_posture
    from glovedb.views import HAND_CENTRE, named_view, pose_for_view, view_direction

    check_image_path(args.out)
    if args.elevation is not None and args.azimuth is None:
        raise ValueError("--elevation needs --azimuth (it tilts that direction)")
    if not 0.1 <= args.distance <= 5:
        raise ValueError(
            f"--distance: expected 0.1 to 5 m (the camera's range), got {args.distance}"
        )
    for option, angle in (("--azimuth", args.azimuth), ("--elevation", args.elevation)):
        if angle is not None and not math.isfinite(angle):
            raise ValueError(f"{option}: expected a finite angle in degrees, got {angle}")
    elevation = args.elevation or 0.0
    posture = named_posture(args.posture)
    skeleton = make_skeleton(args.hand_length)
    if args.azimuth is not None:
        direction = view_direction(math.radians(args.azimuth), math.radians(elevation))
        target = np.array(HAND_CENTRE) * skeleton.hand_length_m
        rotation, translation = pose_for_view(direction, args.distance, target_m=target)
        view = f"azimuth {args.azimuth:g}, elevation {elevation:g}"
    else:
        rotation, translation = named_view(args.view, args.distance, skeleton.hand_length_m)
        view = f"{args.view} view"
    with GloveRenderer(KINECT_V1, mesh=make_hand_mesh(skeleton)) as renderer:
        rendering = renderer.render(posture, rotation, translation)
        picture = rendering_panels(rendering, renderer.pattern)
    picture = title_bar(picture, f"{args.posture}, {view}, {args.distance:g} m")
    path = save_rgb(args.out, picture)
    print(f"wrote {path} ({picture.shape[1]}x{picture.shape[0]}: color | labels | depth)")
    return 0
