"""Thread limits for processes that fill a core by themselves."""

from __future__ import annotations

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
