"""Where frames come from: RGB-D folders, RealSense bags, live cameras, arrays.

Every source yields :class:`tracker.frames.Frame` objects (RGB uint8 color, float32
depth in metres, the intrinsics of both images). :func:`open_source` picks the source
from what it is given:

========================  ===============================================================
spec                      source
========================  ===============================================================
a folder                  :func:`frames_from_folder` (docs/conventions.md RGB-D layout)
a ``.bag`` file           :func:`frames_from_bag` (RealSense recording, via Open3D)
``"realsense"``           :func:`frames_from_realsense` (live Intel RealSense camera)
``"kinect"``              :func:`frames_from_kinect` (live Azure Kinect camera)
an iterable of tuples     :func:`frames_from_arrays` (``(color, depth, intrinsics)``)
========================  ===============================================================

Every problem with the input is a ``ValueError`` whose message is one line naming
the file (or the camera); the CLI prints it and exits with code 2. Problems found by
looking at the folder (missing files, unpaired names, bad ``meta.json``) are raised
when the source is opened; problems inside one image (unreadable, truncated, wrong
size or type) when that frame is reached. A depth image of zeros is not a problem:
the tracker reports that it found no hand.
"""

from __future__ import annotations

import contextlib
import json
import math
import threading
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any, Literal, TypeVar

import cv2
import numpy as np
from numpy.typing import NDArray

from glovedb._validate import as_array
from glovedb.camera import CameraIntrinsics, load_intrinsics
from tracker.frames import Frame, depth_to_metres

SourceKind = Literal["folder", "bag", "realsense", "kinect", "arrays"]
LIVE_CAMERAS: tuple[str, ...] = ("realsense", "kinect")
DEFAULT_DEPTH_SCALE = 1000.0
DEFAULT_TIMEOUT_S = 5.0
IMAGE_SUFFIXES: tuple[str, ...] = (".png", ".jpg", ".jpeg")
# Trailers that a complete file ends with: PNG's IEND chunk and JPEG's EOI marker.
_PNG_END = b"IEND\xaeB`\x82"
_JPEG_END = b"\xff\xd9"
_ROSBAG_MAGIC = b"#ROSBAG"

_T = TypeVar("_T")


@dataclass(frozen=True)
class Source:
    """An opened frame source.

    Attributes
    ----------
    frames : iterator of Frame
        The frames in order; iterate over the source itself for the same.
    kind : {"folder", "bag", "realsense", "kinect", "arrays"}
    description : str
        What was opened, for messages (a path or a camera name).
    fps : float or None
        Frame rate when the source knows it (``meta.json``, the bag, the camera).
    n_frames : int or None
        Number of frames when known in advance (folders), for progress bars.
    """

    frames: Iterator[Frame]
    kind: SourceKind
    description: str
    fps: float | None = None
    n_frames: int | None = None

    def __iter__(self) -> Iterator[Frame]:
        return self.frames


@dataclass(frozen=True)
class FolderSequence:
    """The checked layout of an RGB-D folder (no image read yet).

    Attributes
    ----------
    folder : Path
    intrinsics : CameraIntrinsics
        From ``intrinsic.json``.
    color_paths, depth_paths : tuple of Path
        Paired files in numeric order.
    depth_scale : float
        Depth units per metre (``meta.json``, else 1000).
    fps : float or None
        From ``meta.json``.
    """

    folder: Path
    intrinsics: CameraIntrinsics
    color_paths: tuple[Path, ...]
    depth_paths: tuple[Path, ...]
    depth_scale: float
    fps: float | None

    def __len__(self) -> int:
        return len(self.color_paths)


def open_source(
    spec: str | PathLike[str] | Iterable[tuple[Any, Any, CameraIntrinsics]],
    *,
    depth_scale: float | None = None,
    intrinsics: CameraIntrinsics | None = None,
    timeout_s: float = DEFAULT_TIMEOUT_S,
) -> Source:
    """Open a frame source chosen by what ``spec`` is.

    Parameters
    ----------
    spec : str, path or iterable
        An RGB-D folder, a RealSense ``.bag`` file, ``"realsense"`` or ``"kinect"``
        for a live camera (an existing path of that name wins), or an iterable of
        ``(color, depth, intrinsics)`` tuples (see :func:`frames_from_arrays`).
    depth_scale : float, optional
        Depth units per metre; overrides ``meta.json`` or the recording's value.
    intrinsics : CameraIntrinsics, optional
        Only for ``"kinect"``, whose Open3D interface does not report its calibration.
    timeout_s : float
        How long a camera or recording may take to deliver its first frame.

    Returns
    -------
    Source

    Raises
    ------
    ValueError
        One line naming the folder, file or camera and what is wrong with it.
    TypeError
        ``spec`` is none of the above.
    """
    if isinstance(spec, (str, PathLike)):
        path = Path(spec)
        if str(spec).lower() in LIVE_CAMERAS and not path.exists():
            if str(spec).lower() == "realsense":
                return Source(frames_from_realsense(timeout_s=timeout_s), "realsense", "realsense")
            frames = frames_from_kinect(intrinsics=intrinsics, timeout_s=timeout_s)
            return Source(frames, "kinect", "kinect")
        if path.is_dir():
            sequence = scan_folder(path, depth_scale=depth_scale)
            return Source(_read_folder(sequence), "folder", str(path), sequence.fps, len(sequence))
        if not path.exists():
            raise ValueError(
                f"{path}: no such folder or file (expected an RGB-D folder, a .bag "
                f"recording, {' or '.join(map(repr, LIVE_CAMERAS))})"
            )
        bag = _BagRecording.open(path, depth_scale=depth_scale, timeout_s=timeout_s)
        return Source(bag.frames(), "bag", str(path), bag.fps)
    if isinstance(spec, Iterable):
        return Source(frames_from_arrays(spec, depth_scale=depth_scale), "arrays", "arrays")
    raise TypeError(f"spec: expected a path, a camera name or an iterable, got {type(spec)}")


# --- RGB-D folders ------------------------------------------------------------------


def scan_folder(folder: str | PathLike[str], *, depth_scale: float | None = None) -> FolderSequence:
    """Check an RGB-D folder's layout and pair its color and depth files.

    Parameters
    ----------
    folder : path
        ``intrinsic.json``, ``color/`` and ``depth/`` with numbered images, optional
        ``meta.json`` (docs/conventions.md).
    depth_scale : float, optional
        Overrides ``meta.json``'s ``depth_scale``.

    Returns
    -------
    FolderSequence

    Raises
    ------
    ValueError
        Missing folder or ``intrinsic.json``, bad ``meta.json``, no frames, a color
        file without a depth file or the reverse, a name that is not a number, a
        depth file that is not PNG.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"{folder}: no such folder")
    intrinsic_path = folder / "intrinsic.json"
    if not intrinsic_path.is_file():
        raise ValueError(f"{intrinsic_path}: missing (every RGB-D folder needs intrinsic.json)")
    try:
        intrinsics = load_intrinsics(intrinsic_path)
    except ValueError as error:
        raise ValueError(f"{intrinsic_path}: {error}") from error
    meta_scale, fps = _read_meta(folder / "meta.json")
    scale = _checked_depth_scale(depth_scale if depth_scale is not None else meta_scale)
    color = _numbered_images(folder / "color")
    depth = _numbered_images(folder / "depth")
    unpaired_color = sorted(color.keys() - depth.keys(), key=int)
    if unpaired_color:
        stem = unpaired_color[0]
        raise ValueError(f"{color[stem]}: no depth image {stem}.png in {folder / 'depth'}")
    unpaired_depth = sorted(depth.keys() - color.keys(), key=int)
    if unpaired_depth:
        stem = unpaired_depth[0]
        raise ValueError(f"{depth[stem]}: no color image {stem}.png/.jpg in {folder / 'color'}")
    if not color:
        raise ValueError(f"{folder}: no frames in color/ and depth/")
    for path in depth.values():
        if path.suffix.lower() != ".png":
            raise ValueError(f"{path}: depth must be a 16-bit PNG, got {path.suffix}")
    stems = sorted(color, key=int)
    return FolderSequence(
        folder,
        intrinsics,
        tuple(color[s] for s in stems),
        tuple(depth[s] for s in stems),
        scale,
        fps,
    )


def frames_from_folder(
    folder: str | PathLike[str], *, depth_scale: float | None = None
) -> Iterator[Frame]:
    """Frames of an RGB-D folder in numeric order.

    The layout is checked when this is called (see :func:`scan_folder`); each image
    is read and checked when its frame is reached.

    Parameters
    ----------
    folder : path
    depth_scale : float, optional
        Depth units per metre; default ``meta.json``'s, else 1000.

    Yields
    ------
    Frame
        ``timestamp_s`` is ``index / fps`` when ``meta.json`` gives ``fps``.

    Raises
    ------
    ValueError
        For the layout problems of :func:`scan_folder`, and while iterating for an
        unreadable or truncated image, 8-bit depth, color that is not 3-channel 8-bit,
        or an image whose size differs from ``intrinsic.json``.
    """
    return _read_folder(scan_folder(folder, depth_scale=depth_scale))


def _read_folder(sequence: FolderSequence) -> Iterator[Frame]:
    for index, (color_path, depth_path) in enumerate(
        zip(sequence.color_paths, sequence.depth_paths, strict=True)
    ):
        color = read_color_image(color_path, sequence.intrinsics)
        depth = read_depth_image(depth_path, sequence.intrinsics)
        timestamp = index / sequence.fps if sequence.fps else None
        yield Frame(
            index,
            color,
            depth_to_metres(depth, sequence.depth_scale),
            sequence.intrinsics,
            timestamp,
        )


def read_color_image(path: Path, intrinsics: CameraIntrinsics) -> NDArray[np.uint8]:
    """Read an 8-bit color PNG/JPEG as ``(H, W, 3) uint8`` RGB; one-line ValueError."""
    image = _decode(path)
    if image.dtype != np.uint8:
        raise ValueError(f"{path}: color must be 8-bit, got {image.dtype}")
    if image.ndim != 3 or image.shape[2] != 3:
        channels = 1 if image.ndim == 2 else image.shape[2]
        raise ValueError(f"{path}: color must have 3 channels (RGB), got {channels}")
    _check_size(path, image, intrinsics)
    return np.asarray(cv2.cvtColor(image, cv2.COLOR_BGR2RGB), dtype=np.uint8)


def read_depth_image(path: Path, intrinsics: CameraIntrinsics) -> NDArray[np.uint16]:
    """Read a 16-bit one-channel depth PNG as ``(H, W) uint16``; one-line ValueError."""
    image = _decode(path)
    if image.ndim != 2:
        raise ValueError(f"{path}: depth must have one channel, got {image.shape[2]}")
    if image.dtype != np.uint16:
        bits = 8 * image.dtype.itemsize
        raise ValueError(f"{path}: depth must be 16-bit, got {bits}-bit ({image.dtype})")
    _check_size(path, image, intrinsics)
    return image


def _decode(path: Path) -> NDArray:
    try:
        data = path.read_bytes()
    except OSError as error:
        raise ValueError(f"{path}: cannot read ({error.strerror})") from error
    trailer = _PNG_END if path.suffix.lower() == ".png" else _JPEG_END
    if not data.rstrip(b"\x00").endswith(trailer):
        raise ValueError(f"{path}: truncated or not a {path.suffix[1:].upper()} image")
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f"{path}: unreadable image")
    return image


def _check_size(path: Path, image: NDArray, intrinsics: CameraIntrinsics) -> None:
    height, width = image.shape[:2]
    if (width, height) != (intrinsics.width, intrinsics.height):
        raise ValueError(
            f"{path}: image is {width}x{height}, intrinsic.json says "
            f"{intrinsics.width}x{intrinsics.height}"
        )


def _numbered_images(folder: Path) -> dict[str, Path]:
    if not folder.is_dir():
        raise ValueError(f"{folder}: missing (expected numbered images)")
    images: dict[str, Path] = {}
    for path in folder.iterdir():
        if path.name.startswith(".") or path.suffix.lower() not in IMAGE_SUFFIXES:
            continue
        if not path.stem.isdigit():
            raise ValueError(f"{path}: image names must be frame numbers like 000000.png")
        if path.stem in images:
            raise ValueError(f"{path}: two images with the number {path.stem}")
        images[path.stem] = path
    return images


def _read_meta(path: Path) -> tuple[float, float | None]:
    if not path.exists():
        return DEFAULT_DEPTH_SCALE, None
    try:
        meta = json.loads(path.read_text())
        depth_scale = float(meta.get("depth_scale", DEFAULT_DEPTH_SCALE))
        fps = meta.get("fps")
        fps = None if fps is None else float(fps)
    except (OSError, ValueError, TypeError, AttributeError) as error:
        raise ValueError(f"{path}: malformed meta.json ({error})") from error
    if not (math.isfinite(depth_scale) and depth_scale > 0):
        raise ValueError(f"{path}: depth_scale must be > 0, got {depth_scale}")
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"{path}: fps must be > 0, got {fps}")
    return depth_scale, fps


def _checked_depth_scale(depth_scale: float) -> float:
    if not (math.isfinite(depth_scale) and depth_scale > 0):
        raise ValueError(f"depth_scale: expected > 0, got {depth_scale}")
    return float(depth_scale)


# --- Arrays ---------------------------------------------------------------------------


def frames_from_arrays(
    iterable: Iterable[tuple[Any, Any, CameraIntrinsics]], *, depth_scale: float | None = None
) -> Iterator[Frame]:
    """Frames from ``(color, depth, intrinsics)`` tuples, for library users.

    Parameters
    ----------
    iterable : iterable of (color, depth, intrinsics)
        ``color`` (H, W, 3) uint8 RGB; ``depth`` (H, W) either unsigned integers in
        ``depth_scale`` units per metre or floats in metres (NaN and infinity mean
        missing and become 0); ``intrinsics`` a CameraIntrinsics of size W x H.
    depth_scale : float, optional
        For integer depth only; default 1000 (millimetres).

    Yields
    ------
    Frame
        Numbered from 0, without timestamps.

    Raises
    ------
    ValueError, TypeError
        Naming the frame number and the array at fault.
    """
    scale = _checked_depth_scale(DEFAULT_DEPTH_SCALE if depth_scale is None else depth_scale)
    for index, item in enumerate(iterable):
        try:
            color, depth, intrinsics = item
        except (TypeError, ValueError) as error:
            raise TypeError(
                f"frame {index}: expected a (color, depth, intrinsics) tuple"
            ) from error
        if not isinstance(intrinsics, CameraIntrinsics):
            raise TypeError(f"frame {index}: intrinsics must be CameraIntrinsics")
        size = (intrinsics.height, intrinsics.width)
        color = as_array(f"frame {index} color", color, (*size, 3), kind="u")
        if color.dtype != np.uint8:
            raise TypeError(f"frame {index} color: expected uint8, got {color.dtype}")
        depth = as_array(f"frame {index} depth", depth, size, kind="uif")
        if depth.dtype.kind == "f":
            depth_m = np.nan_to_num(depth.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)
        elif depth.dtype.kind == "i" and np.any(depth < 0):
            raise ValueError(f"frame {index} depth: negative values")
        else:
            depth_m = depth_to_metres(depth, scale)
        yield Frame(index, np.ascontiguousarray(color), depth_m, intrinsics)


# --- Open3D: bags and live cameras ---------------------------------------------------


def frames_from_bag(
    path: str | PathLike[str],
    *,
    depth_scale: float | None = None,
    timeout_s: float = DEFAULT_TIMEOUT_S,
) -> Iterator[Frame]:
    """Frames of a RealSense ``.bag`` recording, depth aligned to color.

    Open3D's ``RSBagReader`` aligns depth to the color camera; the intrinsics are the
    color stream's, from the recording's metadata.

    Parameters
    ----------
    path : path
    depth_scale : float, optional
        Depth units per metre; default the recording's, else 1000 (RealSense D400).
    timeout_s : float
        Longest wait for opening the file.

    Yields
    ------
    Frame
        With ``timestamp_s`` from the recording.

    Raises
    ------
    ValueError
        The file is missing, is not a bag, or Open3D cannot open it (checked when
        this is called).
    """
    return _BagRecording.open(Path(path), depth_scale=depth_scale, timeout_s=timeout_s).frames()


@dataclass(frozen=True)
class _BagRecording:
    path: Path
    reader: Any
    intrinsics: CameraIntrinsics
    depth_scale: float
    color_format: str
    fps: float | None

    @classmethod
    def open(cls, path: Path, *, depth_scale: float | None, timeout_s: float) -> _BagRecording:
        if not path.is_file():
            raise ValueError(f"{path}: no such file")
        with path.open("rb") as stream:
            if not stream.read(len(_ROSBAG_MAGIC)).startswith(_ROSBAG_MAGIC):
                raise ValueError(f"{path}: not a RealSense .bag recording (no ROSBAG header)")
        o3d = _open3d()
        reader = o3d.t.io.RSBagReader()
        try:
            with _quiet_open3d(o3d):
                opened = _call_with_timeout(lambda: reader.open(str(path)), timeout_s, str(path))
        except RuntimeError as error:
            raise ValueError(
                f"{path}: Open3D cannot read this bag ({_first_line(error)})"
            ) from error
        if not opened:
            raise ValueError(f"{path}: Open3D cannot open this bag (no color and depth streams?)")
        metadata = reader.metadata
        intrinsics = _intrinsics_from_open3d(metadata.intrinsics, str(path))
        recorded_scale = float(metadata.depth_scale)
        if depth_scale is None:
            depth_scale = recorded_scale if recorded_scale > 0 else DEFAULT_DEPTH_SCALE
        fps = float(metadata.fps) if metadata.fps > 0 else None
        return cls(
            path,
            reader,
            intrinsics,
            _checked_depth_scale(depth_scale),
            str(metadata.color_format),
            fps,
        )

    def frames(self) -> Iterator[Frame]:
        try:
            index = 0
            while not self.reader.is_eof():
                rgbd = self.reader.next_frame()
                if rgbd.is_empty():
                    break
                yield _frame_from_tensor_rgbd(
                    index,
                    rgbd,
                    self.intrinsics,
                    self.depth_scale,
                    self.color_format,
                    self.reader.get_timestamp() * 1e-6,
                    str(self.path),
                )
                index += 1
        finally:
            self.reader.close()


def frames_from_realsense(*, timeout_s: float = DEFAULT_TIMEOUT_S) -> Iterator[Frame]:
    """Frames of the first connected Intel RealSense camera, depth aligned to color.

    Parameters
    ----------
    timeout_s : float
        Longest wait for the camera to start and deliver its first frame.

    Yields
    ------
    Frame
        Until the caller stops iterating; the camera is stopped then.

    Raises
    ------
    ValueError
        This Open3D build has no RealSense support, no camera is connected, or it
        does not start within ``timeout_s`` (checked when this is called).
    """
    o3d = _open3d()
    if not hasattr(o3d.t.io, "RealSenseSensor"):
        raise ValueError("realsense: this Open3D build has no RealSense support")
    devices = _call_with_timeout(o3d.t.io.RealSenseSensor.enumerate_devices, timeout_s, "realsense")
    if not devices:
        raise ValueError("realsense: no RealSense camera connected")
    sensor = o3d.t.io.RealSenseSensor()

    def start() -> Any:
        sensor.init_sensor(o3d.t.io.RealSenseSensorConfig(), 0)
        sensor.start_capture(False)
        return sensor.get_metadata()

    try:
        with _quiet_open3d(o3d):
            metadata = _call_with_timeout(start, timeout_s, "realsense")
    except RuntimeError as error:
        raise ValueError(f"realsense: cannot start the camera ({_first_line(error)})") from error
    intrinsics = _intrinsics_from_open3d(metadata.intrinsics, "realsense")
    scale = float(metadata.depth_scale) if metadata.depth_scale > 0 else DEFAULT_DEPTH_SCALE
    return _live_frames(
        lambda: sensor.capture_frame(True, True),
        sensor.stop_capture,
        lambda rgbd, index: _frame_from_tensor_rgbd(
            index,
            rgbd,
            intrinsics,
            scale,
            str(metadata.color_format),
            sensor.get_timestamp() * 1e-6,
            "realsense",
        ),
        timeout_s,
        "realsense",
    )


def frames_from_kinect(
    *, intrinsics: CameraIntrinsics | None = None, timeout_s: float = DEFAULT_TIMEOUT_S
) -> Iterator[Frame]:
    """Frames of the first connected Azure Kinect, depth transformed to color.

    Open3D's Azure Kinect interface reports no calibration, so the color camera's
    intrinsics must be given (for example from ``intrinsic.json`` written by Open3D's
    ``azure_kinect_recorder``); depth is in millimetres.

    Parameters
    ----------
    intrinsics : CameraIntrinsics
        Of the color camera at the default 1280 x 720 resolution.
    timeout_s : float
        Longest wait for the camera to start and deliver a frame.

    Yields
    ------
    Frame

    Raises
    ------
    ValueError
        No Azure Kinect support (libk4a missing), no camera connected, no intrinsics,
        or no frame within ``timeout_s`` (checked when this is called).
    """
    o3d = _open3d()
    try:
        with _quiet_open3d(o3d):
            # list_devices raises (instead of aborting the process as constructing a
            # sensor does) when libk4a is missing, and when no device is connected.
            _call_with_timeout(o3d.io.AzureKinectSensor.list_devices, timeout_s, "kinect")
    except RuntimeError as error:
        if "k4a" in str(error):
            raise ValueError(
                "kinect: Azure Kinect support needs libk4a (Azure Kinect Sensor SDK), "
                "which is not installed"
            ) from error
        raise ValueError("kinect: no Azure Kinect connected") from error
    if intrinsics is None:
        raise ValueError("kinect: the color camera's intrinsics must be given (intrinsic.json)")
    sensor = o3d.io.AzureKinectSensor(o3d.io.AzureKinectSensorConfig())
    with _quiet_open3d(o3d):
        connected = _call_with_timeout(lambda: sensor.connect(0), timeout_s, "kinect")
    if not connected:
        raise ValueError("kinect: cannot open the Azure Kinect")

    def to_frame(rgbd: Any, index: int) -> Frame:
        color = np.asarray(rgbd.color)
        depth = np.asarray(rgbd.depth)
        for name, image in (("color", color), ("depth", depth)):
            _check_size(Path(f"kinect {name}"), image, intrinsics)
        return Frame(index, color.copy(), depth_to_metres(depth, DEFAULT_DEPTH_SCALE), intrinsics)

    return _live_frames(
        lambda: sensor.capture_frame(True), sensor.disconnect, to_frame, timeout_s, "kinect"
    )


def _live_frames(
    capture: Callable[[], Any],
    stop: Callable[[], Any],
    to_frame: Callable[[Any, int], Frame],
    timeout_s: float,
    name: str,
) -> Iterator[Frame]:
    try:
        index = 0
        while True:
            rgbd = _call_with_timeout(capture, timeout_s, name)
            if rgbd is None or rgbd.is_empty():
                continue
            yield to_frame(rgbd, index)
            index += 1
    finally:
        stop()


def _frame_from_tensor_rgbd(
    index: int,
    rgbd: Any,
    intrinsics: CameraIntrinsics,
    depth_scale: float,
    color_format: str,
    timestamp_s: float | None,
    name: str,
) -> Frame:
    color = _to_rgb(rgbd.color.as_tensor().numpy(), color_format, name)
    depth = rgbd.depth.as_tensor().numpy()
    depth = depth.reshape(depth.shape[:2])
    for kind, image in (("color", color), ("depth", depth)):
        _check_size(Path(f"{name} {kind}"), image, intrinsics)
    return Frame(index, color, depth_to_metres(depth, depth_scale), intrinsics, timestamp_s)


def _to_rgb(color: NDArray[np.uint8], color_format: str, name: str) -> NDArray[np.uint8]:
    conversions = {
        "BGR8": cv2.COLOR_BGR2RGB,
        "RGBA8": cv2.COLOR_RGBA2RGB,
        "BGRA8": cv2.COLOR_BGRA2RGB,
        "YUYV": cv2.COLOR_YUV2RGB_YUYV,
        "Y8": cv2.COLOR_GRAY2RGB,
    }
    if color_format == "RGB8":
        return np.ascontiguousarray(color)
    if color_format not in conversions:
        raise ValueError(f"{name}: unsupported color format {color_format}")
    rgb = cv2.cvtColor(np.ascontiguousarray(color), conversions[color_format])
    return np.asarray(rgb, dtype=np.uint8)


def _intrinsics_from_open3d(pinhole: Any, name: str) -> CameraIntrinsics:
    k = np.asarray(pinhole.intrinsic_matrix, dtype=np.float64)
    try:
        return CameraIntrinsics(
            int(pinhole.width), int(pinhole.height), k[0, 0], k[1, 1], k[0, 2], k[1, 2]
        )
    except ValueError as error:
        raise ValueError(f"{name}: no usable intrinsics in the metadata ({error})") from error


def _open3d() -> Any:
    import open3d

    return open3d


@contextlib.contextmanager
def _quiet_open3d(o3d: Any) -> Iterator[None]:
    """Keep Open3D's warnings off stdout (``--json`` prints exactly one object there)."""
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        yield


def _call_with_timeout(function: Callable[[], _T], timeout_s: float, name: str) -> _T:
    """Run a call that may block forever on a device in a daemon thread.

    A call still running after ``timeout_s`` is abandoned (a daemon thread does not
    keep the process alive) and reported as a ValueError.
    """
    outcome: dict[str, Any] = {}

    def run() -> None:
        try:
            outcome["value"] = function()
        except BaseException as error:  # re-raised in the caller's thread
            outcome["error"] = error

    worker = threading.Thread(target=run, daemon=True, name=f"{name}-open")
    worker.start()
    worker.join(timeout_s)
    if worker.is_alive():
        raise ValueError(f"{name}: no answer within {timeout_s:g} s")
    if "error" in outcome:
        raise outcome["error"]
    return outcome["value"]


def _first_line(error: BaseException) -> str:
    """Open3D's message without its colour codes, source location and extra lines."""
    text = str(error).replace("\x1b[1;31m", "").replace("\x1b[0;m", "").strip()
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return lines[-1] if lines else type(error).__name__
