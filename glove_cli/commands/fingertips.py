"""``glove fingertips``: train, run and score the depth fingertip detector.

Sub-commands: ``train CONFIG.toml --out MODEL.npz`` (render training data and fit the
forest, its verifier and the heatmap stage), ``calibrate MODEL CONFIG.toml --out
MODEL.npz`` (its confidence maps), ``crops CONFIG.toml --out CROPS.npz`` and
``train-heatmap CONFIG.toml --out NETWORK.onnx`` (the heatmap network's training in
parts), ``eval-heatmap NETWORK INPUT`` (the network alone), ``synth CONFIG.toml --out
DIR`` (write rendered, annotated test frames), ``detect INPUT --out DIR``
(``fingertips.jsonl`` and overlays) and ``eval INPUT`` (scores against
``annotations.jsonl`` or ``groundtruth.jsonl``). The logic lives in :mod:`fingertips`.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, TextIO

from glove_cli.commands.track import (
    add_source_options,
    add_stream_options,
    source_options,
    summary_file,
)


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "fingertips",
        help="train, run and score the depth fingertip detector",
        description="Fingertip detection on depth images with a Hough forest "
        "(Tzionas et al. 2014). See docs/fingertips.md.",
    )
    actions = parser.add_subparsers(dest="action", metavar="ACTION", parser_class=type(parser))
    actions.required = True

    train = actions.add_parser(
        "train",
        help="render training depth and fit the model (forest, verifier, heatmap stage)",
        description="Render hands with the config's [data] settings, fit the forest of "
        "[training] and save it with the [detector] settings.",
    )
    train.add_argument("config", help="TOML config, e.g. configs/fingertips/default.toml")
    train.add_argument("--out", required=True, help="model file to write (.npz)")
    train.add_argument("--images", type=int, help="number of training images (overrides config)")
    train.add_argument(
        "--forest",
        metavar="MODEL",
        help="keep the Hough forest of this model and train only the config's [verifier] "
        "and [heatmap]",
    )
    train.add_argument(
        "--heatmap-network",
        metavar="FILE",
        help="use this heatmap network (.onnx, or a model .npz that has one) instead of "
        "training one: fits only the [heatmap] verifier",
    )
    train.add_argument(
        "--keep-verifier",
        action="store_true",
        help="with --forest: keep its peak verifier too and train only the [heatmap] stage",
    )
    _add_noise_option(train)
    train.set_defaults(run=run_train)

    calibrate = actions.add_parser(
        "calibrate",
        help="fit a model's confidence maps on the frames of a config's [calibration]",
        description="Run the model on the frames named by the config's [calibration] "
        "table (rendered as synth renders them, or read from --frames) and fit the maps "
        "from its verifiers' probabilities to the probability that a detection is right "
        "(isotonic regression); write the model with them. train does the same when the "
        "config has the table.",
    )
    calibrate.add_argument("model", help="model file (.npz) with a peak verifier")
    calibrate.add_argument(
        "config",
        help="TOML config with a [calibration] table, e.g. configs/fingertips/default.toml",
    )
    calibrate.add_argument("--out", required=True, help="model file to write (.npz; may be MODEL)")
    calibrate.add_argument(
        "--frames",
        metavar="DIR",
        help="a folder that synth wrote from the [calibration] frames config (the same "
        "frames, not rendered again)",
    )
    calibrate.set_defaults(run=run_calibrate)

    crops = actions.add_parser(
        "crops",
        help="render the heatmap network's training crops",
        description="Render frames with the config's [data] settings and its [heatmap.data] "
        "overrides and write their hand crops and fingertips, for train-heatmap --crops. "
        "One file per seed lets the rendering run in parts.",
    )
    crops.add_argument("config", help="TOML config with a [heatmap] table")
    crops.add_argument("--out", required=True, help="crop file to write (.npz)")
    crops.add_argument(
        "--seed",
        type=int,
        action="append",
        help="render this seed (repeatable; default: every seed of [heatmap] crop_seeds)",
    )
    crops.add_argument("--images", type=int, help="frames per seed (overrides crops_per_seed)")
    crops.set_defaults(run=run_crops)

    train_heatmap = actions.add_parser(
        "train-heatmap",
        help="train the heatmap network and write it as ONNX",
        description="Train the whole-hand heatmap network of the config's [heatmap] table "
        "on crop files (default: render the crops of its crop_seeds first) and write it as "
        "ONNX, for train --heatmap-network. Needs PyTorch (the train extra).",
    )
    train_heatmap.add_argument("config", help="TOML config with a [heatmap] table")
    train_heatmap.add_argument("--out", required=True, help="network file to write (.onnx)")
    train_heatmap.add_argument(
        "--crops",
        nargs="+",
        metavar="FILE",
        help="crop files of 'glove fingertips crops', joined in this order",
    )
    train_heatmap.set_defaults(run=run_train_heatmap)

    eval_heatmap = actions.add_parser(
        "eval-heatmap",
        help="score a heatmap network alone on annotated frames",
        description="Detect fingertips with the heatmap network alone (its peaks above a "
        "threshold, no forest, no verifier) and score them as eval does, per folder and "
        "threshold.",
    )
    eval_heatmap.add_argument(
        "network", help="network (.onnx) or a model (.npz) that has a heatmap stage"
    )
    eval_heatmap.add_argument(
        "inputs",
        nargs="+",
        metavar="INPUT",
        help="folders with annotations.jsonl or groundtruth.jsonl",
    )
    eval_heatmap.add_argument(
        "--centre",
        choices=("density", "fingers"),
        default="fingers",
        help="the crop centre's rule (default: fingers, the geodesic stage's finger "
        "candidates; density: the nearest object's densest 12 cm)",
    )
    eval_heatmap.add_argument(
        "--passes",
        type=int,
        choices=(1, 2, 4, 8),
        default=1,
        help="averaged turned and mirrored passes (default: 1, the crop alone)",
    )
    eval_heatmap.add_argument(
        "--threshold",
        type=float,
        action="append",
        help="smallest heat of a detection (repeatable; default: 0.5, 0.9 and 0.97)",
    )
    eval_heatmap.add_argument("--json", action="store_true", help="print one JSON object")
    eval_heatmap.set_defaults(run=run_eval_heatmap)

    synth = actions.add_parser(
        "synth",
        help="write rendered, annotated test frames",
        description="Render the config's [data] scenes into an RGB-D folder (depth only) "
        "with groundtruth.jsonl and annotations.jsonl (visible fingertips).",
    )
    synth.add_argument("config", help="TOML config with a [data] table")
    synth.add_argument("--out", required=True, help="output folder")
    synth.add_argument("--images", type=int, help="number of frames (overrides config)")
    _add_noise_option(synth)
    synth.set_defaults(run=run_synth)

    detect = actions.add_parser(
        "detect",
        help="detect fingertips in an RGB-D folder, a recording or a camera",
        description="Write DIR/fingertips.jsonl (one record per frame: frame, fingertips) "
        "and an overlay PNG per frame in DIR/overlay/ (or one contact sheet). A camera "
        "runs until Ctrl-C.",
    )
    detect.add_argument(
        "input",
        help="RGB-D folder (intrinsic.json, depth/NNNNNN.png), RealSense .bag file, "
        "'realsense' or 'kinect'",
    )
    _add_model_options(detect)
    detect.add_argument(
        "--out",
        help="output folder, or - for the records on standard output (no pictures; the "
        "same as --stream -); may be left out with --stream",
    )
    add_stream_options(detect)
    detect.add_argument(
        "--sheet", action="store_true", help="one contact sheet instead of an overlay per frame"
    )
    add_source_options(detect)
    detect.add_argument(
        "--pose-guess",
        action="store_true",
        help="also fit a hand pose to each frame's detections (record key pose_guess) and "
        "name their fingers by Eq. 11",
    )
    detect.set_defaults(run=run_detect)

    evaluate = actions.add_parser(
        "eval",
        help="score the detector on annotated frames",
        description="Detect fingertips in an annotated RGB-D folder and score them: "
        "precision and recall within 15 mm, mean 3D and 2D error of matched detections, "
        "recall within 10 px, time per frame, and the missed tips counted by cause "
        "(border, segmentation, distance, merged, curled, other; docs/fingertips.md).",
    )
    evaluate.add_argument("input", help="folder with annotations.jsonl or groundtruth.jsonl")
    _add_model_options(evaluate)
    evaluate.add_argument(
        "--annotations", help="annotation file in INPUT (default: annotations.jsonl if present)"
    )
    evaluate.add_argument(
        "--pose-guess",
        action="store_true",
        help="also score hand pose guesses against groundtruth.jsonl poses (rendered folders)",
    )
    evaluate.add_argument(
        "--sheet",
        metavar="PNG",
        help=f"also draw a contact sheet of up to {SHEET_FRAMES} frames (evenly spread): "
        "annotated tips green if a detection is within 10 px, red if missed and marked "
        "with the cause's letter (legend below the tiles); detections cyan if matched, "
        "orange if not",
    )
    evaluate.add_argument("--json", action="store_true", help="print one JSON object")
    evaluate.set_defaults(run=run_eval)


def _add_noise_option(parser: argparse.ArgumentParser) -> None:
    from builder.depth_noise import NOISE_PRESETS

    parser.add_argument(
        "--noise",
        choices=NOISE_PRESETS,
        help="use only this depth noise preset ('none': clean depth; overrides config)",
    )


def _add_model_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--model", help="model file (.npz; default: the shipped model)")
    parser.add_argument("--c-thr", type=float, help="confidence threshold (default: the model's)")
    parser.add_argument(
        "--min-tip-probability",
        type=float,
        help="smallest peak verifier probability kept (default: the model's; 0: no check, "
        "and no heatmap stage)",
    )
    parser.add_argument(
        "--heatmap-min-probability",
        type=float,
        help="smallest heatmap verifier probability added (default: the model's; 0: no heatmap)",
    )
    parser.add_argument("--stride", type=int, help="fixed pixel stride (default: the model's)")
    parser.add_argument(
        "--segmentation",
        choices=("band", "surface"),
        help="hand pixels: 'band' (a depth band behind the nearest surface) or 'surface' "
        "(bare hand: tables and walls removed, nearest connected surface, forearm cut); "
        "default: the model's",
    )
    parser.add_argument(
        "--candidates",
        choices=("forest", "union"),
        help="what the verifier scores: 'forest' (the vote peaks) or 'union' (and the "
        "geodesic finger candidates); default: the model's",
    )
    parser.add_argument(
        "--heatmap-centre",
        choices=("density", "fingers"),
        help="where the heatmap stage centres its crop: 'density' (the nearest object's "
        "densest 12 cm) or 'fingers' (the geodesic stage's finger candidates); default: "
        "the model's",
    )


def _positive(name: str, value: int | None) -> int | None:
    if value is not None and value < 1:
        raise ValueError(f"{name}: expected at least 1, got {value}")
    return value


def _data_overrides(args: argparse.Namespace) -> dict[str, Any]:
    overrides: dict[str, Any] = {}
    if _positive("--images", args.images) is not None:
        overrides["n_images"] = args.images
    if args.noise is not None:
        overrides["noise"] = (args.noise,)
    return overrides


def run_train(args: argparse.Namespace) -> int:
    from fingertips.forest import load_forest, save_forest
    from fingertips.training import load_recipe, train_from_recipe

    out = _output_file(args.out, ".npz", "a model file")
    recipe = load_recipe(args.config, **_data_overrides(args))
    if args.keep_verifier and not args.forest:
        raise ValueError("--keep-verifier: needs --forest MODEL")
    base = load_forest(args.forest) if args.forest else None
    network = _heatmap_network(args.heatmap_network) if args.heatmap_network else None
    started = time.perf_counter()
    forest = train_from_recipe(
        recipe,
        progress=sys.stderr.isatty(),
        forest=base,
        keep_verifier=args.keep_verifier,
        heatmap_network=network,
    )
    save_forest(forest, out)
    size_mb = out.stat().st_size / 1e6
    print(
        f"wrote {out} ({forest.n_trees} trees, {forest.node_feature.size} nodes, "
        f"{size_mb:.1f} MB) in {time.perf_counter() - started:.0f} s"
    )
    return 0


def run_calibrate(args: argparse.Namespace) -> int:
    from fingertips.calibration_training import calibrate_from_config
    from fingertips.forest import load_forest, save_forest
    from fingertips.training import load_recipe

    out = _output_file(args.out, ".npz", "a model file")
    calibration = load_recipe(args.config).calibration
    if calibration is None:
        raise ValueError(f"{args.config}: no [calibration] table")
    model = load_forest(args.model)
    started = time.perf_counter()
    model = calibrate_from_config(model, calibration, folder=args.frames, progress=_progress)
    save_forest(model, out)
    recorded = model.settings["calibration"]
    counts = ", ".join(
        f"{kind} {recorded['correct'][kind]} of {n} right"
        for kind, n in recorded["samples"].items()
    )
    print(
        f"wrote {out}: confidence maps from {recorded['n_images']} frames of "
        f"{calibration.frames} ({counts}) in {time.perf_counter() - started:.0f} s"
    )
    return 0


def _output_file(path: str, suffix: str, what: str) -> Path:
    """``--out`` as a path, refused unless it ends in ``suffix`` and its folder exists."""
    out = Path(path)
    if out.suffix != suffix:
        raise ValueError(f"--out {out}: {what} name ends in {suffix}")
    if not out.parent.is_dir():
        raise ValueError(f"{out.parent}: folder does not exist")
    return out


def _heatmap_network(path: str) -> Any:
    """The ONNX bytes of ``--heatmap-network``: an ``.onnx`` file, or a model's network."""
    from fingertips.forest import read_heatmap_network

    try:
        return read_heatmap_network(path)
    except ValueError as error:
        raise ValueError(f"--heatmap-network {error}") from error


def _heatmap_recipe(path: str) -> tuple[Any, Any, Any]:
    """The config's ``[heatmap]`` settings, the data settings of its crops and their
    centre rule (``[heatmap] crop_centre``)."""
    from fingertips.training import load_recipe

    recipe = load_recipe(path)
    if recipe.heatmap is None:
        raise ValueError(f"{path}: no [heatmap] table")
    data = recipe.heatmap.heatmap_data(recipe.data)
    return recipe.heatmap, data, recipe.heatmap.crop_centre


def run_crops(args: argparse.Namespace) -> int:
    from fingertips.heatmap_data import render_crops, save_crops

    out = _output_file(args.out, ".npz", "a crop file")
    heatmap, data, centre = _heatmap_recipe(args.config)
    seeds = args.seed or heatmap.crop_seeds
    per_seed = _positive("--images", args.images) or heatmap.crops_per_seed
    started = time.perf_counter()
    crops = render_crops(data, seeds, per_seed, centre=centre, progress=sys.stderr.isatty())
    save_crops(crops, out, data=data, seeds=seeds, centre=centre)
    print(
        f"wrote {out} ({len(crops.images)} crops, {int(crops.whole_hand.sum())} of whole "
        f"hands) in {time.perf_counter() - started:.0f} s"
    )
    return 0


def run_train_heatmap(args: argparse.Namespace) -> int:
    from fingertips.heatmap_data import load_crops, render_crops, require_training_extra
    from glovedb._files import write_atomically

    out = _output_file(args.out, ".onnx", "a network file")
    heatmap, data, centre = _heatmap_recipe(args.config)
    require_training_extra()
    started = time.perf_counter()
    if args.crops:
        crops = load_crops(args.crops, data=data, centre=centre)
    else:
        crops = render_crops(
            data,
            heatmap.crop_seeds,
            heatmap.crops_per_seed,
            centre=centre,
            progress=sys.stderr.isatty(),
        )
    from fingertips.heatmap_training import train_heatmap_network

    network = train_heatmap_network(crops, heatmap, progress=sys.stderr.isatty())
    write_atomically(out, lambda file: file.write(network.tobytes()))
    print(
        f"wrote {out} (trained on {len(crops.images)} crops, {network.size / 1e6:.1f} MB) "
        f"in {time.perf_counter() - started:.0f} s"
    )
    return 0


def run_eval_heatmap(args: argparse.Namespace) -> int:
    from fingertips.evaluation import read_annotated_depth
    from fingertips.forest import read_heatmap_network
    from fingertips.heatmap import HeatmapNetwork
    from fingertips.heatmap_evaluation import DEFAULT_THRESHOLDS, evaluate_network

    network = HeatmapNetwork(read_heatmap_network(args.network), args.passes)
    thresholds = args.threshold or DEFAULT_THRESHOLDS
    results: dict[str, Any] = {}
    for folder in args.inputs:
        data = read_annotated_depth(folder, annotations=_annotation_file(Path(folder)))
        scores = evaluate_network(
            data, network, thresholds=thresholds, centre=args.centre, progress=_progress
        )
        results[folder] = {str(t): m.as_dict() for t, m in scores.items()}
        for t, m in scores.items():
            if not args.json:
                print(
                    f"{folder} threshold {t}: {m.detections} detections, precision "
                    f"{m.precision_15mm:.3f}, recall {m.recall_15mm:.3f} ({m.error_3d_mm:.1f} "
                    f"mm); recall at 10 px {m.recall_10px:.3f} ({m.error_2d_px:.1f} px)"
                )
    if args.json:
        print(json.dumps(_finite_or_none(results)))
    return 0


def _annotation_file(root: Path) -> str:
    """``annotations.jsonl`` if the folder has one, else ``groundtruth.jsonl``."""
    return "annotations.jsonl" if (root / "annotations.jsonl").is_file() else "groundtruth.jsonl"


def run_synth(args: argparse.Namespace) -> int:
    from dataclasses import asdict, replace

    from builder.sequence import require_empty_folder
    from fingertips.data import (
        generate_examples,
        load_data_config,
        require_one_camera,
        write_annotated_folder,
    )

    config = replace(load_data_config(args.config), **_data_overrides(args))
    require_one_camera(config)  # these two before the progress bar starts
    require_empty_folder(args.out)
    rendered = generate_examples(config)
    examples = _progress(rendered, total=config.n_images, desc="render", unit="img")
    count = write_annotated_folder(examples, args.out, settings={"data": asdict(config)})
    print(f"wrote {count} frames to {args.out}")
    return 0


def _progress(iterable: Iterable[Any], **options: Any) -> Iterable[Any]:
    """A progress bar on standard error, shown only on a terminal (as track and build do)."""
    from tqdm import tqdm

    return tqdm(iterable, disable=None, file=sys.stderr, **options)


def _load_model(args: argparse.Namespace) -> tuple[Any, Any]:
    from dataclasses import replace

    from fingertips import load_forest, model_detector_config
    from fingertips.forest import DEFAULT_MODEL_PATH

    model = load_forest(args.model if args.model else DEFAULT_MODEL_PATH)
    config = model_detector_config(model)
    if args.c_thr is not None:
        if not args.c_thr > 0:
            raise ValueError(f"--c-thr: expected a positive threshold, got {args.c_thr}")
        config = replace(config, c_thr=args.c_thr)
    tip, heat = config.min_tip_probability, config.heatmap_min_probability
    if args.min_tip_probability is not None:
        tip = args.min_tip_probability
        if tip == 0:  # the heatmap stage needs the verifier
            heat = 0.0
    if args.heatmap_min_probability is not None:
        heat = args.heatmap_min_probability
    config = replace(config, min_tip_probability=tip, heatmap_min_probability=heat)
    if _positive("--stride", args.stride) is not None:
        config = replace(config, stride=args.stride, pixel_spacing_m=0.0)
    if args.segmentation is not None:
        config = replace(config, segmentation=args.segmentation)
    if args.candidates is not None:
        config = replace(config, candidates=args.candidates)
    if args.heatmap_centre is not None:
        config = replace(config, heatmap_centre=args.heatmap_centre)
    return model, config


def run_detect(args: argparse.Namespace) -> int:
    from contextlib import ExitStack
    from dataclasses import replace

    from fingertips.depth_input import open_depth_source
    from fingertips.detector import FingertipDetector
    from tracker.outputs.stream import open_stream
    from tracker.prefetch import Prefetch

    if args.out == "-":
        if args.stream not in (None, "-"):
            raise ValueError("--out -: standard output is the stream; give --stream - or a folder")
        args.out, args.stream = None, "-"
    if args.out is None and args.stream is None:
        raise ValueError("detect: give --out (a folder, or - for standard output) or --stream")
    if args.sheet and args.out is None:
        raise ValueError("--sheet: needs an output folder")
    model, config = _load_model(args)
    detector = FingertipDetector(model, config=config)
    source = open_depth_source(args.input, **source_options(args))
    if args.sheet and source.live:
        raise ValueError(f"--sheet: {source.description} is a camera, whose frames do not end")
    with ExitStack() as stack:
        stream = None
        if args.stream is not None:
            stream = stack.enter_context(
                open_stream(args.stream, topic="glove/fingertips", wait_s=args.stream_wait)
            )
        if not source.live:  # recordings: the next frames decode while this one is detected
            source = replace(source, frames=stack.enter_context(Prefetch(iter(source), depth=2)))
        if args.out is None:
            count, seconds = _write_records(
                detector, source, None, pose_guess=args.pose_guess, stream=stream
            )
            print(f"{count} frames, {1000 * seconds / max(count, 1):.1f} ms per frame",
                  file=sys.stderr)  # fmt: skip
            return 0
        return _detect_into_folder(args, detector, source, stream)


def _detect_into_folder(args: argparse.Namespace, detector: Any, source: Any, stream: Any) -> int:
    """``glove fingertips detect --out DIR``: records, overlays or a contact sheet."""
    from fingertips.pictures import contact_sheet, detection_overlay
    from tracker.overlay import write_rgb

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    # An earlier run's outputs are replaced, not mixed with these (a shorter run would
    # leave its overlays beyond the new frames).
    stale = [out / "contact_sheet.png", *(out / "overlay").glob("[0-9]*.png")]
    for path in stale:
        if path.is_file():
            path.unlink()
    if not args.sheet:
        (out / "overlay").mkdir(exist_ok=True)
    elif (out / "overlay").is_dir() and not any((out / "overlay").iterdir()):
        (out / "overlay").rmdir()
    tiles = []

    def draw(frame: Any, record: dict[str, Any]) -> None:
        picture = detection_overlay(frame.depth_m, record, frame.intrinsics)
        if args.sheet:
            tiles.append(picture)
        else:
            write_rgb(out / "overlay" / f"{frame.frame:06d}.png", picture)

    with open(out / "fingertips.jsonl", "w") as records:
        frames = _progress(source, total=source.n_frames, desc="detect", unit="frame")
        count, seconds = _write_records(
            detector, frames, records, pose_guess=args.pose_guess, after=draw, stream=stream
        )
    if args.sheet:
        write_rgb(out / "contact_sheet.png", contact_sheet(tiles))
    print(
        f"wrote {out / 'fingertips.jsonl'} ({count} frames, "
        f"{1000 * seconds / max(count, 1):.1f} ms per frame) and "
        + ("contact_sheet.png" if args.sheet else "overlay/NNNNNN.png"),
        file=summary_file(args),
    )
    return 0


def _write_records(
    detector: Any,
    frames: Iterable[Any],
    out: TextIO | None,
    *,
    pose_guess: bool,
    after: Callable[[Any, dict[str, Any]], None] | None = None,
    stream: Any = None,
) -> tuple[int, float]:
    """Detect on every frame, write its JSON record to ``out`` at once (flushed: a
    camera run ends by Ctrl-C) and publish it on ``stream`` (a
    :class:`tracker.outputs.stream.RecordStream`); ``after(frame, record)`` follows each.
    Returns the number of frames and the seconds spent detecting."""
    count, seconds = 0, 0.0
    for frame in frames:
        started = time.perf_counter()
        record = detector.record(
            frame.frame, frame.depth_m, frame.intrinsics, pose_guess=pose_guess,
            timestamp_s=frame.timestamp_s,
        )  # fmt: skip
        seconds += time.perf_counter() - started
        if out is not None:
            out.write(json.dumps(record) + "\n")
            out.flush()
        if stream is not None:
            stream.publish(record)
        count += 1
        if after is not None:
            after(frame, record)
    return count, seconds


def run_eval(args: argparse.Namespace) -> int:
    from fingertips.evaluation import (
        annotated_tip_causes,
        fingertip_metrics,
        read_annotated_depth,
        run_detector,
    )

    root = Path(args.input)
    name = args.annotations if args.annotations is not None else _annotation_file(root)
    if args.pose_guess and not (root / "groundtruth.jsonl").is_file():
        raise ValueError(f"{root}: pose guesses need groundtruth.jsonl (a rendered folder)")
    if args.sheet and Path(args.sheet).suffix.lower() not in (".png", ".jpg", ".jpeg"):
        raise ValueError(f"--sheet: expected a .png (or .jpg) file name, got {args.sheet}")
    model, config = _load_model(args)
    data = read_annotated_depth(root, annotations=name)
    detections, ms_per_frame = run_detector(data, model, config=config, progress=_progress)
    causes = annotated_tip_causes(data, model, config=config)
    metrics = fingertip_metrics(
        detections, data.tips_m, data.tips_px, ms_per_frame=ms_per_frame, causes=causes
    )
    if args.sheet:
        from fingertips.pictures import scored_sheet
        from tracker.overlay import write_rgb

        Path(args.sheet).parent.mkdir(parents=True, exist_ok=True)
        sheet = scored_sheet(data, detections, causes=causes, max_frames=SHEET_FRAMES)
        write_rgb(Path(args.sheet), sheet)
        print(f"wrote {args.sheet}", file=sys.stderr)
    assert metrics.missed_15mm is not None and metrics.missed_10px is not None
    result = {
        "frames": metrics.frames,
        "detections": metrics.detections,
        "annotated_tips": metrics.annotated_tips,
        "precision": metrics.precision_15mm,
        "recall": metrics.recall_15mm,
        "error_mm_mean": metrics.error_3d_mm,
        "error_px_mean": metrics.error_2d_px,
        "recall_at_10px": metrics.recall_10px,
        "error_px_ungated_mean": metrics.error_2d_px_ungated,
        "ms_per_frame": metrics.ms_per_frame,
        "missed_by_cause": {
            "15mm": metrics.missed_15mm.as_dict(),
            "10px": metrics.missed_10px.as_dict(),
        },
        "recall_by_depth": metrics.recall_by_depth,
        "calibrated": metrics.calibrated,
        "reliability": None if metrics.reliability is None else metrics.reliability.as_dict(),
        "annotations": name,
        "model": str(args.model or "default"),
        "detector": config.as_dict(),
    }
    guesses = None
    if args.pose_guess:
        from fingertips.detector import FingertipDetector
        from fingertips.evaluation import evaluate_pose_guesses

        detector = FingertipDetector(model, config=config)
        guesses = evaluate_pose_guesses(root, detector, progress=_progress)
        result["pose_guess"] = guesses.as_dict()
    if args.json:
        print(json.dumps(_finite_or_none(result)))
        return 0
    print(
        f"{metrics.frames} frames, {metrics.annotated_tips} annotated tips, "
        f"{metrics.detections} detections\n"
        f"precision {metrics.precision_15mm:.3f}, recall {metrics.recall_15mm:.3f} (15 mm)\n"
        f"mean error of matched detections: {metrics.error_3d_mm:.1f} mm, "
        f"{metrics.error_2d_px:.1f} px\n"
        f"recall at 10 px {metrics.recall_10px:.3f}; mean 2D error without a gate "
        f"{metrics.error_2d_px_ungated:.1f} px\n"
        f"{metrics.ms_per_frame:.1f} ms per frame\n"
        f"missed within 15 mm by cause: {_cause_counts(metrics.missed_15mm.as_dict())}\n"
        f"missed within 10 px by cause: {_cause_counts(metrics.missed_10px.as_dict())}\n"
        "recall (15 mm) by tip depth: "
        + ", ".join(
            f"{band} {scores['recall_15mm']:.3f} of {scores['tips']}"
            for band, scores in metrics.recall_by_depth.items()
        ),
        file=sys.stdout,
    )
    if metrics.reliability is not None:
        print(_reliability_text(metrics.reliability, calibrated=metrics.calibrated))
    if guesses is not None:
        print(
            f"pose guess: {guesses.guessed} of {guesses.frames} right-hand frames; medians "
            f"{guesses.rotation_deg_median:.1f} deg, wrist {guesses.wrist_mm_median:.0f} mm, "
            f"keypoints {guesses.keypoint_mm_median:.0f} mm; "
            f"{100 * guesses.within_15deg:.0f}% within 15 deg; {guesses.ms_per_guess:.0f} ms"
        )
    return 0


def _reliability_text(reliability: Any, *, calibrated: bool) -> str:
    """The reliability table of ``eval``: one line per non-empty bin, then the ECE."""
    what = "calibrated confidence" if calibrated else "verifier probability (uncalibrated)"
    lines = [f"reliability of the {what}: bin, detections, mean, share right (15 mm)"]
    lines += [
        f"  {b.low:.1f}-{b.high:.1f}  {b.count:5d}  {b.mean_confidence:.3f}  {b.share_correct:.3f}"
        for b in reliability.bins
        if b.count
    ]
    lines.append(
        f"expected calibration error {reliability.ece:.3f} ({reliability.detections} detections)"
    )
    return "\n".join(lines)


def _cause_counts(counts: dict[str, int]) -> str:
    """``"12 (border 1, segmentation 3, ...)"``: the total, then every cause's count."""
    return f"{sum(counts.values())} (" + ", ".join(f"{c} {n}" for c, n in counts.items()) + ")"


def _finite_or_none(value: Any) -> Any:
    """``value`` with every non-finite float (also inside dicts) replaced by None."""
    if isinstance(value, dict):
        return {k: _finite_or_none(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite_or_none(v) for v in value]
    return None if isinstance(value, float) and not math.isfinite(value) else value


SHEET_FRAMES = 60
"""Most frames ``glove fingertips eval --sheet`` draws."""
