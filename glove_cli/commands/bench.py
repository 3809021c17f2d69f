"""``glove bench lookup``: search latency, throughput, memory and accuracy;
``glove bench track``: end-to-end tracking speed and per-stage latency;
``glove bench fingertips``: end-to-end fingertip detection speed and per-stage latency."""

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
    lookup.add_argument(
        "--cascade",
        default="8:1500,16:100,64:3",  # glovedb.lookup.DEFAULT_CASCADE, not imported: slow
        help="e.g. 16:500,64:3 (default: the tracker's, 8:1500,16:100,64:3)",
    )
    lookup.add_argument("--entries", type=int, help="tile the database to this many entries")
    lookup.add_argument("--queries", type=int, default=20, help="number of queries")
    lookup.add_argument("--workers", type=int, help="search threads (default: all cores)")
    lookup.add_argument(
        "--coarse-maps",
        choices=("cell_mean", "exact"),  # glovedb.search.COARSE_MAPS, not imported: slow
        default="cell_mean",
        help="query maps of the stages before the last (default: cell_mean)",
    )
    lookup.add_argument(
        "--first-stage",
        choices=("auto", "distinct", "scan", "lists"),  # glovedb.lookup.FIRST_STAGES
        default="auto",
        help="scan each distinct image once, every entry (the same result), or only the "
        "lists of images like the query's (approximate) (default: auto, distinct images "
        "when they repeat, lists when at least 250,000 images are left to scan)",
    )
    lookup.add_argument(
        "--against",
        metavar="CASCADE",
        help="also time this cascade, alternating with --cascade query by query in one "
        "process (separate runs on a shared machine can differ by a third in speed)",
    )
    lookup.add_argument("--json", action="store_true", help="print one JSON object")
    lookup.set_defaults(run=run_lookup)
    track = kinds.add_parser(
        "track",
        help="end-to-end tracking speed: frames/s with decoding, per-stage latency",
        description="Track every frame of SOURCE (writing nothing) and report startup, "
        "time to the first pose, end-to-end frames/s (reading and decoding included), "
        "tracking frames/s and per-stage median, p95 and p99 latency.",
    )
    track.add_argument("source", help="RGB-D folder or RealSense .bag file")
    track.add_argument("--db", required=True, help="posture database (.h5)")
    track.add_argument(
        "--read-ahead",
        type=int,
        default=2,
        help="frames decoded ahead while one is tracked (default 2; 0: in turn)",
    )
    track.add_argument("--json", action="store_true", help="print one JSON object")
    track.set_defaults(run=run_track)
    fingertips = kinds.add_parser(
        "fingertips",
        help="end-to-end fingertip detection speed: frames/s with decoding, per-stage latency",
        description="Detect fingertips in every frame of SOURCE as `glove fingertips detect` "
        "does (writing nothing) and report the time to the first detections, end-to-end "
        "frames/s after the first frame (reading and decoding included) and per-stage "
        "median, p95 and p99 latency.",
    )
    fingertips.add_argument("source", help="RGB-D folder (depth/ is enough) or RealSense .bag")
    fingertips.add_argument("--model", help="model file (.npz; default: the shipped model)")
    fingertips.add_argument(
        "--read-ahead",
        type=int,
        default=2,
        help="frames decoded ahead in a thread while one is detected (default 2; 0: in turn)",
    )
    fingertips.add_argument("--json", action="store_true", help="print one JSON object")
    fingertips.set_defaults(run=run_fingertips)


def run_lookup(args: argparse.Namespace) -> int:
    import json

    from builder.lookup_bench import run_lookup_benchmark

    if args.queries < 1:
        raise ValueError("--queries must be at least 1")
    if args.entries is not None and args.entries < 1:
        raise ValueError(f"--entries must be at least 1, got {args.entries}")
    figures = run_lookup_benchmark(
        args.db, cascade=args.cascade, entries=args.entries, queries=args.queries,
        workers=args.workers, coarse_maps=args.coarse_maps, first_stage=args.first_stage,
        against=args.against,
    ).as_dict()  # fmt: skip
    if args.json:
        print(json.dumps(figures))
        return 0
    latency = figures["latency_ms"]
    print(f"{args.db}: {figures['entries']:,} entries ({figures['base_entries']:,} in the file)")
    print(f"  cascade            {figures['cascade']}")
    lists = (f" in {figures['lists']:,} lists, {100 * figures['probe_share']:.0f} % scanned per "
             "query" if figures["first_stage"] == "lists" else "")  # fmt: skip
    print(f"  first stage        {figures['first_stage']}: {figures['scanned_images']:,} images"
          f"{lists}, {figures['index_mb']:.1f} MB, index opened and built in "
          f"{figures['index_build_s']:.2f} s")  # fmt: skip
    print(f"  latency            median {latency['median']:.2f} ms, p95 {latency['p95']:.2f} ms")
    print(f"  per stage (median) {', '.join(f'{t:.2f}' for t in figures['stage_ms_median'])} ms")
    print(f"  throughput         {figures['queries_per_s']:.1f} queries/s")
    print(f"  memory reference   one read of the exhaustive first stage's "
          f"{figures['first_stage_mb']:.0f} MB: {figures['first_stage_read_ms']:.2f} ms; "
          f"median / read {figures['median_over_read']:.2f}, first stage / read "
          f"{figures['first_stage_over_read']:.2f}")  # fmt: skip
    print(f"  exhaustive cascade median {figures['exhaustive_latency_ms_median']:.2f} ms, "
          f"same top-1 entry {figures['recall_top1_vs_exhaustive']:.3f}")  # fmt: skip
    print(f"  recall of top-1    {figures['recall_top1']:.3f} against brute force "
          f"({figures['queries']} queries)")  # fmt: skip
    print(f"  mean rank of NN    {figures['mean_rank_true_nn']:.2f}")
    print(f"  resident memory    {figures['rss_mb']:.0f} MB")
    if (paired := figures["against"]) is not None:
        print(f"  against            {paired['cascade']}, the two alternating query by query: "
              f"median {paired['median_ms']:.2f} against {paired['own_median_ms']:.2f} ms "
              f"({paired['median_over_read']:.2f} against {paired['own_median_over_read']:.2f}"
              f" reads of {paired['read_ms_median']:.2f} ms, timed between them), paired "
              f"difference {paired['paired_difference_ms_median']:+.2f} ms, same top-1 "
              f"entry {paired['same_top1']:.3f}")  # fmt: skip
    return 0


def run_track(args: argparse.Namespace) -> int:
    import json

    from tracker.benchmark import benchmark_tracking

    _check_read_ahead(args.read_ahead)
    figures = benchmark_tracking(args.source, args.db, read_ahead=args.read_ahead).as_dict()
    if args.json:
        print(json.dumps(figures))
        return 0
    machine = figures["machine"]
    print(f"{args.source} with {args.db}: {figures['frames']} frames, hand found in "
          f"{figures['hand_found']} ({machine['cpu']}, {machine['cores']} cores)")  # fmt: skip
    launch = _after_launch(figures["first_pose_since_launch_s"])
    print(f"  startup            {figures['startup_s']:.2f} s, first pose after "
          f"{figures['first_pose_s']:.2f} s{launch}")  # fmt: skip
    print(f"  end to end         {figures['end_to_end_fps']:.1f} frames/s "
          f"(read ahead {figures['read_ahead']}, waiting "
          f"{figures['read_wait_ms_per_frame']:.1f} ms per frame for input)")  # fmt: skip
    print(f"  tracking alone     {figures['tracking_fps']:.1f} frames/s")
    print_stages(figures["stages_ms"], ("median", "p95", "p99", "max"))
    if "background" in figures["stages_ms"]:
        print("  total: a frame's latency; background: a step of a periodic lookup (search,\n"
              "  ICP or fit), one per frame in the frames after it is due (in total)")  # fmt: skip
    return 0


def run_fingertips(args: argparse.Namespace) -> int:
    import json

    from fingertips.benchmark import benchmark_detection

    _check_read_ahead(args.read_ahead)
    figures = benchmark_detection(args.source, args.model, read_ahead=args.read_ahead).as_dict()
    if args.json:
        print(json.dumps(figures))
        return 0
    machine = figures["machine"]
    model = args.model or "the shipped model"
    print(f"{args.source} with {model}: {figures['frames']} frames, {figures['detections']} "
          f"fingertips ({machine['cpu']}, {machine['cores']} cores)")  # fmt: skip
    launch = _after_launch(figures["first_detection_since_launch_s"])
    print(f"  startup            {figures['startup_s']:.2f} s, first detections after "
          f"{figures['first_detection_s']:.2f} s{launch}")  # fmt: skip
    print(f"  end to end         {figures['end_to_end_fps']:.1f} frames/s, "
          f"{figures['end_to_end_ms_per_frame']} ms per frame after the first "
          f"(read ahead {figures['read_ahead']})")  # fmt: skip
    print_stages(figures["stages_ms"], ("median", "p95", "p99", "mean", "max"))
    return 0


def _check_read_ahead(frames: int) -> None:
    if not 0 <= frames <= 64:
        raise ValueError(f"--read-ahead: expected 0 to 64, got {frames}")


def _after_launch(seconds: float | None) -> str:
    """`` (S s after the command started)``, or nothing where the system does not tell."""
    return "" if seconds is None else f" ({seconds:.2f} s after the command started)"


def print_stages(stages_ms: dict[str, dict[str, float]], columns: tuple[str, ...]) -> None:
    """A benchmark's per-stage table: one row per stage, one column per statistic, ms."""
    print(f"  {'stage':10s} " + " ".join(f"{c:>8s}" for c in columns) + "  ms")
    for stage, t in stages_ms.items():
        print(f"  {stage:10s} " + " ".join(f"{t[c]:8.2f}" for c in columns))
