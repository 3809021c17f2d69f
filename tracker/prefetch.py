"""Reading the next frames while the current one is tracked.

Decoding a VGA color and depth PNG pair takes about 10 ms, a third of a frame's
tracking; OpenCV's decoders release the GIL, so a reader thread hides that time
behind tracking on a machine with two cores. :class:`Prefetch` runs any frame iterator
in such a thread, a few frames ahead, and hands its frames (and its errors) to the
caller in order.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterator
from typing import Generic, TypeVar

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
