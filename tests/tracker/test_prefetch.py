"""Reading ahead in a thread or a child process: same items in order, errors where
they happened, bounded memory, and a reader that stops when the caller does."""

import os
import sys
import threading
import time

import numpy as np
import pytest

from tracker.prefetch import Prefetch, ProcessPrefetch, reader_for

READERS = [Prefetch, ProcessPrefetch] if sys.platform.startswith("linux") else [Prefetch]
linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="forks on Linux only")


@pytest.mark.parametrize("reader", READERS)
def test_items_come_out_in_order_and_end(reader):
    assert list(reader(iter(range(100)), depth=3)) == list(range(100))
    assert list(reader(iter([]))) == []


@pytest.mark.parametrize("reader", READERS)
def test_an_error_is_raised_after_the_items_before_it(reader):
    def frames():
        yield 0
        yield 1
        raise ValueError("frame 2: truncated PNG")

    reader = reader(frames())
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


@pytest.mark.parametrize("reader", READERS)
def test_depth_must_be_positive(reader):
    with pytest.raises(ValueError, match="depth"):
        reader(iter([1]), depth=0)


@linux
def test_the_child_process_hands_over_arrays_through_shared_slots_or_the_pipe():
    frames = [{"index": i, "depth": np.full((480, 640), i, np.float32)} for i in range(6)]
    with ProcessPrefetch(iter(frames), depth=2) as reader:
        received = list(reader)
    assert [f["index"] for f in received] == list(range(6))
    pairs = zip(frames, received, strict=True)
    assert all(np.array_equal(a["depth"], b["depth"]) for a, b in pairs)
    received[0]["depth"][0, 0] = -1.0  # a copy the caller owns, not the reused slot
    # Items larger than a slot go through the pipe whole.
    large = [np.arange(300_000, dtype=np.int64), "end"]
    with ProcessPrefetch(iter(large), depth=1, slot_bytes=1 << 20) as reader:
        first, second = list(reader)
    assert np.array_equal(first, large[0]) and second == "end"
    assert isinstance(reader_for(iter([]), depth=1), ProcessPrefetch)


@linux
def test_a_child_that_dies_ends_the_iteration_with_an_error_not_a_hang():
    def frames():
        yield 0
        os._exit(3)  # killed: no exception, no word

    started = time.perf_counter()
    with pytest.raises(RuntimeError, match=r"ended unexpectedly \(exit code 3\)"):
        list(ProcessPrefetch(frames()))
    assert time.perf_counter() - started < 5.0


@linux
def test_the_child_stays_at_most_depth_items_ahead_and_stops_on_close(tmp_path):
    log = tmp_path / "produced"

    def frames():
        for index in range(1000):
            with open(log, "a") as file:  # the child's progress, seen from the parent
                file.write(f"{index}\n")
            yield index

    reader = ProcessPrefetch(frames(), depth=2)
    assert next(reader) == 0
    time.sleep(0.5)  # ample time to run ahead, were it unbounded
    # The caller's item (its slot free once copied out), one in each of the depth + 1
    # slots, and the one the child holds while it waits for a slot.
    assert len(log.read_text().split()) <= 5
    reader.close()
    assert not reader._process.is_alive()


@linux
def test_the_child_ends_when_the_caller_is_killed():
    import subprocess
    import textwrap

    script = textwrap.dedent("""
        import itertools, os
        from tracker.prefetch import ProcessPrefetch
        reader = ProcessPrefetch(itertools.count())
        next(reader)
        print(reader._process.pid, flush=True)
        os._exit(0)  # killed: no close, no exit handlers
    """)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    child = int(run.stdout)

    def running() -> bool:  # a zombie nobody reaps has ended too
        try:
            with open(f"/proc/{child}/stat") as stat:
                return stat.read().rsplit(")", 1)[1].split()[0] != "Z"
        except FileNotFoundError:
            return False

    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline and running():
        time.sleep(0.1)
    assert not running()
