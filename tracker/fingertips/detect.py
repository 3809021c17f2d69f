"""Fingertip detection on one depth frame: forest, Hough voting, assignment to fingers."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from glovedb._validate import as_array
from tracker.fingertips.assignment import FINGER_NAMES, assign_detections
from tracker.fingertips.features import (
    backproject,
    foreground_pixels,
    intrinsics_array,
    mask_depth_range,
    project,
)
from tracker.fingertips.forest import FingertipForest, apply_depth, predict_leaves
from tracker.fingertips.voting import (
    DEFAULT_VOTING,
    Votes,
    VotingConfig,
    cast_votes,
    find_peaks,
)


@dataclass(frozen=True)
class Detection:
    """One detected fingertip.

    Attributes
    ----------
    u_px, v_px : float
        Projection into the image, pixels.
    x_m, y_m, z_m : float
        Position in the camera frame (OpenCV axes), metres.
    confidence : float
        Sum of the vote weights supporting the detection (see
        :mod:`tracker.fingertips.voting`).
    finger : str or None
        Finger name from the assignment to a posed model, None if unassigned or if no
        model was given.
    """

    u_px: float
    v_px: float
    x_m: float
    y_m: float
    z_m: float
    confidence: float
    finger: str | None = None


def fingertip_votes(
    depth_m: ArrayLike,
    intrinsics: ArrayLike,
    model: FingertipForest,
    *,
    stride: int = 2,
    voting: VotingConfig = DEFAULT_VOTING,
) -> Votes:
    """The forest's 3D fingertip votes for one depth frame.

    Parameters
    ----------
    depth_m : (H, W) float32
        Depth in metres, 0 where missing.
    intrinsics : (4,) float
        ``(fx, fy, cx, cy)`` in pixels.
    model : FingertipForest
        Trained forest; its working depth range selects the hand pixels.
    stride : int
        Evaluate every ``stride``-th pixel in both directions.
    voting : VotingConfig

    Returns
    -------
    Votes
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
    camera = intrinsics_array(intrinsics)
    near, far = model.depth_range_m
    masked = mask_depth_range(depth, near_m=near, far_m=far)
    pixels = foreground_pixels(masked, stride=stride)
    prediction = predict_leaves(model, apply_depth(model, masked, pixels, camera))
    z = masked[pixels[:, 1], pixels[:, 0]]
    points = backproject(pixels, z, camera)
    area = (stride * z) ** 2 / np.float32(camera[0] * camera[1])
    return cast_votes(points, prediction.probability, prediction.offset_m, area, config=voting)


def detect_fingertips(
    depth_m: ArrayLike,
    intrinsics: ArrayLike,
    model: FingertipForest,
    *,
    model_tips_m: ArrayLike | None = None,
    c_thr: float = 3.0,
    lam: float = 1.2,
    distance_unit_m: float = 0.01,
    stride: int = 2,
    voting: VotingConfig = DEFAULT_VOTING,
) -> tuple[Detection, ...]:
    """Detect fingertips in a depth frame and, given a posed model, name their fingers.

    Parameters
    ----------
    depth_m : (H, W) float32
        Depth in metres, 0 where missing.
    intrinsics : (4,) float
        ``(fx, fy, cx, cy)`` in pixels.
    model : FingertipForest
        Trained forest (:func:`tracker.fingertips.forest.load_forest`).
    model_tips_m : (5, 3) float, optional
        Fingertips of the posed hand model in the camera frame (metres), in the order
        of :data:`FINGER_NAMES`. When given, detections are assigned to fingers by
        Eq. 11 of Tzionas et al. 2014.
    c_thr : float
        Smallest confidence kept.
    lam : float
        Weight lambda of the assignment.
    distance_unit_m : float
        Unit (metres) of the assignment's detection-to-finger distances.
    stride : int
        Pixel step of the evaluated grid.
    voting : VotingConfig

    Returns
    -------
    tuple of Detection
        Strongest first.
    """
    camera = intrinsics_array(intrinsics)
    votes = fingertip_votes(depth_m, camera, model, stride=stride, voting=voting)
    peaks = find_peaks(votes, c_thr=c_thr, config=voting)
    names: list[str | None] = [None] * peaks.confidences.size
    if model_tips_m is not None:
        tips = as_array("model_tips_m", model_tips_m, (len(FINGER_NAMES), 3), np.float64)
        assignment = assign_detections(
            peaks.positions_m,
            peaks.confidences,
            tips,
            c_thr=c_thr,
            lam=lam,
            distance_unit_m=distance_unit_m,
        )
        names = [FINGER_NAMES[t] if t >= 0 else None for t in assignment.finger_of_detection]
    uv = project(peaks.positions_m.astype(np.float64), camera)
    return tuple(
        Detection(
            u_px=float(uv[k, 0]),
            v_px=float(uv[k, 1]),
            x_m=float(peaks.positions_m[k, 0]),
            y_m=float(peaks.positions_m[k, 1]),
            z_m=float(peaks.positions_m[k, 2]),
            confidence=float(peaks.confidences[k]),
            finger=names[k],
        )
        for k in range(peaks.confidences.size)
    )


def fingertips_output(detections: Sequence[Detection]) -> list[dict[str, Any]]:
    """The ``fingertips`` list of a ``poses.jsonl`` record (CONVENTIONS.md)."""
    return [
        {
            "finger": d.finger,
            "u_px": d.u_px,
            "v_px": d.v_px,
            "x_m": d.x_m,
            "y_m": d.y_m,
            "z_m": d.z_m,
            "confidence": d.confidence,
        }
        for d in detections
    ]
