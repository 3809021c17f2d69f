"""What one frame shows of the hand, prepared for the energy terms.

- the labeled glove point cloud, subsampled (data term);
- over a crop around the hand: the distance of every pixel to the nearest observed
  hand pixel and its gradient (0 on the hand), and the observed depth (silhouette
  term: where the model may be, and what stands in front of it).

The hand mask is the glove pixels of :func:`tracker.point_cloud.hand_region`, closed
by one pixel so that a misread pixel inside the glove is not "outside the hand".
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from glovedb.camera import CameraIntrinsics
from tracker.generative import _kernels
from tracker.point_cloud import HandRegion, LabeledPointCloud

CROP_MARGIN_PX = 48
"""Pixels added around the hand's bounding box: a model this far outside the observed
hand is still pulled in by the silhouette term."""


@dataclass(frozen=True)
class Observation:
    """One frame's evidence about the hand (module docstring).

    Attributes
    ----------
    points_m : (N, 3) float64
        Glove points, camera frame.
    labels : (N,) uint8
        Their classes 1..10.
    intrinsics : CameraIntrinsics
    origin_uv : (2,) int64
        Pixel (column, row) of the crop's top-left corner.
    outside_px : (h, w) float32
        Distance of every crop pixel to the nearest hand pixel, pixels.
    gradient : (h, w, 2) float32
        Its gradient along u and v.
    depth_m : (h, w) float32
        Observed depth over the crop (0: none).
    """

    points_m: NDArray[np.float64]
    labels: NDArray[np.uint8]
    intrinsics: CameraIntrinsics
    origin_uv: NDArray[np.int64]
    outside_px: NDArray[np.float32]
    gradient: NDArray[np.float32]
    depth_m: NDArray[np.float32]


def observe(
    region: HandRegion,
    cloud: LabeledPointCloud,
    depth_m: NDArray[np.float32],
    intrinsics: CameraIntrinsics,
    *,
    max_points: int,
) -> Observation:
    """Prepare one frame for the fit.

    Parameters
    ----------
    region : HandRegion
        The frame's glove pixels.
    cloud : LabeledPointCloud
        Their points.
    depth_m : (H, W) float32
        The frame's depth, metres (0: none).
    intrinsics : CameraIntrinsics
    max_points : int
        The cloud is subsampled evenly, every ``len(cloud) // max_points``-th point:
        at least this many points and fewer than twice as many (all of a cloud of
        fewer).

    Returns
    -------
    Observation
    """
    step = max(1, len(cloud) // max(max_points, 1))
    height, width = depth_m.shape
    uv = region.pixels_uv
    low = np.maximum(uv.min(axis=0) - CROP_MARGIN_PX, 0)
    high = np.minimum(uv.max(axis=0) + CROP_MARGIN_PX + 1, [width, height])
    mask = np.zeros((high[1] - low[1], high[0] - low[0]), dtype=np.uint8)
    mask[uv[:, 1] - low[1], uv[:, 0] - low[0]] = 1
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    outside = cv2.distanceTransform(1 - mask, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    gradient = (
        np.stack(
            [
                cv2.Sobel(outside, cv2.CV_32F, 1, 0, ksize=3),
                cv2.Sobel(outside, cv2.CV_32F, 0, 1, ksize=3),
            ],
            axis=-1,
        )
        / 8.0
    )
    return Observation(
        points_m=cloud.points_m[::step].astype(np.float64),
        labels=cloud.labels[::step],
        intrinsics=intrinsics,
        origin_uv=low.astype(np.int64),
        outside_px=np.asarray(outside, dtype=np.float32),
        gradient=np.asarray(gradient, dtype=np.float32),
        depth_m=np.ascontiguousarray(depth_m[low[1] : high[1], low[0] : high[0]]),
    )


@dataclass(frozen=True)
class CropLookup:
    """What the observation shows where camera-frame points project (:func:`look_up`).

    Attributes
    ----------
    row, col : (P,) int64
        Crop pixel of every point (clipped to the crop).
    inside : (P,) bool
        Whether the point projects into the crop at all.
    outside_px : (P,) float32
        Distance to the observed hand mask, pixels (``inf`` beyond the crop).
    seen_m : (P,) float32
        Observed depth at the pixel (0: none).
    """

    row: NDArray[np.int64]
    col: NDArray[np.int64]
    inside: NDArray[np.bool_]
    outside_px: NDArray[np.float32]
    seen_m: NDArray[np.float32]


def look_up(observation: Observation, points_m: NDArray[np.float64]) -> CropLookup:
    """Project ``(P, 3)`` camera-frame points into the observation's crop and read the
    hand mask's distance and the observed depth there."""
    points = np.ascontiguousarray(points_m, dtype=np.float64)
    height, width = observation.outside_px.shape
    row, col = np.empty(len(points), dtype=np.int64), np.empty(len(points), dtype=np.int64)
    inside = np.empty(len(points), dtype=bool)
    _kernels.crop_pixels(
        points, observation.intrinsics.pinhole, observation.origin_uv, height, width, row, col,
        inside,
    )  # fmt: skip
    outside = np.where(inside, observation.outside_px[row, col], np.float32(np.inf))
    return CropLookup(row, col, inside, outside, observation.depth_m[row, col])
