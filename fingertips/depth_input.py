"""Reading the depth frames of an RGB-D folder (docs/conventions.md layout), or of a recording.

``SEQ/intrinsic.json`` (Open3D JSON), ``SEQ/depth/NNNNNN.png`` (uint16 in
``depth_scale`` units per metre, 0 = missing) and an optional ``SEQ/meta.json`` with
``depth_scale`` (default 1000). Color is not needed for fingertip detection.
:func:`open_depth_source` also reads RealSense ``.bag`` recordings and live cameras,
through :func:`tracker.sources.open_source`.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from glovedb.camera import CameraIntrinsics


@dataclass(frozen=True)
class DepthSequence:
    """The depth frames of a folder, read on demand.

    Attributes
    ----------
    folder : Path
    intrinsics : (4,) float64
        ``(fx, fy, cx, cy)`` in pixels.
    size : tuple of int
        Image ``(width, height)`` from ``intrinsic.json``.
    depth_scale : float
        Depth units per metre in the PNG files.
    frames : tuple of int
        Frame numbers, from the depth file names, ascending.
    """

    folder: Path
    intrinsics: NDArray[np.float64]
    size: tuple[int, int]
    depth_scale: float
    frames: tuple[int, ...]

    def depth_path(self, frame: int) -> Path:
        """Path of the depth PNG of ``frame``."""
        return self.folder / "depth" / f"{frame:06d}.png"

    def read_depth(self, frame: int) -> NDArray[np.float32]:
        """Depth of ``frame`` as ``(H, W) float32`` metres, 0 where missing.

        Raises
        ------
        ValueError
            If the file is missing, not a 16-bit single-channel image, or not of the
            size ``intrinsic.json`` gives (the intrinsics would not fit its pixels).
        """
        path = self.depth_path(frame)
        if not path.is_file():
            raise ValueError(f"{path}: no depth image for frame {frame}")
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None or image.dtype != np.uint16 or image.ndim != 2:
            raise ValueError(f"{path}: expected a 16-bit single-channel depth PNG")
        width, height = self.size
        if image.shape != (height, width):
            raise ValueError(
                f"{path}: {image.shape[1]}x{image.shape[0]} pixels, but intrinsic.json "
                f"gives {width}x{height}"
            )
        return image.astype(np.float32) / np.float32(self.depth_scale)


def read_intrinsics(folder: str | os.PathLike[str]) -> tuple[NDArray[np.float64], tuple[int, int]]:
    """``(fx, fy, cx, cy)`` and ``(width, height)`` from a folder's ``intrinsic.json``.

    Raises
    ------
    ValueError
        If the file is missing or malformed.
    """
    path = Path(folder) / "intrinsic.json"
    try:
        data = json.loads(path.read_text())
        matrix = [float(x) for x in data["intrinsic_matrix"]]
        size = (int(data["width"]), int(data["height"]))
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise ValueError(f"{path}: cannot read camera intrinsics ({error})") from error
    if len(matrix) != 9:
        raise ValueError(f"{path}: intrinsic_matrix must have 9 numbers")
    # Open3D writes the 3x3 matrix column-major: fx at 0, fy at 4, cx at 6, cy at 7.
    return np.array([matrix[0], matrix[4], matrix[6], matrix[7]]), size


def read_depth_scale(folder: str | os.PathLike[str]) -> float:
    """``depth_scale`` of a folder's ``meta.json`` (1000 when there is none)."""
    path = Path(folder) / "meta.json"
    if not path.is_file():
        return 1000.0
    try:
        scale = float(json.loads(path.read_text()).get("depth_scale", 1000.0))
    except (ValueError, TypeError, AttributeError) as error:
        raise ValueError(f"{path}: cannot read depth_scale ({error})") from error
    if not 0 < scale < math.inf:
        raise ValueError(f"{path}: depth_scale must be positive and finite, got {scale}")
    return scale


def _frame_number(path: Path) -> int:
    """The frame a depth file holds; ``ValueError`` unless named ``NNNNNN.png``.

    Frames are read back by their six-digit name, so ``5.png`` or ``0000005.png``
    would be read as another file or not at all.
    """
    frame = int(path.stem)
    if path.name != f"{frame:06d}.png":
        raise ValueError(f"{path}: depth images must be named by six-digit frame numbers")
    return frame


def open_depth_sequence(folder: str | os.PathLike[str]) -> DepthSequence:
    """Index the depth frames of an RGB-D folder.

    Raises
    ------
    ValueError
        If the folder has no ``intrinsic.json`` or no ``depth/NNNNNN.png`` frames.
    """
    root = Path(folder)
    if not root.is_dir():
        raise ValueError(f"{root}: not a folder")
    intrinsics, size = read_intrinsics(root)
    names = sorted((root / "depth").glob("*.png")) if (root / "depth").is_dir() else []
    frames = tuple(sorted(_frame_number(path) for path in names if path.stem.isdigit()))
    if not frames:
        raise ValueError(f"{root}: no depth/NNNNNN.png frames")
    return DepthSequence(root, intrinsics, size, read_depth_scale(root), frames)


@dataclass(frozen=True)
class DepthFrame:
    """One depth frame for the fingertip detector.

    Attributes
    ----------
    frame : int
        Frame number (from the file name, or counted from 0 in a recording).
    depth_m : (H, W) float32
        Metres, 0 where missing.
    intrinsics : (4,) float64
        ``(fx, fy, cx, cy)`` in pixels.
    timestamp_s : float or None
        Capture time in seconds when the source gives one.
    """

    frame: int
    depth_m: NDArray[np.float32]
    intrinsics: NDArray[np.float64]
    timestamp_s: float | None = None


@dataclass(frozen=True)
class DepthSource:
    """Depth frames from a folder, a recording or a camera.

    Attributes
    ----------
    frames : iterator of DepthFrame
    description : str
        What was opened, for messages.
    n_frames : int or None
        Known for folders.
    live : bool
        A camera: the frames go on until the caller stops.
    """

    frames: Iterator[DepthFrame]
    description: str
    n_frames: int | None
    live: bool

    def __iter__(self) -> Iterator[DepthFrame]:
        return self.frames


def open_depth_source(
    spec: str | os.PathLike[str],
    *,
    depth_scale: float | None = None,
    intrinsics: CameraIntrinsics | None = None,
) -> DepthSource:
    """Open the depth frames of an RGB-D folder, a ``.bag`` recording or a live camera.

    A folder needs only ``intrinsic.json`` and ``depth/`` (:func:`open_depth_sequence`);
    anything else goes to :func:`tracker.sources.open_source` (a RealSense ``.bag``,
    ``"realsense"``, ``"kinect"``), whose color frames are not used.

    Parameters
    ----------
    spec : str or path
    depth_scale : float, optional
        Depth units per metre; overrides ``meta.json`` or the recording's value.
    intrinsics : CameraIntrinsics, optional
        Only for ``"kinect"`` (see :func:`tracker.sources.open_source`).

    Raises
    ------
    ValueError
        One line naming what could not be opened.
    """
    if Path(spec).is_dir():
        sequence = open_depth_sequence(spec)
        if depth_scale is not None:
            sequence = replace(sequence, depth_scale=float(depth_scale))

        def from_folder() -> Iterator[DepthFrame]:
            for frame in sequence.frames:
                yield DepthFrame(frame, sequence.read_depth(frame), sequence.intrinsics)

        return DepthSource(from_folder(), str(spec), len(sequence.frames), live=False)
    from tracker.sources import LIVE_CAMERAS, open_source

    source = open_source(spec, depth_scale=depth_scale, intrinsics=intrinsics)

    def from_source() -> Iterator[DepthFrame]:
        for frame in source:
            pinhole = frame.intrinsics.pinhole
            yield DepthFrame(frame.index, frame.depth_m, pinhole, frame.timestamp_s)

    live = source.kind in LIVE_CAMERAS
    return DepthSource(from_source(), source.description, source.n_frames, live=live)
