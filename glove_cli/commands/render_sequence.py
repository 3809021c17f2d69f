"""``glove render-sequence``: a synthetic RGB-D sequence with ground truth."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterable, Iterator
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from builder.sequence import SequenceSettings


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    from builder.depth_noise import NOISE_PRESETS

    parser = subparsers.add_parser(
        "render-sequence",
        help="render a trajectory into an RGB-D folder with ground truth",
        description="Render the glove hand along a trajectory in front of a background, "
        "add camera noise and write intrinsic.json, color/, depth/, meta.json and "
        "groundtruth.jsonl (the RGB-D folder layout). See docs/synthetic_data.md.",
    )
    parser.add_argument(
        "--trajectory",
        required=True,
        help="named trajectory (tr1 ... tr5, free, or a file stem in configs/trajectories/) "
        "or a trajectory JSON file",
    )
    parser.add_argument("--out", required=True, help="output folder (new or empty)")
    parser.add_argument(
        "--camera",
        default="kinect_v1",
        help="camera preset in configs/camera/ (kinect_v1, realsense_d435) or a TOML "
        "file (default: %(default)s)",
    )
    parser.add_argument(
        "--frames", type=int, help="number of frames (default: the whole trajectory)"
    )
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    parser.add_argument(
        "--background",
        default="plain",
        help="scene behind the hand: plain, clutter or table (default: %(default)s)",
    )
    parser.add_argument(
        "--noise",
        default="none",
        choices=NOISE_PRESETS,
        help="depth and color noise of a camera (default: %(default)s)",
    )
    hand = parser.add_argument_group("the hand's shape (default: the model hand)")
    hand.add_argument(
        "--hand-length",
        type=float,
        metavar="M",
        help="wrist crease to the middle fingertip, metres, 0.095-0.38 (default: 0.19); "
        "the whole hand scales about the wrist",
    )
    hand.add_argument(
        "--finger-length",
        metavar="F[,F,F,F,F]",
        help="finger length factors, 0.5-2: one for all five fingers or five, thumb "
        "first (default: 1)",
    )
    hand.add_argument(
        "--palm-width", type=float, metavar="F", help="palm width factor, 0.5-2 (default: 1)"
    )
    occluder = parser.add_argument_group(
        "an occluder: a ball passing in front of the hand",
        "Write a leading minus with '=': --occluder-from=-0.1,0,-0.05.",
    )
    occluder.add_argument(
        "--occluder-radius",
        type=float,
        metavar="M",
        help="the ball's radius, metres (default: 0, no ball)",
    )
    occluder.add_argument(
        "--occluder-from",
        metavar="X,Y,Z",
        help="the ball's centre relative to the hand's centre at the first frame, camera "
        "frame (x right, y down, z away), metres (default: -0.12,0,-0.04)",
    )
    occluder.add_argument(
        "--occluder-to",
        metavar="X,Y,Z",
        help="the same at the last frame; the ball moves linearly in between "
        "(default: 0.12,0,-0.04)",
    )
    parser.add_argument(
        "--misregistration",
        metavar="DU[,DV]",
        help="shift of the color image against depth, pixels right and down (sub-pixel "
        "allowed); one number shifts horizontally (default: 0,0)",
    )
    parser.add_argument(
        "--light",
        type=float,
        metavar="F",
        help="the room's light against the noise preset's, in (0, 1]: a dim room raises "
        "the camera's gain and color noise (up to 4x) and darkens the image beyond "
        "that; needs --noise (default: 1)",
    )
    parser.set_defaults(run=run)


def numbers(option: str, text: str, counts: tuple[int, ...]) -> tuple[float, ...]:
    """The comma-separated numbers of an option's value.

    Parameters
    ----------
    option : str
        The option's name, for the error message.
    text : str
        E.g. ``"-0.12,0,-0.04"``.
    counts : tuple of int
        How many numbers are allowed.

    Returns
    -------
    tuple of float

    Raises
    ------
    ValueError
        Naming the option, when a part is not a number or the count is not allowed.
    """
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError:
        values = ()
    if len(values) not in counts:
        allowed = " or ".join(map(str, counts))
        raise ValueError(f"{option}: expected {allowed} comma-separated numbers, got {text!r}")
    return values


def settings_from_args(args: argparse.Namespace) -> SequenceSettings:
    """The :class:`~builder.sequence.SequenceSettings` of parsed arguments; options not
    given keep the settings' defaults."""
    from builder.sequence import SequenceSettings

    options: dict[str, Any] = {}
    if args.hand_length is not None:
        options["hand_length_m"] = args.hand_length
    if args.finger_length is not None:
        factors = numbers("--finger-length", args.finger_length, (1, 5))
        options["finger_length"] = factors * 5 if len(factors) == 1 else factors
    if args.palm_width is not None:
        options["palm_width"] = args.palm_width
    if args.occluder_radius is not None:
        options["occluder_radius_m"] = args.occluder_radius
    if args.occluder_from is not None:
        options["occluder_from_m"] = numbers("--occluder-from", args.occluder_from, (3,))
    if args.occluder_to is not None:
        options["occluder_to_m"] = numbers("--occluder-to", args.occluder_to, (3,))
    if args.misregistration is not None:
        shift = numbers("--misregistration", args.misregistration, (1, 2))
        options["misregistration_px"] = shift if len(shift) == 2 else (shift[0], 0.0)
    if args.light is not None:
        options["light"] = args.light
    return SequenceSettings(
        trajectory=args.trajectory,
        camera=args.camera,
        frames=args.frames,
        seed=args.seed,
        background=args.background,
        noise=args.noise,
        **options,
    )


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from builder.sequence import render_sequence

    settings = settings_from_args(args)

    def bar(frames: Iterator[Any], total: int) -> Iterable[Any]:
        return tqdm(frames, total=total, desc="rendering", unit="frame", disable=None,
                    file=sys.stderr)  # fmt: skip

    report = render_sequence(settings, args.out, progress=bar)
    print(
        f"wrote {report.path}: {report.frames} frames ({report.visible_frames} with the hand "
        f"in view) in {report.seconds:.1f} s"
    )
    return 0
