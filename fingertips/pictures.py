"""Pictures of detections for people: overlays on depth, scored frames, contact sheets.

``glove fingertips detect`` draws :func:`detection_overlay` per frame (or a
:func:`contact_sheet` of them); ``glove fingertips eval --sheet`` draws
:func:`scored_sheet`. Pictures are RGB ``uint8`` arrays; writing them is the caller's.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from fingertips.detect import Detection
from fingertips.evaluation import AnnotatedDepth, TipCauses, match_frame_2d
from fingertips.features import project
from fingertips.miss_causes import CAUSE_LETTERS, MISS_CAUSES, MissCause
from tracker.overlay import draw_fingertips, draw_skeleton

SHEET_TILE_WIDTH = 320
"""Wider frames are scaled down to this width (pixels) on a scored sheet."""

_LABEL = (255, 255, 0)
_MISSED = (255, 40, 40)
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def depth_picture(
    depth_m: NDArray[np.float32], *, span_m: float | None = None
) -> NDArray[np.uint8]:
    """``(H, W, 3) uint8``: depth in gray, near bright, black where missing.

    The gray ramp runs from the 1st to the 99th depth percentile, or over ``span_m``
    metres behind the 1st percentile (detail on a hand in front of a far background).
    """
    valid = depth_m > 0
    picture = np.zeros(depth_m.shape + (3,), np.uint8)
    if valid.any():
        near, far = np.percentile(depth_m[valid], [1, 99])
        if span_m is not None:
            far = near + span_m
        scaled = 1.0 - np.clip((depth_m - near) / max(far - near, 1e-6), 0.0, 1.0)
        gray = (40 + 200 * scaled).astype(np.uint8)
        picture[valid] = gray[valid][:, None]
    return picture


def detection_overlay(
    depth_m: NDArray[np.float32], record: dict[str, Any], intrinsics: ArrayLike
) -> NDArray[np.uint8]:
    """``(H, W, 3) uint8`` RGB: depth in gray (near bright), the detections circled and
    labelled (finger or "?", confidence), and the pose guess's skeleton if there is one.

    ``record`` is a frame's record (:meth:`fingertips.detector.FingertipDetector.record`).
    """
    picture = depth_picture(depth_m)
    guess = record.get("pose_guess")
    if guess is not None:
        keypoints = np.asarray(guess["keypoints_3d_m"], dtype=np.float64)
        picture = draw_skeleton(picture, project(keypoints, np.asarray(intrinsics)), radius_px=2)
    return draw_fingertips(picture, record["fingertips"], radius_px=5)


def contact_sheet(tiles: Sequence[NDArray[np.uint8]], columns: int = 6) -> NDArray[np.uint8]:
    """Tiles of equal size in rows of ``columns``, padded with black."""
    height, width = tiles[0].shape[:2]
    rows = math.ceil(len(tiles) / columns)
    sheet = np.zeros((rows * height, min(columns, len(tiles)) * width, 3), np.uint8)
    for k, tile in enumerate(tiles):
        r, c = divmod(k, columns)
        sheet[r * height : (r + 1) * height, c * width : (c + 1) * width] = tile
    return sheet


def scored_overlay(
    depth_m: NDArray[np.float32],
    uv_px: ArrayLike,
    tips_px: ArrayLike,
    *,
    gate_px: float = 10.0,
    causes: Sequence[MissCause | None] | None = None,
) -> NDArray[np.uint8]:
    """``(h, w, 3) uint8`` RGB of one scored frame, at most :data:`SHEET_TILE_WIDTH` wide.

    Annotated tips are circles, green when a detection lies within ``gate_px`` (the
    one-to-one matching of ``recall_at_10px``), red when missed, with the letter of
    the miss's cause (:data:`fingertips.miss_causes.CAUSE_LETTERS`) beside the circle
    when ``causes`` (one per row of ``tips_px``) is given; detections are crosses, cyan
    when matched, orange when not. The corner reads "found/annotated".
    """
    uv = np.asarray(uv_px, dtype=np.float64).reshape(-1, 2)
    tips = np.asarray(tips_px, dtype=np.float64).reshape(-1, 2)
    found, matched = match_frame_2d(uv, tips, gate_px=gate_px)
    picture = depth_picture(depth_m, span_m=0.15)
    scale = min(1.0, SHEET_TILE_WIDTH / picture.shape[1])
    if scale < 1.0:
        size = (round(picture.shape[1] * scale), round(picture.shape[0] * scale))
        picture = np.asarray(cv2.resize(picture, size, interpolation=cv2.INTER_AREA), np.uint8)
    radius = max(round(gate_px * scale), 3)
    annotated = np.all(np.isfinite(tips), axis=1)
    for tip, hit in zip(tips[annotated] * scale, found[annotated], strict=True):
        color = (0, 220, 0) if hit else _MISSED
        cv2.circle(picture, tuple(round(x) for x in tip.tolist()), radius, color, 1, cv2.LINE_AA)
    if causes is not None:
        if len(causes) != tips.shape[0]:
            raise ValueError(f"causes: expected {tips.shape[0]}, one per tip, got {len(causes)}")
        for k in np.flatnonzero(annotated & ~found):
            cause = causes[int(k)]
            if cause is not None:
                corner = (round(tips[k, 0] * scale) + radius, round(tips[k, 1] * scale) - radius)
                _outlined_text(picture, CAUSE_LETTERS[cause], corner, 0.45, _MISSED)
    for point, hit in zip(uv * scale, matched, strict=True):
        color = (0, 230, 255) if hit else (255, 150, 0)
        centre = tuple(round(x) for x in point.tolist())
        cv2.drawMarker(picture, centre, color, cv2.MARKER_CROSS, radius + 4, 2)
    label = f"{int(found.sum())}/{int(annotated.sum())}"
    cv2.putText(picture, label, (4, 14), _FONT, 0.45, _LABEL, 1)
    return picture


def _outlined_text(
    picture: NDArray[np.uint8],
    text: str,
    origin: tuple[int, int],
    scale: float,
    color: tuple[int, int, int],
) -> None:
    """Text with a black outline, readable on any gray."""
    cv2.putText(picture, text, origin, _FONT, scale, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(picture, text, origin, _FONT, scale, color, 1, cv2.LINE_AA)


def cause_legend(width: int) -> NDArray[np.uint8]:
    """``(h, width, 3) uint8`` RGB: what the letters beside missed tips mean, in lines
    that fit ``width`` pixels."""
    entries = [f"{CAUSE_LETTERS[cause]} {cause}" for cause in MISS_CAUSES]
    lines: list[str] = []
    line = "missed:"
    for entry in entries:
        wider = f"{line}  {entry}"
        if cv2.getTextSize(wider, _FONT, 0.45, 1)[0][0] + 8 > width and line != "missed:":
            lines.append(line)
            wider = entry
        line = wider
    lines.append(line)
    legend = np.zeros((18 * len(lines) + 6, width, 3), np.uint8)
    for k, text in enumerate(lines):
        _outlined_text(legend, text, (4, 18 * k + 16), 0.45, _MISSED)
    return legend


def scored_sheet(
    data: AnnotatedDepth,
    detections: Sequence[Sequence[Detection]],
    *,
    max_frames: int,
    causes: TipCauses | None = None,
) -> NDArray[np.uint8]:
    """A :func:`contact_sheet` of :func:`scored_overlay` of up to ``max_frames`` evenly
    spread frames, each labelled with its frame number.

    With ``causes`` (per frame, per tip: :func:`fingertips.evaluation.annotated_tip_causes`)
    each miss carries its cause's letter and a :func:`cause_legend` runs below the tiles.

    Raises
    ------
    ValueError
        When there are no frames.
    """
    n = len(detections)
    if n == 0:
        raise ValueError("--sheet: no annotated frames to draw")
    chosen = np.unique(np.linspace(0, n - 1, min(n, max_frames)).round().astype(int))
    tiles = []
    for k in chosen:
        uv = [(d.u_px, d.v_px) for d in detections[k]]
        frame_causes = None if causes is None else causes[k]
        tile = scored_overlay(data.depth_m[k], uv, data.tips_px[k], causes=frame_causes)
        label = f"frame {int(data.frames[k])}"
        cv2.putText(tile, label, (4, tile.shape[0] - 6), _FONT, 0.4, _LABEL, 1)
        tiles.append(tile)
    sheet = contact_sheet(tiles)
    if causes is None:
        return sheet
    return np.concatenate([sheet, cause_legend(sheet.shape[1])])
