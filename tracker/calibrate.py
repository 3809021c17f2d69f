"""Calibrating the color table to the user's real glove (``glove calibrate``).

The nominal table knows the pattern's intended colors; a real glove's dyes, a camera's
color response and the room's light move them. Calibration learns the table from the
glove itself: frames are tracked with the current table, and where the hand is found
confidently, the fitted model's class labels are rasterised into the image
(:func:`glovedb.rasterize.model_label_image`). Pixels where the model and the measured depth agree
within ``depth_tolerance_m`` become samples of their model class; pixels well outside
the model's silhouette become background samples. The table is then learned from the
samples (:func:`tracker.classify.calibrated_table`), and the procedure can repeat
with the new table.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from glovedb.rasterize import model_label_image
from tracker.classify import ColorTable, calibrated_table
from tracker.frames import Frame
from tracker.pipeline import Tracker, TrackingResult


def calibration_samples(
    frame: Frame,
    result: TrackingResult,
    tracker: Tracker,
    *,
    depth_tolerance_m: float = 0.015,
    background_margin_px: int = 15,
    background_samples: int = 4000,
    rng: np.random.Generator,
) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
    """Labelled color samples of one tracked frame (see the module docstring).

    Returns
    -------
    colors : (N, 3) uint8
    labels : (N,) uint8
    """
    if not result.hand_found:
        return np.zeros((0, 3), np.uint8), np.zeros(0, np.uint8)
    assert result.posture_rad is not None and result.rotation is not None
    assert result.translation_m is not None
    labels, model_depth = model_label_image(
        tracker.mesh, tracker.split, result.posture_rad, result.rotation,
        result.translation_m, frame.intrinsics,
    )  # fmt: skip
    # Shrink each patch by a pixel so that samples do not straddle patch borders.
    interior = np.zeros_like(labels)
    for label in np.unique(labels[labels > 0]):
        patch = cv2.erode((labels == label).astype(np.uint8), np.ones((3, 3), np.uint8))
        interior[patch > 0] = label
    agrees = (frame.depth_m > 0) & (np.abs(frame.depth_m - model_depth) < depth_tolerance_m)
    glove = (interior > 0) & agrees
    near = cv2.dilate((labels > 0).astype(np.uint8), np.ones((3, 3), np.uint8),
                      iterations=background_margin_px)  # fmt: skip
    background = np.flatnonzero(near.ravel() == 0)
    background = rng.choice(
        background, size=min(background_samples, len(background)), replace=False
    )
    colors = np.concatenate([frame.color[glove], frame.color.reshape(-1, 3)[background]])
    classes = np.concatenate([interior[glove], np.zeros(len(background), np.uint8)])
    return colors, classes


@dataclass(frozen=True)
class Calibration:
    """Outcome of :func:`calibrate`.

    Attributes
    ----------
    table : ColorTable
    frames_used : int
        Frames whose hand was found confidently and gave samples.
    glove_samples, background_samples : int
    """

    table: ColorTable
    frames_used: int
    glove_samples: int
    background_samples: int


def calibrate(
    frames: Iterable[Frame],
    tracker: Tracker,
    *,
    rounds: int = 2,
    min_confidence: float = 0.1,
    seed: int = 0,
) -> Calibration:
    """Learn a color table from frames of the user's glove.

    Parameters
    ----------
    frames : iterable of Frame
        A few dozen frames showing the glove from several sides (kept in memory).
    tracker : Tracker
        Tracks with its current table; its table is replaced after every round.
    rounds : int
        Track-and-learn rounds.
    min_confidence : float
        Frames tracked less confidently give no samples.
    seed : int

    Raises
    ------
    ValueError
        When no frame gives samples (no glove found).
    """
    frames = list(frames)
    if not frames:
        raise ValueError("calibration needs frames")
    calibration = None
    for _ in range(rounds):
        rng = np.random.default_rng(seed)
        colors, labels, used = [], [], 0
        for frame in frames:
            result = tracker.track(frame)
            if not result.hand_found or result.confidence < min_confidence:
                continue
            frame_colors, frame_labels = calibration_samples(frame, result, tracker, rng=rng)
            if (frame_labels > 0).sum() < 100:
                continue
            colors.append(frame_colors)
            labels.append(frame_labels)
            used += 1
        tracker.reset()
        if not used:
            if calibration is not None:
                break
            raise ValueError("no frame showed the glove clearly enough to calibrate")
        all_labels = np.concatenate(labels)
        table = calibrated_table(np.concatenate(colors), all_labels)
        tracker.color_table = table
        calibration = Calibration(
            table, used, int((all_labels > 0).sum()), int((all_labels == 0).sum())
        )
    assert calibration is not None
    return calibration
