"""The heatmap network alone on annotated frames: its own peaks, no forest, no verifier.

A check of a newly trained network (``glove fingertips eval-heatmap``) before its
verifier is fitted, as the ninth session's prototype scored its networks
(docs/fingertips_experiments.md): each frame's crop
(:func:`fingertips.heatmap.hand_crop`) goes through the network, and the local maxima
of the mean map above a threshold, lifted to 3D (:func:`fingertips.heatmap.heat_peaks`),
are the detections.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fingertips.detect import Detection
from fingertips.evaluation import AnnotatedDepth, FingertipMetrics, FrameProgress, fingertip_metrics
from fingertips.features import intrinsics_array
from fingertips.heatmap import CropCentre, frame_crop_centre, hand_crop, heat_peaks

DEFAULT_THRESHOLDS = (0.5, 0.9, 0.97)
"""Heat thresholds ``glove fingertips eval-heatmap`` scores at."""


def network_detections(
    depth_m: NDArray[np.float32],
    intrinsics: ArrayLike,
    network: Callable[[NDArray[np.float32]], NDArray[np.float32]],
    *,
    min_value: float,
    centre: CropCentre = "fingers",
) -> tuple[Detection, ...]:
    """The network's peaks in one frame whose mean heat exceeds ``min_value``.

    Parameters
    ----------
    depth_m : (H, W) float32
        Metres, 0 where missing.
    intrinsics : (4,) float
    network : callable
        Crop ``(CROP_PX, CROP_PX)`` to the maps ``(P, GRID, GRID)`` of every pass
        (:class:`fingertips.heatmap.HeatmapNetwork`).
    min_value : float
    centre : {"density", "fingers"}
        The crop centre's rule (:func:`fingertips.heatmap.frame_crop_centre`).

    Returns
    -------
    tuple of Detection
        ``source`` "heatmap", ``confidence`` the peak's mean heat; empty when no object
        is in view.
    """
    camera = intrinsics_array(intrinsics)
    middle = frame_crop_centre(depth_m, camera, centre)
    if middle is None:
        return ()
    maps = network(hand_crop(depth_m, camera, middle))
    peaks = heat_peaks(maps.mean(axis=0), middle, depth_m, camera, min_value=min_value)
    return tuple(
        Detection(
            u_px=float(uv[0]),
            v_px=float(uv[1]),
            x_m=float(xyz[0]),
            y_m=float(xyz[1]),
            z_m=float(xyz[2]),
            confidence=float(value),
            source="heatmap",
        )
        for uv, xyz, value in zip(peaks.uv_px, peaks.xyz_m, peaks.values, strict=True)
    )


def evaluate_network(
    data: AnnotatedDepth,
    network: Callable[[NDArray[np.float32]], NDArray[np.float32]],
    *,
    thresholds: Sequence[float] = DEFAULT_THRESHOLDS,
    centre: CropCentre = "fingers",
    progress: FrameProgress | None = None,
) -> dict[float, FingertipMetrics]:
    """Score the network's peaks on ``data`` at each heat threshold.

    The network runs once per frame on the crop centred by the ``centre`` rule
    (:func:`network_detections`): the peaks above a threshold are those above the
    smallest one with a larger value.

    Raises
    ------
    ValueError
        Unless every threshold is a probability in [0, 1).
    """
    if not thresholds or not all(0 <= t < 1 for t in thresholds):
        raise ValueError(f"thresholds: expected probabilities in [0, 1), got {list(thresholds)}")
    frames = data.depth_m if progress is None else progress(data.depth_m)
    lowest = min(thresholds)
    found = [
        network_detections(d, data.intrinsics, network, min_value=lowest, centre=centre)
        for d in frames
    ]
    return {
        float(t): fingertip_metrics(
            [tuple(d for d in frame if d.confidence > t) for frame in found],
            data.tips_m,
            data.tips_px,
        )
        for t in thresholds
    }
