"""``glove demo``: the main job on embedded defaults, start to finish.

1. build the thesis database DB_open+pinch+power (or reuse it from the cache);
2. render a synthetic pinch-grasp sequence (trajectory tr1) with Kinect-like depth
   and color noise;
3. track it and score it against its ground truth;
4. print our errors next to the thesis' (Figure 4.6) and write the overlay video,
   the error plot and the per-frame errors.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
from pathlib import Path

# Thesis Figure 4.6 (DB_open+pinch+power on Tr1-Tr5, 4 cores, about 15 Hz): ranges of
# the per-trajectory mean errors.
THESIS = {
    "posture_error_deg": (2.2, 4.9),
    "rotation_error_deg": (3.0, 5.6),
    "position_error_mm": (4.0, 6.0),
}
THESIS_FPS = 15.0


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "demo",
        help="run the main job on embedded defaults",
        description="Build (or reuse) the open+pinch+power database, render a noisy "
        "synthetic pinch sequence, track it, and compare the errors with the thesis.",
    )
    parser.add_argument("--out", default="glove_demo", help="output folder (default: %(default)s)")
    parser.add_argument("--frames", type=int, default=120, help="frames of the sequence (30 fps)")
    parser.add_argument("--trajectory", default="tr1", help="trajectory name or file")
    parser.add_argument(
        "--cache",
        default=None,
        help="where the database is kept (default: $GLOVE_CACHE, else ~/.cache/glove)",
    )
    parser.set_defaults(run=run)


def database_cache(cache: str | None) -> Path:
    """The cache folder: ``--cache``, else :func:`glovedb.cache.cache_folder`."""
    from glovedb.cache import cache_folder

    return Path(cache) if cache else cache_folder()


def cached_database(cache: Path, workers: int) -> Path:
    """The open+pinch+power database, built into the cache unless an identical build is
    there (the file name carries a hash of the settings, the project version, and the
    source and data files that decide the database's contents)."""
    from builder.build import build_database, stored_settings
    from builder.config import load_config
    from glovedb.resources import config_path

    config = load_config(config_path("db/open_pinch_power.toml"))
    digest = hashlib.sha256(json.dumps(stored_settings(config), sort_keys=True).encode())
    # The code that makes the bytes is part of the key, so a changed builder rebuilds.
    for package in ("glovedb", "builder"):
        for source in sorted((Path(__file__).resolve().parents[2] / package).glob("*.py")):
            digest.update(source.read_bytes())
    for data in ("glove/pattern.toml", "hand/postures.toml"):
        digest.update(config_path(data).read_bytes())
    path = cache / f"open_pinch_power-{digest.hexdigest()[:12]}.h5"
    if path.exists():
        print(f"database: reusing {path}")
        return path
    cache.mkdir(parents=True, exist_ok=True)
    print(f"database: building {config.name} into {path}")
    report = build_database(
        config, path, workers=workers, resume=path.with_name(path.name + ".parts").exists()
    )
    print(f"  {report.entries:,} entries in {report.seconds:.1f} s")
    return path


def _rendered_by_glove(folder: Path) -> bool:
    """Whether ``folder`` is a sequence that ``glove render-sequence`` (or a demo) wrote:
    only such a folder is deleted to render the demo's sequence again."""
    try:
        meta = json.loads((folder / "meta.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(meta, dict) and meta.get("generator") == "glove render-sequence"


def run(args: argparse.Namespace) -> int:
    import shutil

    from builder.sequence import SequenceSettings, render_sequence, resolve_trajectory
    from glove_cli.commands.track import progress_bar
    from glovedb.trajectory import load_trajectory
    from tracker.evaluation import report_run
    from tracker.pipeline import Tracker
    from tracker.run import POSES_FILE, track_source
    from tracker.sources import open_source

    if args.frames < 1:
        raise ValueError("--frames must be at least 1")
    load_trajectory(resolve_trajectory(args.trajectory))  # a bad name fails before any output
    out = Path(args.out)
    sequence = out / "sequence"
    if sequence.exists():
        if not _rendered_by_glove(sequence):
            raise ValueError(f"{sequence}: not a rendered sequence, left alone; use another --out")
        shutil.rmtree(sequence)  # the previous demo's: rendered again below
    cache = database_cache(args.cache)
    if cache.exists() and not cache.is_dir():
        raise ValueError(f"--cache: {cache} is a file, expected a folder")
    out.mkdir(parents=True, exist_ok=True)
    database = cached_database(cache, os.cpu_count() or 1)

    settings = SequenceSettings(
        trajectory=args.trajectory, frames=args.frames, noise="kinect_v1", background="plain"
    )
    print(f"sequence: rendering {args.frames} frames of {args.trajectory} with Kinect noise")
    render_sequence(settings, sequence, progress=progress_bar("rendering"))

    tracking = out / "tracking"
    with Tracker(database) as tracker:
        summary = track_source(
            open_source(sequence), tracker, tracking, progress=progress_bar("tracking")
        )
    title = f"{args.trajectory}, DB_open+pinch+power"
    result = report_run(sequence, tracking / POSES_FILE, out, fps=30.0, title=title)
    figures = result.as_dict()
    print()
    print(f"{result.frames} frames, hand found in {summary.found}, {result.missed_frames} missed")
    print(f"{'':22s}{'ours (mean)':>14s}{'ours (median)':>15s}{'thesis (Fig. 4.6)':>20s}")
    for name, (low, high) in THESIS.items():
        stats = figures[name]
        mean = "-" if stats["mean"] is None else f"{stats['mean']:.2f}"
        median = "-" if stats["median"] is None else f"{stats['median']:.2f}"
        print(f"{name:22s}{mean:>14s}{median:>15s}{f'{low:g}-{high:g}':>20s}")
    print(
        f"{'frames per second':22s}{summary.fps:>14.1f}{'':>15s}{f'{THESIS_FPS:g} (4 cores)':>20s}"
    )
    print()
    print(summary.timing.table())
    print(f"outputs: {out}/errors.png, {out}/errors.csv, {tracking}/ (poses.jsonl, overlay, BVH)")
    (out / "summary.json").write_text(
        json.dumps({**figures, "fps": summary.fps, "timing_ms": summary.timing.as_dict()}, indent=1)
    )
    return 0
