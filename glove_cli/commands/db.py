"""``glove db info``: what a posture database holds."""

from __future__ import annotations

import argparse


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("db", help="inspect posture databases")
    actions = parser.add_subparsers(dest="db_command", metavar="ACTION", parser_class=type(parser))
    actions.required = True
    info = actions.add_parser(
        "info",
        help="entries, postures, views, resolutions, size, format version",
        description="Print what a posture database holds.",
    )
    info.add_argument("database", help="database file (.h5)")
    info.add_argument("--json", action="store_true", help="print one JSON object")
    info.set_defaults(run=run_info)


def run_info(args: argparse.Namespace) -> int:
    import json

    from glovedb.database import GloveDatabase

    with GloveDatabase(args.database) as database:
        info = database.info()
    if args.json:
        print(json.dumps(info.as_dict()))
        return 0
    print(f"{info.path}: {info.name}")
    print(f"  entries            {info.entries:,}")
    print(f"  postures           {info.postures:,}")
    print(f"  views per posture  {info.views_per_posture} "
          f"({info.camera_positions} camera positions x {info.rolls} rolls)")  # fmt: skip
    print(f"  resolutions        {', '.join(f'{s}x{s}' for s in info.resolutions)}")
    print(f"  size               {info.size_bytes / 2**20:,.1f} MiB "
          f"({info.size_bytes / max(info.entries, 1):,.0f} bytes per entry)")  # fmt: skip
    print(f"  format version     {info.format_version}")
    print(f"  built by           glove {info.project_version}")
    return 0
