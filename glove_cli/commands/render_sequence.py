"""``glove render-sequence``: a synthetic RGB-D sequence with ground truth."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterable, Iterator
from typing import Any


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
        help="named trajectory (tr1 ... tr5, or a file stem in configs/trajectories/) "
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
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from builder.sequence import SequenceSettings, render_sequence

    settings = SequenceSettings(
        trajectory=args.trajectory,
        camera=args.camera,
        frames=args.frames,
        seed=args.seed,
        background=args.background,
        noise=args.noise,
    )

    def bar(frames: Iterator[Any], total: int) -> Iterable[Any]:
        return tqdm(frames, total=total, desc="rendering", unit="frame", disable=None,
                    file=sys.stderr)  # fmt: skip

    report = render_sequence(settings, args.out, progress=bar)
    print(
        f"wrote {report.path}: {report.frames} frames ({report.visible_frames} with the hand "
        f"in view) in {report.seconds:.1f} s"
    )
    return 0
