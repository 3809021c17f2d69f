"""Reading the next frames while the current one is tracked.

Decoding a VGA color and depth PNG pair takes about 10 ms, a third of a frame's
tracking; OpenCV's decoders release the GIL, so a reader thread hides that time
behind tracking on a machine with two cores. :class:`Prefetch` runs any frame iterator
in such a thread, a few frames ahead, and hands its frames (and its errors) to the
caller in order.

A thread still shares the interpreter with the tracking: its segmentation holds the
GIL for its NumPy steps and the two threads slow each other (on Tr3, 2 cores: a
frame's segmentation 5.4 ms of wall time for 3.3 ms of CPU, 2.7 ms alone; the fit
11.2 ms for 9.9 alone). :class:`ProcessPrefetch` runs the iterator in a forked child
process instead: the tracking thread has the interpreter to itself. Each item is
pickled with its arrays out of band (protocol 5) and the arrays copied through one of
``depth + 1`` slots of memory shared with the child, so that no pixel goes through a
pipe. The pickles are only this hand-over between the tracker and the child it
forked (what a ``multiprocessing`` queue does with any object): nothing is written to
a file, and nothing from outside the process is unpickled; saved models and data stay
ONNX, ``.npz`` and HDF5. Where ``fork`` is missing (Windows, macOS' default is unsafe
with threads) :func:`reader_for` falls back to the thread.
"""

from __future__ import annotations

import mmap
import multiprocessing
import os
import pickle
import queue
import sys
import threading
from collections.abc import Iterator
from typing import Any, Generic, TypeVar

T = TypeVar("T")

_DONE = object()


class _Failure:
    """An exception raised by the reader, to be raised again in the caller."""

    def __init__(self, error: BaseException) -> None:
        self.error = error


class Prefetch(Generic[T]):
    """Iterate over ``frames`` in a background thread, at most ``depth`` items ahead.

    Items come out in order; an exception of the reader is raised in the caller at
    the position where it happened (the items before it come out first). Closing the
    iterator early (``close()``, leaving a ``with`` block, or its garbage collection)
    stops the reader at its next item.

    Parameters
    ----------
    frames : iterator
        E.g. a :class:`tracker.sources.Source`.
    depth : int
        Items read ahead; memory is ``depth`` frames (about 1.5 MB each for VGA).
    """

    def __init__(self, frames: Iterator[T], depth: int = 2) -> None:
        if depth < 1:
            raise ValueError(f"prefetch depth: expected >= 1, got {depth}")
        self._queue: queue.Queue[object] = queue.Queue(depth)
        self._stop = threading.Event()
        self._finished = False
        self._thread = threading.Thread(
            target=self._read, args=(iter(frames),), name="glove-reader", daemon=True
        )
        self._thread.start()

    def _put(self, item: object) -> bool:
        """Queue ``item`` unless stopped; False once stopped."""
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=0.05)
                return True
            except queue.Full:
                continue
        return False

    def _read(self, frames: Iterator[T]) -> None:
        try:
            for frame in frames:
                if not self._put(frame):
                    return
        except BaseException as error:  # handed to the caller, raised there
            self._put(_Failure(error))
            return
        self._put(_DONE)

    def __iter__(self) -> Prefetch[T]:
        return self

    def ready(self) -> bool:
        """Whether the next item (or the end) can be taken without waiting."""
        return self._finished or not self._queue.empty()

    def __next__(self) -> T:
        if self._finished:
            raise StopIteration
        item = self._queue.get()
        if item is _DONE:
            self._finished = True
            raise StopIteration
        if isinstance(item, _Failure):
            self._finished = True
            raise item.error
        return item  # type: ignore[return-value]

    def close(self) -> None:
        """Stop the reader (it finishes the item it is reading) and wait for it."""
        self._finished = True
        self._stop.set()
        self._thread.join(5.0)

    def __enter__(self) -> Prefetch[T]:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        stop = getattr(self, "_stop", None)  # absent when __init__ refused its arguments
        if stop is not None:
            stop.set()


SLOT_BYTES = 16 << 20
"""Bytes of one shared slot: a VGA frame prepared for tracking is 3.9 MB of arrays;
an item whose arrays are larger goes through the pipe instead."""


def reader_for(frames: Iterator[T], depth: int) -> Prefetch[T] | ProcessPrefetch[T]:
    """A :class:`ProcessPrefetch` where the platform forks (Linux), else a :class:`Prefetch`."""
    if sys.platform.startswith("linux") and "fork" in multiprocessing.get_all_start_methods():
        return ProcessPrefetch(frames, depth=depth)
    return Prefetch(frames, depth=depth)


class ProcessPrefetch(Generic[T]):
    """Iterate over ``frames`` in a forked child process, at most ``depth`` items ahead.

    The same contract as :class:`Prefetch`: items in order, the child's exception
    raised in the caller where it happened, early closing stops the child. A child
    that dies without a word (killed, out of memory) ends the iteration with a
    ``RuntimeError`` instead of a hang.

    Parameters
    ----------
    frames : iterator
        Iterated in the child only; what it yields must pickle.
    depth : int
        Items read ahead; shared memory is ``depth + 1`` slots of ``slot_bytes``,
        touched only as far as items fill them.
    slot_bytes : int
    """

    def __init__(self, frames: Iterator[T], depth: int = 2, slot_bytes: int = SLOT_BYTES) -> None:
        if depth < 1:
            raise ValueError(f"prefetch depth: expected >= 1, got {depth}")
        context = multiprocessing.get_context("fork")
        self._slot_bytes = slot_bytes
        # Anonymous and shared: the child inherits it; no /dev/shm file to size or leak.
        self._memory = mmap.mmap(-1, (depth + 1) * slot_bytes)
        self._free: Any = context.Queue()
        for slot in range(depth + 1):
            self._free.put(slot)
        self._ready: Any = context.Queue()
        self._stop = context.Event()
        self._finished = False
        self._parent = os.getpid()
        self._process = context.Process(
            target=self._read, args=(iter(frames),), name="glove-reader", daemon=True
        )
        self._process.start()

    # The child -------------------------------------------------------------------

    def _take_slot(self) -> int | None:
        """A free slot, waiting for the caller to release one; None once stopped or
        once the caller's process is gone (killed: it never set the stop)."""
        while not self._stop.is_set() and os.getppid() == self._parent:
            try:
                return int(self._free.get(timeout=0.05))
            except queue.Empty:
                continue
        return None

    def _read(self, frames: Iterator[T]) -> None:
        try:
            for item in frames:
                slot = self._take_slot()
                if slot is None:  # the caller left: exit without flushing to it
                    self._ready.cancel_join_thread()
                    return
                self._ready.put(self._message(item, slot))
        except BaseException as error:  # handed to the caller, raised there
            self._ready.put(("error", _picklable(error)))
            return
        self._ready.put(("done",))

    def _message(self, item: T, slot: int) -> tuple[Any, ...]:
        """The item's pickle with its arrays in ``slot``, or all of it inline."""
        buffers: list[pickle.PickleBuffer] = []
        payload = pickle.dumps(item, protocol=5, buffer_callback=buffers.append)
        raws = [buffer.raw() for buffer in buffers]
        if sum(raw.nbytes for raw in raws) > self._slot_bytes:
            return ("inline", slot, pickle.dumps(item, protocol=5))
        offset = slot * self._slot_bytes
        sizes = []
        for raw in raws:
            self._memory[offset : offset + raw.nbytes] = raw
            offset += raw.nbytes
            sizes.append(raw.nbytes)
        return ("item", slot, payload, sizes)

    # The caller ------------------------------------------------------------------

    def __iter__(self) -> ProcessPrefetch[T]:
        return self

    def ready(self) -> bool:
        """Whether the next item (or the end) can be taken without waiting (what the
        child has sent; a message still in its pipe may be missed)."""
        return self._finished or not self._ready.empty() or not self._process.is_alive()

    def __next__(self) -> T:
        if self._finished:
            raise StopIteration
        message = self._receive()
        kind = message[0]
        if kind == "done":
            self._finished = True
            raise StopIteration
        if kind == "error":
            self._finished = True
            raise message[1]
        slot = message[1]
        if kind == "inline":
            self._free.put(slot)
            return pickle.loads(message[2])
        payload, sizes = message[2], message[3]
        view, offset, arrays = memoryview(self._memory), slot * self._slot_bytes, []
        for size in sizes:
            arrays.append(bytearray(view[offset : offset + size]))  # a copy: the slot is reused
            offset += size
        view.release()
        self._free.put(slot)
        return pickle.loads(payload, buffers=arrays)

    def _receive(self) -> tuple[Any, ...]:
        while True:
            try:
                return self._ready.get(timeout=0.1)
            except queue.Empty:
                if self._process.is_alive():
                    continue
            try:  # what the child sent just before it ended
                return self._ready.get(timeout=0.5)
            except queue.Empty:
                self._finished = True
                raise RuntimeError(
                    "the frame reader process ended unexpectedly "
                    f"(exit code {self._process.exitcode})"
                ) from None

    def close(self) -> None:
        """Stop the child (it finishes the item it is reading) and wait for it."""
        self._finished = True
        self._stop.set()
        self._process.join(5.0)
        if self._process.is_alive():
            self._process.terminate()
            self._process.join(1.0)
        for channel in (self._free, self._ready):
            channel.close()
            channel.cancel_join_thread()
        self._memory.close()

    def __enter__(self) -> ProcessPrefetch[T]:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        stop = getattr(self, "_stop", None)  # absent when __init__ refused its arguments
        if stop is not None and not self._finished:
            stop.set()


def _picklable(error: BaseException) -> BaseException:
    """``error`` if it survives pickling, else a RuntimeError with its text."""
    try:
        pickle.loads(pickle.dumps(error))
    except Exception:
        return RuntimeError(f"{type(error).__name__}: {error}")
    return error
