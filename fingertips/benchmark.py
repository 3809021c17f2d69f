"""End-to-end fingertip detection speed: the job behind ``glove bench fingertips``.

Times what ``glove fingertips detect`` makes a user wait for: opening the model, the
first frame's detections, then every frame of the source read and decoded ahead in a
thread (:class:`tracker.prefetch.Prefetch`, as ``glove bench track`` does), detected
and turned into its JSON record. Per frame it also times the detector's stages,
exclusive of one another:

=============  ==========================================================================
stage          what
=============  ==========================================================================
``read``       waiting for the next decoded frame (what reading ahead did not hide)
``hand``       the hand depth (:func:`fingertips.detect.hand_depth`)
``forest``     probe image, compiled forest descent, leaf predictions and votes
``peaks``      mean-shift of the votes (:func:`fingertips.voting.find_peaks`)
``geodesic``   geodesic candidates (:func:`fingertips.geodesic.geodesic_candidates`):
               first, on the frame's thread, when the network's crop centre needs
               them (the shipped model); else in a worker thread beside the forest
``describe``   merging the candidates and their verifier features
``verify``     the peak verifier (:func:`fingertips.verify.verify_peaks`)
``network``    the hand crop and the heatmap network's passes (onnxruntime), in the
               network's thread beside the stages above
``heatmap``    the rest of the heatmap stage: the heat peaks, their features and verifier
``other``      the rest of a frame's detection and its record (checks, waiting for the
               geodesic stage and the network, calibration)
``detect``     all of a frame's detection and record: every stage but ``read``,
               ``network`` and a ``geodesic`` stage in its worker (which overlap
               them), and ``other``
=============  ==========================================================================

The stages are timed by wrapping, for the run only, the functions
:func:`fingertips.detect.detect_fingertips` calls (the originals are put back after),
so the timed code is the command's own; each wrapper adds about a microsecond.
The first frame, which loads the compiled kernels and the network, counts in
``first_detection_s`` only: the rates and the stage statistics are of the frames after it.
"""

from __future__ import annotations

import contextlib
import functools
import importlib
import json
import os
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from tracker.benchmark import machine, process_age_s
from tracker.overlay import TimingSummary, timing_summary

STAGES: tuple[tuple[str, str, str], ...] = (
    ("hand", "fingertips.detect", "hand_depth"),
    ("forest", "fingertips.detect", "_hand_votes"),
    ("peaks", "fingertips.detect", "find_peaks"),
    ("geodesic", "fingertips.detect", "geodesic_candidates"),
    ("describe", "fingertips.detect", "merge_candidates"),
    ("describe", "fingertips.detect", "candidate_features"),
    ("verify", "fingertips.detect", "verify_peaks"),
    ("heatmap", "fingertips.detect", "heatmap_peaks"),
    ("network", "fingertips.heatmap", "hand_heatmaps"),
)
"""``(stage, module, attribute)``: the functions timed as each stage, nested calls excluded."""


@dataclass(frozen=True)
class DetectionBenchmark:
    """What :func:`benchmark_detection` measured.

    Attributes
    ----------
    frames : int
        Frames detected, the first included.
    detections : int
        Fingertips reported over all frames.
    startup_s : float
        Opening the source and the model.
    first_detection_s : float
        From the start to the first frame's record (its reading, the compiled kernels'
        loading and the network's session included).
    first_detection_since_launch_s : float or None
        From the launch of this process (Python's start and imports included) to the
        first frame's record; None where the system does not tell (not Linux).
    loop_seconds : float
        From the first frame's record to the last one's: the frames after the first,
        read, detected and recorded.
    read_ahead : int
        Frames read ahead in a thread (0: read in turn).
    timing : TimingSummary
        Per-stage milliseconds of the frames after the first (module docstring).
    """

    frames: int
    detections: int
    startup_s: float
    first_detection_s: float
    first_detection_since_launch_s: float | None
    loop_seconds: float
    read_ahead: int
    timing: TimingSummary

    @property
    def end_to_end_fps(self) -> float:
        """Frames per second after the first: reading, detection and records."""
        return (self.frames - 1) / self.loop_seconds if self.loop_seconds > 0 else 0.0

    def as_dict(self) -> dict[str, Any]:
        stages = self.timing.as_dict()
        since_launch = self.first_detection_since_launch_s
        return {
            "frames": self.frames,
            "detections": self.detections,
            "startup_s": round(self.startup_s, 3),
            "first_detection_s": round(self.first_detection_s, 3),
            "first_detection_since_launch_s": (
                None if since_launch is None else round(since_launch, 3)
            ),
            "end_to_end_fps": round(self.end_to_end_fps, 2),
            "end_to_end_ms_per_frame": (
                round(1000.0 / self.end_to_end_fps, 2) if self.end_to_end_fps > 0 else None
            ),
            "detect_ms_mean": round(stages["detect"]["mean"], 3) if "detect" in stages else None,
            "read_ahead": self.read_ahead,
            "stages_ms": stages,
            "machine": machine(),
        }


def benchmark_detection(
    source: str | os.PathLike[str],
    model: str | os.PathLike[str] | None = None,
    *,
    read_ahead: int = 2,
) -> DetectionBenchmark:
    """Detect fingertips in every frame of ``source`` and time it.

    Parameters
    ----------
    source : str or path
        What :func:`fingertips.depth_input.open_depth_source` opens: an RGB-D folder
        (only ``depth/`` and ``intrinsic.json`` are needed), a ``.bag`` recording.
    model : str or path, optional
        Model file (.npz); default the shipped model, with its recorded settings.
    read_ahead : int
        Frames read and decoded ahead in a thread (0: read in turn).

    Returns
    -------
    DetectionBenchmark

    Raises
    ------
    ValueError
        For a source that cannot be opened, a live camera (its frames do not end), a
        source without frames or a negative ``read_ahead``.
    """
    from fingertips.depth_input import open_depth_source
    from fingertips.detector import FingertipDetector
    from tracker.prefetch import Prefetch

    if read_ahead < 0:
        raise ValueError(f"read_ahead: expected >= 0, got {read_ahead}")
    started = time.perf_counter()
    launched = process_age_s()
    depth_source = open_depth_source(source)
    if depth_source.live:
        raise ValueError(f"{depth_source.description}: a camera's frames do not end")
    detector = FingertipDetector(model)
    startup = time.perf_counter() - started
    frames: Iterator[Any] = iter(depth_source)
    timings: list[dict[str, float]] = []
    detections, first, loop_started = 0, None, 0.0
    clock = StageClock()
    with contextlib.ExitStack() as stack:
        if read_ahead > 0:
            frames = stack.enter_context(Prefetch(frames, depth=read_ahead))
        stack.enter_context(timed_stages(clock))
        while True:
            waiting = time.perf_counter()
            frame = next(frames, None)
            read = time.perf_counter() - waiting
            if frame is None:
                break
            clock.start_frame()
            detecting = time.perf_counter()
            record = detector.record(frame.frame, frame.depth_m, frame.intrinsics)
            json.dumps(record)
            done = time.perf_counter()
            detections += len(record["fingertips"])
            if first is None:
                first, loop_started = done - started, done
            else:
                timings.append(clock.frame_ms(read, done - detecting))
        loop_seconds = time.perf_counter() - loop_started
    if first is None:
        raise ValueError(f"{depth_source.description}: no frames")
    return DetectionBenchmark(
        frames=len(timings) + 1,
        detections=detections,
        startup_s=startup,
        first_detection_s=first,
        first_detection_since_launch_s=None if launched is None else launched + first,
        loop_seconds=loop_seconds if timings else 0.0,
        read_ahead=read_ahead,
        timing=timing_summary(timings),
    )


class StageClock:
    """Exclusive time per stage of one frame, from wrapped functions (:meth:`wrap`).

    A wrapped call's time, less that of the wrapped calls nested in it on its thread,
    is added to its stage. Calls on another thread than the frame's (the heatmap
    network's) run beside the frame's own stages and are not subtracted from them.
    """

    def __init__(self) -> None:
        self._seconds: dict[str, float] = {}
        self._beside: set[str] = set()
        self._frame_thread = threading.get_ident()
        self._nested = threading.local()
        self._lock = threading.Lock()

    def start_frame(self) -> None:
        """Forget the previous frame's times; the calling thread is the frame's."""
        with self._lock:
            self._seconds = {}
            self._beside = set()
            self._frame_thread = threading.get_ident()

    def wrap(self, stage: str, function: Callable[..., Any]) -> Callable[..., Any]:
        """``function`` timed as ``stage``."""

        @functools.wraps(function)
        def timed(*args: Any, **kwargs: Any) -> Any:
            nested = self._nested.__dict__.setdefault("stack", [])
            nested.append(0.0)
            begun = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                elapsed = time.perf_counter() - begun
                inner = nested.pop()
                if nested:
                    nested[-1] += elapsed
                with self._lock:
                    self._seconds[stage] = self._seconds.get(stage, 0.0) + elapsed - inner
                    if threading.get_ident() != self._frame_thread:
                        self._beside.add(stage)

        return timed

    def frame_ms(self, read_s: float, detect_s: float) -> dict[str, float]:
        """The frame's ``{stage: ms}``: ``read``, every stage, ``other`` and ``detect``.

        ``other`` is ``detect_s`` less the stages timed on the frame's thread.
        """
        with self._lock:
            stages = {name: 0.0 for name, _, _ in STAGES}
            stages.update(self._seconds)
            own = sum(s for name, s in stages.items() if name not in self._beside)
        return {
            "read": 1000.0 * read_s,
            **{name: 1000.0 * s for name, s in stages.items()},
            "other": 1000.0 * max(detect_s - own, 0.0),
            "detect": 1000.0 * detect_s,
        }


@contextlib.contextmanager
def timed_stages(clock: StageClock) -> Iterator[None]:
    """Within the block, the functions of :data:`STAGES` report to ``clock``."""
    patched: list[tuple[Any, str, Any]] = []
    try:
        for stage, name, attribute in STAGES:
            module = importlib.import_module(name)
            original = getattr(module, attribute)
            patched.append((module, attribute, original))
            setattr(module, attribute, clock.wrap(stage, original))
        yield
    finally:
        for module, attribute, original in reversed(patched):
            setattr(module, attribute, original)
