"""Where each frame's result goes the moment it exists, besides the output folder.

- :mod:`tracker.outputs.stream`: live messages for other programs, over ZeroMQ
  (``tcp://HOST:PORT``) or as JSON lines on standard output (``-``);
- :mod:`tracker.outputs.mcap_file`: an MCAP recording (JSON-schema channels) that
  Foxglove and ROS 2 tools open;
- :mod:`tracker.outputs.rerun_view`: the rerun 3D viewer, live or saved to an
  ``.rrd`` file (the optional ``view`` extra);
- :mod:`tracker.outputs.background`: any sink in a thread of its own, dropping
  frames while it is behind (the live viewer).

Each is a :class:`ResultSink`: :func:`tracker.run.track_source` hands it every
frame with that frame's ``poses.jsonl`` record, in order, and closes it at the end.
A sink must never slow tracking down by much: what cannot keep up is dropped.
"""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path
from typing import Any, Protocol

from tracker.frames import Frame


class ResultSink(Protocol):
    """Receives each tracked frame and its record (docs/tracker.md, "poses.jsonl")."""

    def write(self, frame: Frame, record: dict[str, Any]) -> None:
        """Take one frame's input and its result record."""

    def close(self) -> None:
        """Finish (flush, write the file's index, disconnect); called once."""


def open_sinks(
    stack: ExitStack,
    tracker: Any,
    *,
    stream: str | None = None,
    stream_wait_s: float = 0.0,
    mcap: str | Path | None = None,
    view: bool = False,
    rrd: str | Path | None = None,
) -> list[ResultSink]:
    """Open the sinks a tracking run asked for; ``stack`` closes them.

    Parameters
    ----------
    stack : ExitStack
        Each sink is entered into it.
    tracker : Tracker
        For the viewer (the hand model it draws).
    stream : str, optional
        A :func:`tracker.outputs.stream.open_stream` address (``tcp://HOST:PORT``, ``-``).
    stream_wait_s : float
        Seconds the stream waits for a first subscriber.
    mcap : path, optional
        An MCAP file to record into.
    view, rrd : bool, path
        The rerun viewer live, and/or saved to an ``.rrd`` file. The live viewer
        alone logs in a thread of its own (:class:`tracker.outputs.background.
        BackgroundSink`) and skips frames rather than slow tracking; with a file,
        every frame is logged on the tracking thread.

    Returns
    -------
    list of ResultSink
    """
    sinks: list[ResultSink] = []
    if stream is not None:
        from tracker.outputs.stream import open_stream

        sinks.append(stack.enter_context(open_stream(stream, wait_s=stream_wait_s)))
    if mcap is not None:
        from tracker.outputs.mcap_file import McapRecorder

        sinks.append(stack.enter_context(McapRecorder(mcap)))
    if view or rrd is not None:
        from tracker.outputs.background import BackgroundSink
        from tracker.outputs.rerun_view import RerunLogger

        logger = RerunLogger(tracker, spawn=view, path=rrd)
        # A live view only: in its own thread, dropping frames while the viewer is
        # behind. A saved recording gets every frame, at the tracker's pace.
        viewer: BackgroundSink | RerunLogger = BackgroundSink(logger) if rrd is None else logger
        stack.enter_context(viewer)
        sinks.append(viewer)
    return sinks
