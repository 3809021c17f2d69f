"""``glove track``: track an RGB-D sequence, recording or camera into an output folder."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from tracker.pipeline import Tracker


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "track",
        help="track the glove hand in an RGB-D folder, a .bag recording or a camera",
        description="Track the glove hand frame by frame and write poses.jsonl, an "
        "overlay video, a BVH file, hand.json and a timing summary into --out; with "
        "--stream, --mcap, --view or --rrd, also (or only) send each frame's record there "
        "the moment it is tracked.",
    )
    parser.add_argument("input", help="RGB-D folder, RealSense .bag file, 'realsense' or 'kinect'")
    parser.add_argument("--db", required=True, help="posture database (.h5)")
    parser.add_argument(
        "--out", help="output folder (may be left out when --stream, --mcap, --view or --rrd)"
    )
    add_source_options(parser)
    add_tracker_options(parser)
    parser.add_argument("--no-overlay", action="store_true", help="do not write the overlay video")
    parser.add_argument("--no-bvh", action="store_true", help="do not write the BVH file")
    add_stream_options(parser)
    parser.add_argument(
        "--mcap",
        metavar="FILE",
        help="record each frame's result into an MCAP file (Foxglove, ROS 2 tools)",
    )
    parser.add_argument(
        "--view",
        action="store_true",
        help="show color, labeled point cloud, fitted hand and keypoints live in the rerun "
        "viewer (needs the view extra: scripts/setup.sh --view)",
    )
    parser.add_argument(
        "--rrd", metavar="FILE", help="the same, saved to a rerun .rrd file (view extra)"
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.set_defaults(run=run)


def add_stream_options(parser: argparse.ArgumentParser) -> None:
    """``--stream`` and ``--stream-wait``; shared by ``track`` and ``fingertips detect``."""
    parser.add_argument(
        "--stream",
        metavar="URL",
        help="publish each frame's record live: tcp://HOST:PORT (ZeroMQ PUB, two-part "
        "messages [topic, JSON]) or - (JSON lines on standard output); a slow reader "
        "misses messages, it never slows tracking",
    )
    parser.add_argument(
        "--stream-wait",
        type=float,
        default=0.0,
        metavar="SECONDS",
        help="ZeroMQ: wait up to this long for a first subscriber before the first frame "
        "(default 0)",
    )


def summary_file(args: argparse.Namespace) -> Any:
    """Where a command prints its summary: standard error when standard output carries
    the ``--stream -`` records."""
    return sys.stderr if getattr(args, "stream", None) == "-" else sys.stdout


def add_source_options(parser: argparse.ArgumentParser) -> None:
    """How the input is read; shared by ``track``, ``calibrate`` and ``fingertips detect``."""
    parser.add_argument(
        "--depth-scale",
        type=float,
        help="depth units per metre of the input (default: meta.json, the recording's "
        "metadata or 1000; e.g. 4000 for an L515 .bag)",
    )
    parser.add_argument(
        "--intrinsics",
        metavar="FILE",
        help="intrinsic.json of the color camera, for 'kinect' (whose Open3D interface "
        "does not report it)",
    )


def source_options(args: argparse.Namespace) -> dict[str, Any]:
    """``depth_scale`` and ``intrinsics`` keywords of :func:`tracker.sources.open_source`
    from :func:`add_source_options`' options, checked."""
    from glovedb.camera import load_intrinsics

    options: dict[str, Any] = {}
    if args.depth_scale is not None:
        if not 0 < args.depth_scale < math.inf:
            raise ValueError(f"--depth-scale: expected a positive number, got {args.depth_scale}")
        options["depth_scale"] = args.depth_scale
    if args.intrinsics is not None:
        if str(args.input).lower() != "kinect" or Path(args.input).exists():
            raise ValueError(
                "--intrinsics: only for a live 'kinect' (folders and recordings carry their own)"
            )
        options["intrinsics"] = load_intrinsics(args.intrinsics)
    return options


def add_tracker_options(parser: argparse.ArgumentParser) -> None:
    """Options shared by ``track`` and ``eval``."""
    parser.add_argument(
        "--cascade",
        help="lookup cascade, e.g. 16:500,64:3 (default: 8:1500,16:100,64:3 on the sizes "
        "the database has)",
    )
    parser.add_argument(
        "--colors",
        help="color table (.npz) from glove calibrate (default: DB.colors.npz if present)",
    )
    parser.add_argument("--icp-stride", type=int, help="use every n-th point in ICP")
    parser.add_argument(
        "--no-smoothing",
        action="store_true",
        help="turn the fit's temporal term and the pose filter off",
    )
    parser.add_argument(
        "--fit-iterations",
        type=int,
        help="Levenberg-Marquardt steps of the generative fit per start (default 4)",
    )
    parser.add_argument(
        "--hand",
        metavar="FILE",
        help="the user's hand proportions (hand.json of an earlier run): skip their "
        "online estimation over the first frames",
    )
    parser.add_argument(
        "--temporal-prior",
        type=float,
        help="lookup pull toward the previous frame's posture, pixels per radian "
        "(default 1; 0 turns it off)",
    )
    parser.add_argument(
        "--min-confidence",
        type=float,
        help="fits below this confidence mean no hand (default 0.02; 0 keeps every fit)",
    )
    parser.add_argument(
        "--fingertips",
        action="store_true",
        help="detect fingertips in the depth (the shipped model) and let them pull the "
        "model's fingertips in the generative fit",
    )
    parser.add_argument(
        "--fingertip-model",
        metavar="MODEL",
        help="the same with another fingertip model (from glove fingertips train)",
    )
    parser.add_argument(
        "--fingertip-weight",
        type=float,
        help="weight of a detected fingertip in the generative fit, per metre (default 300; "
        "needs --fingertips)",
    )


def make_tracker(args: argparse.Namespace) -> Tracker:
    """A Tracker configured from the shared options."""
    from dataclasses import replace

    from glove_cli.commands.calibrate import default_table_path
    from glovedb.proportions import load_proportions
    from tracker.classify import load_table
    from tracker.pipeline import Tracker, TrackerSettings

    settings = TrackerSettings()
    if args.cascade:
        settings = replace(settings, cascade=args.cascade)
    if args.icp_stride is not None:
        if not 1 <= args.icp_stride <= 64:
            raise ValueError(f"--icp-stride: expected 1 to 64, got {args.icp_stride}")
        settings = replace(settings, icp_stride=args.icp_stride)
    if args.no_smoothing:
        settings = replace(settings, smoothing=None, fit=replace(settings.fit, temporal_weight=0.0))
    if args.fit_iterations is not None:
        if not 1 <= args.fit_iterations <= 50:
            raise ValueError(f"--fit-iterations: expected 1 to 50, got {args.fit_iterations}")
        settings = replace(settings, fit=replace(settings.fit, iterations=args.fit_iterations))
    if args.hand is not None:
        settings = replace(settings, hand_proportions=load_proportions(args.hand))
    if args.temporal_prior is not None:
        if not 0 <= args.temporal_prior < math.inf:
            raise ValueError(f"--temporal-prior: expected 0 or more, got {args.temporal_prior}")
        settings = replace(settings, temporal_prior_px=args.temporal_prior)
    if args.min_confidence is not None:
        if not 0 <= args.min_confidence <= 1:
            raise ValueError(f"--min-confidence: expected 0 to 1, got {args.min_confidence}")
        settings = replace(settings, min_confidence=args.min_confidence)
    if args.fingertips or args.fingertip_model:
        settings = replace(settings, fingertip_model=args.fingertip_model or "default")
    if args.fingertip_weight is not None:
        if settings.fingertip_model is None:
            raise ValueError("--fingertip-weight: needs --fingertips or --fingertip-model")
        if not 0 <= args.fingertip_weight < math.inf:
            raise ValueError(f"--fingertip-weight: expected 0 or more, got {args.fingertip_weight}")
        settings = replace(
            settings, fit=replace(settings.fit, fingertip_weight=args.fingertip_weight)
        )
    colors = args.colors
    beside = default_table_path(args.db)
    if colors is None and beside.exists():
        colors = beside
        print(f"glove: using the calibrated color table {beside}", file=sys.stderr)
    table = load_table(colors) if colors else None
    return Tracker(args.db, settings=settings, color_table=table)


def progress_bar(description: str) -> Callable[[Iterator, int | None], Iterator]:
    """A progress wrapper for :func:`tracker.run.track_source`."""
    from tqdm import tqdm

    def wrap(frames: Iterator, total: int | None) -> Iterator:
        return iter(tqdm(frames, total=total, desc=description, unit="frame", disable=None,
                         file=sys.stderr))  # fmt: skip

    return wrap


def run(args: argparse.Namespace) -> int:
    import json
    from contextlib import ExitStack

    from tracker.outputs import open_sinks
    from tracker.run import track_source
    from tracker.sources import LIVE_CAMERAS, open_source

    if args.out is None and not (args.stream or args.mcap or args.view or args.rrd):
        raise ValueError("track: give --out, or at least one of --stream, --mcap, --view, --rrd")
    if args.json and args.stream == "-":
        raise ValueError("--json: standard output carries the --stream - records")
    source = open_source(args.input, **source_options(args))
    with make_tracker(args) as tracker, ExitStack() as stack:
        sinks = open_sinks(
            stack, tracker, stream=args.stream, stream_wait_s=args.stream_wait, mcap=args.mcap,
            view=args.view, rrd=args.rrd,
        )  # fmt: skip
        summary = track_source(
            source, tracker, args.out, overlay=not args.no_overlay, bvh=not args.no_bvh,
            sinks=sinks, progress=progress_bar("tracking"),
        )  # fmt: skip
    outputs = dict(summary.outputs)
    for name, value in (("stream", args.stream), ("mcap", args.mcap), ("rrd", args.rrd)):
        if value is not None:
            outputs[name] = str(value)
    if args.json:
        print(json.dumps({**summary.as_dict(), "outputs": outputs}))
        return 0
    out = summary_file(args)
    stopped = " (stopped by Ctrl-C)" if summary.interrupted else ""
    print(f"tracked {summary.frames} frames of {source.description}{stopped}: hand found in "
          f"{summary.found}, {summary.fps:.1f} frames/s", file=out)  # fmt: skip
    print(summary.timing.table(), file=out)
    for name, path in outputs.items():
        print(f"  {name:8s} {path}", file=out)
    # Ctrl-C is how a camera run ends; a recording cut short says so in its exit code.
    return 130 if summary.interrupted and source.kind not in LIVE_CAMERAS else 0
