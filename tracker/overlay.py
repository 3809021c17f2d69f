"""Pictures of the tracking result on the color frame, video output, timing tables.

Drawing functions are pure: they take an ``(H, W, 3) uint8`` RGB image and return a
new one, leaving the input untouched. Pixel coordinates follow the OpenCV convention
(pixel (0, 0) is the centre of the top-left pixel).

- :func:`draw_skeleton`: the 21 keypoints and the bones between them, one color per
  finger (:data:`FINGER_COLORS`);
- :func:`outline_mask` / :func:`draw_outline` / :func:`draw_model_outline`: the
  silhouette of the posed glove mesh, from its camera-facing triangles rasterised into
  a mask, drawn as the mask's outer contour;
- :func:`draw_fingertips`: fingertips as circles labelled with the finger;
- :func:`draw_detections`: depth fingertip detections as small crosses;
- :func:`draw_status`: a text line (frame, fps, confidence);
- :func:`draw_record`: all of the above for one ``poses.jsonl`` record.

:class:`VideoWriter` writes frames to an ``.mp4`` (or a PNG sequence when the codec
is missing); :func:`timing_summary` turns per-frame ``timing_ms`` into a table.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from types import TracebackType
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array
from glovedb.camera import CameraIntrinsics
from glovedb.hand_model import FINGERS, N_KEYPOINTS
from glovedb.mesh import HandMesh, pose_mesh
from tracker import _overlay_kernels

RGB = tuple[int, int, int]
FINGER_COLORS: dict[str, RGB] = {
    "thumb": (255, 64, 64),
    "index": (255, 160, 0),
    "middle": (255, 255, 0),
    "ring": (0, 220, 80),
    "little": (40, 160, 255),
}
PALM_COLOR: RGB = (255, 255, 255)
OUTLINE_COLOR: RGB = (255, 255, 255)
UNKNOWN_FINGER_COLOR: RGB = (200, 200, 200)
TEXT_COLOR: RGB = (255, 255, 255)

# Bones between keypoints (MediaPipe order): each finger's chain from the wrist, and
# the knuckle line across the palm.
FINGER_BONES: tuple[tuple[int, int], ...] = tuple(
    (0 if joint == 0 else 4 * finger + joint, 4 * finger + joint + 1)
    for finger in range(5)
    for joint in range(4)
)
PALM_BONES: tuple[tuple[int, int], ...] = ((5, 9), (9, 13), (13, 17), (1, 5))

_SHIFT = 4  # sub-pixel bits for OpenCV drawing
_NEAR_M = 0.01  # triangles with a vertex closer than this to the camera are skipped
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def draw_skeleton(
    image: ArrayLike, keypoints_2d_px: ArrayLike, *, radius_px: int = 3, thickness_px: int = 2
) -> NDArray[np.uint8]:
    """Draw the 21 keypoints and the bones between them.

    Parameters
    ----------
    image : (H, W, 3) uint8
        RGB.
    keypoints_2d_px : (21, 2) float
        MediaPipe order; non-finite points (and their bones) are skipped.
    radius_px, thickness_px : int

    Returns
    -------
    (H, W, 3) uint8
        A new image.
    """
    canvas = _copy_image(image)
    points = as_array("keypoints_2d_px", keypoints_2d_px, (N_KEYPOINTS, 2), np.float64)
    valid = np.isfinite(points).all(axis=1)
    fixed = _fixed_point(points)
    for a, b in PALM_BONES:
        if valid[a] and valid[b]:
            cv2.line(canvas, fixed[a], fixed[b], PALM_COLOR, thickness_px, cv2.LINE_AA, _SHIFT)
    for index, (a, b) in enumerate(FINGER_BONES):
        color = FINGER_COLORS[FINGERS[index // 4]]
        if valid[a] and valid[b]:
            cv2.line(canvas, fixed[a], fixed[b], color, thickness_px, cv2.LINE_AA, _SHIFT)
    for keypoint in np.flatnonzero(valid):
        color = PALM_COLOR if keypoint == 0 else FINGER_COLORS[FINGERS[(keypoint - 1) // 4]]
        cv2.circle(canvas, fixed[keypoint], radius_px << _SHIFT, color, -1, cv2.LINE_AA, _SHIFT)
    return canvas


def outline_mask(
    vertices_m: ArrayLike, faces: ArrayLike, intrinsics: CameraIntrinsics
) -> NDArray[np.bool_]:
    """Pixels covered by a mesh's camera-facing triangles.

    A pixel is covered when its centre lies inside (or on the edge of) a projected
    triangle that faces the camera; for a closed mesh that is its silhouette.
    Triangles with a vertex closer than 1 cm to the camera (or behind it) are skipped.

    Parameters
    ----------
    vertices_m : (V, 3) float
        In the camera frame, metres.
    faces : (F, 3) int
        Counter-clockwise seen from outside (as :class:`glovedb.mesh.HandMesh`).
    intrinsics : CameraIntrinsics

    Returns
    -------
    (H, W) bool
    """
    vertices = as_array("vertices_m", vertices_m, (None, 3), np.float64, finite=True)
    face_index = as_array("faces", faces, (None, 3), kind="iu")
    if len(face_index) and (face_index.min() < 0 or face_index.max() >= len(vertices)):
        raise ValueError(f"faces: indices must be in [0, {len(vertices)})")
    z = vertices[:, 2]
    in_front = z > _NEAR_M
    safe_z = np.where(in_front, z, 1.0)
    pixels = np.stack(
        [
            intrinsics.fx * vertices[:, 0] / safe_z + intrinsics.cx,
            intrinsics.fy * vertices[:, 1] / safe_z + intrinsics.cy,
        ],
        axis=-1,
    )
    triangles = pixels[face_index]
    edge_1 = triangles[:, 1] - triangles[:, 0]
    edge_2 = triangles[:, 2] - triangles[:, 0]
    # With y down, a triangle that is counter-clockwise seen from the camera has a
    # negative signed area in pixel coordinates.
    facing = edge_1[:, 0] * edge_2[:, 1] - edge_1[:, 1] * edge_2[:, 0] < 0
    visible = facing & in_front[face_index].all(axis=1)
    mask = np.zeros((intrinsics.height, intrinsics.width), dtype=np.bool_)
    _overlay_kernels.fill_triangles(np.ascontiguousarray(triangles[visible]), mask)
    return mask


def draw_outline(
    image: ArrayLike,
    mask: ArrayLike,
    *,
    color: RGB = OUTLINE_COLOR,
    thickness_px: int = 2,
) -> NDArray[np.uint8]:
    """Draw the outer contour of a mask (e.g. :func:`outline_mask`).

    Parameters
    ----------
    image : (H, W, 3) uint8
    mask : (H, W) bool
    color : (int, int, int)
        RGB.
    thickness_px : int

    Returns
    -------
    (H, W, 3) uint8
    """
    canvas = _copy_image(image)
    region = as_array("mask", mask, canvas.shape[:2]).astype(np.uint8)
    contours, _ = cv2.findContours(region, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    cv2.drawContours(canvas, contours, -1, color, thickness_px, cv2.LINE_AA)
    return canvas


def draw_model_outline(
    image: ArrayLike,
    mesh: HandMesh,
    posture_rad: ArrayLike,
    rotation: ArrayLike,
    translation_m: ArrayLike,
    intrinsics: CameraIntrinsics,
    *,
    color: RGB = OUTLINE_COLOR,
    thickness_px: int = 2,
) -> NDArray[np.uint8]:
    """Pose the glove mesh and draw its silhouette's outline.

    Parameters
    ----------
    image : (H, W, 3) uint8
    mesh : HandMesh
    posture_rad : (20,) float
    rotation : (3, 3) float
        ``cam_R_hand``.
    translation_m : (3,) float
        Wrist in the camera frame.
    intrinsics : CameraIntrinsics
    color : (int, int, int)
    thickness_px : int

    Returns
    -------
    (H, W, 3) uint8
    """
    rotation = as_array("rotation", rotation, (3, 3), np.float64, finite=True)
    translation = as_array("translation_m", translation_m, (3,), np.float64, finite=True)
    vertices = pose_mesh(mesh, posture_rad).reshape(-1, 3) @ rotation.T + translation
    mask = outline_mask(vertices, mesh.faces, intrinsics)
    return draw_outline(image, mask, color=color, thickness_px=thickness_px)


def draw_fingertips(
    image: ArrayLike, fingertips: Iterable[Mapping[str, Any]], *, radius_px: int = 7
) -> NDArray[np.uint8]:
    """Draw fingertip detections as circles labelled with the finger name.

    Parameters
    ----------
    image : (H, W, 3) uint8
    fingertips : iterable of mapping
        ``poses.jsonl`` fingertip objects: ``u_px``, ``v_px``, ``finger`` (name or
        None, drawn as "?"), optionally ``confidence``.
    radius_px : int

    Returns
    -------
    (H, W, 3) uint8
    """
    canvas = _copy_image(image)
    for tip, point, color in _tip_points(fingertips):
        finger = tip.get("finger")
        centre = _fixed_point(point[None])[0]
        cv2.circle(canvas, centre, radius_px << _SHIFT, color, 2, cv2.LINE_AA, _SHIFT)
        label = finger or "?"
        if tip.get("confidence") is not None:
            label += f" {float(tip['confidence']):.2f}"
        origin = (round(point[0]) + radius_px + 2, round(point[1]) - radius_px)
        _put_text(canvas, label, origin, color, scale=0.4)
    return canvas


def draw_detections(
    image: ArrayLike, detections: Iterable[Mapping[str, Any]], *, size_px: int = 9
) -> NDArray[np.uint8]:
    """Draw depth fingertip detections as crosses, in their finger's color when named.

    Parameters
    ----------
    image : (H, W, 3) uint8
    detections : iterable of mapping
        ``fingertip_detections`` objects of a ``poses.jsonl`` record (``u_px``,
        ``v_px``, ``finger`` name or None).
    size_px : int
        Width of a cross.

    Returns
    -------
    (H, W, 3) uint8
    """
    canvas = _copy_image(image)
    for _, point, color in _tip_points(detections):
        centre = (round(point[0]), round(point[1]))
        cv2.drawMarker(canvas, centre, color, cv2.MARKER_TILTED_CROSS, size_px, 2, cv2.LINE_AA)
    return canvas


def _tip_points(
    tips: Iterable[Mapping[str, Any]],
) -> Iterator[tuple[Mapping[str, Any], NDArray[np.float64], RGB]]:
    """Each fingertip object with a finite image position, that position ``(2,)`` and its
    finger's color (:data:`UNKNOWN_FINGER_COLOR` when unnamed)."""
    for tip in tips:
        point = np.array([tip["u_px"], tip["v_px"]], dtype=np.float64)
        if np.isfinite(point).all():
            finger = tip.get("finger")
            yield tip, point, FINGER_COLORS.get(finger or "", UNKNOWN_FINGER_COLOR)


def status_text(frame: int, *, fps: float | None = None, confidence: float | None = None) -> str:
    """``"frame 12 | 29.8 fps | confidence 0.81"``; ``"no hand"`` without confidence."""
    parts = [f"frame {frame}"]
    if fps is not None:
        parts.append(f"{fps:.1f} fps")
    parts.append("no hand" if confidence is None else f"confidence {confidence:.2f}")
    return " | ".join(parts)


def draw_status(
    image: ArrayLike, frame: int, *, fps: float | None = None, confidence: float | None = None
) -> NDArray[np.uint8]:
    """Draw :func:`status_text` at the top left on a dark band; returns a new image."""
    canvas = _copy_image(image)
    text = status_text(frame, fps=fps, confidence=confidence)
    (width, height), baseline = cv2.getTextSize(text, _FONT, 0.5, 1)
    band = canvas[: height + baseline + 8, : width + 10]
    band[:] = band // 3
    _put_text(canvas, text, (5, height + 4), TEXT_COLOR, scale=0.5)
    return canvas


def draw_record(
    image: ArrayLike,
    record: Mapping[str, Any],
    intrinsics: CameraIntrinsics,
    *,
    mesh: HandMesh | None = None,
    fps: float | None = None,
) -> NDArray[np.uint8]:
    """Draw one ``poses.jsonl`` record: outline, skeleton, fingertips (and the depth
    fingertip detections, when the record has them) and status.

    Parameters
    ----------
    image : (H, W, 3) uint8
        The frame's color image.
    record : mapping
        docs/conventions.md tracking output for this frame.
    intrinsics : CameraIntrinsics
    mesh : HandMesh, optional
        Draw the model's outline when given (costs a skinning of the mesh).
    fps : float, optional
        Shown in the status line.

    Returns
    -------
    (H, W, 3) uint8
    """
    canvas = _copy_image(image)
    found = bool(record.get("hand_found", False))
    if found and mesh is not None:
        canvas = draw_model_outline(
            canvas,
            mesh,
            record["posture_rad"],
            record["rotation"],
            record["translation_m"],
            intrinsics,
        )
    if found and record.get("keypoints_2d_px") is not None:
        canvas = draw_skeleton(canvas, record["keypoints_2d_px"])
    canvas = draw_fingertips(canvas, record.get("fingertips") or ())
    canvas = draw_detections(canvas, record.get("fingertip_detections") or ())
    confidence = record.get("confidence") if found else None
    return draw_status(canvas, int(record.get("frame", 0)), fps=fps, confidence=confidence)


# --- Video output ---------------------------------------------------------------------


class VideoWriter:
    """Write RGB frames to an ``.mp4`` file, or to a PNG sequence if that fails.

    The video is opened with the first frame (which fixes the size). If OpenCV cannot
    open an ``mp4v`` writer, the frames go to ``<stem>_frames/000000.png, ...`` beside
    the requested file instead; :attr:`note` says so (and a ``RuntimeWarning`` is
    issued), and :attr:`output_path` is the folder.

    Parameters
    ----------
    path : path
        The ``.mp4`` to write.
    fps : float
    codec : str
        FourCC, default ``"mp4v"``.

    Examples
    --------
    >>> with VideoWriter("overlay.mp4", fps=30) as video:  # doctest: +SKIP
    ...     for image in images:
    ...         video.write(image)
    """

    def __init__(self, path: str | PathLike[str], fps: float, *, codec: str = "mp4v") -> None:
        if not fps > 0:
            raise ValueError(f"fps: expected > 0, got {fps}")
        if len(codec) != 4:
            raise ValueError(f"codec: expected a four-character code, got {codec!r}")
        self.path = Path(path)
        self.fps = float(fps)
        self.codec = codec
        self.frames_written = 0
        self.note: str | None = None
        self._writer: cv2.VideoWriter | None = None
        self._folder: Path | None = None
        self._size: tuple[int, int] | None = None

    @property
    def output_path(self) -> Path:
        """The video file, or the PNG folder after a fallback."""
        return self._folder if self._folder is not None else self.path

    @property
    def fell_back(self) -> bool:
        """Whether frames go to a PNG sequence instead of a video."""
        return self._folder is not None

    def write(self, image: ArrayLike) -> None:
        """Append one ``(H, W, 3) uint8`` RGB frame (all frames the same size)."""
        frame = as_array("image", image, (None, None, 3), kind="u")
        if frame.dtype != np.uint8:
            raise TypeError(f"image: expected uint8, got {frame.dtype}")
        size = (frame.shape[1], frame.shape[0])
        if self._size is None:
            self._open(size)
        elif size != self._size:
            raise ValueError(
                f"image: expected {self._size[0]}x{self._size[1]}, got {size[0]}x{size[1]}"
            )
        bgr = cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_RGB2BGR)
        if self._folder is not None:
            target = self._folder / f"{self.frames_written:06d}.png"
            if not cv2.imwrite(str(target), bgr):
                raise ValueError(f"{target}: cannot write")
        else:
            assert self._writer is not None
            self._writer.write(bgr)
        self.frames_written += 1

    def close(self) -> None:
        """Finish the file (safe to call twice)."""
        if self._writer is not None:
            self._writer.release()
            self._writer = None

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()

    def _open(self, size: tuple[int, int]) -> None:
        self._size = size
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fourcc = cv2.VideoWriter.fourcc(*self.codec)
        writer = cv2.VideoWriter(str(self.path), fourcc, self.fps, size)
        if writer.isOpened():
            self._writer = writer
            return
        writer.release()
        self._folder = frames_folder(self.path)
        self._folder.mkdir(parents=True, exist_ok=True)
        self.note = (
            f"{self.path}: OpenCV cannot write {self.codec!r} video here; "
            f"writing PNG frames to {self._folder} instead"
        )
        warnings.warn(self.note, RuntimeWarning, stacklevel=3)


# --- Timing ---------------------------------------------------------------------------


@dataclass(frozen=True)
class StageTiming:
    """Statistics of one stage's time over the frames that report it (milliseconds)."""

    median_ms: float
    p95_ms: float
    mean_ms: float
    max_ms: float
    frames: int
    p99_ms: float = 0.0


@dataclass(frozen=True)
class TimingSummary:
    """Per-stage timing of a run.

    Attributes
    ----------
    stages : mapping of str to StageTiming
        In the order the stages first appear.
    frames : int
        Number of timing records summarised.
    """

    stages: Mapping[str, StageTiming]
    frames: int

    def as_dict(self) -> dict[str, dict[str, float]]:
        """``{stage: {"median", "p95", "p99", "mean", "max", "frames"}}``, JSON-ready."""
        return {
            name: {
                "median": t.median_ms,
                "p95": t.p95_ms,
                "p99": t.p99_ms,
                "mean": t.mean_ms,
                "max": t.max_ms,
                "frames": t.frames,
            }
            for name, t in self.stages.items()
        }

    def table(self) -> str:
        """A fixed-width table with one row per stage."""
        width = max([len("stage"), *map(len, self.stages)])
        header = (
            f"{'stage':<{width}}  {'median ms':>9}  {'p95 ms':>8}  {'max ms':>8}  {'frames':>6}"
        )
        rows = [
            f"{name:<{width}}  {t.median_ms:9.2f}  {t.p95_ms:8.2f}  {t.max_ms:8.2f}  {t.frames:6d}"
            for name, t in self.stages.items()
        ]
        return "\n".join([header, "-" * len(header), *rows])


def timing_summary(timings: Iterable[Mapping[str, float]]) -> TimingSummary:
    """Median, 95th and 99th percentile per stage of per-frame ``timing_ms`` dicts.

    Parameters
    ----------
    timings : iterable of mapping of str to float
        One ``{stage: milliseconds}`` per frame; a stage missing from a frame is left
        out of that stage's statistics.

    Returns
    -------
    TimingSummary

    Raises
    ------
    ValueError
        A time that is negative or not a finite number (naming frame and stage).
    """
    values: dict[str, list[float]] = {}
    frames = 0
    for frame, timing in enumerate(timings):
        frames += 1
        for stage, milliseconds in timing.items():
            try:
                value = float(milliseconds)
            except (TypeError, ValueError) as error:
                raise ValueError(f"timing of frame {frame}, {stage!r}: not a number") from error
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"timing of frame {frame}, {stage!r}: got {value}")
            values.setdefault(stage, []).append(value)
    stages = {
        stage: StageTiming(
            float(np.median(times)),
            float(np.percentile(times, 95)),
            float(np.mean(times)),
            float(np.max(times)),
            len(times),
            float(np.percentile(times, 99)),
        )
        for stage, times in values.items()
    }
    return TimingSummary(stages, frames)


# --- Helpers --------------------------------------------------------------------------


def write_rgb(path: str | PathLike[str], image: ArrayLike) -> Path:
    """Write an RGB picture (PNG or JPEG by the extension); ``ValueError`` naming the
    file if it cannot be written."""
    path = Path(path)
    rgb = as_array("image", image, (None, None, 3), np.uint8, kind="u")
    if not cv2.imwrite(str(path), np.ascontiguousarray(rgb[..., ::-1])):
        raise ValueError(f"{path}: could not write the picture")
    return path


def frames_folder(video_path: str | PathLike[str]) -> Path:
    """Where :class:`VideoWriter` puts PNG frames when it cannot write ``video_path``."""
    path = Path(video_path)
    return path.with_name(f"{path.stem}_frames")


def _copy_image(image: ArrayLike) -> NDArray[np.uint8]:
    array = as_array("image", image, (None, None, 3), kind="u")
    if array.dtype != np.uint8:
        raise TypeError(f"image: expected uint8, got {array.dtype}")
    return np.array(array, dtype=np.uint8, order="C", copy=True)


def _fixed_point(points: NDArray[np.float64]) -> list[tuple[int, int]]:
    """Pixel coordinates as OpenCV sub-pixel integers (clipped far outside the image)."""
    scaled = np.clip(np.nan_to_num(points), -1e5, 1e5) * (1 << _SHIFT)
    return [(int(u), int(v)) for u, v in np.round(scaled).astype(np.int64)]


def _put_text(
    canvas: NDArray[np.uint8], text: str, origin: tuple[int, int], color: RGB, *, scale: float
) -> None:
    cv2.putText(canvas, text, origin, _FONT, scale, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(canvas, text, origin, _FONT, scale, color, 1, cv2.LINE_AA)
