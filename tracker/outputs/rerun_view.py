"""The tracking result in the rerun 3D viewer, live or saved to an ``.rrd`` file.

Needs the optional ``view`` extra (``rerun-sdk``); it is imported only when a
:class:`RerunLogger` is made. Everything is in the camera frame of the record, OpenCV
axes (x right, y down, z forward, metres), the camera at the origin.

Entity paths:

- ``world``: view coordinates RDF and the annotation context naming the glove's color
  classes with the pattern's colors (0 "unlabeled", grey); static;
- ``world/camera``: the pinhole of the frame's intrinsics (logged when they change);
- ``world/camera/color``: the color image; ``world/camera/depth``: the depth, metres;
- ``world/points``: the depth point cloud, class ids = the glove color labels
  (:meth:`tracker.classify.ColorTable.classify`), at most :data:`MAX_POINTS`;
- ``world/hand/mesh``: the glove mesh posed from the record, vertices split where
  color patches meet and colored by class (:func:`glovedb.pattern.split_by_label`);
- ``world/hand/keypoints``: the 21 keypoints, colored by finger, labelled with their
  name and visibility; ``world/hand/bones``: one two-point strip per bone;
- ``confidence``: the record's confidence, 0 when there is no hand.

The default layout shows the 3D scene without the depth image, the two images and the
confidence.

In a frame without the hand, ``world/hand`` is cleared (recursively). Timelines:
``frame`` (sequence, the frame index) and, for frames with a timestamp (the record's
``timestamp_s``, else the frame's), ``capture_time`` (duration, seconds).
"""

from __future__ import annotations

import math
import os
import shutil
import socket
import sys
import uuid
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._closing import Closing
from glovedb._validate import as_array
from glovedb.camera import CameraIntrinsics
from glovedb.hand_model import FINGERS, KEYPOINT_NAMES, N_KEYPOINTS
from glovedb.mesh import HandMesh, pose_mesh, vertex_normals
from glovedb.pattern import GlovePattern, load_pattern, split_by_label
from tracker.classify import ColorTable
from tracker.frames import Frame
from tracker.overlay import FINGER_BONES, FINGER_COLORS, PALM_BONES, PALM_COLOR
from tracker.point_cloud import HandRegion, LabeledPointCloud, labeled_point_cloud

MAX_POINTS = 20_000
"""At most this many points of the depth cloud are logged per frame."""
UNLABELED_COLOR = (128, 128, 128)
VIEWER_PORT = 9876  # rerun's default: a viewer already listening there is reused
MISSING_EXTRA = (
    "the 3D viewer needs the 'view' extra: bash scripts/setup.sh --view "
    "(or pip install 'glove-tracker[view]')"
)

_KEYPOINT_RADIUS_M = 0.004
_BONE_RADIUS_M = 0.0015


class TrackerLike(Protocol):
    """What the logger reads from the tracker (a :class:`tracker.pipeline.Tracker`)."""

    mesh: HandMesh
    color_table: ColorTable


def labeled_depth_cloud(
    color: ArrayLike,
    depth_m: ArrayLike,
    intrinsics: CameraIntrinsics,
    color_table: ColorTable,
    *,
    max_points: int = MAX_POINTS,
) -> LabeledPointCloud:
    """The frame's depth as points with the glove color class of their pixel.

    The image is sampled on a regular grid (every ``step``-th row and column, the
    smallest step that gives at most ``max_points`` pixels); the sampled pixels are
    classified and those with depth back-projected.

    Parameters
    ----------
    color : (H, W, 3) uint8
        RGB, registered to depth.
    depth_m : (H, W) float32
        Metres, 0 where there is no measurement.
    intrinsics : CameraIntrinsics
    color_table : ColorTable
    max_points : int

    Returns
    -------
    LabeledPointCloud
        ``points_m`` in the camera frame; ``labels`` 0 (no glove color) to 10.
    """
    depth = as_array("depth_m", depth_m, (intrinsics.height, intrinsics.width), np.float32)
    rgb = as_array("color", color, (*depth.shape, 3), kind="u")
    if max_points < 1:
        raise ValueError(f"max_points: expected >= 1, got {max_points}")
    height, width = depth.shape
    step = max(1, math.ceil(math.sqrt(height * width / max_points)))
    while math.ceil(height / step) * math.ceil(width / step) > max_points:
        step += 1
    rows, cols = np.mgrid[0:height:step, 0:width:step].reshape(2, -1)
    # The whole sampled frame as one region: labeled_point_cloud keeps the pixels with
    # depth and back-projects them; label 0 (no glove color) stays in.
    grid = HandRegion(
        pixels_uv=np.stack([cols, rows], axis=1).astype(np.int64),
        labels=color_table.classify(rgb[::step, ::step]).ravel(),
        depth_m=depth[::step, ::step].ravel(),
    )
    return labeled_point_cloud(grid, intrinsics)


class RerunLogger(Closing):
    """A :class:`~tracker.outputs.ResultSink` that logs every frame to rerun.

    Logs on its own recording stream (never rerun's global one), so several loggers
    in one process keep their data apart. See the module docstring for what is logged
    where.

    Parameters
    ----------
    tracker : Tracker
        Read for ``mesh`` (the hand model with the current proportions, posed from each
        record) and ``color_table`` (the glove color labels of the point cloud).
    spawn : bool
        Start the native rerun viewer and stream to it (needs a display).
    path : str or Path, optional
        Also (or instead) save the recording to this ``.rrd`` file.

    Raises
    ------
    ValueError
        Without ``spawn`` or ``path``; when rerun is not installed; when the viewer
        cannot start (no display, no viewer executable) or the file cannot be written.

    Examples
    --------
    >>> with RerunLogger(tracker, path="run.rrd") as view:  # doctest: +SKIP
    ...     for frame in frames:
    ...         view.write(frame, tracker.track(frame).as_record())
    """

    def __init__(
        self, tracker: TrackerLike, *, spawn: bool = False, path: str | Path | None = None
    ) -> None:
        if not spawn and path is None:
            raise ValueError("RerunLogger: give spawn=True (live viewer), a path, or both")
        rr = _import_rerun()
        self._rr = rr
        self._tracker = tracker
        pattern = load_pattern()
        # The tracker's mesh changes vertices (hand proportions) but never its faces,
        # so the split into single-colored patches holds for every frame.
        self._split = split_by_label(tracker.mesh, pattern)
        self._intrinsics: CameraIntrinsics | None = None
        self._closed = False
        self.recording = rr.RecordingStream("glove-tracker", recording_id=uuid.uuid4())
        _attach_sinks(rr, self.recording, spawn=spawn, path=path)
        self.recording.log("world", rr.ViewCoordinates.RDF, static=True)
        self.recording.log("world", _annotation_context(rr, pattern), static=True)

    def write(self, frame: Frame, record: dict[str, Any]) -> None:
        """Log one frame's images, point cloud and result (a ``poses.jsonl`` record)."""
        rr, recording = self._rr, self.recording
        recording.reset_time()  # a frame without a timestamp must not inherit the last one
        recording.set_time("frame", sequence=frame.index)
        timestamp_s = record.get("timestamp_s", frame.timestamp_s)
        if timestamp_s is not None:
            recording.set_time("capture_time", duration=float(timestamp_s))
        intrinsics = frame.intrinsics
        if intrinsics != self._intrinsics:
            recording.log(
                "world/camera",
                rr.Pinhole(
                    image_from_camera=intrinsics.matrix,
                    resolution=[intrinsics.width, intrinsics.height],
                    camera_xyz=rr.ViewCoordinates.RDF,
                ),
            )
            self._intrinsics = intrinsics
        recording.log("world/camera/color", rr.Image(frame.color))
        recording.log("world/camera/depth", rr.DepthImage(frame.depth_m, meter=1.0))
        cloud = labeled_depth_cloud(
            frame.color, frame.depth_m, intrinsics, self._tracker.color_table
        )
        recording.log("world/points", rr.Points3D(cloud.points_m, class_ids=cloud.labels))
        found = bool(record.get("hand_found", False))
        if found:
            self._log_hand(record)
        else:
            recording.log("world/hand", rr.Clear(recursive=True))
        confidence = float(record.get("confidence", 0.0)) if found else 0.0
        recording.log("confidence", rr.Scalars(confidence))

    def _log_hand(self, record: dict[str, Any]) -> None:
        rr, recording, split = self._rr, self.recording, self._split
        mesh = self._tracker.mesh
        rotation = as_array("rotation", record["rotation"], (3, 3), np.float64, finite=True)
        translation = as_array(
            "translation_m", record["translation_m"], (3,), np.float64, finite=True
        )
        vertices = pose_mesh(mesh, record["posture_rad"]) @ rotation.T + translation
        normals = vertex_normals(vertices, mesh.faces)
        recording.log(
            "world/hand/mesh",
            rr.Mesh3D(
                vertex_positions=vertices[split.source_vertex],
                triangle_indices=split.faces,
                vertex_normals=normals[split.source_vertex],
                class_ids=split.labels,
            ),
        )
        keypoints = as_array(
            "keypoints_3d_m", record["keypoints_3d_m"], (N_KEYPOINTS, 3), np.float64
        )
        visibility = record.get("keypoint_visibility") or ["?"] * N_KEYPOINTS
        recording.log(
            "world/hand/keypoints",
            rr.Points3D(
                keypoints,
                radii=_KEYPOINT_RADIUS_M,
                colors=_keypoint_colors(),
                labels=[f"{n} ({v})" for n, v in zip(KEYPOINT_NAMES, visibility, strict=True)],
                show_labels=False,
            ),
        )
        bones = FINGER_BONES + PALM_BONES
        recording.log(
            "world/hand/bones",
            rr.LineStrips3D(
                keypoints[np.array(bones)], radii=_BONE_RADIUS_M, colors=_bone_colors()
            ),
        )

    def close(self) -> None:
        """Flush the stream, finish the ``.rrd`` file and disconnect from the viewer."""
        if self._closed:
            return
        self._closed = True
        self.recording.flush()
        self.recording.disconnect()


def _keypoint_colors() -> NDArray[np.uint8]:
    """``(21, 3)`` RGB of the keypoints, as the overlay draws them."""
    fingers = [FINGER_COLORS[FINGERS[(k - 1) // 4]] for k in range(1, N_KEYPOINTS)]
    return np.array([PALM_COLOR, *fingers], dtype=np.uint8)


def _bone_colors() -> NDArray[np.uint8]:
    """``(24, 3)`` RGB of :data:`FINGER_BONES` then :data:`PALM_BONES`."""
    fingers = [FINGER_COLORS[FINGERS[index // 4]] for index in range(len(FINGER_BONES))]
    return np.array(fingers + [PALM_COLOR] * len(PALM_BONES), dtype=np.uint8)


def _import_rerun() -> Any:
    try:
        import rerun
    except ImportError as error:
        raise ValueError(MISSING_EXTRA) from error
    return rerun


def _attach_sinks(rr: Any, recording: Any, *, spawn: bool, path: str | Path | None) -> None:
    """Send the recording to the ``.rrd`` file and/or a newly spawned viewer."""
    if path is not None and (Path(path).is_dir() or not Path(path).parent.is_dir()):
        reason = "a folder" if Path(path).is_dir() else "no such folder"
        raise ValueError(f"{path}: cannot write the rerun recording ({reason})")
    sinks = [] if path is None else [rr.FileSink(str(path))]
    if spawn:
        _spawn_viewer(rr, recording)
        sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{VIEWER_PORT}/proxy"))
    try:
        recording.set_sinks(*sinks, default_blueprint=_blueprint())
    except RuntimeError as error:  # the file cannot be created
        raise ValueError(f"{path}: cannot write the rerun recording ({error})") from error


def _blueprint() -> Any:
    """The viewer's default layout: the 3D scene without the depth image (rerun would
    draw it as a second, unlabeled point cloud), the images and the confidence."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(
                name="camera frame",
                origin="world",
                contents=["+ $origin/**", "- $origin/camera/depth"],
            ),
            rrb.Vertical(
                rrb.Spatial2DView(name="color", origin="world/camera", contents="$origin/color"),
                rrb.Spatial2DView(name="depth", origin="world/camera", contents="$origin/depth"),
                rrb.TimeSeriesView(name="confidence", origin="confidence"),
            ),
            column_shares=[2, 1],
        ),
        collapse_panels=True,
    )


def _annotation_context(rr: Any, pattern: GlovePattern) -> Any:
    """Class id = glove color label: the pattern's name and color, 0 unlabeled grey."""
    classes = [rr.AnnotationInfo(id=0, label="unlabeled", color=UNLABELED_COLOR)]
    for label, name in enumerate(pattern.color_names, 1):
        color = tuple(int(c) for c in pattern.colors_rgb[label - 1])
        classes.append(rr.AnnotationInfo(id=label, label=name, color=color))
    return rr.AnnotationContext(classes)


def _spawn_viewer(rr: Any, recording: Any) -> None:
    """Start the native viewer on :data:`VIEWER_PORT`; a one-line ``ValueError`` when it
    cannot run."""
    if sys.platform.startswith("linux") and not any(
        os.environ.get(name) for name in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")
    ):
        raise ValueError(
            "the rerun viewer needs a display (DISPLAY is not set): save the recording "
            "to an .rrd file instead and open it with `rerun FILE.rrd` on a desktop"
        )
    executable = _viewer_executable()
    if executable is None:
        raise ValueError(f"the rerun viewer executable was not found; {MISSING_EXTRA}")
    try:
        rr.spawn(
            port=VIEWER_PORT,
            connect=False,
            executable_path=executable,
            hide_welcome_screen=True,
            recording=recording,
        )
    except RuntimeError as error:
        first_line = str(error).strip().splitlines()[0] if str(error).strip() else "no reason"
        raise ValueError(f"the rerun viewer did not start: {first_line}") from error
    try:
        socket.create_connection(("127.0.0.1", VIEWER_PORT), timeout=2.0).close()
    except OSError as error:
        raise ValueError(
            f"the rerun viewer did not start (nothing listens on port {VIEWER_PORT}; "
            "its own messages above say why)"
        ) from error


def _viewer_executable() -> str | None:
    """The ``rerun`` executable installed with this Python's rerun-sdk, else on PATH.

    rerun looks only on PATH, which misses a virtual environment that is not
    activated; the one beside the interpreter also matches the SDK's version.
    """
    name = "rerun.exe" if os.name == "nt" else "rerun"
    beside = Path(sys.executable).parent / name
    if beside.is_file() and os.access(beside, os.X_OK):
        return str(beside)
    return shutil.which("rerun")
