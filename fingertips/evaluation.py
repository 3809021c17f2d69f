"""Scoring fingertip detections against annotated depth frames.

An annotated folder has the RGB-D layout of docs/conventions.md (``intrinsic.json``,
``depth/000000.png``, optional ``meta.json``) plus a JSON-lines file with one object
per frame, holding ``frame`` and either

* ``fingertips``: ``{finger name: {"xyz_m": [3], "uv_px": [2]}}`` (a finger may be
  absent), as in ``shared/data/real_depth/hmodel_andrii``; or
* ``keypoints_3d_m`` (21 x 3) and ``keypoints_2d_px`` (21 x 2) in MediaPipe order,
  fingertips at 4, 8, 12, 16, 20, as in ``groundtruth.jsonl`` (a frame with
  ``hand_visible`` false has no fingertips).

Where the folder also has ``groundtruth.jsonl`` (rendered folders), its 21
``keypoints_3d_m`` per frame come along: the miss causes use them
(:mod:`fingertips.miss_causes`).

Detections are matched to annotated fingertips one-to-one regardless of finger name
(the detector does not know fingers before assignment), maximising the number of
pairs within the distance gate. Each annotated tip that no detection matches is given
one cause (:func:`fingertips.miss_causes.tip_causes`), and the metrics count the
misses by cause.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment

from fingertips.assignment import FINGER_NAMES
from fingertips.calibration import Reliability, reliability_table
from fingertips.depth_input import DepthSequence, read_depth_scale, read_intrinsics
from fingertips.detect import (
    DEFAULT_DETECTOR,
    Detection,
    DetectorConfig,
    detect_fingertips,
    detection_points,
    hand_depth,
)
from fingertips.detector import FingertipDetector
from fingertips.forest import FingertipForest
from fingertips.miss_causes import (
    DEFAULT_MISS_CAUSE_PARAMS,
    MISS_CAUSES,
    MissCause,
    MissCauseParams,
    tip_causes,
)
from glovedb._validate import as_array

MEDIAPIPE_TIPS = (4, 8, 12, 16, 20)
"""Indices of the thumb, index, middle, ring and little fingertips among 21 keypoints."""

TipCauses = Sequence[Sequence[MissCause | None]]
"""Per frame, per annotated tip (thumb to little) its miss cause; None where not
annotated (:func:`annotated_tip_causes`)."""

FrameProgress = Callable[[Iterable[NDArray[np.float32]]], Iterable[NDArray[np.float32]]]
"""Wraps the iterable of depth frames to show progress (e.g. ``tqdm.tqdm``)."""


@dataclass(frozen=True)
class AnnotatedDepth:
    """Depth frames with fingertip annotations.

    Attributes
    ----------
    depth_m : (N, H, W) float32
        Depth in metres, 0 where missing.
    intrinsics : (4,) float64
        ``(fx, fy, cx, cy)`` in pixels.
    tips_m : (N, 5, 3) float64
        Fingertips in the camera frame (metres), thumb to little; NaN if not annotated.
    tips_px : (N, 5, 2) float64
        Fingertips in the image (pixels); NaN if not annotated.
    frames : (N,) int64
        Frame numbers.
    keypoints_m : (N, 21, 3) float64 or None
        The hand's keypoints (MediaPipe order, camera frame, metres) where the folder
        gives them (rendered folders); NaN for a frame without; None when no frame has
        them.
    """

    depth_m: NDArray[np.float32]
    intrinsics: NDArray[np.float64]
    tips_m: NDArray[np.float64]
    tips_px: NDArray[np.float64]
    frames: NDArray[np.int64]
    keypoints_m: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class MissCauseCounts:
    """Missed annotated tips counted by cause (:mod:`fingertips.miss_causes`).

    Attributes
    ----------
    border, segmentation, distance, merged, curled, other : int
        Misses per cause; they add up to :attr:`total`.
    """

    border: int = 0
    segmentation: int = 0
    distance: int = 0
    merged: int = 0
    curled: int = 0
    other: int = 0

    @property
    def total(self) -> int:
        """All misses."""
        return sum(self.as_dict().values())

    def as_dict(self) -> dict[str, int]:
        """The counts as a JSON-ready dict, in the rule's order."""
        return {cause: getattr(self, cause) for cause in MISS_CAUSES}

    @classmethod
    def of(cls, causes: Iterable[MissCause | None]) -> MissCauseCounts:
        """Count the causes (None, a tip that is not annotated, is not counted)."""
        listed = list(causes)
        return cls(**{cause: listed.count(cause) for cause in MISS_CAUSES})


DEPTH_BANDS_M = (0.5, 0.75, 1.0, 1.25)
"""Edges of the depth bands of :attr:`FingertipMetrics.recall_by_depth`, metres."""


def depth_band_names(edges_m: Sequence[float] = DEPTH_BANDS_M) -> tuple[str, ...]:
    """``("0-0.5 m", "0.5-0.75 m", ..., "1.25+ m")`` for the band edges."""
    bounds = ["0", *(f"{edge:g}" for edge in edges_m)]
    return tuple(f"{a}-{b} m" for a, b in itertools.pairwise(bounds)) + (f"{bounds[-1]}+ m",)


def recall_by_depth(
    depths_m: ArrayLike, found: ArrayLike, edges_m: Sequence[float] = DEPTH_BANDS_M
) -> dict[str, dict[str, float]]:
    """Count and recall of annotated tips per depth band.

    Parameters
    ----------
    depths_m : (N,) float
        Camera-frame z of each annotated tip, metres.
    found : (N,) bool
        Whether a detection matched it.
    edges_m : sequence of float
        Band edges, metres, increasing.

    Returns
    -------
    dict
        ``{band name: {"tips": count, "recall_15mm": share or NaN}}`` in band order.
    """
    depths = as_array("depths_m", depths_m, (None,), np.float64, kind="fiu")
    hits = as_array("found", found, (len(depths),), bool, kind="b")
    band = np.searchsorted(np.asarray(edges_m, dtype=np.float64), depths, side="right")
    return {
        name: {
            "tips": int(np.sum(band == k)),
            "recall_15mm": _safe_ratio(int(np.sum(hits[band == k])), int(np.sum(band == k))),
        }
        for k, name in enumerate(depth_band_names(edges_m))
    }


@dataclass(frozen=True)
class FingertipMetrics:
    """Detection scores, pooled over all frames.

    Attributes
    ----------
    frames, detections, annotated_tips : int
        Counts.
    precision_15mm, recall_15mm : float
        Share of detections / annotated tips matched within 15 mm in 3D (NaN if there
        are none to share).
    error_3d_mm, error_2d_px : float
        Mean 3D distance (mm) and 2D distance (px) of the pairs matched within 15 mm.
    recall_10px : float
        Share of annotated tips matched within 10 px in the image.
    error_2d_px_ungated : float
        Mean 2D distance (px) of a one-to-one matching of detections to annotated tips
        without a distance gate (each frame pairs min(detections, tips) of them).
    ms_per_frame : float
        Mean detection time per frame in milliseconds (NaN when not measured).
    missed_15mm, missed_10px : MissCauseCounts or None
        The annotated tips no detection matches within 15 mm (3D) or 10 px, by cause;
        None when the causes were not given.
    recall_by_depth : dict
        Per band of the annotated tips' depth (:data:`DEPTH_BANDS_M`, named like
        ``"0.5-0.75 m"``): ``{"tips": count, "recall_15mm": share}`` (NaN if none).
    reliability : Reliability or None
        The detections' probabilities against their being matched within 15 mm
        (:func:`fingertips.calibration.reliability_table`): the calibrated confidences
        when ``calibrated``, else the verifiers' ``tip_probability``; None when a
        detection has neither (a model without a verifier).
    calibrated : bool
        Whether the detections' confidences are calibrated.
    """

    frames: int
    detections: int
    annotated_tips: int
    precision_15mm: float
    recall_15mm: float
    error_3d_mm: float
    error_2d_px: float
    recall_10px: float
    error_2d_px_ungated: float = math.nan
    ms_per_frame: float = math.nan
    missed_15mm: MissCauseCounts | None = None
    missed_10px: MissCauseCounts | None = None
    recall_by_depth: dict[str, dict[str, float]] = field(default_factory=dict)
    reliability: Reliability | None = None
    calibrated: bool = False

    def as_dict(self) -> dict[str, Any]:
        """The metrics as a JSON-ready dict (the miss counts as nested dicts)."""
        return asdict(self)


def _coordinates(name: str, value: ArrayLike, shape: tuple[int, ...]) -> NDArray[np.float64]:
    return as_array(name, value, shape, np.float64, kind="fiu", finite=True)


def _tips_of_record(record: dict) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Fingertips of one annotation record; NaN rows where a tip is not annotated.

    A record gives ``fingertips`` (``{finger: {"xyz_m", "uv_px"}}``, a missing or null
    finger is not annotated), or the 21 ``keypoints_3d_m`` and ``keypoints_2d_px``, or
    ``"hand_visible": false``. Anything else (an unknown finger, a tip with only one
    of its positions, non-finite values) raises ValueError: a silently dropped tip
    would change the scores.
    """
    tips_m = np.full((len(FINGER_NAMES), 3), np.nan)
    tips_px = np.full((len(FINGER_NAMES), 2), np.nan)
    if "fingertips" in record:
        fingertips = record["fingertips"]
        if not isinstance(fingertips, dict):
            raise ValueError(f"fingertips: expected an object, got {fingertips!r}")
        unknown = sorted(set(fingertips) - set(FINGER_NAMES))
        if unknown:
            raise ValueError(f"fingertips: unknown finger {unknown[0]!r}, expected {FINGER_NAMES}")
        for k, name in enumerate(FINGER_NAMES):
            tip = fingertips.get(name)
            if tip is None:
                continue
            tips_m[k] = _coordinates(f"fingertips.{name}.xyz_m", tip["xyz_m"], (3,))
            tips_px[k] = _coordinates(f"fingertips.{name}.uv_px", tip["uv_px"], (2,))
    elif "keypoints_3d_m" in record or "keypoints_2d_px" in record:
        if record.get("hand_visible", True):
            keypoints_m = _coordinates("keypoints_3d_m", record["keypoints_3d_m"], (21, 3))
            keypoints_px = _coordinates("keypoints_2d_px", record["keypoints_2d_px"], (21, 2))
            tips_m[:] = keypoints_m[list(MEDIAPIPE_TIPS)]
            tips_px[:] = keypoints_px[list(MEDIAPIPE_TIPS)]
    elif record.get("hand_visible", True) is not False:
        raise ValueError('expected fingertips, keypoints_3d_m or "hand_visible": false')
    return tips_m, tips_px


def _keypoints_of_record(record: dict) -> NDArray[np.float64]:
    """The 21 ``keypoints_3d_m`` of a record, NaN when it has none or no visible hand."""
    if "keypoints_3d_m" in record and record.get("hand_visible", True):
        return _coordinates("keypoints_3d_m", record["keypoints_3d_m"], (21, 3))
    return np.full((21, 3), np.nan)


def _read_jsonl(path: Path) -> Iterable[tuple[int, dict]]:
    """``(line number, record)`` of every non-empty line; ValueError names FILE:LINE."""
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as error:
        raise ValueError(f"{path}: not UTF-8 text (byte {error.start})") from error
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError as error:
            raise ValueError(f"{path}:{number}: not an annotation record ({error!r})") from error
        if not isinstance(record, dict):
            raise ValueError(f"{path}:{number}: not an annotation record (expected an object)")
        yield number, record


def _groundtruth_keypoints(path: Path) -> dict[int, NDArray[np.float64]]:
    """Frame number to its 21 keypoints (NaN without a visible hand) of ``groundtruth.jsonl``."""
    keypoints = {}
    for number, record in _read_jsonl(path):
        try:
            keypoints[_frame_number(record["frame"])] = _keypoints_of_record(record)
        except (KeyError, TypeError) as error:
            raise ValueError(f"{path}:{number}: not a ground-truth record ({error!r})") from error
        except ValueError as error:
            raise ValueError(f"{path}:{number}: {error}") from error
    return keypoints


def _frame_number(value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"frame: expected a whole number >= 0, got {value!r}")
    return value


def read_annotated_depth(
    folder: str | os.PathLike[str], *, annotations: str = "annotations.jsonl"
) -> AnnotatedDepth:
    """Read the depth frames and fingertip annotations of an annotated RGB-D folder.

    Parameters
    ----------
    folder : path
        The sequence folder.
    annotations : str
        Name of the JSON-lines annotation file inside ``folder`` (e.g.
        ``"groundtruth.jsonl"`` for synthetic sequences).

    Returns
    -------
    AnnotatedDepth
        The annotated frames, in file order; with the keypoints of the annotation
        records, or else of the folder's ``groundtruth.jsonl`` if there is one.

    Raises
    ------
    ValueError
        If a file is missing, an annotation line (or a ``groundtruth.jsonl`` line read
        for its keypoints) is malformed, there are no annotated frames, or a depth
        image is not a 16-bit PNG of the size ``intrinsic.json`` gives.
    """
    root = Path(folder)
    path = root / annotations
    if not path.is_file() or not (root / "intrinsic.json").is_file():
        raise ValueError(f"{root}: expected intrinsic.json and {annotations}")
    frames, tips_m, tips_px, keypoints = [], [], [], []
    seen: set[int] = set()
    for number, record in _read_jsonl(path):
        try:
            frame = _frame_number(record["frame"])
            frame_m, frame_px = _tips_of_record(record)
            keypoints.append(_keypoints_of_record(record))
        except (KeyError, TypeError, AttributeError) as error:
            raise ValueError(f"{path}:{number}: not an annotation record ({error!r})") from error
        except ValueError as error:
            raise ValueError(f"{path}:{number}: {error}") from error
        if frame in seen:
            raise ValueError(f"{path}:{number}: frame {frame} is annotated twice")
        seen.add(frame)
        frames.append(frame)
        tips_m.append(frame_m)
        tips_px.append(frame_px)
    if not frames:
        raise ValueError(f"{path}: no annotated frames")
    truth = root / "groundtruth.jsonl"
    if np.all(np.isnan(keypoints)) and truth.is_file() and truth != path:
        by_frame = _groundtruth_keypoints(truth)
        keypoints = [by_frame.get(frame, np.full((21, 3), np.nan)) for frame in frames]
    intrinsics, size = read_intrinsics(root)
    sequence = DepthSequence(root, intrinsics, size, read_depth_scale(root), tuple(frames))
    return AnnotatedDepth(
        depth_m=np.stack([sequence.read_depth(frame) for frame in frames]),
        intrinsics=intrinsics,
        tips_m=np.stack(tips_m),
        tips_px=np.stack(tips_px),
        frames=np.array(frames, dtype=np.int64),
        keypoints_m=None if np.all(np.isnan(keypoints)) else np.stack(keypoints),
    )


def match_within(distance: NDArray[np.float64], gate: float) -> tuple[NDArray, NDArray]:
    """Largest one-to-one matching with ``distance <= gate``, cheapest among those.

    Parameters
    ----------
    distance : (S, T) float
        Pairwise distances; NaN never matches.
    gate : float

    Returns
    -------
    rows, cols : (K,) intp
        Matched index pairs.
    """
    allowed = np.isfinite(distance) & (distance <= gate)
    # A penalty above any sum of allowed distances makes the count come first.
    penalty = 1.0 + gate * (min(distance.shape) + 1)
    cost = np.where(allowed, np.nan_to_num(distance), penalty)
    rows, cols = linear_sum_assignment(cost)
    keep = allowed[rows, cols]
    return rows[keep], cols[keep]


def matched_detections(
    detections: Sequence[Detection], tips_m: ArrayLike, *, gate_m: float = 0.015
) -> NDArray[np.bool_]:
    """Which detections of one frame are matched to an annotated tip within ``gate_m``.

    The one-to-one matching of ``precision`` (:func:`match_within` on 3D distances).

    Parameters
    ----------
    detections : sequence of Detection
    tips_m : (5, 3) float
        Annotated fingertips, metres; NaN rows are not annotated.
    gate_m : float

    Returns
    -------
    (K,) bool
    """
    tips = np.asarray(tips_m, dtype=np.float64).reshape(-1, 3)
    annotated = tips[np.all(np.isfinite(tips), axis=1)]
    distance = np.linalg.norm(detection_points(detections)[:, None] - annotated[None], axis=2)
    matched = np.zeros(len(detections), dtype=bool)
    matched[match_within(distance, gate_m)[0]] = True
    return matched


def match_frame_2d(
    uv_px: NDArray[np.float64], tips_px: NDArray[np.float64], *, gate_px: float = 10.0
) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Which annotated tips and which detections of one frame are paired within ``gate_px``.

    The one-to-one matching of ``recall_at_10px`` (:func:`match_within` on image
    distances).

    Parameters
    ----------
    uv_px : (K, 2) float
        Detections, pixels.
    tips_px : (5, 2) float
        Annotated fingertips, pixels; NaN rows are not annotated (never found).
    gate_px : float

    Returns
    -------
    tip_found : (5,) bool
    detection_matched : (K,) bool
    """
    detections = np.asarray(uv_px, dtype=np.float64).reshape(-1, 2)
    tips = np.asarray(tips_px, dtype=np.float64).reshape(-1, 2)
    annotated = np.flatnonzero(np.all(np.isfinite(tips), axis=1))
    distance = np.linalg.norm(detections[:, None] - tips[None, annotated], axis=2)
    rows, cols = match_within(distance, gate_px)
    tip_found = np.zeros(tips.shape[0], dtype=bool)
    tip_found[annotated[cols]] = True
    detection_matched = np.zeros(detections.shape[0], dtype=bool)
    detection_matched[rows] = True
    return tip_found, detection_matched


def _safe_ratio(numerator: float, denominator: float) -> float:
    return numerator / denominator if denominator else math.nan


def fingertip_metrics(
    detections: Sequence[Sequence[Detection]],
    tips_m: NDArray[np.float64],
    tips_px: NDArray[np.float64],
    *,
    gate_3d_m: float = 0.015,
    gate_2d_px: float = 10.0,
    ms_per_frame: float = math.nan,
    causes: TipCauses | None = None,
) -> FingertipMetrics:
    """Score per-frame detections against annotated fingertips.

    Parameters
    ----------
    detections : sequence of sequences of Detection
        One sequence per frame.
    tips_m : (N, 5, 3) float
        Annotated fingertips, metres; NaN where not annotated.
    tips_px : (N, 5, 2) float
        Annotated fingertips, pixels; NaN where not annotated.
    gate_3d_m, gate_2d_px : float
        Match gates in 3D (metres) and 2D (pixels).
    ms_per_frame : float
        Detection time to report with the scores (from :func:`run_detector`).
    causes : sequence of sequences of (str or None), optional
        Per frame, each tip's miss cause (:func:`annotated_tip_causes`); given, the
        misses at each gate are counted by cause.

    Returns
    -------
    FingertipMetrics
    """
    if not len(detections) == tips_m.shape[0] == tips_px.shape[0]:
        raise ValueError("detections, tips_m, tips_px: expected one entry per frame each")
    if causes is not None and not (
        len(causes) == len(detections) and all(len(c) == tips_m.shape[1] for c in causes)
    ):
        raise ValueError("causes: expected one cause per annotated tip slot of every frame")
    if np.any(np.all(np.isfinite(tips_m), axis=2) != np.all(np.isfinite(tips_px), axis=2)):
        raise ValueError("tips_m, tips_px: every tip needs both positions or neither")
    n_det = n_tip = matched_3d = matched_2d = 0
    errors_3d: list[float] = []
    errors_2d: list[float] = []
    errors_ungated: list[float] = []
    missed_3d: list[MissCause | None] = []
    missed_2d: list[MissCause | None] = []
    tip_depths: list[float] = []
    tip_found: list[bool] = []
    correct: list[bool] = []
    for k, (frame_dets, frame_m, frame_px) in enumerate(
        zip(detections, tips_m, tips_px, strict=True)
    ):
        annotated = np.all(np.isfinite(frame_m), axis=1)
        xyz = detection_points(frame_dets)
        uv = np.array([[d.u_px, d.v_px] for d in frame_dets]).reshape(-1, 2)
        distance_3d = np.linalg.norm(xyz[:, None] - frame_m[None, annotated], axis=2)
        distance_2d = np.linalg.norm(uv[:, None] - frame_px[None, annotated], axis=2)
        rows, cols = match_within(distance_3d, gate_3d_m)
        correct.extend(np.isin(np.arange(len(frame_dets)), rows).tolist())
        errors_3d.extend(1000.0 * distance_3d[rows, cols])
        errors_2d.extend(distance_2d[rows, cols])
        n_det += len(frame_dets)
        n_tip += int(annotated.sum())
        matched_3d += rows.size
        found_2d = match_frame_2d(uv, frame_px, gate_px=gate_2d_px)[0]
        matched_2d += int(found_2d.sum())
        found_3d = np.zeros(annotated.size, dtype=bool)
        found_3d[np.flatnonzero(annotated)[cols]] = True
        tip_depths.extend(frame_m[annotated, 2].tolist())
        tip_found.extend(found_3d[annotated].tolist())
        if causes is not None:
            missed_3d.extend(causes[k][t] for t in np.flatnonzero(annotated & ~found_3d).tolist())
            missed_2d.extend(causes[k][t] for t in np.flatnonzero(annotated & ~found_2d).tolist())
        if distance_2d.size:
            rows_all, cols_all = linear_sum_assignment(distance_2d)
            errors_ungated.extend(distance_2d[rows_all, cols_all])
    return FingertipMetrics(
        frames=len(detections),
        detections=n_det,
        annotated_tips=n_tip,
        precision_15mm=_safe_ratio(matched_3d, n_det),
        recall_15mm=_safe_ratio(matched_3d, n_tip),
        error_3d_mm=float(np.mean(errors_3d)) if errors_3d else math.nan,
        error_2d_px=float(np.mean(errors_2d)) if errors_2d else math.nan,
        recall_10px=_safe_ratio(matched_2d, n_tip),
        error_2d_px_ungated=float(np.mean(errors_ungated)) if errors_ungated else math.nan,
        ms_per_frame=ms_per_frame,
        missed_15mm=None if causes is None else MissCauseCounts.of(missed_3d),
        missed_10px=None if causes is None else MissCauseCounts.of(missed_2d),
        recall_by_depth=recall_by_depth(tip_depths, np.array(tip_found, dtype=bool)),
        reliability=_reliability([d for frame in detections for d in frame], correct),
        calibrated=any(d.raw_confidence is not None for frame in detections for d in frame),
    )


def detection_probability(detection: Detection) -> float | None:
    """A detection's probability of being right: its calibrated confidence, else its
    verifier probability (None without either)."""
    if detection.raw_confidence is not None:
        return detection.confidence
    return detection.tip_probability


def _reliability(detections: Sequence[Detection], correct: Sequence[bool]) -> Reliability | None:
    """The reliability table of the detections' probabilities, None if one has none."""
    probabilities = [detection_probability(d) for d in detections]
    if any(p is None for p in probabilities):
        return None
    return reliability_table(np.array(probabilities, dtype=np.float64), np.array(correct, bool))


def annotated_tip_causes(
    data: AnnotatedDepth,
    model: FingertipForest,
    *,
    config: DetectorConfig = DEFAULT_DETECTOR,
    params: MissCauseParams = DEFAULT_MISS_CAUSE_PARAMS,
) -> list[tuple[MissCause | None, ...]]:
    """The cause each annotated tip of each frame would be missed for.

    :func:`fingertips.miss_causes.tip_causes` with the hand pixels the detector keeps
    (:func:`fingertips.detect.hand_depth` with ``config``'s segmentation), the model's
    working depth range and the frames' keypoints where ``data`` has them.

    Parameters
    ----------
    data : AnnotatedDepth
    model : FingertipForest
    config : DetectorConfig
        The settings the detections were made with.
    params : MissCauseParams

    Returns
    -------
    list of tuple of (str or None)
        Per frame, per tip slot (thumb to little): a cause of
        :data:`fingertips.miss_causes.MISS_CAUSES`, None where not annotated.
    """
    causes = []
    for k, depth in enumerate(data.depth_m):
        hand = hand_depth(
            depth,
            model,
            depth_band_m=config.depth_band_m,
            segmentation=config.segmentation,
            intrinsics=data.intrinsics,
        )
        causes.append(
            tip_causes(
                depth,
                data.intrinsics,
                data.tips_m[k],
                data.tips_px[k],
                hand_depth_m=hand,
                keypoints_m=None if data.keypoints_m is None else data.keypoints_m[k],
                working_range_m=model.depth_range_m,
                params=params,
            )
        )
    return causes


def evaluate_detector(
    data: AnnotatedDepth,
    model: FingertipForest,
    *,
    config: DetectorConfig = DEFAULT_DETECTOR,
    progress: FrameProgress | None = None,
) -> FingertipMetrics:
    """Run :func:`detect_fingertips` on every frame and score the detections.

    Parameters
    ----------
    data : AnnotatedDepth
    model : FingertipForest
    config : DetectorConfig
    progress : callable, optional
        Wraps the frame iterable (e.g. ``tqdm.tqdm``) to show progress.

    Returns
    -------
    FingertipMetrics
        Including the mean wall-clock detection time per frame and the misses by
        cause (:func:`annotated_tip_causes`).
    """
    detections, ms_per_frame = run_detector(data, model, config=config, progress=progress)
    causes = annotated_tip_causes(data, model, config=config)
    return fingertip_metrics(
        detections, data.tips_m, data.tips_px, ms_per_frame=ms_per_frame, causes=causes
    )


def run_detector(
    data: AnnotatedDepth,
    model: FingertipForest,
    *,
    config: DetectorConfig = DEFAULT_DETECTOR,
    progress: FrameProgress | None = None,
) -> tuple[list[tuple[Detection, ...]], float]:
    """:func:`detect_fingertips` on every frame of ``data``.

    Parameters
    ----------
    data : AnnotatedDepth
    model : FingertipForest
    config : DetectorConfig
    progress : FrameProgress, optional

    Returns
    -------
    detections : list of tuple of Detection
        One tuple per frame.
    ms_per_frame : float
        Mean wall-clock detection time, milliseconds, after one untimed run on the
        first frame (which loads the heatmap network into onnxruntime and the compiled
        forest code).
    """
    frames: Iterable[NDArray[np.float32]] = data.depth_m
    if len(data.depth_m):
        detect_fingertips(data.depth_m[0], data.intrinsics, model, config=config)
    if progress is not None:
        frames = progress(frames)
    detections = []
    elapsed = 0.0
    for depth in frames:
        start = time.perf_counter()
        detections.append(detect_fingertips(depth, data.intrinsics, model, config=config))
        elapsed += time.perf_counter() - start
    return detections, 1000.0 * elapsed / max(len(detections), 1)


@dataclass(frozen=True)
class PoseGuessMetrics:
    """How well :meth:`FingertipDetector.guess_pose` starts a tracker, against rendered truth.

    Attributes
    ----------
    frames : int
        Right-hand frames with a visible hand (the guess fits a right hand).
    guessed : int
        Of those, frames with a guess (at least three detections).
    rotation_deg_median, wrist_mm_median, keypoint_mm_median : float
        Medians over the guessed frames: rotation angle error, wrist distance, mean
        distance of the 21 keypoints.
    within_15deg : float
        Share of the guessed frames with a rotation error below 15 degrees.
    ms_per_guess : float
        Mean wall-clock time of a guess, over the guessed frames (detection not
        included).
    """

    frames: int
    guessed: int
    rotation_deg_median: float
    wrist_mm_median: float
    keypoint_mm_median: float
    within_15deg: float
    ms_per_guess: float

    def as_dict(self) -> dict[str, float | int]:
        """The metrics as a JSON-ready dict."""
        return asdict(self)


def evaluate_pose_guesses(
    folder: str | os.PathLike[str],
    detector: FingertipDetector,
    *,
    posture_rad: NDArray[np.float64] | None = None,
    progress: Callable[[Iterable[int]], Iterable[int]] | None = None,
) -> PoseGuessMetrics:
    """Score pose guesses on a rendered folder whose ``groundtruth.jsonl`` has poses.

    Parameters
    ----------
    folder : path
        Written by ``glove fingertips synth`` or ``glove render-sequence``.
    detector : FingertipDetector
    posture_rad : (20,) or (P, 20) float, optional
        Postures offered to the guess (default: the detector's, the named postures).
    progress : callable, optional
        Wraps the iterable of scored record indices (e.g. ``tqdm.tqdm``).

    Raises
    ------
    ValueError
        If ``groundtruth.jsonl`` is missing, or a line of it lacks a pose field
        (:func:`tracker.evaluation.read_groundtruth`).
    """
    from fingertips.depth_input import open_depth_sequence
    from glovedb.hand_model import make_skeleton
    from glovedb.rotations import geodesic_angle
    from tracker.evaluation import read_groundtruth

    root = Path(folder)
    path = root / "groundtruth.jsonl"
    if not path.is_file():
        raise ValueError(f"{root}: pose guesses need groundtruth.jsonl (a rendered folder)")
    truth = read_groundtruth(path)  # every line's pose fields, FILE:LINE on errors
    # The fields the tracker's ground truth does not have: which hand, and its length.
    extras = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    sequence = open_depth_sequence(root)
    rows, elapsed = [], 0.0
    usable = [
        k
        for k, extra in enumerate(extras)
        if truth.hand_visible[k] and extra.get("hand", "right") == "right"
    ]
    for k in progress(usable) if progress is not None else usable:
        depth = sequence.read_depth(int(truth.frames[k]))
        detections = detector.detect(depth, sequence.intrinsics)
        length = extras[k].get("hand_length_m")
        skeleton = make_skeleton(float(length)) if length is not None else None
        started = time.perf_counter()
        guess = detector.guess_pose(
            detections, depth, sequence.intrinsics, posture_rad=posture_rad, skeleton=skeleton
        )
        if guess is None:
            continue
        elapsed += time.perf_counter() - started
        rows.append(
            (
                float(np.degrees(geodesic_angle(guess.rotation, truth.rotation[k]))),
                1000.0 * float(np.linalg.norm(guess.translation_m - truth.translation_m[k])),
                1000.0
                * float(
                    np.linalg.norm(guess.keypoints_3d_m - truth.keypoints_3d_m[k], axis=1).mean()
                ),
            )
        )
    errors = np.array(rows).reshape(-1, 3)
    median = np.median(errors, axis=0) if rows else np.full(3, math.nan)
    return PoseGuessMetrics(
        frames=len(usable),
        guessed=len(rows),
        rotation_deg_median=float(median[0]),
        wrist_mm_median=float(median[1]),
        keypoint_mm_median=float(median[2]),
        within_15deg=_safe_ratio(float(np.sum(errors[:, 0] < 15.0)), len(rows)),
        ms_per_guess=1000.0 * elapsed / max(len(rows), 1),
    )
