"""The database lookup off the frame: a second start found in steps over the next
frames.

While the hand is tracked, the tracker still looks it up in the database every
``reinit_every`` frames, fits from the looked-up start and keeps the lower energy: on
the rendered Tr1-Tr5 sequences this second start wins about half the time and takes
0-0.5 degrees off the mean posture error (0.5 on Tr3). Within one frame it costs the
lookup, the ICP and a second fit, about 16 ms on a laptop-class core besides the
frame's own 10: those frames would set the 99th percentile of the latency.

:class:`DeferredLookup` spreads that work over the frames that follow, in the tracking
thread: the job is a generator that yields between its steps (the lookup, the ICP,
each iteration of the fit: :func:`tracker.generative.fit.fit_frame_steps`;
:meth:`tracker.pipeline.Tracker` writes it), each frame runs one step, and the frame
``delay_frames`` later collects the result, running whatever steps are left. So a
frame does its own work and one step (or, when collecting early, the steps left), and
a run gives the same poses on every machine. When the looked-up fit explained its frame with
a lower energy than the warm fit of that frame did, the tracker's next start carries
the difference (:func:`carried_start`): the lookup's correction applied to the pose
the warm fits have reached since.

Until issue 22 a worker thread ran the job at a lower priority and the collecting
frame waited for it. On a 2-core machine tracking a recording, the reader thread
(decoding, classification, segmentation) keeps the second core busy, so the worker got
little of either core and the collecting frames waited up to 17 ms
(`glove bench track` on Tr3: 8 of 241 frames over 25 ms were such frames, and the
frames beside the job slowed too).

A lookup that the warm fit's failure asks for (no hand, a fit that fails the quality
test) is not deferred: that frame has no other answer; nor is one that a suspect fit
asks for (more model outside the hand than usual, ``relook_outside``), where a late
correction cost a ball in front of the hand and a dim cluttered room accuracy.
"""

from __future__ import annotations

import time
from collections.abc import Generator
from dataclasses import dataclass
from typing import Generic, TypeVar

from tracker.generative.model import HandPose

T = TypeVar("T")
W = TypeVar("W")

Job = Generator[None, None, T]
"""A deferred job: yields between its steps, returns its result."""


@dataclass
class _Pending(Generic[W, T]):
    frame_index: int
    warm: W
    job: Job[T]
    done: bool = False
    result: T | None = None


class DeferredLookup(Generic[W, T]):
    """At most one job at a time, run one step per frame, collected at a fixed frame.

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
        self._pending: _Pending[W, T] | None = None

    @property
    def busy(self) -> bool:
        """Whether a job waits to be collected."""
        return self._pending is not None

    @property
    def has_steps(self) -> bool:
        """Whether a job has steps left for :meth:`advance`."""
        return self._pending is not None and not self._pending.done

    def submit(self, frame_index: int, warm: W, job: Job[T]) -> None:
        """Take ``job`` for frame ``frame_index`` (whose warm fit was ``warm``); none of
        it runs until :meth:`advance` or :meth:`collect`.

        Raises
        ------
        RuntimeError
            When a job is still pending.
        """
        if self._pending is not None:
            raise RuntimeError("a deferred lookup is still pending")
        self._pending = _Pending(frame_index, warm, job)

    def advance(self) -> float:
        """Run the pending job's next step, if it has one left; the milliseconds it took
        (0 when nothing ran). A job's exception is raised here."""
        pending = self._pending
        if pending is None or pending.done:
            return 0.0
        started = time.perf_counter()
        try:
            self._step(pending)
        except BaseException:
            self._pending = None
            raise
        return (time.perf_counter() - started) * 1000.0

    def collect(self, frame_index: int) -> tuple[W, T] | None:
        """The warm fit and the result of the job due at ``frame_index`` (its steps
        left run first), or None when none is due. A job's exception is raised here."""
        pending = self._pending
        if pending is None or frame_index < pending.frame_index + self.delay_frames:
            return None
        self._pending = None
        while not pending.done:
            self._step(pending)
        return pending.warm, pending.result  # type: ignore[return-value]

    def discard(self) -> None:
        """Forget the pending job; its steps left never run."""
        if self._pending is not None:
            self._pending.job.close()
        self._pending = None

    @staticmethod
    def _step(pending: _Pending[W, T]) -> None:
        try:
            next(pending.job)
        except StopIteration as finished:
            pending.done, pending.result = True, finished.value


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
