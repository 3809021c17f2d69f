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

from tracker.generative import _kernels
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
    camera = np.asarray(pinhole, dtype=np.float64).reshape(4)
    flags = np.empty(len(hand.keypoints_m), np.int8)
    # One compiled pass (0.04 ms; 1.0 ms as a loop with a median per keypoint).
    _kernels.keypoint_flags(
        hand.points_m, hand.facing, np.ascontiguousarray(hand.keypoints_m, dtype=np.float64),
        np.ascontiguousarray(depth_m), camera, float(radius_m), float(margin_m), int(cell_px),
        flags,
    )  # fmt: skip
    return tuple(VISIBILITY[flag] for flag in flags)
