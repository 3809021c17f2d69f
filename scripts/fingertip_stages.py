"""What each fingertip stage adds: the table of docs/fingertips.md ("What each stage adds").

    .venv/bin/python scripts/fingertip_stages.py FOLDER [--model MODEL] [--json]

FOLDER is an annotated folder rendered by ``glove fingertips synth`` (it needs the
keypoints of ``groundtruth.jsonl`` for the distance bands), e.g.
``glove fingertips synth configs/fingertips/validation.toml --out FOLDER``. Rows, with
the model's settings otherwise: the forest's vote peaks without a verifier; the
geodesic finger candidates alone (no forest, no verifier); the union of both without a
verifier; the union (or the model's candidates) with the verifier; and with the
heatmap stage. Each row gives precision, recall and the mean 3D error of the matches
(one-to-one within 15 mm, as ``glove fingertips eval``) over all frames and per band
of the hand's distance (the mean depth of its 21 keypoints), and the mean detection
time per frame.
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from dataclasses import replace

import numpy as np

from fingertips.detect import (
    Detection,
    DetectorConfig,
    detect_fingertips,
    hand_depth,
    model_detector_config,
)
from fingertips.evaluation import AnnotatedDepth, fingertip_metrics, read_annotated_depth
from fingertips.features import project
from fingertips.forest import DEFAULT_MODEL_PATH, FingertipForest, load_forest
from fingertips.geodesic import geodesic_candidates
from fingertips.geodesic_evaluation import DISTANCE_BANDS_M


def geodesic_detections(
    data: AnnotatedDepth, model: FingertipForest, config: DetectorConfig
) -> tuple[list[tuple[Detection, ...]], float]:
    """Every geodesic finger candidate of the detector's hand depth as a detection."""
    detections, elapsed = [], 0.0
    for depth in data.depth_m:
        start = time.perf_counter()
        hand = hand_depth(depth, model, depth_band_m=config.depth_band_m)
        fingers = geodesic_candidates(hand, data.intrinsics).fingers()
        elapsed += time.perf_counter() - start
        uv = project(fingers.points_m.astype(np.float64), data.intrinsics)
        detections.append(
            tuple(
                Detection(
                    u_px=float(uv[k, 0]),
                    v_px=float(uv[k, 1]),
                    x_m=float(fingers.points_m[k, 0]),
                    y_m=float(fingers.points_m[k, 1]),
                    z_m=float(fingers.points_m[k, 2]),
                    confidence=float(fingers.reach_m[k]),
                    source="geodesic",
                )
                for k in range(len(fingers))
            )
        )
    return detections, 1000 * elapsed / max(len(data.depth_m), 1)


def detector_detections(
    data: AnnotatedDepth, model: FingertipForest, config: DetectorConfig
) -> tuple[list[tuple[Detection, ...]], float]:
    """:func:`detect_fingertips` on every frame, timed after one warm-up frame."""
    detect_fingertips(data.depth_m[0], data.intrinsics, model, config=config)
    detections, elapsed = [], 0.0
    for depth in data.depth_m:
        start = time.perf_counter()
        detections.append(detect_fingertips(depth, data.intrinsics, model, config=config))
        elapsed += time.perf_counter() - start
    return detections, 1000 * elapsed / len(data.depth_m)


def scores(detections: list[tuple[Detection, ...]], data: AnnotatedDepth) -> dict[str, list]:
    """Precision, recall, mean 3D error (mm) and tips, over all frames and per band."""
    if data.keypoints_m is None:
        raise ValueError("FOLDER: needs groundtruth.jsonl keypoints (a synth folder)")
    distance = np.nanmean(data.keypoints_m[:, :, 2], axis=1)
    bands = {"all": (0.0, np.inf)} | {
        f"{low}-{high} m": (low, high) for low, high in itertools.pairwise(DISTANCE_BANDS_M)
    }
    table = {}
    for name, (low, high) in bands.items():
        inside = np.flatnonzero((distance >= low) & (distance < high))
        metrics = fingertip_metrics(
            [detections[k] for k in inside], data.tips_m[inside], data.tips_px[inside]
        )
        table[name] = [
            round(metrics.precision_15mm, 3),
            round(metrics.recall_15mm, 3),
            round(metrics.error_3d_mm, 1),
            metrics.annotated_tips,
        ]
    return table


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder")
    parser.add_argument("--model", default=str(DEFAULT_MODEL_PATH))
    parser.add_argument("--json", action="store_true", help="one JSON object per row")
    args = parser.parse_args()
    data = read_annotated_depth(args.folder)
    model = load_forest(args.model)
    config = model_detector_config(model)
    plain = replace(config, min_tip_probability=0.0, heatmap_min_probability=0.0)
    rows = {
        "forest peaks, no verifier": replace(plain, candidates="forest"),
        "geodesic finger candidates alone": None,
        "union, no verifier": replace(plain, candidates="union"),
        f"{config.candidates} + verifier": replace(config, heatmap_min_probability=0.0),
        f"{config.candidates} + verifier + heatmap": config,
    }
    for name, row_config in rows.items():
        if row_config is None:
            detections, ms = geodesic_detections(data, model, config)
        else:
            detections, ms = detector_detections(data, model, row_config)
        table = scores(detections, data)
        if args.json:
            print(json.dumps({"row": name, "ms_per_frame": round(ms, 1), **table}))
            continue
        cells = " | ".join(f"{p:.3f} / {r:.3f} / {e:.1f}" for p, r, e, _ in table.values())
        print(f"| {name} | {cells} | {ms:.1f} |", flush=True)


if __name__ == "__main__":
    main()
