"""``glove bench lookup``: search latency, throughput, memory and accuracy."""

from __future__ import annotations

import argparse


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("bench", help="benchmarks")
    kinds = parser.add_subparsers(
        dest="bench_command", metavar="BENCHMARK", parser_class=type(parser)
    )
    kinds.required = True
    lookup = kinds.add_parser(
        "lookup",
        help="speed and accuracy of the cascaded database search",
        description="Search held-out rendered queries (postures and views not in the "
        "database, with label noise) and report latency, throughput, resident memory "
        "and accuracy against brute force.",
    )
    lookup.add_argument("--db", required=True, help="database file (.h5)")
    lookup.add_argument("--cascade", default="8:2000,16:300,64:3", help="e.g. 16:500,64:3")
    lookup.add_argument("--entries", type=int, help="tile the database to this many entries")
    lookup.add_argument("--queries", type=int, default=20, help="number of queries")
    lookup.add_argument("--workers", type=int, help="search threads (default: all cores)")
    lookup.add_argument(
        "--coarse-maps",
        choices=("cell_mean", "exact"),  # glovedb.search.COARSE_MAPS, not imported: slow
        default="cell_mean",
        help="query maps of the stages before the last (default: cell_mean)",
    )
    lookup.add_argument("--json", action="store_true", help="print one JSON object")
    lookup.set_defaults(run=run_lookup)


def run_lookup(args: argparse.Namespace) -> int:
    import json

    from builder.lookup_bench import run_lookup_benchmark

    if args.queries < 1:
        raise ValueError("--queries must be at least 1")
    if args.entries is not None and args.entries < 1:
        raise ValueError(f"--entries must be at least 1, got {args.entries}")
    figures = run_lookup_benchmark(
        args.db, cascade=args.cascade, entries=args.entries, queries=args.queries,
        workers=args.workers, coarse_maps=args.coarse_maps,
    ).as_dict()  # fmt: skip
    if args.json:
        print(json.dumps(figures))
        return 0
    latency = figures["latency_ms"]
    print(f"{args.db}: {figures['entries']:,} entries ({figures['base_entries']:,} in the file)")
    print(f"  cascade            {figures['cascade']}")
    print(f"  latency            median {latency['median']:.2f} ms, p95 {latency['p95']:.2f} ms")
    print(f"  per stage (median) {', '.join(f'{t:.2f}' for t in figures['stage_ms_median'])} ms")
    print(f"  throughput         {figures['queries_per_s']:.1f} queries/s")
    print(f"  recall of top-1    {figures['recall_top1']:.3f} ({figures['queries']} queries)")
    print(f"  mean rank of NN    {figures['mean_rank_true_nn']:.2f}")
    print(f"  resident memory    {figures['rss_mb']:.0f} MB")
    return 0
