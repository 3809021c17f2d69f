"""Live per-frame messages for other programs: ZeroMQ or JSON lines on standard output.

``glove track --stream URL`` and ``glove fingertips detect --stream URL`` publish each
frame's record (the same object as a line of ``poses.jsonl`` or ``fingertips.jsonl``)
the moment the frame is done:

- ``tcp://HOST:PORT`` (or ``ipc://PATH``): a ZeroMQ publisher bound to that address;
  each message has two parts, the topic (``glove/hand`` or ``glove/fingertips``, so a
  subscriber can filter) and the record as UTF-8 JSON;
- ``-``: one JSON line per record on standard output, for a pipe
  (``glove track realsense --stream - | my_robot``).

A slow or absent reader never slows the tracker: ZeroMQ keeps at most
:data:`QUEUE_MESSAGES` messages per subscriber and drops the newer ones beyond them
(its publisher never blocks), and standard output is written by a thread from a queue
of the same length whose overflow is dropped. Dropped messages are counted
(:attr:`RecordStream.dropped`). Messages are never reordered.
"""

from __future__ import annotations

import json
import os
import queue
import sys
import threading
import time
from typing import Any, TextIO

from tracker.frames import Frame

QUEUE_MESSAGES = 100
"""Messages kept for a reader that does not keep up, per subscriber (about 4 KB each)."""
CLOSE_TIMEOUT_S = 1.0
"""How long closing waits for queued messages to leave before giving them up."""
TOPICS = ("glove/hand", "glove/fingertips")


class RecordStream:
    """Publishes records, one message each; a :class:`tracker.outputs.ResultSink`.

    Open it with :func:`open_stream`. ``dropped`` counts the messages a reader missed
    because it did not keep up (on ZeroMQ, only those the publisher knows of: its own
    queue's overflow, not what a subscriber's queue dropped).
    """

    dropped: int = 0
    sent: int = 0

    def publish(self, record: dict[str, Any]) -> None:
        """Send one record (never blocks for long)."""
        raise NotImplementedError

    def write(self, frame: Frame, record: dict[str, Any]) -> None:
        """The sink interface: ``frame`` is not sent, only its record."""
        self.publish(record)

    def close(self) -> None:
        """Send what is queued (for at most :data:`CLOSE_TIMEOUT_S`) and stop."""

    def __enter__(self) -> RecordStream:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_stream(url: str, *, topic: str = "glove/hand", wait_s: float = 0.0) -> RecordStream:
    """Open a live stream of records.

    Parameters
    ----------
    url : str
        ``tcp://HOST:PORT`` or ``ipc://PATH`` (ZeroMQ, bound here; ``tcp://*:5555``
        listens on every interface, ``tcp://127.0.0.1:5555`` on this machine only), or
        ``-`` for JSON lines on standard output.
    topic : str
        The first part of each ZeroMQ message, one of :data:`TOPICS`.
    wait_s : float
        ZeroMQ only: before its first message, wait up to this many seconds (counted
        from opening) for a subscriber, so that one started beforehand gets every
        frame. Without it, a subscriber that joins late misses what was sent before.

    Returns
    -------
    RecordStream

    Raises
    ------
    ValueError
        For an address that is not one of those, or that cannot be bound (in use,
        not this machine's).
    """
    if topic not in TOPICS:
        raise ValueError(f"stream topic: expected one of {TOPICS}, got {topic!r}")
    if not 0 <= wait_s < 3600:
        raise ValueError(f"stream wait: expected 0 to 3600 s, got {wait_s}")
    if url == "-":
        sys.stdout.flush()
        try:
            return JsonLinesStream(sys.stdout.fileno())
        except (AttributeError, OSError, ValueError):  # replaced by one without a descriptor
            return JsonLinesStream(sys.stdout)
    if url.startswith("tcp://"):
        host, _, port = url[len("tcp://") :].rpartition(":")
        if not host or not (port == "*" or (port.isdigit() and 0 < int(port) < 65536)):
            raise ValueError(f"--stream {url}: expected tcp://HOST:PORT with a port 1-65535")
    if url.startswith(("tcp://", "ipc://")):
        return ZmqStream(url, topic, wait_s=wait_s)
    raise ValueError(f"--stream {url}: expected tcp://HOST:PORT, ipc://PATH or - (standard output)")


def encode(record: dict[str, Any]) -> bytes:
    """A record as UTF-8 JSON, the same text as its line in the run's ``.jsonl`` file."""
    return json.dumps(record).encode()


class ZmqStream(RecordStream):
    """A ZeroMQ publisher (XPUB, so that it can tell when a subscriber arrives)."""

    def __init__(self, url: str, topic: str, *, wait_s: float = 0.0) -> None:
        import zmq

        self._zmq = zmq
        self.url = url
        self.topic = topic.encode()
        self._context = zmq.Context()
        self._socket = self._context.socket(zmq.XPUB)
        self._socket.setsockopt(zmq.SNDHWM, QUEUE_MESSAGES)
        self._socket.setsockopt(zmq.LINGER, int(CLOSE_TIMEOUT_S * 1000))
        try:
            self._socket.bind(url)
        except zmq.ZMQError as error:
            self._socket.close(linger=0)
            self._context.term()
            raise ValueError(f"--stream {url}: cannot listen there: {error}") from None
        self._deadline = time.monotonic() + wait_s
        self.subscribers = 0

    def _read_subscriptions(self, timeout_s: float) -> None:
        """Count subscribe/unsubscribe messages, waiting up to ``timeout_s`` for one."""
        while self._socket.poll(int(max(timeout_s, 0.0) * 1000), self._zmq.POLLIN):
            message = self._socket.recv()
            self.subscribers += 1 if message[:1] == b"\x01" else -1
            timeout_s = 0.0

    def publish(self, record: dict[str, Any]) -> None:
        wait = self._deadline - time.monotonic() if self.subscribers <= 0 else 0.0
        self._read_subscriptions(0.0)
        while self.subscribers <= 0 and wait > 0:
            started = time.monotonic()
            self._read_subscriptions(wait)
            wait -= time.monotonic() - started
        self._deadline = 0.0  # waits once, before the first message
        try:
            self._socket.send_multipart([self.topic, encode(record)], flags=self._zmq.NOBLOCK)
            self.sent += 1
        except self._zmq.Again:
            self.dropped += 1

    def close(self) -> None:
        if self._socket.closed:
            return
        self._socket.close()  # lingers up to CLOSE_TIMEOUT_S for queued messages
        self._context.term()


class JsonLinesStream(RecordStream):
    """JSON lines written to a file descriptor (standard output) by a thread from a queue.

    The thread writes to its own duplicate of the descriptor with ``os.write``, so a
    reader that never reads blocks only that thread, never the interpreter's
    ``sys.stdout`` (whose lock a blocked writer would hold at exit). A text stream
    without a descriptor (a test's captured output) is written as text instead.
    """

    def __init__(self, out: int | TextIO) -> None:
        self._fd = os.dup(out) if isinstance(out, int) else None
        self._text = None if isinstance(out, int) else out
        self._queue: queue.Queue[bytes | None] = queue.Queue(QUEUE_MESSAGES)
        self.broken = False
        self._thread = threading.Thread(target=self._drain, name="glove-stream", daemon=True)
        self._thread.start()

    def _drain(self) -> None:
        while (line := self._queue.get()) is not None:
            try:
                self._write(line)
            except (OSError, ValueError):  # BrokenPipeError: the reader left (``| head``)
                self.broken = True
        if self._fd is not None:
            os.close(self._fd)

    def _write(self, line: bytes) -> None:
        if self.broken:
            return
        if self._text is not None:
            self._text.write(line.decode())
            self._text.flush()
            return
        assert self._fd is not None
        view = memoryview(line)
        while view:
            view = view[os.write(self._fd, view) :]

    def publish(self, record: dict[str, Any]) -> None:
        if self.broken:
            self.dropped += 1
            return
        try:
            self._queue.put_nowait(encode(record) + b"\n")
            self.sent += 1
        except queue.Full:
            self.dropped += 1

    def close(self) -> None:
        """Let the queued lines out for at most :data:`CLOSE_TIMEOUT_S`, then give up
        on them (the thread dies with the process)."""
        if not self._thread.is_alive():
            return
        deadline = time.monotonic() + CLOSE_TIMEOUT_S
        while True:
            try:
                self._queue.put(None, timeout=max(deadline - time.monotonic(), 0.001))
                break
            except queue.Full:
                if time.monotonic() >= deadline:
                    break
        self._thread.join(max(deadline - time.monotonic(), 0.0))
