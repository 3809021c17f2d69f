"""MCAP recordings of the tracking results, which Foxglove opens.

:class:`McapRecorder` writes one message per frame on each channel, JSON encoded with
a ``jsonschema`` schema; ``log_time`` and ``publish_time`` are the frame's capture time
(``timestamp_s``, or the wall clock at write when the source gives none), in
nanoseconds, and ``sequence`` is the frame index.

- ``/glove/hand`` (schema ``glove.HandRecord``): the frame's ``poses.jsonl`` record;
- ``/glove/keypoints`` (``foxglove.SceneUpdate``): entity ``hand`` in frame ``camera``,
  a sphere per keypoint and a line per bone, so that the 3D panel shows the hand; a
  frame without a hand deletes the entity;
- ``/glove/fingertip_detections`` (``glove.FingertipDetections``): the fingertip
  detections, on frames whose record has them (``glove track --fingertips``).

Foxglove turns a JSON schema into message types with one type per field and no arrays
of arrays, so two rules hold here. A field that may be null (``timestamp_s``, a
detection's ``finger``) says so in its description, not in its type. The matrices
``rotation`` (3x3), ``keypoints_3d_m`` (21x3) and ``keypoints_2d_px`` (21x2) are stored
row-major as flat lists (``keypoints_3d_m[3 * k + 2]`` is keypoint ``k``'s z);
:func:`read_records` gives the records back with the nested lists of ``poses.jsonl``.
JSON has no NaN or infinity: such numbers (none are expected) are written as null.
"""

from __future__ import annotations

import io
import json
import math
import struct
import time
from collections.abc import Mapping, Sequence
from os import PathLike
from pathlib import Path
from typing import IO, Any

import numpy as np
from mcap.exceptions import EndOfFile
from mcap.reader import NonSeekingReader, make_reader
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import MCAP0_MAGIC, CompressionType, Writer
from numpy.typing import ArrayLike, NDArray

from glovedb._closing import Closing
from glovedb._validate import as_array
from glovedb.hand_model import FINGERS, JOINT_NAMES, KEYPOINT_NAMES, N_JOINTS, N_KEYPOINTS
from tracker.frames import Frame
from tracker.generative.visibility import VISIBILITY
from tracker.overlay import FINGER_BONES, FINGER_COLORS, PALM_BONES, PALM_COLOR, RGB
from tracker.pipeline import STAGES

HAND_TOPIC = "/glove/hand"
KEYPOINTS_TOPIC = "/glove/keypoints"
FINGERTIPS_TOPIC = "/glove/fingertip_detections"
FRAME_ID = "camera"
"""Frame of the keypoint entity: the camera's (OpenCV axes: x right, y down, z ahead)."""
ENTITY_ID = "hand"

CHUNK_SIZE_BYTES = 256 * 1024
"""Messages are compressed in chunks of this size, about a second at 30 frames/s."""
KEYPOINT_DIAMETER_M = 0.012
BONE_THICKNESS_M = 0.004

_MATRIX_SHAPES: dict[str, tuple[int, int]] = {
    "rotation": (3, 3),
    "keypoints_3d_m": (N_KEYPOINTS, 3),
    "keypoints_2d_px": (N_KEYPOINTS, 2),
}
_BONES = PALM_BONES + FINGER_BONES
_BONE_COLORS: tuple[RGB, ...] = (PALM_COLOR,) * len(PALM_BONES) + tuple(
    FINGER_COLORS[FINGERS[bone // 4]] for bone in range(len(FINGER_BONES))
)
_KEYPOINT_COLORS: tuple[RGB, ...] = (PALM_COLOR,) + tuple(
    FINGER_COLORS[FINGERS[(keypoint - 1) // 4]] for keypoint in range(1, N_KEYPOINTS)
)
_DELETE_MATCHING_ID = 0
_LINE_LIST = 2


# --- schemas -------------------------------------------------------------------------


def _number(description: str) -> dict[str, Any]:
    return {"type": "number", "description": description}


def _numbers(count: int, description: str) -> dict[str, Any]:
    return {
        "type": "array",
        "items": {"type": "number"},
        "minItems": count,
        "maxItems": count,
        "description": description,
    }


def _object(
    title: str,
    description: str,
    properties: dict[str, Any],
    required: Sequence[str] | None = None,
) -> dict[str, Any]:
    """An object schema; every property is required unless ``required`` says otherwise."""
    required = list(properties if required is None else required)
    schema = {"title": title, "description": description, "type": "object"}
    return schema | {"properties": properties, "required": required}


def _enum(title: str, description: str, names: Sequence[str]) -> dict[str, Any]:
    alternatives = [{"title": name, "const": value} for value, name in enumerate(names)]
    return {"title": title, "description": description, "type": "integer", "oneOf": alternatives}


def _fingertip(description: str, finger: str, confidence: str) -> dict[str, Any]:
    return _object(
        "glove.Fingertip",
        description,
        {
            "finger": {"type": "string", "description": finger},
            "u_px": _number("Image column of the tip, pixels"),
            "v_px": _number("Image row of the tip, pixels"),
            "x_m": _number("x of the tip in the camera frame (right), metres"),
            "y_m": _number("y of the tip in the camera frame (down), metres"),
            "z_m": _number("z of the tip in the camera frame (depth), metres"),
            "confidence": _number(confidence),
        },
    )


_MODEL_TIP = _fingertip(
    "A tip of the fitted hand model",
    "thumb, index, middle, ring or little",
    "The frame's fit confidence, 0-1",
)
_DETECTED_TIP = _fingertip(
    "A fingertip found in the depth image",
    "thumb, index, middle, ring or little; null when not assigned to a finger",
    "Sum of the votes for the detection (forest), or its mean heat 0-1 (heatmap)",
)
_POSE_FIELDS = (
    "posture_rad", "rotation", "translation_m", "keypoints_3d_m", "keypoints_2d_px",
    "fingertips", "confidence", "keypoint_visibility",
)  # fmt: skip
"""Fields of a record present only when ``hand_found`` is true."""
_TIMESTAMP_S = _number("Capture time from the source, seconds; null when it gives none")

HAND_SCHEMA: dict[str, Any] = _object(
    "glove.HandRecord",
    "One frame's poses.jsonl record (docs/tracker.md). The pose fields are present only "
    "when hand_found is true; matrices are flattened row-major.",
    {
        "frame": {"type": "integer", "description": "Frame number in its sequence, from 0"},
        "hand_found": {"type": "boolean", "description": "Whether the glove was tracked"},
        "timestamp_s": _TIMESTAMP_S,
        "posture_rad": _numbers(N_JOINTS, "Joint angles, radians: " + ", ".join(JOINT_NAMES)),
        "rotation": _numbers(9, "cam_R_hand, hand frame to camera frame, 3x3 row-major"),
        "translation_m": _numbers(3, "Wrist position in the camera frame, metres"),
        "keypoints_3d_m": _numbers(
            3 * N_KEYPOINTS,
            "21 keypoints in the camera frame, metres, 21x3 row-major (x, y, z of each): "
            + ", ".join(KEYPOINT_NAMES),
        ),
        "keypoints_2d_px": _numbers(
            2 * N_KEYPOINTS, "The keypoints' projections, pixels, 21x2 row-major (u, v of each)"
        ),
        "fingertips": {"type": "array", "items": _MODEL_TIP, "description": "The 5 model tips"},
        "confidence": _number("Fit confidence, 0-1"),
        "keypoint_visibility": {
            "type": "array",
            "items": {"type": "string", "enum": list(VISIBILITY)},
            "minItems": N_KEYPOINTS,
            "maxItems": N_KEYPOINTS,
            "description": "Per keypoint: " + ", ".join(VISIBILITY),
        },
        "fingertip_detections": {
            "type": "array",
            "items": _DETECTED_TIP,
            "description": "Depth fingertip detections (only with --fingertips)",
        },
        "timing_ms": _object(
            "glove.Timing",
            "Time per stage, milliseconds (stages that ran)",
            {stage: _number(f"{stage}, milliseconds") for stage in STAGES},
            required=[],
        ),
    },
    required=["frame", "hand_found", "timestamp_s", "timing_ms"],
) | {
    "if": {"properties": {"hand_found": {"const": True}}},
    "then": {"required": list(_POSE_FIELDS)},
}

FINGERTIPS_SCHEMA: dict[str, Any] = _object(
    "glove.FingertipDetections",
    "The fingertip detections of one frame",
    {
        "frame": {"type": "integer", "description": "Frame number in its sequence, from 0"},
        "timestamp_s": _TIMESTAMP_S,
        "detections": {"type": "array", "items": _DETECTED_TIP, "description": "Detections"},
    },
)


def _time(title: str, description: str) -> dict[str, Any]:
    """Foxglove's ``time`` (``sec`` >= 0) or ``duration`` (``sec`` of either sign)."""
    seconds = {"type": "integer"} | ({"minimum": 0} if title == "time" else {})
    nanoseconds = {"type": "integer", "minimum": 0, "maximum": 999_999_999}
    return _object(title, description, {"sec": seconds, "nsec": nanoseconds})


def _xyz(title: str, description: str, unit: str) -> dict[str, Any]:
    return _object(title, description, {axis: _number(f"{axis}, {unit}") for axis in "xyz"})


def _pose(description: str) -> dict[str, Any]:
    quaternion = _object(
        "foxglove.Quaternion",
        "Orientation",
        {axis: _number(f"{axis} of the unit quaternion") for axis in "xyzw"},
    )
    position = _xyz("foxglove.Vector3", "Position", "metres")
    return _object("foxglove.Pose", description, {"position": position, "orientation": quaternion})


def _color(description: str) -> dict[str, Any]:
    return _object("foxglove.Color", description, {c: _number(f"{c}, 0-1") for c in "rgba"})


_SPHERE = _object(
    "foxglove.SpherePrimitive",
    "A sphere",
    {
        "pose": _pose("Centre of the sphere"),
        "size": _xyz("foxglove.Vector3", "Diameter along each axis", "metres"),
        "color": _color("Color of the sphere"),
    },
)
_LINE = _object(
    "foxglove.LinePrimitive",
    "Line segments",
    {
        "type": _enum(
            "foxglove.LineType", "Kind of line", ("LINE_STRIP", "LINE_LOOP", "LINE_LIST")
        ),
        "pose": _pose("Origin of the points"),
        "thickness": _number("Width, metres (pixels if scale_invariant)"),
        "scale_invariant": {"type": "boolean", "description": "Thickness in pixels"},
        "points": {
            "type": "array",
            "items": _xyz("foxglove.Point3", "A point", "metres"),
            "description": "Points, relative to pose; pairs for LINE_LIST",
        },
        "color": _color("Color of the whole line, when colors is empty"),
        "colors": {"type": "array", "items": _color("Color"), "description": "Per point"},
        "indices": {
            "type": "array",
            "items": {"type": "integer", "minimum": 0},
            "description": "Indices into points; empty means all points in order",
        },
    },
)

KEYPOINTS_SCHEMA: dict[str, Any] = _object(
    "foxglove.SceneUpdate",
    "An update to the entities displayed in a 3D scene (the fields this recorder uses of "
    "Foxglove's schema; missing primitive lists are empty)",
    {
        "deletions": {
            "type": "array",
            "items": _object(
                "foxglove.SceneEntityDeletion",
                "Command to remove previously published entities",
                {
                    "timestamp": _time("time", "Deletes matching entities earlier than this"),
                    "type": _enum(
                        "foxglove.SceneEntityDeletionType", "What to delete", ("MATCHING_ID", "ALL")
                    ),
                    "id": {"type": "string", "description": "Entity id, for MATCHING_ID"},
                },
            ),
            "description": "Scene entities to delete",
        },
        "entities": {
            "type": "array",
            "items": _object(
                "foxglove.SceneEntity",
                "A visual element in a 3D scene",
                {
                    "timestamp": _time("time", "Timestamp of the entity"),
                    "frame_id": {"type": "string", "description": "Frame of reference"},
                    "id": {"type": "string", "description": "Replaces the entity of this id"},
                    "lifetime": _time("duration", "Removed after this; zero means never"),
                    "frame_locked": {"type": "boolean", "description": "Follows frame_id"},
                    "metadata": {
                        "type": "array",
                        "items": _object(
                            "foxglove.KeyValuePair",
                            "A key with its value",
                            {"key": {"type": "string"}, "value": {"type": "string"}},
                        ),
                        "description": "Additional metadata",
                    },
                    "spheres": {"type": "array", "items": _SPHERE, "description": "Spheres"},
                    "lines": {"type": "array", "items": _LINE, "description": "Lines"},
                },
                required=["timestamp", "frame_id", "id", "lifetime", "frame_locked"],
            ),
            "description": "Scene entities to add or replace",
        },
    },
)

_CHANNELS: tuple[tuple[str, str, dict[str, Any]], ...] = (
    (HAND_TOPIC, "glove.HandRecord", HAND_SCHEMA),
    (KEYPOINTS_TOPIC, "foxglove.SceneUpdate", KEYPOINTS_SCHEMA),
    (FINGERTIPS_TOPIC, "glove.FingertipDetections", FINGERTIPS_SCHEMA),
)
_SCHEMA_BYTES: tuple[bytes, ...] = tuple(json.dumps(s).encode() for _, _, s in _CHANNELS)


# --- messages ------------------------------------------------------------------------


def frame_messages(record: Mapping[str, Any], time_ns: int) -> list[tuple[str, dict[str, Any]]]:
    """The messages of one frame, as ``(topic, message)`` pairs.

    Parameters
    ----------
    record : dict
        The frame's ``poses.jsonl`` record (:meth:`TrackingResult.as_record`).
    time_ns : int
        Its time, nanoseconds (stamps the scene update).

    Returns
    -------
    list of (str, dict)
        ``/glove/hand``, ``/glove/keypoints`` and, when the record has
        ``fingertip_detections``, ``/glove/fingertip_detections``.
    """
    keypoints = record["keypoints_3d_m"] if record["hand_found"] else None
    messages = [
        (HAND_TOPIC, _flattened(record)),
        (KEYPOINTS_TOPIC, scene_update(keypoints, time_ns)),
    ]
    if "fingertip_detections" in record:
        detections = {
            "frame": record["frame"],
            "timestamp_s": record.get("timestamp_s"),
            "detections": record["fingertip_detections"],
        }
        messages.append((FINGERTIPS_TOPIC, detections))
    return messages


def scene_update(keypoints_3d_m: ArrayLike | None, time_ns: int) -> dict[str, Any]:
    """The ``foxglove.SceneUpdate`` that shows (or clears) the hand skeleton.

    Parameters
    ----------
    keypoints_3d_m : (21, 3) float or None
        Keypoints in the camera frame, metres, ``KEYPOINT_NAMES`` order; None for a
        frame without a hand. Non-finite keypoints and their bones are left out.
    time_ns : int
        Time of the frame, nanoseconds since the epoch of the recording's clock.

    Returns
    -------
    dict
        Entity ``hand`` in frame ``camera``: one sphere per keypoint (colored by finger,
        the wrist white) and one ``LINE_LIST`` of the bones of
        :data:`tracker.overlay.PALM_BONES` and :data:`tracker.overlay.FINGER_BONES`;
        for None, no entity and the deletion of ``hand``.
    """
    stamp = _foxglove_time(time_ns)
    if keypoints_3d_m is None:
        deletion = {"timestamp": stamp, "type": _DELETE_MATCHING_ID, "id": ENTITY_ID}
        return {"deletions": [deletion], "entities": []}
    points = as_array("keypoints_3d_m", keypoints_3d_m, (N_KEYPOINTS, 3), np.float64)
    finite = np.isfinite(points).all(axis=1)
    size = _vector((KEYPOINT_DIAMETER_M,) * 3)
    spheres = [
        {"pose": _pose_at(points[k]), "size": size, "color": _rgba(_KEYPOINT_COLORS[k])}
        for k in np.flatnonzero(finite)
    ]
    bones = [
        (a, b, color)
        for (a, b), color in zip(_BONES, _BONE_COLORS, strict=True)
        if finite[a] and finite[b]
    ]
    line = {
        "type": _LINE_LIST,
        "pose": _pose_at(np.zeros(3)),
        "thickness": BONE_THICKNESS_M,
        "scale_invariant": False,
        "points": [_vector(points[end]) for a, b, _ in bones for end in (a, b)],
        "color": _rgba(PALM_COLOR),
        "colors": [_rgba(color) for _, _, color in bones for _ in range(2)],
        "indices": [],
    }
    entity = {
        "timestamp": stamp,
        "frame_id": FRAME_ID,
        "id": ENTITY_ID,
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": False,
        "metadata": [],
        "spheres": spheres,
        "lines": [line],
    }
    return {"deletions": [], "entities": [entity]}


def _foxglove_time(time_ns: int) -> dict[str, int]:
    sec, nsec = divmod(int(time_ns), 1_000_000_000)
    return {"sec": sec, "nsec": nsec}


def _vector(xyz: Sequence[float] | NDArray[np.float64]) -> dict[str, float]:
    return {"x": float(xyz[0]), "y": float(xyz[1]), "z": float(xyz[2])}


def _pose_at(position: NDArray[np.float64]) -> dict[str, dict[str, float]]:
    return {"position": _vector(position), "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}


def _rgba(color: RGB) -> dict[str, float]:
    r, g, b = (channel / 255 for channel in color)
    return {"r": r, "g": g, "b": b, "a": 1.0}


def _flattened(record: Mapping[str, Any]) -> dict[str, Any]:
    message = dict(record)
    for name, shape in _MATRIX_SHAPES.items():
        if name in message:
            message[name] = as_array(name, message[name], shape, np.float64).ravel().tolist()
    return message


def _nested(message: dict[str, Any]) -> dict[str, Any]:
    for name, (_, columns) in _MATRIX_SHAPES.items():
        if name in message:
            flat = message[name]
            message[name] = [flat[i : i + columns] for i in range(0, len(flat), columns)]
    return message


def _json_bytes(message: Any) -> bytes:
    try:
        text = json.dumps(message, separators=(",", ":"), allow_nan=False)
    except ValueError:  # NaN or infinity somewhere: JSON has neither
        text = json.dumps(_finite_or_null(message), separators=(",", ":"))
    return text.encode()


def _finite_or_null(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {key: _finite_or_null(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_finite_or_null(item) for item in value]
    return value


def _time_ns(frame: Frame, record: Mapping[str, Any]) -> int:
    seconds = frame.timestamp_s if frame.timestamp_s is not None else record.get("timestamp_s")
    if seconds is None:
        return time.time_ns()
    if not (math.isfinite(seconds) and seconds >= 0):
        raise ValueError(f"frame {frame.index}: timestamp_s: expected >= 0 s, got {seconds}")
    return round(seconds * 1e9)


# --- file ----------------------------------------------------------------------------


class McapRecorder(Closing):
    """Records each frame's result into an MCAP file (a :class:`ResultSink`).

    Parameters
    ----------
    path : str or PathLike
        The ``.mcap`` file; an existing file is overwritten. Its folder must exist.
    chunk_size_bytes : int
        Size of the compressed chunks (zstd) that messages are grouped in.

    Raises
    ------
    FileNotFoundError
        When the folder of ``path`` does not exist.
    ValueError
        When ``path`` is a folder, or ``chunk_size_bytes`` is not positive.

    Notes
    -----
    :meth:`close` (or leaving the ``with`` block, also by an exception) writes the
    file's index and footer. A process killed before that leaves a file without them:
    the chunks completed so far are on disk (the file is flushed after every frame),
    and :func:`read_records`, a linear MCAP reader or ``mcap recover`` read them; the
    messages of the chunk being filled (at most ``chunk_size_bytes``, about a second
    by default) are lost. Foxglove may refuse such a file; ``mcap recover`` rewrites
    it whole.
    """

    def __init__(
        self, path: str | PathLike[str], *, chunk_size_bytes: int = CHUNK_SIZE_BYTES
    ) -> None:
        self.path = Path(path)
        if self.path.is_dir():
            raise ValueError(f"MCAP output {self.path}: is a folder, expected a file name")
        if not self.path.parent.is_dir():
            raise FileNotFoundError(f"MCAP output {self.path}: folder {self.path.parent} missing")
        if chunk_size_bytes <= 0:
            raise ValueError(f"chunk_size_bytes: expected > 0, got {chunk_size_bytes}")
        self._file: IO[bytes] = self.path.open("wb")
        self._writer = Writer(
            self._file, chunk_size=chunk_size_bytes, compression=CompressionType.ZSTD
        )
        self._writer.start()
        self._channels: dict[str, int] = {}
        for (topic, name, _), schema in zip(_CHANNELS, _SCHEMA_BYTES, strict=True):
            schema_id = self._writer.register_schema(name, SchemaEncoding.JSONSchema, schema)
            self._channels[topic] = self._writer.register_channel(
                topic, MessageEncoding.JSON, schema_id
            )
        self._file.flush()
        self._closed = False

    def write(self, frame: Frame, record: dict[str, Any]) -> None:
        """Record one frame's messages (see the module notes).

        Parameters
        ----------
        frame : Frame
            Gives the index (``sequence``) and capture time (``log_time``).
        record : dict
            The frame's ``poses.jsonl`` record.
        """
        if self._closed:
            raise ValueError(f"MCAP output {self.path}: write() after close()")
        time_ns = _time_ns(frame, record)
        for topic, message in frame_messages(record, time_ns):
            self._writer.add_message(
                self._channels[topic],
                log_time=time_ns,
                data=_json_bytes(message),
                publish_time=time_ns,
                sequence=frame.index,
            )
        self._file.flush()

    def close(self) -> None:
        """Write the index and footer and close the file; later calls do nothing."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.finish()
        finally:
            self._file.close()


def read_records(path: str | PathLike[str]) -> list[dict[str, Any]]:
    """The ``/glove/hand`` records of a recording, in the order they were written.

    Parameters
    ----------
    path : str or PathLike
        An MCAP file written by :class:`McapRecorder`.

    Returns
    -------
    list of dict
        ``poses.jsonl`` records, matrices as nested lists again. An unfinished file (the
        recorder was not closed) is read up to its last complete chunk.
    """
    with Path(path).open("rb") as stream:
        if _is_finished(stream):
            reader = make_reader(stream)
            messages = reader.iter_messages(topics=[HAND_TOPIC], log_time_order=False)
            return [_nested(json.loads(message.data)) for _, _, message in messages]
        return _read_unfinished(stream)


def _is_finished(stream: IO[bytes]) -> bool:
    size = stream.seek(0, io.SEEK_END)
    stream.seek(max(size - len(MCAP0_MAGIC), 0))
    finished = size > len(MCAP0_MAGIC) and stream.read() == MCAP0_MAGIC
    stream.seek(0)
    return finished


def _read_unfinished(stream: IO[bytes]) -> list[dict[str, Any]]:
    records = []
    reader = NonSeekingReader(stream)
    try:
        for _, _, message in reader.iter_messages(topics=[HAND_TOPIC], log_time_order=False):
            records.append(_nested(json.loads(message.data)))
    except (EndOfFile, struct.error):  # the file stops at or inside its last record
        pass
    return records
