"""A sink that works in its own thread, so that a slow one never holds tracking up.

:class:`BackgroundSink` hands each frame to a wrapped :class:`~tracker.outputs.
ResultSink` through a short queue. When the wrapped sink is still busy with earlier
frames and the queue is full, the new frame is dropped (counted in ``dropped``):
right for a live view, where the newest frame matters and a late one does not. The
frames it does pass on keep their order. An error of the wrapped sink is raised in the
caller, at its next ``write`` or at ``close``.
"""

from __future__ import annotations

import queue
import threading
from typing import Any

from glovedb._closing import Closing
from tracker.frames import Frame
from tracker.outputs import ResultSink

QUEUE_FRAMES = 2
"""Frames that may wait for a busy sink; more are dropped."""


class BackgroundSink(Closing):
    """Run ``sink.write`` in a thread; drop frames while it is busy.

    Parameters
    ----------
    sink : ResultSink
        Closed by :meth:`close`, in the thread that calls it, after the queued frames.
    """

    def __init__(self, sink: ResultSink) -> None:
        self.sink = sink
        self.dropped = 0
        self._queue: queue.Queue[tuple[Frame, dict[str, Any]] | None] = queue.Queue(QUEUE_FRAMES)
        self._error: BaseException | None = None
        self._closed = False
        self._thread = threading.Thread(target=self._work, name="glove-sink", daemon=True)
        self._thread.start()

    def _work(self) -> None:
        while (item := self._queue.get()) is not None:
            if self._error is not None:
                continue
            try:
                self.sink.write(*item)
            except BaseException as error:  # raised again in the caller's thread
                self._error = error

    def _raise_error(self) -> None:
        if self._error is not None:
            error, self._error = self._error, None
            raise error

    def write(self, frame: Frame, record: dict[str, Any]) -> None:
        """Queue the frame for the sink, or drop it when the sink is behind."""
        self._raise_error()
        try:
            self._queue.put_nowait((frame, record))
        except queue.Full:
            self.dropped += 1

    def close(self) -> None:
        """Let the queued frames through, close the sink, raise its error if any."""
        if self._closed:
            return
        self._closed = True
        self._queue.put(None)
        self._thread.join()
        try:
            self._raise_error()
        finally:
            self.sink.close()
