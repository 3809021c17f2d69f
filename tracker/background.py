"""The database lookup off the frame: a second start found while the next frames are
tracked.

While the hand is tracked, the tracker still looks it up in the database every
``reinit_every`` frames, fits from the looked-up start and keeps the lower energy: on
the rendered Tr1-Tr5 sequences this second start wins about half the time and takes
0-0.5 degrees off the mean posture error (0.5 on Tr3). Within the frame it costs the
lookup, the ICP and a second fit, about 26 ms on a laptop-class core: those frames
set the 99th percentile of the latency.

:class:`BackgroundLookup` runs that work in a worker thread on the frame where it is
due while the tracker goes on with the next frames from their warm starts, and hands
the looked-up fit back ``delay_frames`` later, at a fixed frame (waiting for it if
need be), so that a run gives the same poses on every machine. When the looked-up
fit explained its frame with a lower energy than the warm fit of that frame did, the
tracker's next start carries the difference (:func:`carried_start`): the lookup's
correction applied to the pose the warm fits have reached since.

The worker runs at a lower scheduling priority (niceness 10, on Linux, where it is
per thread), so that the frames tracked beside a job keep their cores and the job
takes what is left. On a 2-core machine (`Tr3`, DB_open+pinch+power, three
interleaved pairs of runs) frames over 25 ms went from 59-68 to 52-59 of 241, the
median latency from 18.4-19.9 to 17.9-18.3 ms; the frames that collect a job wait
a little longer for it.

A lookup that the warm fit's failure asks for (no hand, a fit that fails the quality
test) is not deferred: that frame has no other answer; nor is one that a suspect fit
asks for (more model outside the hand than usual, ``relook_outside``), where a late
correction cost a ball in front of the hand and a dim cluttered room accuracy.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Generic, TypeVar

from tracker.generative.model import HandPose

_WORKER_NICENESS = 10
T = TypeVar("T")
W = TypeVar("W")


@dataclass(frozen=True)
class _Pending(Generic[W, T]):
    frame_index: int
    warm: W
    future: Future[T]


class BackgroundLookup(Generic[W, T]):
    """At most one job at a time in a worker thread, collected at a fixed frame.

    Parameters
    ----------
    delay_frames : int
        A job submitted at frame ``i`` is collected at frame ``i + delay_frames``
        (>= 1).
    """

    def __init__(self, delay_frames: int) -> None:
        if delay_frames < 1:
            raise ValueError(f"delay_frames: expected >= 1, got {delay_frames}")
        self.delay_frames = delay_frames
        self._executor: ThreadPoolExecutor | None = None
        self._pending: _Pending[W, T] | None = None

    @property
    def busy(self) -> bool:
        """Whether a job waits to be collected."""
        return self._pending is not None

    def submit(self, frame_index: int, warm: W, job: Callable[[], T]) -> None:
        """Start ``job`` for frame ``frame_index`` (whose warm fit was ``warm``).

        Raises
        ------
        RuntimeError
            When a job is still pending.
        """
        if self._pending is not None:
            raise RuntimeError("a background lookup is still pending")
        if self._executor is None:
            self._executor = ThreadPoolExecutor(
                1, thread_name_prefix="glove-lookup", initializer=_yield_to_other_threads
            )
        self._pending = _Pending(frame_index, warm, self._executor.submit(job))

    def collect(self, frame_index: int) -> tuple[W, T] | None:
        """The warm fit and the job's result of the job due at ``frame_index``
        (waiting for it to finish), or None when none is due. A job's exception is
        raised here."""
        pending = self._pending
        if pending is None or frame_index < pending.frame_index + self.delay_frames:
            return None
        self._pending = None
        return pending.warm, pending.future.result()

    def discard(self) -> None:
        """Forget the pending job (it finishes in the worker; its result is dropped)."""
        if self._pending is not None:
            self._pending.future.cancel()
        self._pending = None

    def close(self) -> None:
        """Discard the pending job and stop the worker once it is done."""
        self.discard()
        if self._executor is not None:
            self._executor.shutdown(wait=True)
            self._executor = None


def _yield_to_other_threads() -> None:
    """Lower the calling thread's scheduling priority (Linux: per thread), so that the
    frames tracked beside a job keep their cores; elsewhere nothing changes."""
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), _WORKER_NICENESS)
    except (AttributeError, OSError):
        pass


def carried_start(looked_up: HandPose, warm: HandPose, latest: HandPose) -> HandPose:
    """``latest`` moved by the correction that ``looked_up`` made to ``warm``.

    ``looked_up`` and ``warm`` are two fits of the same (earlier) frame; the
    difference of their postures is added to ``latest``'s posture, the rotation
    between them (in the hand's frame: ``warm.R^T looked_up.R``) is applied to
    ``latest``'s, and the difference of their wrist positions is added to
    ``latest``'s.

    Parameters
    ----------
    looked_up, warm : HandPose
        Fits of one frame from the lookup's start and from the previous frame's.
    latest : HandPose
        The newest fit (a later frame) from the warm starts.

    Returns
    -------
    HandPose
    """
    correction = warm.rotation.T @ looked_up.rotation
    return HandPose(
        latest.posture_rad + (looked_up.posture_rad - warm.posture_rad),
        latest.rotation @ correction,
        latest.translation_m + (looked_up.translation_m - warm.translation_m),
    )
