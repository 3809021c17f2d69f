"""One RGB-D frame as the tracker receives it, from any source."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from glovedb._validate import as_array
from glovedb.camera import CameraIntrinsics


@dataclass(frozen=True)
class Frame:
    """Registered color and depth of one moment.

    Attributes
    ----------
    index : int
        Frame number in its sequence, from 0.
    color : (H, W, 3) uint8
        RGB, registered to depth.
    depth_m : (H, W) float32
        Depth along the optical axis in metres; 0 where there is no measurement.
    intrinsics : CameraIntrinsics
        Of both images (OpenCV convention).
    timestamp_s : float or None
        Capture time when the source gives one.
    """

    index: int
    color: NDArray[np.uint8]
    depth_m: NDArray[np.float32]
    intrinsics: CameraIntrinsics
    timestamp_s: float | None = None

    def __post_init__(self) -> None:
        height, width = self.intrinsics.height, self.intrinsics.width
        as_array("color", self.color, (height, width, 3), kind="u")
        as_array("depth_m", self.depth_m, (height, width), kind="f")
        if self.color.dtype != np.uint8:
            raise TypeError(f"color: expected uint8, got {self.color.dtype}")


def depth_to_metres(depth: NDArray, depth_scale: float) -> NDArray[np.float32]:
    """uint16 depth in ``depth_scale`` units per metre to float32 metres (0 stays 0)."""
    if not depth_scale > 0:
        raise ValueError(f"depth_scale: expected > 0, got {depth_scale}")
    return (np.asarray(depth, dtype=np.float32) / np.float32(depth_scale)).astype(np.float32)
