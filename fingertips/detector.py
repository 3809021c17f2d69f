"""The fingertip detector for other programs: a loaded model, per-frame records, pose guesses.

A thin class over the pure functions of :mod:`fingertips.detect` and
:mod:`fingertips.pose_guess`; ``glove fingertips detect`` writes exactly the
records :meth:`FingertipDetector.record` returns. Typical use by another tracker::

    from fingertips.detector import FingertipDetector

    detector = FingertipDetector()  # the shipped model and its settings
    record = detector.record(frame, depth_m, intrinsics, pose_guess=True)
    # record["fingertips"]: [{"finger", "u_px", "v_px", "x_m", "y_m", "z_m",
    #                         "confidence"}, ...]
    # record["pose_guess"]: {"rotation", "translation_m", "posture_rad",
    #                        "keypoints_3d_m", "tip_rms_m", "surface_rms_m"} or None
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fingertips.detect import (
    Detection,
    DetectorConfig,
    detect_fingertips,
    detection_points,
    fingertips_output,
    model_detector_config,
    name_fingers,
)
from fingertips.forest import DEFAULT_MODEL_PATH, FingertipForest, load_forest
from fingertips.pose_guess import (
    PoseGuess,
    guess_hand_pose,
    hand_points_from_depth,
)
from glovedb.hand_model import FINGERTIP_KEYPOINTS, Skeleton


def pose_guess_output(guess: PoseGuess | None) -> dict[str, Any] | None:
    """JSON-ready form of a :class:`~fingertips.pose_guess.PoseGuess` (None stays None)."""
    if guess is None:
        return None
    return {
        "rotation": guess.rotation.tolist(),
        "translation_m": guess.translation_m.tolist(),
        "posture_rad": guess.posture_rad.tolist(),
        "keypoints_3d_m": guess.keypoints_3d_m.tolist(),
        "tip_rms_m": guess.tip_rms_m,
        "surface_rms_m": guess.surface_rms_m if np.isfinite(guess.surface_rms_m) else None,
    }


class FingertipDetector:
    """A fingertip forest with its detection settings, ready for frame after frame.

    Parameters
    ----------
    model : path or FingertipForest, optional
        Default: the shipped model.
    config : DetectorConfig, optional
        Default: the settings recorded in the model.
    """

    def __init__(
        self,
        model: str | os.PathLike[str] | FingertipForest | None = None,
        *,
        config: DetectorConfig | None = None,
    ) -> None:
        if not isinstance(model, FingertipForest):
            model = load_forest(DEFAULT_MODEL_PATH if model is None else model)
        self.model = model
        self.config = config if config is not None else model_detector_config(model)
        self._postures: NDArray[np.float64] | None = None

    def detect(
        self, depth_m: ArrayLike, intrinsics: ArrayLike, *, model_tips_m: ArrayLike | None = None
    ) -> tuple[Detection, ...]:
        """:func:`~fingertips.detect.detect_fingertips` with this model and settings."""
        return detect_fingertips(
            depth_m, intrinsics, self.model, model_tips_m=model_tips_m, config=self.config
        )

    def guess_pose(
        self,
        detections: tuple[Detection, ...],
        depth_m: ArrayLike,
        intrinsics: ArrayLike,
        *,
        posture_rad: ArrayLike | None = None,
        skeleton: Skeleton | None = None,
    ) -> PoseGuess | None:
        """A hand pose fitted to the detections and the frame's hand points.

        See :func:`~fingertips.pose_guess.guess_hand_pose`; ``posture_rad``
        ``(20,)`` or ``(P, 20)`` are the postures to choose from (default: the
        project's named postures, :func:`glovedb.postures.load_named_postures`).
        None with fewer than three detections.
        """
        if posture_rad is None:
            posture_rad = self._named_postures()
        near, far = self.model.depth_range_m
        band = self.config.depth_band_m if np.isfinite(self.config.depth_band_m) else 0.2
        points = hand_points_from_depth(depth_m, intrinsics, depth_range_m=(near, far), band_m=band)
        return guess_hand_pose(
            detection_points(detections),
            posture_rad=posture_rad,
            skeleton=skeleton,
            hand_points_m=points,
        )

    def record(
        self,
        frame: int,
        depth_m: ArrayLike,
        intrinsics: ArrayLike,
        *,
        pose_guess: bool = False,
        posture_rad: ArrayLike | None = None,
        timestamp_s: float | None = None,
    ) -> dict[str, Any]:
        """One ``fingertips.jsonl`` record: ``frame``, ``timestamp_s`` (the frame's capture
        time in seconds, None when unknown), ``fingertips`` (and ``pose_guess``).

        With ``pose_guess``, a hand pose is fitted to the detections
        (:meth:`guess_pose`, with ``posture_rad`` or the named postures) and the
        detections are named by Eq. 11 against the fitted model's fingertips.
        """
        detections = self.detect(depth_m, intrinsics)
        stamp = None if timestamp_s is None else round(float(timestamp_s), 6)
        if not pose_guess:
            return {
                "frame": int(frame),
                "timestamp_s": stamp,
                "fingertips": fingertips_output(detections),
            }
        guess = self.guess_pose(detections, depth_m, intrinsics, posture_rad=posture_rad)
        if guess is not None:
            detections = name_fingers(
                detections,
                guess.keypoints_3d_m[list(FINGERTIP_KEYPOINTS)],
                c_thr=self.config.c_thr,
                min_tip_probability=self.config.min_tip_probability,
                heatmap_min_probability=self.config.heatmap_min_probability,
            )
        return {
            "frame": int(frame),
            "timestamp_s": stamp,
            "fingertips": fingertips_output(detections),
            "pose_guess": pose_guess_output(guess),
        }

    def _named_postures(self) -> NDArray[np.float64]:
        if self._postures is None:
            from glovedb.postures import load_named_postures

            self._postures = np.stack(list(load_named_postures().values()))
        return self._postures

    def run(self, source: str | os.PathLike[str], *, pose_guess: bool = False) -> Iterator[dict]:
        """The records of every depth frame of an RGB-D folder, a ``.bag`` recording or a
        camera (``"realsense"``, ``"kinect"``; until the caller stops), in frame order.

        See :func:`fingertips.depth_input.open_depth_source`.
        """
        from fingertips.depth_input import open_depth_source

        for frame in open_depth_source(source):
            yield self.record(frame.frame, frame.depth_m, frame.intrinsics, pose_guess=pose_guess)
