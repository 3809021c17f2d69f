"""Reading ahead in a thread: same items in order, errors where they happened, bounded
memory, and a reader that stops when the caller does."""

import threading
import time

import pytest

from tracker.prefetch import Prefetch


def test_items_come_out_in_order_and_end():
    assert list(Prefetch(iter(range(100)), depth=3)) == list(range(100))
    assert list(Prefetch(iter([]))) == []


def test_an_error_is_raised_after_the_items_before_it():
    def frames():
        yield 0
        yield 1
        raise ValueError("frame 2: truncated PNG")

    reader = Prefetch(frames())
    assert next(reader) == 0 and next(reader) == 1
    with pytest.raises(ValueError, match="frame 2: truncated PNG"):
        next(reader)
    with pytest.raises(StopIteration):
        next(reader)


def test_the_reader_stays_at_most_depth_items_ahead_and_stops_on_close():
    produced = []

    def frames():
        for index in range(1000):
            produced.append(index)
            yield index

    reader = Prefetch(frames(), depth=2)
    assert next(reader) == 0
    time.sleep(0.3)  # ample time to run ahead, were it unbounded
    # The caller holds item 0, two wait in the queue, the reader holds one more.
    assert len(produced) <= 4
    reader.close()
    time.sleep(0.1)
    count = len(produced)
    time.sleep(0.2)
    assert len(produced) == count <= 5
    assert not any(t.name == "glove-reader" and t.is_alive() for t in threading.enumerate())


def test_depth_must_be_positive():
    with pytest.raises(ValueError, match="depth"):
        Prefetch(iter([1]), depth=0)
