"""Live output: every record over ZeroMQ in order; a reader that never reads loses
messages, never blocks the writer or grows its memory; JSON lines on a pipe."""

import importlib.util
import json
import os
import resource
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zmq

from tracker.outputs.mcap_file import read_records
from tracker.outputs.stream import QUEUE_MESSAGES, JsonLinesStream, open_stream


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def subscribe(url: str, count: int, received: list, timeout_s: float = 240.0) -> threading.Thread:
    """A subscriber thread that collects ``count`` two-part messages into ``received``."""

    def run() -> None:
        context = zmq.Context()
        socket_ = context.socket(zmq.SUB)
        socket_.setsockopt(zmq.SUBSCRIBE, b"glove/")
        socket_.connect(url)
        deadline = time.monotonic() + timeout_s
        while len(received) < count and time.monotonic() < deadline:
            if socket_.poll(200):
                topic, payload = socket_.recv_multipart()
                received.append((topic.decode(), json.loads(payload)))
        socket_.close(linger=0)
        context.term()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def test_a_subscriber_gets_every_record_in_order():
    url = f"tcp://127.0.0.1:{free_port()}"
    records = [{"frame": i, "timestamp_s": i / 30, "hand_found": i % 3 > 0} for i in range(50)]
    received: list = []
    with open_stream(url, topic="glove/fingertips", wait_s=10.0) as stream:
        listener = subscribe(url, len(records), received)
        for record in records:
            stream.publish(record)
    listener.join(30)
    assert received == [("glove/fingertips", record) for record in records]
    assert stream.sent == len(records) and stream.dropped == 0


def test_a_subscriber_that_never_reads_costs_bounded_memory_and_no_waiting():
    url = f"tcp://127.0.0.1:{free_port()}"
    context = zmq.Context()
    idle = context.socket(zmq.SUB)
    idle.setsockopt(zmq.SUBSCRIBE, b"")
    idle.setsockopt(zmq.RCVHWM, 10)
    idle.connect(url)
    record = {"frame": 0, "padding": "x" * 4000}  # about a tracking record's size
    with open_stream(url, wait_s=10.0) as stream:
        stream.publish(record)
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux
        for frame in range(20_000):  # 80 MB, were it all kept
            record["frame"] = frame
            stream.publish(record)
        grown_mib = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
    idle.close(linger=0)
    context.term()
    assert grown_mib < 20, f"{grown_mib:.0f} MiB kept for a subscriber that never reads"


def test_json_lines_to_a_pipe_nobody_reads_drop_instead_of_blocking():
    read_end, write_end = os.pipe()
    stream = JsonLinesStream(write_end)
    os.close(write_end)  # the stream holds its own copy
    # The pipe's buffer (64 KB) and the queue fill, then records are dropped: publish
    # must come back every time (a hang here would fail the join below).
    writer = threading.Thread(
        target=lambda: [stream.publish({"frame": i, "pad": "y" * 1000}) for i in range(2000)],
        daemon=True,
    )
    writer.start()
    writer.join(60)
    assert not writer.is_alive(), "publish blocked on a pipe nobody reads"
    assert stream.dropped > 0 and stream.sent >= QUEUE_MESSAGES
    # What did arrive is whole lines, in order.
    with os.fdopen(read_end, "rb") as pipe:
        reader = threading.Thread(target=stream.close)
        reader.start()
        data = pipe.read()
        reader.join(10)
    frames = [json.loads(line)["frame"] for line in data.splitlines()]
    assert frames == sorted(frames) and frames[0] == 0 and len(frames) == stream.sent


def test_a_reader_that_leaves_does_not_stop_the_writer():
    read_end, write_end = os.pipe()
    stream = JsonLinesStream(write_end)
    os.close(write_end)
    os.close(read_end)  # like `glove track ... --stream - | head -1` after its line
    for frame in range(300):
        stream.publish({"frame": frame})
    stream.close()
    assert stream.broken and stream.dropped > 0


@pytest.mark.parametrize(
    ("url", "message"),
    [
        ("udp://1.2.3.4:5", "expected tcp://HOST:PORT, ipc://PATH or -"),
        ("tcp://256.0.0.1:5555", "cannot listen there"),
        ("tcp://127.0.0.1:99999", "a port 1-65535"),
        ("tcp://localhost", "a port 1-65535"),
    ],
)
def test_bad_addresses_are_one_line_errors(url, message):
    with pytest.raises(ValueError, match=message):
        open_stream(url)


@pytest.mark.gl
@pytest.mark.slow
def test_glove_track_streams_every_frame_of_a_rendered_sequence(small_database, tmp_path):
    sequence = tmp_path / "seq"
    glove = [sys.executable, "-m", "glove_cli"]
    rendered = subprocess.run(
        [*glove, "render-sequence", "--trajectory", "tr1", "--frames", "8", "--out",
         str(sequence)], capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert rendered.returncode == 0, rendered.stderr
    url = f"tcp://127.0.0.1:{free_port()}"
    received: list = []
    listener = subscribe(url, 8, received)
    # One run writes the folder, the stream, an MCAP recording and (with the view
    # extra) a rerun recording: all four carry the same records.
    viewer = importlib.util.find_spec("rerun") is not None
    tracked = subprocess.run(
        [*glove, "track", str(sequence), "--db", str(small_database), "--out",
         str(tmp_path / "out"), "--no-overlay", "--stream", url, "--stream-wait", "30",
         "--mcap", str(tmp_path / "run.mcap"),
         *(["--rrd", str(tmp_path / "run.rrd")] if viewer else [])],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert tracked.returncode == 0, tracked.stderr
    listener.join(30)
    lines = (tmp_path / "out" / "poses.jsonl").read_text().splitlines()
    assert [topic for topic, _ in received] == ["glove/hand"] * 8
    assert [record for _, record in received] == [json.loads(line) for line in lines]
    assert read_records(tmp_path / "run.mcap") == [json.loads(line) for line in lines]
    if viewer:
        from rerun.chunk import RrdReader

        entities = {chunk.entity_path for chunk in RrdReader(tmp_path / "run.rrd").stream()}
        assert {"/world/points", "/world/hand/mesh", "/world/hand/keypoints"} <= entities
    assert sum(record["hand_found"] for _, record in received) >= 6
    assert [record["timestamp_s"] for _, record in received] == pytest.approx(
        [i / 30 for i in range(8)], abs=1e-6
    )
    # The same records as JSON lines on standard output, with no folder at all.
    piped = subprocess.run(
        [*glove, "track", str(sequence), "--db", str(small_database), "--stream", "-"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert piped.returncode == 0, piped.stderr
    assert [json.loads(line)["frame"] for line in piped.stdout.splitlines()] == list(range(8))
    assert "tracked 8 frames" in piped.stderr


def test_the_example_subscriber_prints_what_the_tracker_publishes():
    url = f"tcp://127.0.0.1:{free_port()}"
    example = Path(__file__).resolve().parents[2] / "examples" / "subscribe.py"
    with open_stream(url, wait_s=30.0) as stream:
        subscriber = subprocess.Popen(
            [sys.executable, str(example), url, "--count", "2"], stdout=subprocess.PIPE, text=True
        )
        stream.publish({"frame": 0, "hand_found": False})
        stream.publish(
            {"frame": 1, "hand_found": True, "translation_m": [0.01, -0.02, 0.5],
             "confidence": 0.9}
        )  # fmt: skip
    out, _ = subscriber.communicate(timeout=60)
    assert out.splitlines() == [
        "frame 0: no hand",
        "frame 1: wrist at (0.010, -0.020, 0.500) m, confidence 0.90",
    ]


def test_fingertip_detections_stream_on_their_own_topic(tmp_path):
    import cv2
    import numpy as np

    from glovedb.camera import CameraIntrinsics, save_intrinsics

    folder = tmp_path / "depth_only"
    (folder / "depth").mkdir(parents=True)
    save_intrinsics(CameraIntrinsics(64, 48, 60.0, 60.0, 31.5, 23.5), folder / "intrinsic.json")
    for index in range(3):
        cv2.imwrite(str(folder / "depth" / f"{index:06d}.png"), np.full((48, 64), 700, np.uint16))
    url = f"tcp://127.0.0.1:{free_port()}"
    received: list = []
    listener = subscribe(url, 3, received)
    detected = subprocess.run(
        [sys.executable, "-m", "glove_cli", "fingertips", "detect", str(folder), "--stream", url,
         "--stream-wait", "30"], capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert detected.returncode == 0, detected.stderr
    listener.join(30)
    assert [topic for topic, _ in received] == ["glove/fingertips"] * 3
    assert [record["frame"] for _, record in received] == [0, 1, 2]
    assert all(record["fingertips"] == [] for _, record in received)  # a flat wall
