"""Thread limits for processes that fill a core by themselves, and the scan threads."""

from __future__ import annotations

import functools
import itertools
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any


def single_threaded_blas() -> Any:
    """Limit BLAS to one thread (until ``restore_original_limits()`` or, used as a
    context manager, until the block ends).

    Our matrix products are small (skinning, 6x6 to 26x26 normal equations): more
    BLAS threads only spin for milliseconds after each one, on a core that another
    worker, or the tracker's own scan threads, needs. A tracked frame took 72 ms of
    wall time with OpenBLAS's default threads on a busy 2-core machine and 27 ms with
    one.
    """
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1, user_api="blas")


@functools.cache
def thread_pool(workers: int) -> ThreadPoolExecutor:
    """One pool per thread count for the life of the process: starting threads for
    every scan costs a noticeable part of a 1,000,000-entry scan."""
    return ThreadPoolExecutor(workers, thread_name_prefix="glovedb-scan")


def run_parts(work: Callable[[int, int], None], cuts: Sequence[int], workers: int) -> None:
    """``work(a, b)`` for each consecutive pair of ``cuts`` (empty parts skipped), on
    ``workers`` threads; the calling thread runs the first part itself, so a split
    in two wakes one pool thread only. ``work`` should release the GIL (a compiled
    ``nogil`` kernel)."""
    parts = [(a, b) for a, b in itertools.pairwise(cuts) if b > a]
    if workers == 1 or len(parts) < 2:
        for part in parts:
            work(*part)
        return
    others = [thread_pool(workers).submit(work, *part) for part in parts[1:]]
    work(*parts[0])
    for other in others:
        other.result()
