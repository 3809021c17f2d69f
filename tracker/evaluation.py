"""Scoring tracking output against synthetic ground truth (thesis ch. 4.3).

The definitions are docs/conventions.md's, per frame:

- **posture error**: mean over the 20 joint angles of ``|estimate - truth|``, degrees;
- **rotation error**: geodesic angle of ``R_est^T R_true``, degrees;
- **position error**: distance between estimated and true wrist, millimetres;
- **keypoint error**: mean 2D distance over the 21 keypoints, pixels.

A frame whose hand is visible (``hand_visible`` in ``groundtruth.jsonl``) but not
found (``hand_found`` false in ``poses.jsonl``) is a **missed frame**: it is counted
apart and left out of the error statistics. A frame whose hand is not visible but
found is a **false detection**, also counted apart. Errors are summarised as
``{"mean", "median", "max"}`` over the scored frames (visible and found).

Besides the numbers: the per-frame errors as CSV (:func:`write_errors_csv`) and a
picture like the thesis' Figures 4.7 and 4.8 (:func:`error_plot`): posture, rotation
and position error over time with a strip of keyframe thumbnails above.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array
from glovedb.rotations import geodesic_angle
from tracker.overlay import write_rgb

N_JOINTS = 20
N_KEYPOINTS = 21


@dataclass(frozen=True)
class ErrorSummary:
    """Mean, median and maximum of an error over the scored frames (NaN if none)."""

    mean: float
    median: float
    max: float

    def as_dict(self) -> dict[str, float | None]:
        """``{"mean", "median", "max"}``, JSON-ready (None for NaN)."""
        return {
            key: None if math.isnan(value) else value
            for key, value in (("mean", self.mean), ("median", self.median), ("max", self.max))
        }


def summarize(values: ArrayLike) -> ErrorSummary:
    """:class:`ErrorSummary` of the finite entries of ``values`` ``(N,)``."""
    array = as_array("values", values, (None,), np.float64)
    finite = array[np.isfinite(array)]
    if len(finite) == 0:
        return ErrorSummary(math.nan, math.nan, math.nan)
    return ErrorSummary(float(finite.mean()), float(np.median(finite)), float(finite.max()))


def posture_error_deg(estimate_rad: ArrayLike, truth_rad: ArrayLike) -> NDArray[np.float64]:
    """Mean absolute joint angle difference per frame.

    Parameters
    ----------
    estimate_rad, truth_rad : (N, 20) float
        Postures in radians.

    Returns
    -------
    (N,) float64
        Degrees.
    """
    estimate = as_array("estimate_rad", estimate_rad, (None, N_JOINTS), np.float64)
    truth = as_array("truth_rad", truth_rad, estimate.shape, np.float64)
    return np.degrees(np.abs(estimate - truth).mean(axis=1))


def rotation_error_deg(estimate: ArrayLike, truth: ArrayLike) -> NDArray[np.float64]:
    """Geodesic angle of ``R_est^T R_true`` per frame.

    Parameters
    ----------
    estimate, truth : (N, 3, 3) float
        ``cam_R_hand``.

    Returns
    -------
    (N,) float64
        Degrees in ``[0, 180]``.
    """
    R_est = as_array("estimate", estimate, (None, 3, 3), np.float64)
    R_true = as_array("truth", truth, R_est.shape, np.float64)
    return np.degrees(geodesic_angle(R_est, R_true))


def position_error_mm(estimate_m: ArrayLike, truth_m: ArrayLike) -> NDArray[np.float64]:
    """Distance between estimated and true wrist positions per frame.

    Parameters
    ----------
    estimate_m, truth_m : (N, 3) float
        Wrist in the camera frame, metres.

    Returns
    -------
    (N,) float64
        Millimetres.
    """
    estimate = as_array("estimate_m", estimate_m, (None, 3), np.float64)
    truth = as_array("truth_m", truth_m, estimate.shape, np.float64)
    return 1000.0 * np.linalg.norm(estimate - truth, axis=1)


def keypoint_error_px(estimate_px: ArrayLike, truth_px: ArrayLike) -> NDArray[np.float64]:
    """Mean 2D distance over the 21 keypoints per frame.

    Parameters
    ----------
    estimate_px, truth_px : (N, 21, 2) float
        Keypoint projections, pixels.

    Returns
    -------
    (N,) float64
        Pixels.
    """
    estimate = as_array("estimate_px", estimate_px, (None, N_KEYPOINTS, 2), np.float64)
    truth = as_array("truth_px", truth_px, estimate.shape, np.float64)
    return np.linalg.norm(estimate - truth, axis=2).mean(axis=1)


@dataclass(frozen=True)
class GroundTruth:
    """The contents of a ``groundtruth.jsonl`` file, frame by frame.

    Attributes
    ----------
    frames : (N,) int64
    hand_visible : (N,) bool
    posture_rad : (N, 20) float64
    rotation : (N, 3, 3) float64
    translation_m : (N, 3) float64
    keypoints_3d_m : (N, 21, 3) float64
    keypoints_2d_px : (N, 21, 2) float64
    """

    frames: NDArray[np.int64]
    hand_visible: NDArray[np.bool_]
    posture_rad: NDArray[np.float64]
    rotation: NDArray[np.float64]
    translation_m: NDArray[np.float64]
    keypoints_3d_m: NDArray[np.float64]
    keypoints_2d_px: NDArray[np.float64]


@dataclass(frozen=True)
class TrackedPoses:
    """The scored fields of a ``poses.jsonl`` file; NaN where the hand was not found.

    Attributes
    ----------
    frames : (N,) int64
    hand_found : (N,) bool
    posture_rad : (N, 20) float64
    rotation : (N, 3, 3) float64
    translation_m : (N, 3) float64
    keypoints_2d_px : (N, 21, 2) float64
    """

    frames: NDArray[np.int64]
    hand_found: NDArray[np.bool_]
    posture_rad: NDArray[np.float64]
    rotation: NDArray[np.float64]
    translation_m: NDArray[np.float64]
    keypoints_2d_px: NDArray[np.float64]


_POSE_FIELDS: dict[str, tuple[int, ...]] = {
    "posture_rad": (N_JOINTS,),
    "rotation": (3, 3),
    "translation_m": (3,),
    "keypoints_2d_px": (N_KEYPOINTS, 2),
}
_TRUTH_FIELDS: dict[str, tuple[int, ...]] = {**_POSE_FIELDS, "keypoints_3d_m": (N_KEYPOINTS, 3)}


def _records(path: Path) -> Iterator[tuple[str, dict[str, Any]]]:
    """``(where, object)`` of every non-blank line; ``where`` is ``path:line``."""
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError as error:
        raise ValueError(f"{path}: cannot read ({error.strerror})") from error
    except UnicodeDecodeError as error:
        raise ValueError(f"{path}: not UTF-8 text (byte {error.start})") from error
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        where = f"{path}:{number}"
        try:
            record = json.loads(line)
        except json.JSONDecodeError as error:
            raise ValueError(f"{where}: not valid JSON ({error.msg})") from error
        if not isinstance(record, dict):
            raise ValueError(f"{where}: expected a JSON object")
        yield where, record


def _flag(record: dict[str, Any], key: str, where: str) -> bool:
    value = record.get(key)
    if not isinstance(value, bool):
        raise ValueError(f"{where}: expected {key!r} true or false, got {value!r}")
    return value


def _frame(record: dict[str, Any], where: str, previous: int | None) -> int:
    value = record.get("frame")
    if not isinstance(value, int) or isinstance(value, bool) or value < 0:
        raise ValueError(f"{where}: expected 'frame' a non-negative integer, got {value!r}")
    if previous is not None and value != previous + 1:
        raise ValueError(f"{where}: frame {value} follows frame {previous} (expected consecutive)")
    return value


def _fields(
    record: dict[str, Any], shapes: Mapping[str, tuple[int, ...]], where: str
) -> dict[str, NDArray[np.float64]]:
    values = {}
    for key, shape in shapes.items():
        if key not in record:
            raise ValueError(f"{where}: missing {key!r}")
        try:
            values[key] = as_array(f"{where}: {key}", record[key], shape, np.float64, finite=True)
        except TypeError as error:
            raise ValueError(str(error)) from error
    return values


def _stack(rows: list[dict[str, NDArray[np.float64]]], key: str) -> NDArray[np.float64]:
    return np.array([row[key] for row in rows], dtype=np.float64)


def read_groundtruth(path: str | Path) -> GroundTruth:
    """Read ``groundtruth.jsonl``; one-line ``ValueError`` naming the line if malformed.

    Every line needs ``frame`` (consecutive), ``hand_visible`` and the pose fields of
    docs/conventions.md, also when the hand is not visible.
    """
    path = Path(path)
    frames: list[int] = []
    visible: list[bool] = []
    rows: list[dict[str, NDArray[np.float64]]] = []
    for where, record in _records(path):
        frames.append(_frame(record, where, frames[-1] if frames else None))
        visible.append(_flag(record, "hand_visible", where))
        rows.append(_fields(record, _TRUTH_FIELDS, where))
    if not frames:
        raise ValueError(f"{path}: no frames")
    return GroundTruth(
        np.array(frames, np.int64), np.array(visible, bool),
        *(_stack(rows, key) for key in ("posture_rad", "rotation", "translation_m",
                                        "keypoints_3d_m", "keypoints_2d_px")),
    )  # fmt: skip


def read_poses(path: str | Path) -> TrackedPoses:
    """Read the scored fields of ``poses.jsonl``; one-line ``ValueError`` if malformed.

    Every line needs ``frame`` (consecutive) and ``hand_found``; a found hand needs
    ``posture_rad``, ``rotation``, ``translation_m`` and ``keypoints_2d_px``.
    """
    path = Path(path)
    frames: list[int] = []
    found: list[bool] = []
    rows: list[dict[str, NDArray[np.float64]]] = []
    missing = {key: np.full(shape, np.nan) for key, shape in _POSE_FIELDS.items()}
    for where, record in _records(path):
        frames.append(_frame(record, where, frames[-1] if frames else None))
        found.append(_flag(record, "hand_found", where))
        rows.append(_fields(record, _POSE_FIELDS, where) if found[-1] else missing)
    if not frames:
        raise ValueError(f"{path}: no frames")
    return TrackedPoses(
        np.array(frames, np.int64), np.array(found, bool),
        *(_stack(rows, key) for key in ("posture_rad", "rotation", "translation_m",
                                        "keypoints_2d_px")),
    )  # fmt: skip


@dataclass(frozen=True)
class FrameErrors:
    """Errors of every frame; NaN where a frame is not scored (not visible or not found).

    Attributes
    ----------
    frames : (N,) int64
    hand_visible, hand_found : (N,) bool
    posture_error_deg, rotation_error_deg, position_error_mm, keypoint_error_px : (N,) float64
    """

    frames: NDArray[np.int64]
    hand_visible: NDArray[np.bool_]
    hand_found: NDArray[np.bool_]
    posture_error_deg: NDArray[np.float64]
    rotation_error_deg: NDArray[np.float64]
    position_error_mm: NDArray[np.float64]
    keypoint_error_px: NDArray[np.float64]

    @property
    def missed(self) -> NDArray[np.bool_]:
        """``(N,) bool``: hand visible but not found."""
        return self.hand_visible & ~self.hand_found

    @property
    def scored(self) -> NDArray[np.bool_]:
        """``(N,) bool``: hand visible and found."""
        return self.hand_visible & self.hand_found


ERROR_NAMES = ("posture_error_deg", "rotation_error_deg", "position_error_mm", "keypoint_error_px")


@dataclass(frozen=True)
class EvaluationResult:
    """Scores of a tracked sequence (module docstring).

    Attributes
    ----------
    frames : int
        Frames scored against the ground truth (the frames of ``poses.jsonl``).
    visible_frames : int
        Of those, frames with the hand visible.
    missed_frames : int
        Hand visible but not found.
    false_detections : int
        Hand not visible but found.
    posture_error_deg, rotation_error_deg, position_error_mm, keypoint_error_px : ErrorSummary
        Over the frames with the hand visible and found.
    per_frame : FrameErrors
    """

    frames: int
    visible_frames: int
    missed_frames: int
    false_detections: int
    posture_error_deg: ErrorSummary
    rotation_error_deg: ErrorSummary
    position_error_mm: ErrorSummary
    keypoint_error_px: ErrorSummary
    per_frame: FrameErrors

    def as_dict(self) -> dict[str, Any]:
        """The scores as a JSON-ready dict (the keys of ``glove eval --json``)."""
        counts = {
            "frames": self.frames,
            "visible_frames": self.visible_frames,
            "scored_frames": int(self.per_frame.scored.sum()),
            "missed_frames": self.missed_frames,
            "false_detections": self.false_detections,
        }
        return counts | {name: getattr(self, name).as_dict() for name in ERROR_NAMES}


def frame_errors(
    truth: GroundTruth, poses: TrackedPoses, *, require_all: bool = True
) -> FrameErrors:
    """Per-frame errors of ``poses`` against ``truth``, matched by frame number.

    Parameters
    ----------
    truth : GroundTruth
    poses : TrackedPoses
    require_all : bool
        Whether ``poses`` must cover every ground truth frame; if False, only its
        frames are scored.

    Raises
    ------
    ValueError
        If ``poses`` has a frame the ground truth lacks, or lacks one (``require_all``).
    """
    position = {int(frame): index for index, frame in enumerate(truth.frames)}
    unknown = [int(frame) for frame in poses.frames if int(frame) not in position]
    if unknown:
        raise ValueError(f"poses: frame {unknown[0]} is not in the ground truth")
    if require_all and len(poses.frames) != len(truth.frames):
        raise ValueError(f"poses: cover {len(poses.frames)} of {len(truth.frames)} frames")
    rows = np.array([position[int(frame)] for frame in poses.frames], dtype=np.int64)
    visible = truth.hand_visible[rows]
    scored = visible & poses.hand_found
    nan = np.full(len(rows), np.nan)
    return FrameErrors(
        poses.frames.copy(), visible, poses.hand_found.copy(),
        np.where(scored, posture_error_deg(poses.posture_rad, truth.posture_rad[rows]), nan),
        np.where(scored, rotation_error_deg(np.nan_to_num(poses.rotation), truth.rotation[rows]),
                 nan),
        np.where(scored, position_error_mm(poses.translation_m, truth.translation_m[rows]), nan),
        np.where(scored, keypoint_error_px(poses.keypoints_2d_px, truth.keypoints_2d_px[rows]),
                 nan),
    )  # fmt: skip


def score(truth: GroundTruth, poses: TrackedPoses, *, require_all: bool = True) -> EvaluationResult:
    """Score tracked poses against ground truth (arguments as :func:`frame_errors`)."""
    errors = frame_errors(truth, poses, require_all=require_all)
    return EvaluationResult(
        frames=len(errors.frames),
        visible_frames=int(errors.hand_visible.sum()),
        missed_frames=int(errors.missed.sum()),
        false_detections=int((~errors.hand_visible & errors.hand_found).sum()),
        posture_error_deg=summarize(errors.posture_error_deg),
        rotation_error_deg=summarize(errors.rotation_error_deg),
        position_error_mm=summarize(errors.position_error_mm),
        keypoint_error_px=summarize(errors.keypoint_error_px),
        per_frame=errors,
    )


def evaluate(
    poses_path: str | Path, groundtruth_path: str | Path, *, require_all: bool = True
) -> EvaluationResult:
    """Score a ``poses.jsonl`` file against a ``groundtruth.jsonl`` file."""
    return score(
        read_groundtruth(groundtruth_path), read_poses(poses_path), require_all=require_all
    )


def write_errors_csv(errors: FrameErrors, path: str | Path) -> Path:
    """Write one row per frame: frame, hand_visible, hand_found, missed and the four
    errors (empty where not scored)."""
    path = Path(path)
    with open(path, "w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(["frame", "hand_visible", "hand_found", "missed", *ERROR_NAMES])
        columns = [getattr(errors, name) for name in ERROR_NAMES]
        for index, frame in enumerate(errors.frames):
            flags = (errors.hand_visible[index], errors.hand_found[index], errors.missed[index])
            values = ["" if np.isnan(c[index]) else f"{c[index]:.4f}" for c in columns]
            writer.writerow([int(frame), *(int(flag) for flag in flags), *values])
    return path


# --- the picture of Figures 4.7 and 4.8 -------------------------------------------------

_FONT = cv2.FONT_HERSHEY_SIMPLEX
_PANELS = (
    ("posture_error_deg", "posture error [deg]", (200, 60, 40)),
    ("rotation_error_deg", "rotation error [deg]", (40, 110, 200)),
    ("position_error_mm", "position error [mm]", (30, 150, 70)),
)
_WHITE, _INK, _GRID = (255, 255, 255), (30, 30, 30), (215, 215, 215)
_MISSED, _HIDDEN = (250, 205, 205), (232, 232, 232)


def keyframe_indices(count: int, thumbnails: int) -> list[int]:
    """Indices of ``thumbnails`` frames spread evenly over ``count`` frames (ends included)."""
    if count <= 0 or thumbnails <= 0:
        return []
    return sorted({round(i) for i in np.linspace(0, count - 1, min(thumbnails, count))})


def _nice_ceiling(value: float) -> float:
    """The smallest of 1, 2, 2.5, 5 times a power of ten that is >= ``value`` (> 0)."""
    if not value > 0:
        return 1.0
    power = 10.0 ** math.floor(math.log10(value))
    return next(step * power for step in (1.0, 2.0, 2.5, 5.0, 10.0) if step * power >= value)


def _draw_panel(
    canvas: NDArray[np.uint8],
    box: tuple[int, int, int, int],
    times_s: NDArray[np.float64],
    span_s: float,
    values: NDArray[np.float64],
    errors: FrameErrors,
    label: str,
    color: tuple[int, int, int],
) -> None:
    left, top, right, bottom = box

    def x_of(t: float) -> int:
        return round(left + (t - times_s[0]) / span_s * (right - left))

    finite = values[np.isfinite(values)]
    ceiling = _nice_ceiling(float(finite.max()) * 1.05 if len(finite) else 0.0)
    half_step = 0.5 * (times_s[1] - times_s[0]) if len(times_s) > 1 else 0.5 * span_s
    for flags, shade in ((~errors.hand_visible, _HIDDEN), (errors.missed, _MISSED)):
        for t in times_s[flags]:
            cv2.rectangle(canvas, (x_of(t - half_step), top), (x_of(t + half_step), bottom),
                          shade, -1)  # fmt: skip
    for fraction in (0.0, 0.5, 1.0):
        y = round(bottom - fraction * (bottom - top))
        cv2.line(canvas, (left, y), (right, y), _GRID, 1)
        cv2.putText(canvas, f"{fraction * ceiling:g}", (left - 52, y + 5), _FONT, 0.4, _INK, 1,
                    cv2.LINE_AA)  # fmt: skip
    ys = bottom - np.clip(values / ceiling, 0, 1) * (bottom - top)
    points = [
        (x_of(t), round(y)) if np.isfinite(y) else None for t, y in zip(times_s, ys, strict=True)
    ]
    for a, b in itertools.pairwise(points):
        if a is not None and b is not None:
            cv2.line(canvas, a, b, color, 2, cv2.LINE_AA)
    mean = f"mean {finite.mean():.2f}" if len(finite) else "no scored frames"
    cv2.putText(canvas, f"{label}   {mean}", (left + 8, top + 18), _FONT, 0.5, _INK, 1,
                cv2.LINE_AA)  # fmt: skip
    cv2.rectangle(canvas, (left, top), (right, bottom), _INK, 1)


def error_plot(
    errors: FrameErrors,
    *,
    fps: float,
    thumbnails: Mapping[int, NDArray[np.uint8]] | None = None,
    title: str = "",
    width: int = 1200,
) -> NDArray[np.uint8]:
    """Posture, rotation and position error over time, keyframe thumbnails above.

    Light red bands mark missed frames, gray bands frames without a visible hand.

    Parameters
    ----------
    errors : FrameErrors
    fps : float
        Frame rate: the x axis is ``frame / fps`` seconds.
    thumbnails : mapping of int to (h, w, 3) uint8, optional
        RGB images by frame number (e.g. from :func:`read_thumbnails`), drawn in order
        above the curves with a line to their time.
    title : str
    width : int
        Picture width in pixels.

    Returns
    -------
    (H, W, 3) uint8
        RGB.
    """
    if len(errors.frames) == 0:
        raise ValueError("errors: no frames to plot")
    if not fps > 0:
        raise ValueError(f"fps: expected > 0, got {fps}")
    thumbnails = dict(thumbnails or {})
    strip = 150 if thumbnails else 0
    left, right, panel, gap = 70, width - 20, 170, 26
    height = 40 + strip + len(_PANELS) * (panel + gap) + 30
    canvas = np.full((height, width, 3), _WHITE, np.uint8)
    cv2.putText(canvas, title, (left, 27), _FONT, 0.7, _INK, 2, cv2.LINE_AA)
    times = errors.frames / fps
    span = max(float(times[-1] - times[0]), 1.0 / fps)  # one frame still spans a frame period
    top = 40 + strip
    if thumbnails:
        box = (left, 40, right, top - 20)
        _draw_thumbnails(canvas, thumbnails, times, span, errors.frames, box)
    for name, label, color in _PANELS:
        box = (left, top, right, top + panel)
        _draw_panel(canvas, box, times, span, getattr(errors, name), errors, label, color)
        top += panel + gap
    for t in np.unique(np.linspace(times[0], times[-1], 6)):
        x = round(left + (t - times[0]) / span * (right - left))
        cv2.putText(canvas, f"{t:.1f}", (x - 12, top - gap + 18), _FONT, 0.4, _INK, 1, cv2.LINE_AA)
    cv2.putText(canvas, "time [s]", (right - 70, height - 8), _FONT, 0.45, _INK, 1, cv2.LINE_AA)
    for x, shade, text in ((left, _MISSED, "missed"), (left + 110, _HIDDEN, "hand not visible")):
        cv2.rectangle(canvas, (x, height - 20), (x + 14, height - 8), shade, -1)
        cv2.putText(canvas, text, (x + 20, height - 8), _FONT, 0.45, _INK, 1, cv2.LINE_AA)
    return canvas


def _draw_thumbnails(
    canvas: NDArray[np.uint8],
    thumbnails: Mapping[int, NDArray[np.uint8]],
    times_s: NDArray[np.float64],
    span_s: float,
    frames: NDArray[np.int64],
    box: tuple[int, int, int, int],
) -> None:
    left, top, right, bottom = box
    order = sorted(frame for frame in thumbnails if frame in set(frames.tolist()))
    if not order:
        return
    slot = (right - left) // len(order)
    height = bottom - top
    for index, frame in enumerate(order):
        image = as_array(f"thumbnails[{frame}]", thumbnails[frame], (None, None, 3), kind="u")
        scale = min(height / image.shape[0], (slot - 8) / image.shape[1])
        size = (max(1, int(image.shape[1] * scale)), max(1, int(image.shape[0] * scale)))
        small = cv2.resize(image.astype(np.uint8), size, interpolation=cv2.INTER_AREA)
        x0 = left + index * slot + (slot - size[0]) // 2
        canvas[top : top + size[1], x0 : x0 + size[0]] = small
        cv2.rectangle(canvas, (x0, top), (x0 + size[0] - 1, top + size[1] - 1), _INK, 1)
        t = float(times_s[list(frames).index(frame)])
        x_time = round(left + (t - times_s[0]) / span_s * (right - left))
        cv2.line(canvas, (x0 + size[0] // 2, top + size[1]), (x_time, bottom + 20), _INK, 1,
                 cv2.LINE_AA)  # fmt: skip


def read_thumbnails(
    sequence: str | Path, frames: Sequence[int], *, height: int = 120
) -> dict[int, NDArray[np.uint8]]:
    """Color frames ``SEQ/color/NNNNNN.png`` (or ``.jpg``) scaled to ``height`` pixels.

    Returns
    -------
    dict of int to (height, w, 3) uint8
        RGB, by frame; frames without a readable image are left out.
    """
    images: dict[int, NDArray[np.uint8]] = {}
    for frame in frames:
        for suffix in (".png", ".jpg"):
            image = cv2.imread(str(Path(sequence) / "color" / f"{frame:06d}{suffix}"))
            if image is not None:
                width = max(1, round(image.shape[1] * height / image.shape[0]))
                small = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
                images[frame] = np.ascontiguousarray(small[..., ::-1], dtype=np.uint8)
                break
    return images


def save_error_plot(path: str | Path, picture: NDArray[np.uint8]) -> Path:
    """Write an RGB picture from :func:`error_plot` as PNG; ``ValueError`` if it cannot."""
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"{path}: expected a .png file name")
    return write_rgb(path, picture)


def report_run(
    sequence: str | Path,
    poses_path: str | Path,
    out: str | Path,
    *,
    fps: float,
    title: str = "",
    thumbnails: int = 6,
) -> EvaluationResult:
    """Score a tracking run of a synthetic sequence and write ``errors.csv`` and
    ``errors.png`` (error curves with keyframe thumbnails) into ``out``."""
    sequence, out = Path(sequence), Path(out)
    result = evaluate(poses_path, sequence / "groundtruth.jsonl")
    write_errors_csv(result.per_frame, out / "errors.csv")
    keyframes = keyframe_indices(len(result.per_frame.frames), thumbnails)
    picture = error_plot(
        result.per_frame, fps=fps, thumbnails=read_thumbnails(sequence, keyframes), title=title
    )
    save_error_plot(out / "errors.png", picture)
    return result
