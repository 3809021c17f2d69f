"""``glove calibrate``: learn the color table of the user's real glove."""

from __future__ import annotations

import argparse
import itertools
from pathlib import Path

from glove_cli.commands.track import add_source_options, source_options


def default_table_path(database: str | Path) -> Path:
    """Where a database's calibrated color table lives: ``DB.colors.npz`` beside it."""
    path = Path(database)
    return path.with_name(path.stem + ".colors.npz")


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "calibrate",
        help="learn the color table of your glove from a few frames",
        description="Track a few frames showing the glove from several sides, take the "
        "colors of the pixels the fitted model covers, and learn the color table from "
        "them. The table is saved beside the database (DB.colors.npz), where glove track "
        "and glove eval pick it up.",
    )
    parser.add_argument("input", help="RGB-D folder, .bag file, 'realsense' or 'kinect'")
    parser.add_argument("--db", required=True, help="posture database (.h5)")
    parser.add_argument(
        "--out", help="table file (default: beside the database; only an earlier table is replaced)"
    )
    parser.add_argument("--frames", type=int, default=30, help="frames to use (default: 30)")
    parser.add_argument("--every", type=int, default=5, help="use every n-th frame (default: 5)")
    add_source_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from tracker.calibrate import calibrate
    from tracker.classify import load_table
    from tracker.pipeline import Tracker
    from tracker.sources import open_source

    if args.frames < 1 or args.every < 1:
        raise ValueError("--frames and --every must be at least 1")
    if args.out == "":
        raise ValueError("--out: expected a file name")
    out = Path(args.out) if args.out is not None else default_table_path(args.db)
    if out.suffix != ".npz":
        raise ValueError(f"{out}: the color table is saved as .npz")
    if not out.parent.is_dir():
        raise ValueError(f"{out.parent}: folder does not exist")
    if out.exists():
        if out.resolve() == Path(args.db).resolve():
            raise ValueError(f"{out}: that is the database; choose another --out")
        load_table(out)  # only an earlier color table is replaced, nothing else
    source = open_source(args.input, **source_options(args))
    frames = list(itertools.islice(source, 0, args.frames * args.every, args.every))
    with Tracker(args.db) as tracker:
        result = calibrate(frames, tracker)
    result.table.save(out)
    print(
        f"wrote {out}: learned from {result.glove_samples:,} glove and "
        f"{result.background_samples:,} background pixels of {result.frames_used} frames"
    )
    return 0
