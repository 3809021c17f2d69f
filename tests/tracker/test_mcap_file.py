"""MCAP recordings: channels, schemas, times and records read back against known values."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

from glovedb.camera import CameraIntrinsics
from glovedb.hand_model import FINGERS, FINGERTIP_KEYPOINTS
from tracker.frames import Frame
from tracker.outputs import mcap_file
from tracker.outputs.mcap_file import (
    FINGERTIPS_TOPIC,
    HAND_TOPIC,
    KEYPOINTS_TOPIC,
    McapRecorder,
    frame_messages,
    read_records,
    scene_update,
)
from tracker.overlay import FINGER_BONES, PALM_BONES

INTRINSICS = CameraIntrinsics(4, 3, 5.0, 5.0, 1.5, 1.0)
TIMES_S = (12.5, 12.533333, 12.566667)
# Keypoint k at (1 cm * k, -0.5 cm * k, 45 cm + 2 mm * k) in the camera frame.
KEYPOINTS_M = np.column_stack(
    [0.01 * np.arange(21), -0.005 * np.arange(21), 0.45 + 0.002 * np.arange(21)]
)
N_BONES = len(PALM_BONES) + len(FINGER_BONES)


def hand_record(frame: int, *, detections: list[dict[str, Any]] | None = None) -> dict[str, Any]:
    """A found hand with known values (as TrackingResult.as_record writes them)."""
    pixels = np.column_stack([320.0 + 10 * np.arange(21), 240.0 - 5 * np.arange(21)])
    record: dict[str, Any] = {
        "frame": frame,
        "timestamp_s": TIMES_S[frame],
        "hand_found": True,
        "posture_rad": [0.05 * j for j in range(20)],
        "rotation": [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
        "translation_m": KEYPOINTS_M[0].tolist(),
        "keypoints_3d_m": KEYPOINTS_M.tolist(),
        "keypoints_2d_px": pixels.tolist(),
        "fingertips": [
            {
                "finger": finger,
                "u_px": pixels[tip, 0],
                "v_px": pixels[tip, 1],
                "x_m": KEYPOINTS_M[tip, 0],
                "y_m": KEYPOINTS_M[tip, 1],
                "z_m": KEYPOINTS_M[tip, 2],
                "confidence": 0.8,
            }
            for finger, tip in zip(FINGERS, FINGERTIP_KEYPOINTS, strict=True)
        ],
        "confidence": 0.8,
        "keypoint_visibility": ["seen"] * 19 + ["occluded", "self_occluded"],
    }
    if detections is not None:
        record["fingertip_detections"] = detections
    record["timing_ms"] = {"classify": 1.5, "segment": 2.25, "fit": 6.0, "total": 10.0}
    return record


DETECTIONS: list[dict[str, Any]] = [
    {"finger": "index", "u_px": 400.0, "v_px": 200.0, "x_m": 0.08, "y_m": -0.04,
     "z_m": 0.466, "confidence": 3.5},
    {"finger": None, "u_px": 100.0, "v_px": 50.0, "x_m": -0.1, "y_m": -0.12,
     "z_m": 0.5, "confidence": 1.25},
]  # fmt: skip
RECORDS = [
    hand_record(0),
    {"frame": 1, "timestamp_s": TIMES_S[1], "hand_found": False, "timing_ms": {"total": 3.0}},
    hand_record(2, detections=DETECTIONS),
]


def make_frame(index: int, timestamp_s: float | None) -> Frame:
    color = np.zeros((INTRINSICS.height, INTRINSICS.width, 3), np.uint8)
    depth = np.zeros((INTRINSICS.height, INTRINSICS.width), np.float32)
    return Frame(index, color, depth, INTRINSICS, timestamp_s)


def record_file(path: Path, records: list[dict[str, Any]], **options: Any) -> Path:
    with McapRecorder(path, **options) as recorder:
        for record in records:
            recorder.write(make_frame(record["frame"], record["timestamp_s"]), record)
    return path


def read_messages(path: Path) -> tuple[Any, list[tuple[Any, Any, Any]]]:
    """The summary and every ``(schema, channel, message)`` in file order."""
    with path.open("rb") as stream:
        reader = make_reader(stream)
        return reader.get_summary(), list(reader.iter_messages(log_time_order=False))


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return record_file(tmp_path_factory.mktemp("mcap") / "run.mcap", RECORDS)


def messages_on(path: Path, topic: str) -> list[Any]:
    return [message for _, channel, message in read_messages(path)[1] if channel.topic == topic]


def decoded(path: Path, topic: str) -> list[dict[str, Any]]:
    return [json.loads(message.data) for message in messages_on(path, topic)]


def test_channels_and_schemas(recording: Path) -> None:
    summary, _ = read_messages(recording)
    channels = {channel.topic: channel for channel in summary.channels.values()}
    assert set(channels) == {HAND_TOPIC, KEYPOINTS_TOPIC, FINGERTIPS_TOPIC}
    expected = {
        HAND_TOPIC: ("glove.HandRecord", mcap_file.HAND_SCHEMA),
        KEYPOINTS_TOPIC: ("foxglove.SceneUpdate", mcap_file.KEYPOINTS_SCHEMA),
        FINGERTIPS_TOPIC: ("glove.FingertipDetections", mcap_file.FINGERTIPS_SCHEMA),
    }
    for topic, (name, schema) in expected.items():
        channel = channels[topic]
        assert channel.message_encoding == "json"
        stored = summary.schemas[channel.schema_id]
        assert (stored.name, stored.encoding) == (name, "jsonschema")
        assert json.loads(stored.data) == schema


def test_message_count_per_topic(recording: Path) -> None:
    summary, messages = read_messages(recording)
    topics = [channel.topic for _, channel, _ in messages]
    counts = {topic: topics.count(topic) for topic in set(topics)}
    assert counts == {HAND_TOPIC: 3, KEYPOINTS_TOPIC: 3, FINGERTIPS_TOPIC: 1}
    assert summary.statistics.message_count == 7


def test_records_read_back_equal(recording: Path) -> None:
    assert read_records(recording) == RECORDS


def test_log_time_is_the_capture_time_and_sequence_the_frame(recording: Path) -> None:
    for topic, frames in ((HAND_TOPIC, [0, 1, 2]), (KEYPOINTS_TOPIC, [0, 1, 2])):
        messages = messages_on(recording, topic)
        assert [m.sequence for m in messages] == frames
        assert [m.log_time for m in messages] == [round(TIMES_S[f] * 1e9) for f in frames]
        assert [m.publish_time for m in messages] == [m.log_time for m in messages]
    (detections,) = messages_on(recording, FINGERTIPS_TOPIC)
    assert (detections.sequence, detections.log_time) == (2, 12_566_667_000)


def test_matrices_are_flat_row_major_in_the_file(recording: Path) -> None:
    message = decoded(recording, HAND_TOPIC)[0]
    assert message["rotation"] == [0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]
    np.testing.assert_array_equal(message["keypoints_3d_m"], KEYPOINTS_M.ravel())
    assert message["keypoints_2d_px"][2 * 20 : 2 * 21] == [520.0, 140.0]


def test_scene_update_has_a_sphere_at_every_keypoint(recording: Path) -> None:
    update = decoded(recording, KEYPOINTS_TOPIC)[0]
    assert update["deletions"] == []
    (entity,) = update["entities"]
    assert (entity["frame_id"], entity["id"]) == ("camera", "hand")
    assert entity["timestamp"] == {"sec": 12, "nsec": 500_000_000}
    centres = [[s["pose"]["position"][a] for a in "xyz"] for s in entity["spheres"]]
    np.testing.assert_allclose(centres, KEYPOINTS_M, atol=0)
    (line,) = entity["lines"]
    assert line["type"] == 2  # LINE_LIST
    ends = np.array([[p[a] for a in "xyz"] for p in line["points"]]).reshape(-1, 2, 3)
    bones = PALM_BONES + FINGER_BONES
    np.testing.assert_allclose(ends, KEYPOINTS_M[np.array(bones)], atol=0)
    assert len(line["colors"]) == 2 * N_BONES


def test_frame_without_hand_deletes_the_entity(recording: Path) -> None:
    update = decoded(recording, KEYPOINTS_TOPIC)[1]
    assert update["entities"] == []
    assert update["deletions"] == [
        {"timestamp": {"sec": 12, "nsec": 533_333_000}, "type": 0, "id": "hand"}
    ]


def test_fingertip_detections_channel(recording: Path) -> None:
    (message,) = decoded(recording, FINGERTIPS_TOPIC)
    assert message == {"frame": 2, "timestamp_s": TIMES_S[2], "detections": DETECTIONS}


def test_messages_fit_their_schemas(recording: Path) -> None:
    """Valid where nullable fields are not null (Foxglove's parser allows one type)."""
    jsonschema = pytest.importorskip("jsonschema")
    base = jsonschema.Draft202012Validator

    def or_null(kind: str) -> Any:
        return lambda _, value: value is None or base.TYPE_CHECKER.is_type(value, kind)

    nullable = base.TYPE_CHECKER.redefine_many({k: or_null(k) for k in ("number", "string")})
    validator = jsonschema.validators.extend(base, type_checker=nullable)
    for schema, _, message in read_messages(recording)[1]:
        validator(json.loads(schema.data)).validate(json.loads(message.data))
    without_pose = {"frame": 1, "timestamp_s": 1.0, "hand_found": True, "timing_ms": {}}
    assert not validator(mcap_file.HAND_SCHEMA).is_valid(without_pose)


def foxglove_problems(schema: dict[str, Any], path: str = "") -> list[str]:
    """What Foxglove's JSON-schema reader rejects: objects without properties, fields
    without exactly one type, arrays of arrays."""
    if schema.get("type") != "object" or not isinstance(schema.get("properties"), dict):
        return [f"{path or 'root'}: not an object with properties"]
    problems = []
    scalars = ("boolean", "string", "number", "integer")
    for name, field in schema["properties"].items():
        kind = field.get("type")
        item = field.get("items", {}).get("type") if kind == "array" else None
        if kind == "object" or item == "object":
            problems += foxglove_problems(field if kind == "object" else field["items"], name)
        elif kind not in scalars and item not in scalars:
            problems.append(f"{path}.{name}: type {kind!r}, items {item!r}")
    return problems


@pytest.mark.parametrize("name", ["HAND_SCHEMA", "KEYPOINTS_SCHEMA", "FINGERTIPS_SCHEMA"])
def test_schemas_are_readable_by_foxglove(name: str) -> None:
    assert foxglove_problems(getattr(mcap_file, name)) == []


def test_wall_clock_when_the_frame_has_no_time(tmp_path: Path) -> None:
    record = RECORDS[1] | {"timestamp_s": None}
    before = time.time_ns()
    with McapRecorder(tmp_path / "clock.mcap") as recorder:
        recorder.write(make_frame(1, None), record)
    after = time.time_ns()
    times = [m.log_time for _, _, m in read_messages(tmp_path / "clock.mcap")[1]]
    assert len(times) == 2 and all(before <= t <= after for t in times)
    assert read_records(tmp_path / "clock.mcap") == [record]


def test_unclosed_recording_keeps_its_complete_chunks(tmp_path: Path) -> None:
    path = tmp_path / "crash.mcap"
    one_chunk_per_message = McapRecorder(path, chunk_size_bytes=1)
    in_memory = McapRecorder(tmp_path / "buffered.mcap")
    for record in RECORDS:
        frame = make_frame(record["frame"], record["timestamp_s"])
        one_chunk_per_message.write(frame, record)
        in_memory.write(frame, record)
    assert read_records(path) == RECORDS  # before close(): no index, no footer
    assert read_records(tmp_path / "buffered.mcap") == []  # still in the open chunk
    data = path.read_bytes()
    read = []
    for length in range(0, len(data), 61):  # killed while writing byte `length`
        (tmp_path / "cut.mcap").write_bytes(data[:length])
        read.append(read_records(tmp_path / "cut.mcap"))
    assert all(records == RECORDS[: len(records)] for records in read)
    assert [len(records) for records in read] == sorted(len(records) for records in read)
    assert {len(records) for records in read} == {0, 1, 2, 3}
    one_chunk_per_message.close()
    in_memory.close()
    assert read_records(tmp_path / "buffered.mcap") == RECORDS


def test_non_finite_numbers_become_null(tmp_path: Path) -> None:
    record = hand_record(0)
    record["keypoints_3d_m"][20][2] = math.nan
    record_file(tmp_path / "nan.mcap", [record])
    (back,) = read_records(tmp_path / "nan.mcap")
    assert back["keypoints_3d_m"][20] == [KEYPOINTS_M[20, 0], KEYPOINTS_M[20, 1], None]
    (entity,) = decoded(tmp_path / "nan.mcap", KEYPOINTS_TOPIC)[0]["entities"]
    assert len(entity["spheres"]) == 20
    assert len(entity["lines"][0]["points"]) == 2 * (N_BONES - 1)


def test_overwrites_an_existing_file(tmp_path: Path) -> None:
    path = tmp_path / "old.mcap"
    path.write_bytes(b"not an mcap file" * 1000)
    record_file(path, RECORDS[:1])
    assert read_records(path) == RECORDS[:1]


def test_bad_paths_raise_one_clear_line(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="missing"):
        McapRecorder(tmp_path / "no_such_folder" / "run.mcap")
    with pytest.raises(ValueError, match="is a folder"):
        McapRecorder(tmp_path)


def test_write_after_close_raises_and_close_is_idempotent(tmp_path: Path) -> None:
    recorder = McapRecorder(tmp_path / "closed.mcap")
    recorder.close()
    recorder.close()
    with pytest.raises(ValueError, match="after close"):
        recorder.write(make_frame(0, 1.0), RECORDS[0])


def test_negative_time_is_rejected(tmp_path: Path) -> None:
    with (
        McapRecorder(tmp_path / "neg.mcap") as recorder,
        pytest.raises(ValueError, match="frame 0"),
    ):
        recorder.write(make_frame(0, -1.0), RECORDS[0])


def test_frame_messages_topics() -> None:
    assert [t for t, _ in frame_messages(RECORDS[0], 0)] == [HAND_TOPIC, KEYPOINTS_TOPIC]
    assert [t for t, _ in frame_messages(RECORDS[2], 0)][-1] == FINGERTIPS_TOPIC


def test_scene_update_checks_the_keypoint_shape() -> None:
    with pytest.raises(ValueError, match="keypoints_3d_m"):
        scene_update(np.zeros((20, 3)), 0)
