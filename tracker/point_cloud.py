"""The color-labeled point cloud of the glove (thesis Eq. 4.1) and the hand's pixels.

:func:`hand_region` picks the glove pixels that belong to the hand: classified glove
pixels whose depth is missing or inside the working range, grouped into 8-connected
blobs (after closing one-pixel gaps between patches); the blob with the most solid
glove (what a 3x3 opening keeps) is the hand, and blobs near it in the image and in
depth join it (a finger split off by an occluding edge). Of the kept blobs, pixels far
from the hand's depth or from solid glove are dropped. Both matter in a dark room:
the camera's gain makes scattered background pixels glove-like, dense enough to
connect into one large blob with the hand; they do not survive the opening, so they
neither choose the hand nor set its depth, and those on a wall behind it fall outside
the band.
:func:`labeled_point_cloud` back-projects the hand's pixels that have depth.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array
from glovedb.camera import CameraIntrinsics


@dataclass(frozen=True)
class HandRegion:
    """The hand's glove pixels in one frame.

    Attributes
    ----------
    pixels_uv : (N, 2) int64
        Column, row of every hand pixel.
    labels : (N,) uint8
        Their classes 1..10.
    depth_m : (N,) float32
        Their depths (0 where the sensor has none).
    """

    pixels_uv: NDArray[np.int64]
    labels: NDArray[np.uint8]
    depth_m: NDArray[np.float32]

    def __len__(self) -> int:
        return len(self.labels)


@dataclass(frozen=True)
class LabeledPointCloud:
    """Glove points in the camera frame with their classes.

    Attributes
    ----------
    points_m : (N, 3) float32
        Camera frame (OpenCV axes), metres.
    labels : (N,) uint8
        Classes 1..10.
    """

    points_m: NDArray[np.float32]
    labels: NDArray[np.uint8]

    def __len__(self) -> int:
        return len(self.labels)

    def subsample(self, stride: int) -> LabeledPointCloud:
        """Every ``stride``-th point (thesis Figure 4.11: speed against accuracy)."""
        if stride < 1:
            raise ValueError(f"stride: expected >= 1, got {stride}")
        return LabeledPointCloud(self.points_m[::stride], self.labels[::stride])


def hand_region(
    labels: ArrayLike,
    depth_m: ArrayLike,
    *,
    z_range_m: tuple[float, float] = (0.2, 1.5),
    join_depth_m: float = 0.15,
    hand_depth_band_m: float = 0.2,
) -> HandRegion:
    """The glove pixels of the hand (see the module docstring).

    Parameters
    ----------
    labels : (H, W) uint8
        Classified frame.
    depth_m : (H, W) float32
        0 where there is no measurement.
    z_range_m : (float, float)
        Working depth range; glove-colored pixels outside it are dropped.
    join_depth_m : float
        A blob joins the hand if its median depth is this close to the hand's.
    hand_depth_band_m : float
        Pixels of the hand's blobs whose depth lies farther than this from the hand's
        median depth are something else seen beside the hand (a wall behind it
        through misregistered color, noise on it in a dark room) and are dropped.

    Returns
    -------
    HandRegion
        Empty when the frame has no glove pixels.
    """
    label_image = as_array("labels", labels, (None, None), kind="u")
    depth = as_array("depth_m", depth_m, label_image.shape, np.float32)
    z_min, z_max = z_range_m
    valid_depth = (depth >= z_min) & (depth <= z_max)
    glove = (label_image > 0) & ((depth == 0) | valid_depth)
    rows_with_glove = np.flatnonzero(glove.any(axis=1))
    if len(rows_with_glove) == 0:
        return _empty_region()
    # Everything below works in the glove pixels' bounding box, widened by a margin
    # that no 3x3 closing or opening (or the 5x5 dilation) reaches across: the same
    # blobs, in the same order, as on the whole frame, at a fraction of the cost.
    cols_with_glove = np.flatnonzero(glove.any(axis=0))
    height, width = glove.shape
    top = max(int(rows_with_glove[0]) - _WINDOW_MARGIN_PX, 0)
    bottom = min(int(rows_with_glove[-1]) + _WINDOW_MARGIN_PX + 1, height)
    left = max(int(cols_with_glove[0]) - _WINDOW_MARGIN_PX, 0)
    right = min(int(cols_with_glove[-1]) + _WINDOW_MARGIN_PX + 1, width)
    window = (slice(top, bottom), slice(left, right))
    region = _region_in_window(
        label_image[window], depth[window], glove[window], join_depth_m, hand_depth_band_m
    )
    region.pixels_uv[:, 0] += left
    region.pixels_uv[:, 1] += top
    return region


def _region_in_window(
    label_image: NDArray[np.uint8],
    depth: NDArray[np.float32],
    glove: NDArray[np.bool_],
    join_depth_m: float,
    hand_depth_band_m: float,
) -> HandRegion:
    """:func:`hand_region` within a window that holds every glove pixel; pixels in
    window coordinates."""
    square = np.ones((3, 3), np.uint8)
    glove_u8 = glove.astype(np.uint8)
    closed = cv2.morphologyEx(glove_u8, cv2.MORPH_CLOSE, square)
    count, blobs, stats, _ = cv2.connectedComponentsWithStats(closed, connectivity=8)
    # Solid glove: what survives an opening (isolated pixels, a dark room's color noise,
    # do not). The hand is the blob with the most of it, and its depth is the solid
    # part's: noise connected to the hand into one blob must not decide either.
    solid = cv2.morphologyEx(glove_u8, cv2.MORPH_OPEN, square).astype(bool)
    sizes = np.bincount(blobs[solid], minlength=count)[1:]
    if not sizes.any():
        return _empty_region()
    hand = 1 + int(np.argmax(sizes))
    keep = np.zeros(count, bool)
    keep[hand] = True
    hand_depth = _median_depth(depth, (blobs == hand) & solid)
    x, y, w, h = stats[hand, :4]
    margin = max(w, h) // 2
    for blob in range(1, count):
        if blob == hand or stats[blob, cv2.CC_STAT_AREA] < 20:
            continue
        bx, by, bw, bh = stats[blob, :4]
        near = (
            bx < x + w + margin
            and bx + bw > x - margin
            and by < y + h + margin
            and by + bh > y - margin
        )
        if near and abs(_median_depth(depth, blobs == blob) - hand_depth) < join_depth_m:
            keep[blob] = True
    # Of the kept blobs, the glove pixels at the hand's depth (or without depth) and
    # within 2 px of solid glove (a finger's sliver beside an occluder stays), found
    # within the blobs' bounding box, whose row-major order is the frame's.
    kept = np.flatnonzero(keep)
    left, top = int(stats[kept, 0].min()), int(stats[kept, 1].min())
    right = int((stats[kept, 0] + stats[kept, 2]).max())
    bottom = int((stats[kept, 1] + stats[kept, 3]).max())
    box = (slice(top, bottom), slice(left, right))
    depth_box = depth[box]
    near_hand = (depth_box == 0) | (np.abs(depth_box - hand_depth) < hand_depth_band_m)
    beside_solid = cv2.dilate(solid[box].astype(np.uint8), np.ones((5, 5), np.uint8))
    rows, cols = np.nonzero(keep[blobs[box]] & glove[box] & near_hand & beside_solid.astype(bool))
    return HandRegion(
        pixels_uv=np.stack([cols + left, rows + top], axis=1).astype(np.int64),
        labels=label_image[box][rows, cols].astype(np.uint8),
        depth_m=depth_box[rows, cols],
    )


def labeled_point_cloud(region: HandRegion, intrinsics: CameraIntrinsics) -> LabeledPointCloud:
    """Back-project the hand pixels that have depth (thesis Eq. 4.1)."""
    has_depth = region.depth_m > 0
    points = intrinsics.back_project(region.pixels_uv[has_depth], region.depth_m[has_depth])
    return LabeledPointCloud(points.astype(np.float32), region.labels[has_depth])


_WINDOW_MARGIN_PX = 4
"""Pixels around the glove's bounding box that :func:`hand_region` works in."""


def _median_depth(depth: NDArray[np.float32], mask: NDArray[np.bool_]) -> float:
    values = depth[mask]
    values = values[values > 0]
    return float(np.median(values)) if len(values) else float("nan")


def _empty_region() -> HandRegion:
    return HandRegion(np.zeros((0, 2), np.int64), np.zeros(0, np.uint8), np.zeros(0, np.float32))
