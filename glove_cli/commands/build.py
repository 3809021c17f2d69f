"""``glove build``: build a posture database from a TOML config."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Iterator


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "build",
        help="build a posture database (HDF5) from a config",
        description="Render the glove hand in the config's postures from every view and "
        "write the tiny images into an HDF5 database. The file appears only when it is "
        "complete; an interrupted build continues with --resume.",
    )
    parser.add_argument("config", help="database config, e.g. configs/db/grasp20.toml")
    parser.add_argument("--out", required=True, help="database file to write (.h5)")
    parser.add_argument(
        "--workers",
        type=int,
        default=os.cpu_count() or 1,
        help="worker processes, or the CPUs of the local Ray instance (default: all cores)",
    )
    parser.add_argument(
        "--executor",
        choices=("local", "ray"),
        default="local",
        help="render in local processes (default) or on Ray actors (pip install -e '.[ray]')",
    )
    parser.add_argument(
        "--address",
        help="Ray cluster address HOST:PORT, or 'auto' for the running cluster "
        "(default: start a local Ray instance with --workers CPUs)",
    )
    parser.add_argument("--resume", action="store_true", help="continue an interrupted build")
    parser.add_argument(
        "--json", action="store_true", help="print one JSON object with the figures"
    )
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import json

    from tqdm import tqdm

    from builder.build import build_database
    from builder.config import load_config

    config = load_config(args.config)

    def bar(finished: Iterator[int], remaining: int) -> Iterator[int]:
        return iter(
            tqdm(finished, total=remaining, desc=f"building {config.name}", unit="posture",
                 disable=None, file=sys.stderr)
        )  # fmt: skip

    report = build_database(
        config,
        args.out,
        workers=args.workers,
        resume=args.resume,
        progress=bar,
        executor=args.executor,
        address=args.address,
    )
    where = f"{args.workers} worker(s)" if args.executor == "local" else "Ray"
    figures = {
        "path": report.path,
        "entries": report.entries,
        "postures": report.postures,
        "rendered_postures": report.rendered_postures,
        "seconds": round(report.seconds, 2),
        "entries_per_second": round(report.entries_per_second, 1),
        "render_entries_per_second": round(report.render_entries_per_second, 1),
        "plan_seconds": round(report.plan_seconds, 2),
        "render_seconds": round(report.render_seconds, 2),
        "write_seconds": round(report.write_seconds, 2),
        "workers": args.workers,
        "executor": args.executor,
    }
    if args.json:
        print(json.dumps(figures))
    else:
        print(
            f"wrote {report.path}: {report.entries:,} entries ({report.postures} postures) in "
            f"{report.seconds:.1f} s, {report.entries_per_second:,.0f} entries/s on {where} "
            f"(planning {report.plan_seconds:.1f} s, rendering {report.render_seconds:.1f} s "
            f"at {report.render_entries_per_second:,.0f} entries/s, writing the file "
            f"{report.write_seconds:.1f} s)"
        )
    return 0
