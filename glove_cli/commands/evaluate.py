"""``glove eval``: track a synthetic sequence and score it against its ground truth."""

from __future__ import annotations

import argparse
from pathlib import Path

from glove_cli.commands.track import add_tracker_options, make_tracker, progress_bar


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "eval",
        help="track a sequence with ground truth and score it",
        description="Track an RGB-D folder that has groundtruth.jsonl and report posture, "
        "rotation, position and keypoint errors, missed frames, fps and stage timings. "
        "Per-frame errors (CSV), an error plot and the tracking outputs go to --out.",
    )
    parser.add_argument("--db", required=True, help="posture database (.h5)")
    parser.add_argument("--sequence", required=True, help="RGB-D folder with groundtruth.jsonl")
    parser.add_argument("--out", help="output folder (default: SEQUENCE/eval)")
    add_tracker_options(parser)
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import json

    import numpy as np

    from tracker.evaluation import read_groundtruth, report_run
    from tracker.run import POSES_FILE, track_source
    from tracker.sources import open_source

    sequence = Path(args.sequence)
    truth = sequence / "groundtruth.jsonl"
    if not truth.is_file():
        raise ValueError(f"{sequence}: no groundtruth.jsonl (not a synthetic sequence)")
    out = Path(args.out) if args.out else sequence / "eval"
    source = open_source(sequence)
    frames = read_groundtruth(truth).frames  # checked before the tracking, not after it
    if source.n_frames is not None and not np.array_equal(frames, np.arange(source.n_frames)):
        raise ValueError(
            f"{truth}: frames {frames[0]}..{frames[-1]}, but the sequence has "
            f"{source.n_frames} images (frames 0..{source.n_frames - 1})"
        )
    with make_tracker(args) as tracker:
        summary = track_source(source, tracker, out, bvh=False, progress=progress_bar("evaluating"))
    title = f"{sequence.name} with {Path(args.db).name}"
    result = report_run(sequence, out / POSES_FILE, out, fps=source.fps or 30.0, title=title)
    figures = {**result.as_dict(), "fps": round(summary.fps, 2),
               "timing_ms": summary.timing.as_dict(), "outputs": str(out)}  # fmt: skip
    if args.json:
        print(json.dumps(figures))
        return 0
    print(f"{sequence}: {result.frames} frames, {result.missed_frames} missed, "
          f"{summary.fps:.1f} frames/s")  # fmt: skip
    for name in (
        "posture_error_deg",
        "rotation_error_deg",
        "position_error_mm",
        "keypoint_error_px",
    ):
        stats = figures[name]
        if stats["mean"] is None:
            continue
        mean, median, worst = stats["mean"], stats["median"], stats["max"]
        print(f"  {name:20s} mean {mean:7.2f}  median {median:7.2f}  max {worst:7.2f}")
    print(f"  outputs in {out}")
    return 0
