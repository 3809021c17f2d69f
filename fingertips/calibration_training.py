"""Fitting a model's confidence maps (:mod:`fingertips.calibration`) on annotated frames.

The detector runs on every frame twice, with the model's recorded settings except:

- for the ``"verifier"`` map, ``min_tip_probability`` lowered to ``min_probability``
  and the heatmap stage off (on, when the model judges the candidates with the
  heat, :mod:`fingertips.judge` or :mod:`fingertips.heat_fusion`; its peaks are then
  left out): the
  forest's and geodesic detections of (almost) every verifier probability.
  Detections at a threshold are exactly those of this run with a probability that
  reaches it (the separation of detections does not depend
  on the threshold), so the map holds for any ``min_tip_probability`` at or above
  ``min_probability``;
- for the ``"heatmap"`` map, ``heatmap_min_probability`` lowered to
  ``min_probability`` (``min_tip_probability`` as recorded: the heatmap verifier's
  features depend on it): the heatmap's detections.

Each detection is labelled as ``glove fingertips eval`` scores, one-to-one within
15 mm of an annotated tip among that run's detections of the frame
(:func:`fingertips.evaluation.matched_detections`), and each map is the isotonic
regression of the labels on the verifier probabilities
(:func:`fingertips.calibration.fit_isotonic`). The frames must be neither the
verifiers' training frames nor those the map is then judged on; the shipped model's
are ``configs/fingertips/validation_unseen.toml``'s (``[calibration]`` of
``configs/fingertips/default.toml``).
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Mapping
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fingertips.calibration import (
    SOURCE_SCORE,
    Calibration,
    ConfidenceMap,
    ScoreKind,
    fit_isotonic,
)
from fingertips.data import FingertipDataConfig
from fingertips.detect import DetectorConfig, model_detector_config
from fingertips.evaluation import (
    AnnotatedDepth,
    FrameProgress,
    matched_detections,
    read_annotated_depth,
    run_detector,
)
from fingertips.forest import FingertipForest
from glovedb._validate import dataclass_from_table


@dataclass(frozen=True)
class CalibrationConfig:
    """The ``[calibration]`` table of a training config.

    Attributes
    ----------
    frames : str
        A config whose ``[data]`` table renders the frames (as ``glove fingertips
        synth`` does), relative to the training config's folder.
    n_images : int
        Frames rendered; 0: the frames config's ``n_images``.
    min_probability : float
        The verifier thresholds while fitting (module docstring): the maps hold for
        thresholds at or above it. Positive.
    """

    frames: str
    n_images: int = 0
    min_probability: float = 0.05

    def __post_init__(self) -> None:
        if not 0 < self.min_probability < 1:
            raise ValueError(
                f"min_probability: expected a probability in (0, 1), got {self.min_probability}"
            )
        if self.n_images < 0:
            raise ValueError(f"n_images: expected 0 or more, got {self.n_images}")


def calibration_config_from_dict(table: Mapping[str, Any]) -> CalibrationConfig:
    """Build a :class:`CalibrationConfig` from a TOML table; unknown keys are errors."""
    return dataclass_from_table(CalibrationConfig, table, "calibration")


def _frames_data(config: CalibrationConfig) -> FingertipDataConfig:
    """The data settings the calibration frames are rendered with."""
    from fingertips.data import load_data_config

    data = load_data_config(config.frames)
    return replace(data, n_images=config.n_images) if config.n_images else data


def render_calibration_frames(config: CalibrationConfig) -> tuple[AnnotatedDepth, dict[str, Any]]:
    """Render the frames of ``config`` exactly as ``glove fingertips synth`` writes them.

    They are written to a temporary folder and read back (depth in whole
    millimetres, annotations through JSON), so that fitting on them gives the
    same maps as fitting on a folder ``synth`` wrote.

    Returns
    -------
    frames : AnnotatedDepth
    settings : dict
        What to record: the frames config and the number of frames.
    """
    from fingertips.data import generate_examples, require_one_camera, write_annotated_folder

    data = _frames_data(config)
    require_one_camera(data)
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch) / "frames"
        write_annotated_folder(generate_examples(data), folder, settings={"data": asdict(data)})
        frames = read_annotated_depth(folder, annotations="annotations.jsonl")
    return frames, {"frames": config.frames, "n_images": data.n_images}


def read_calibration_frames(folder: str | Path, config: CalibrationConfig) -> AnnotatedDepth:
    """The frames of ``config`` from a folder ``glove fingertips synth`` wrote.

    Raises
    ------
    ValueError
        If the folder's ``meta.json`` does not record the data settings that
        :func:`render_calibration_frames` would render (another config, seed or
        number of frames).
    """
    data = _frames_data(config)
    expected = json.loads(json.dumps(asdict(data)))
    try:
        recorded = json.loads((Path(folder) / "meta.json").read_text())["settings"]["data"]
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise ValueError(f"{folder}: no meta.json with the data settings of synth") from error
    if recorded != expected:
        raise ValueError(
            f"{folder}: not rendered from {config.frames} with {data.n_images} frames "
            "(its meta.json records other data settings)"
        )
    return read_annotated_depth(folder, annotations="annotations.jsonl")


def calibration_samples(
    frames: AnnotatedDepth,
    model: FingertipForest,
    *,
    min_probability: float,
    config: DetectorConfig | None = None,
    progress: FrameProgress | None = None,
) -> dict[ScoreKind, tuple[NDArray[np.float64], NDArray[np.bool_]]]:
    """The verifier probabilities of detections and whether each is right, per map.

    Parameters
    ----------
    frames : AnnotatedDepth
    model : FingertipForest
        With a peak verifier; its own confidence maps are ignored.
    min_probability : float
        See :class:`CalibrationConfig`.
    config : DetectorConfig, optional
        Default: the model's recorded settings.
    progress : FrameProgress, optional

    Returns
    -------
    dict
        ``{"verifier": (scores (N,) float64, correct (N,) bool)}``, and ``"heatmap"``
        for a model with a heatmap stage.
    """
    if model.verifier is None:
        raise ValueError("model: calibration needs a peak verifier")
    if not 0 < min_probability < 1:
        raise ValueError(
            f"min_probability: expected a probability in (0, 1), got {min_probability}"
        )
    model = without_calibration(model)
    detector = config if config is not None else model_detector_config(model)
    # With a judge or a fusion (fingertips.judge, fingertips.heat_fusion) the
    # candidates' probabilities need the heatmap stage on; its peaks are then left out
    # of the first run's matching.
    fused = model.heatmap is not None and model.heatmap.judges_candidates
    heat_for_fusion = detector.heatmap_min_probability if fused else 0.0
    runs: dict[ScoreKind, DetectorConfig] = {
        "verifier": replace(
            detector,
            min_tip_probability=min_probability,
            heatmap_min_probability=heat_for_fusion,
        )
    }
    if model.heatmap is not None:
        if detector.min_tip_probability == 0:
            raise ValueError("config: the heatmap stage needs min_tip_probability > 0")
        runs["heatmap"] = replace(detector, heatmap_min_probability=min_probability)
    samples = {}
    for kind, settings in runs.items():
        found = run_detector(frames, model, config=settings, progress=progress)[0]
        scores, correct = [], []
        for frame_detections, tips in zip(found, frames.tips_m, strict=True):
            # The heat peaks join the others' matching only in the heatmap's run.
            detections = (
                frame_detections
                if kind == "heatmap"
                else tuple(d for d in frame_detections if SOURCE_SCORE[d.source] == kind)
            )
            matched = matched_detections(detections, tips)
            for detection, right in zip(detections, matched, strict=True):
                if SOURCE_SCORE[detection.source] == kind:
                    scores.append(float(detection.tip_probability or 0.0))
                    correct.append(bool(right))
        samples[kind] = (np.array(scores, dtype=np.float64), np.array(correct, dtype=bool))
    return samples


def fit_calibration(
    frames: AnnotatedDepth,
    model: FingertipForest,
    *,
    min_probability: float,
    settings: Mapping[str, Any] | None = None,
    progress: FrameProgress | None = None,
) -> FingertipForest:
    """``model`` with confidence maps fitted on ``frames`` (module docstring).

    Parameters
    ----------
    frames : AnnotatedDepth
    model : FingertipForest
        With a peak verifier; confidence maps it has are replaced.
    min_probability : float
        See :class:`CalibrationConfig`.
    settings : mapping, optional
        Recorded in the model's settings (``calibration``) beside ``min_probability``
        and the sample counts, e.g. which frames these are.
    progress : FrameProgress, optional

    Returns
    -------
    FingertipForest

    Raises
    ------
    ValueError
        Without a verifier, or when a map has no sample of either outcome.
    """
    samples = calibration_samples(frames, model, min_probability=min_probability, progress=progress)
    maps: dict[str, ConfidenceMap] = {}
    for kind, (scores, correct) in samples.items():
        if correct.all() or not correct.any():
            raise ValueError(
                f"frames: the {kind} detections ({correct.size}) are all right or all "
                "wrong; a confidence map needs both"
            )
        maps[kind] = fit_isotonic(scores, correct)
    recorded = {
        **dict(settings or {}),
        "min_probability": min_probability,
        "samples": {kind: int(s[0].size) for kind, s in samples.items()},
        "correct": {kind: int(s[1].sum()) for kind, s in samples.items()},
    }
    model_settings = {**without_calibration(model).settings, "calibration": recorded}
    return replace(model, calibration=Calibration(maps), settings_json=json.dumps(model_settings))


def without_calibration(model: FingertipForest) -> FingertipForest:
    """``model`` without confidence maps and without their recorded settings."""
    settings = {k: v for k, v in model.settings.items() if k != "calibration"}
    return replace(model, calibration=None, settings_json=json.dumps(settings))


def calibrate_from_config(
    model: FingertipForest,
    config: CalibrationConfig,
    *,
    folder: str | Path | None = None,
    progress: FrameProgress | None = None,
) -> FingertipForest:
    """:func:`fit_calibration` on the frames of ``config``: rendered, or read from a
    ``folder`` that ``glove fingertips synth`` wrote from them
    (:func:`read_calibration_frames`; the same maps, faster)."""
    if folder is None:
        frames, recorded = render_calibration_frames(config)
    else:
        frames = read_calibration_frames(folder, config)
        recorded = {"frames": config.frames, "n_images": len(frames.frames)}
    return fit_calibration(
        frames,
        model,
        min_probability=config.min_probability,
        settings=recorded,
        progress=progress,
    )
