"""Which keypoints the camera sees: seen, hidden by the hand itself, or by something else.

A keypoint is a joint centre inside the hand, about a finger radius behind the
surface that faces the camera. The fitted model's camera-facing samples are splatted
into a coarse depth buffer (cells of ``cell_px`` pixels, the nearest sample wins):

- ``out_of_view``: the keypoint projects outside the image;
- ``self_occluded``: the model's own surface at the keypoint's cell is nearer than the
  keypoint by more than ``radius_m`` plus the margin (a finger or the palm in front);
- ``occluded``: the observed depth there is nearer than the model's surface by more
  than the margin (an object in front), or the sensor sees nothing of the hand there;
- ``seen``: otherwise.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tracker.generative.model import PosedHand

VISIBILITY: tuple[str, ...] = ("seen", "self_occluded", "occluded", "out_of_view")


def keypoint_visibility(
    hand: PosedHand,
    depth_m: NDArray[np.float32],
    pinhole: ArrayLike,
    *,
    radius_m: float = 0.012,
    margin_m: float = 0.012,
    cell_px: int = 4,
) -> tuple[str, ...]:
    """The visibility of each of the 21 keypoints of a fitted hand (module docstring).

    Parameters
    ----------
    hand : PosedHand
        The fitted model.
    depth_m : (H, W) float32
        The frame's observed depth (0: none).
    pinhole : (4,) float
        fx, fy, cx, cy.
    radius_m, margin_m : float
        How far behind the model's front surface a keypoint lies, and the tolerance.
    cell_px : int
        Size of a depth-buffer cell, pixels (samples are a few pixels apart).

    Returns
    -------
    tuple of str
        21 entries of :data:`VISIBILITY`.
    """
    fx, fy, cx, cy = (float(value) for value in np.asarray(pinhole).reshape(4))
    height, width = depth_m.shape
    points = hand.points_m[hand.facing & (hand.points_m[:, 2] > 1e-3)]
    cells = (-(-height // cell_px), -(-width // cell_px))
    buffer = np.full(cells, np.inf)
    u = np.rint(fx * points[:, 0] / points[:, 2] + cx).astype(np.int64)
    v = np.rint(fy * points[:, 1] / points[:, 2] + cy).astype(np.int64)
    inside = (u >= 0) & (u < width) & (v >= 0) & (v < height)
    np.minimum.at(buffer, (v[inside] // cell_px, u[inside] // cell_px), points[inside, 2])
    # All 21 keypoints at once; ``np.rint`` rounds half to even as ``round`` does.
    x, y, z = hand.keypoints_m.T
    with np.errstate(divide="ignore", invalid="ignore"):
        ku, kv = np.rint(fx * x / z + cx), np.rint(fy * y / z + cy)
    in_view = (z > 0) & (ku >= 0) & (ku < width) & (kv >= 0) & (kv < height)
    ku = np.where(in_view, ku, 0).astype(np.int64)
    kv = np.where(in_view, kv, 0).astype(np.int64)
    surface = buffer[kv // cell_px, ku // cell_px]
    self_occluded = surface < z - radius_m - margin_m
    # The observed depth in the 3 x 3 pixels around each keypoint (fewer at the image
    # border): its median where the sensor measured something.
    rows = kv[:, None] + np.array([-1, -1, -1, 0, 0, 0, 1, 1, 1])
    columns = ku[:, None] + np.array([-1, 0, 1, -1, 0, 1, -1, 0, 1])
    within = (rows >= 0) & (rows < height) & (columns >= 0) & (columns < width)
    window = depth_m[np.clip(rows, 0, height - 1), np.clip(columns, 0, width - 1)]
    measured = within & (window > 0)
    count = measured.sum(axis=1)
    ordered = np.sort(np.where(measured, window, np.inf), axis=1)
    low = np.take_along_axis(ordered, (np.maximum(count - 1, 0) // 2)[:, None], 1)[:, 0]
    high = np.take_along_axis(ordered, (count // 2)[:, None], 1)[:, 0]
    median = np.where(count % 2 == 1, low, (low + high) / 2)  # np.median's, bit for bit
    front = np.minimum(surface, z - radius_m)
    hidden = (count == 0) | (median < front - margin_m)
    flags = np.select([~in_view, self_occluded, hidden], [3, 1, 2], 0)
    return tuple(VISIBILITY[flag] for flag in flags)
