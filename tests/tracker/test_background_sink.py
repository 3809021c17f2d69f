"""A sink in its own thread: frames dropped while it is busy, the rest in order, its
errors raised in the caller, closed after the queued frames."""

import threading

import pytest

from tracker.outputs.background import QUEUE_FRAMES, BackgroundSink


class GatedSink:
    """Blocks in ``write`` until released; records what it got."""

    def __init__(self, fail_on: int | None = None) -> None:
        self.got: list[int] = []
        self.busy = threading.Event()
        self.release = threading.Event()
        self.closed = False
        self.fail_on = fail_on

    def write(self, frame, record) -> None:
        self.busy.set()
        self.release.wait(10)
        if record["frame"] == self.fail_on:
            raise OSError("disk full")
        self.got.append(record["frame"])

    def close(self) -> None:
        self.closed = True


def test_frames_are_dropped_while_the_sink_is_busy_and_the_rest_arrive_in_order():
    sink = GatedSink()
    background = BackgroundSink(sink)
    background.write(None, {"frame": 0})
    assert sink.busy.wait(10)  # the thread holds frame 0 inside the sink
    for frame in range(1, 6):  # QUEUE_FRAMES wait, the others are dropped
        background.write(None, {"frame": frame})
    assert background.dropped == 5 - QUEUE_FRAMES
    sink.release.set()
    background.close()
    assert sink.got == list(range(QUEUE_FRAMES + 1)) and sink.closed


def test_an_error_of_the_sink_is_raised_in_the_caller():
    sink = GatedSink(fail_on=0)
    sink.release.set()
    background = BackgroundSink(sink)
    background.write(None, {"frame": 0})
    with pytest.raises(OSError, match="disk full"):
        background.close()
    assert sink.closed
