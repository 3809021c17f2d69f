"""Pinhole camera intrinsics in the OpenCV convention, and their file format.

x right, y down, z forward; pixel (0, 0) is the centre of the top-left pixel, so a
point projects to ``u = fx * x / z + cx``, ``v = fy * y / z + cy``. On disk the
intrinsics are Open3D's ``PinholeCameraIntrinsic`` JSON (docs/conventions.md), whose
``intrinsic_matrix`` is the 3x3 matrix in column-major order.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array


@dataclass(frozen=True)
class CameraIntrinsics:
    """Image size in pixels and pinhole parameters in pixels (OpenCV convention)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"camera size must be positive, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0):
            raise ValueError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")

    @property
    def matrix(self) -> NDArray[np.float64]:
        """``(3, 3)`` float64 camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def pinhole(self) -> NDArray[np.float64]:
        """``(4,)`` float64 ``(fx, fy, cx, cy)``, the form the fingertip detector takes."""
        return np.array([self.fx, self.fy, self.cx, self.cy])

    def project(self, points_m: ArrayLike) -> NDArray[np.float64]:
        """Pixel coordinates ``(..., 2)`` of camera-frame points ``(..., 3)`` (z > 0)."""
        p = as_array("points_m", points_m, (..., 3), np.float64)
        z = p[..., 2]
        return np.stack([self.fx * p[..., 0] / z + self.cx, self.fy * p[..., 1] / z + self.cy], -1)

    def back_project(self, pixels_px: ArrayLike, depth_m: ArrayLike) -> NDArray[np.float64]:
        """Camera-frame points ``(..., 3)`` of pixels ``(..., 2)`` at depths ``(...)``."""
        uv = as_array("pixels_px", pixels_px, (..., 2), np.float64)
        z = np.asarray(depth_m, dtype=np.float64)
        x = (uv[..., 0] - self.cx) / self.fx * z
        y = (uv[..., 1] - self.cy) / self.fy * z
        return np.stack([x, y, z], -1)

    def scaled(self, factor: float) -> CameraIntrinsics:
        """The same camera with the image resized by ``factor`` (pixel centres kept)."""
        return CameraIntrinsics(
            width=round(self.width * factor),
            height=round(self.height * factor),
            fx=self.fx * factor,
            fy=self.fy * factor,
            cx=(self.cx + 0.5) * factor - 0.5,
            cy=(self.cy + 0.5) * factor - 0.5,
        )

    def plane_depth(
        self, normal: ArrayLike, point_m: ArrayLike, *, max_depth_m: float = 5.0
    ) -> NDArray[np.float32]:
        """Depth image ``(H, W) float32`` of an infinite plane seen by this camera.

        Parameters
        ----------
        normal : (3,) float
            Plane normal, camera frame.
        point_m : (3,) float
            A point of the plane, camera frame, metres.
        max_depth_m : float
            Farther plane points, and points behind the camera, read 0.
        """
        n = as_array("normal", normal, (3,), np.float64, finite=True)
        p = as_array("point_m", point_m, (3,), np.float64, finite=True)
        v, u = np.indices((self.height, self.width), dtype=np.float64)
        # The ray through (u, v) is z * ((u - cx) / fx, (v - cy) / fy, 1); it meets the
        # plane n . x = n . p at z = (n . p) / (n . ray(z = 1)).
        facing = n[0] * (u - self.cx) / self.fx + n[1] * (v - self.cy) / self.fy + n[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = np.where(np.abs(facing) > 1e-9, (n @ p) / facing, 0.0)
        depth[(depth <= 0) | (depth > max_depth_m) | ~np.isfinite(depth)] = 0.0
        return depth.astype(np.float32)

    def to_open3d_json(self) -> dict:
        """The Open3D ``PinholeCameraIntrinsic`` JSON object (column-major matrix)."""
        return {
            "width": self.width,
            "height": self.height,
            "intrinsic_matrix": self.matrix.T.ravel().tolist(),
        }

    @classmethod
    def from_open3d_json(cls, data: dict) -> CameraIntrinsics:
        """Read the Open3D JSON object; raises ``ValueError`` on a malformed one."""
        try:
            k = np.array(data["intrinsic_matrix"], dtype=np.float64).reshape(3, 3).T
            return cls(int(data["width"]), int(data["height"]), k[0, 0], k[1, 1], k[0, 2], k[1, 2])
        except (KeyError, TypeError, ValueError) as error:
            raise ValueError(f"malformed camera intrinsics: {error}") from error


def load_intrinsics(path: str | Path) -> CameraIntrinsics:
    """Read an ``intrinsic.json`` file; one-line ``ValueError`` if it is unreadable."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as error:
        raise ValueError(f"{path}: cannot read camera intrinsics ({error})") from error
    return CameraIntrinsics.from_open3d_json(data)


def save_intrinsics(intrinsics: CameraIntrinsics, path: str | Path) -> None:
    """Write ``intrinsic.json`` in Open3D's format."""
    Path(path).write_text(json.dumps(intrinsics.to_open3d_json(), indent=1))


KINECT_V1 = CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
