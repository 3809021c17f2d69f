"""Tracking a whole source into an output folder: the job behind ``glove track``.

The folder gets

- ``poses.jsonl``: one docs/conventions.md record per input frame, in order, never
  skipping one, each line flushed as soon as its frame is done (an interrupted run
  keeps every finished frame);
- ``overlay.mp4`` (or a PNG sequence where the codec is missing): the color frames
  with the model's outline, skeleton and fingertips;
- ``hand.bvh``: the skeleton's motion for animation tools;
- ``timing.json``: per-stage median and p95 milliseconds, and the frame rate;
- ``hand.json``: the hand proportions the tracker ended with (estimated online over
  the first frames unless given), which ``--hand`` takes back.

Each frame's record also goes, the moment it exists, to the run's result sinks
(:mod:`tracker.outputs`: a live stream, an MCAP recording, the 3D viewer); a run
with sinks may have no folder at all.
"""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from glovedb.proportions import save_proportions
from tracker.bvh import pose_arrays, write_bvh
from tracker.frames import Frame
from tracker.outputs import ResultSink
from tracker.overlay import (
    TimingSummary,
    VideoWriter,
    draw_record,
    frames_folder,
    timing_summary,
)
from tracker.pipeline import PreparedFrame, Tracker
from tracker.prefetch import reader_for
from tracker.sources import LIVE_CAMERAS, Source

POSES_FILE = "poses.jsonl"
HAND_FILE = "hand.json"


@dataclass(frozen=True)
class RunSummary:
    """What a tracking run did.

    Attributes
    ----------
    frames : int
    found : int
        Frames with the hand found.
    tracking_seconds : float
        Time spent in :meth:`Tracker.track` only (no reading or writing).
    wall_seconds : float
        The whole run.
    timing : TimingSummary
        Per-stage statistics.
    outputs : dict of str to str
        What was written where (nothing without an output folder).
    interrupted : bool
        Stopped by Ctrl-C (the usual end of a camera run); the outputs are complete
        for the frames tracked until then.
    loop_seconds : float
        The frame loop: reading, tracking and writing each frame (setup and the
        end-of-run files excluded); ``frames / loop_seconds`` is the end-to-end rate.
    read_wait_seconds : float
        Time the loop waited for the next frame to be read and decoded: what reading
        ahead (:func:`tracker.prefetch.reader_for`) did not hide.
    """

    frames: int
    found: int
    tracking_seconds: float
    wall_seconds: float
    timing: TimingSummary
    outputs: dict[str, str]
    interrupted: bool = False
    loop_seconds: float = 0.0
    read_wait_seconds: float = 0.0

    @property
    def fps(self) -> float:
        """Frames per second of tracking (reading and writing excluded)."""
        return self.frames / self.tracking_seconds if self.tracking_seconds > 0 else 0.0

    @property
    def end_to_end_fps(self) -> float:
        """Frames per second of the whole loop: reading, tracking and writing."""
        return self.frames / self.loop_seconds if self.loop_seconds > 0 else 0.0

    @property
    def read_wait_ms(self) -> float:
        """Mean milliseconds per frame the loop waited for its input."""
        return 1000.0 * self.read_wait_seconds / max(self.frames, 1)

    def as_dict(self) -> dict[str, Any]:
        return {
            "frames": self.frames,
            "hand_found": self.found,
            "fps": round(self.fps, 2),
            "end_to_end_fps": round(self.end_to_end_fps, 2),
            "read_wait_ms_per_frame": round(self.read_wait_ms, 2),
            "wall_seconds": round(self.wall_seconds, 2),
            "timing_ms": self.timing.as_dict(),
            "outputs": self.outputs,
            "interrupted": self.interrupted,
        }


def _remove_earlier_outputs(folder: Path) -> None:
    """Delete what an earlier run wrote into ``folder``, so that no output of it (an
    overlay or BVH this run does not write) passes for this run's."""
    for name in (POSES_FILE, "overlay.mp4", "hand.bvh", "timing.json", HAND_FILE):
        (folder / name).unlink(missing_ok=True)
    frames = frames_folder(folder / "overlay.mp4")  # VideoWriter's PNG fallback
    if frames.is_dir():
        for path in frames.glob("[0-9]*.png"):
            path.unlink()
        if not any(frames.iterdir()):
            frames.rmdir()


class IdleTime:
    """Runs the tracker's deferred work (the periodic lookup's steps,
    :mod:`tracker.background`) while the frame loop would wait for its next frame, so
    that the frame that collects that work finds it done.

    Two kinds of wait are known: a reader preparing frames ahead that has none ready
    (``ready``), and a camera whose next frame is due one period after the last
    arrived, when the loop had to wait for that one (``fps``; the camera gives no sign
    of a frame waiting, so a step runs only while the longest step so far still ends
    before the frame is due). The poses do not change, only where the time goes; a
    frame that arrives during a step waits for it (not counted in its ``total``).

    Parameters
    ----------
    ready : callable or None
        Whether the reader has the next frame.
    fps : float or None
        The camera's frame rate (None: not a camera).
    """

    def __init__(self, ready: Callable[[], bool] | None, fps: float | None) -> None:
        self._ready = ready
        self._period = None if fps is None or fps <= 0 else 1.0 / fps
        self._due: float | None = None
        self._longest = 0.0

    def arrived(self, wait_s: float) -> None:
        """A frame came after the loop waited ``wait_s`` for it."""
        self._due = None
        if self._period is not None and wait_s > 0.001:  # the camera sets the pace
            self._due = time.perf_counter() + self._period

    def run(self, tracker: Tracker) -> float:
        """Run deferred steps until the next frame is due or none are left; the
        milliseconds they took."""
        spent = 0.0
        while not self._frame_due():
            ran = tracker.run_deferred_step()
            if ran == 0.0:
                break
            spent += ran
            self._longest = max(self._longest, ran / 1000.0)
        return spent

    def _frame_due(self) -> bool:
        if self._ready is not None:
            return self._ready()
        return self._due is None or time.perf_counter() + self._longest >= self._due


def track_source(
    source: Source,
    tracker: Tracker,
    out: str | Path | None,
    *,
    overlay: bool = True,
    bvh: bool = True,
    sinks: Sequence[ResultSink] = (),
    read_ahead: int = 2,
    progress: Callable[[Iterator[Any], int | None], Iterator[Any]] | None = None,
) -> RunSummary:
    """Track every frame of ``source``, write the outputs into ``out`` and hand each
    frame's record to ``sinks``. Where the loop would wait for its next frame, the
    tracker's deferred lookup steps use the time (:class:`IdleTime`).

    Parameters
    ----------
    source : Source
        From :func:`tracker.sources.open_source`.
    tracker : Tracker
    out : str or Path or None
        Output folder (created; existing outputs in it are replaced); None writes no
        files (the sinks are the outputs).
    overlay, bvh : bool
        Whether to write the overlay video and the BVH file.
    sinks : sequence of ResultSink
        Each gets every frame and its record as soon as it is tracked; the caller
        opens and closes them.
    read_ahead : int
        Frames of a folder or recording read, decoded and prepared (classified and
        segmented, :meth:`Tracker.prepare`) ahead in a child process (a thread where
        the platform cannot fork; :func:`tracker.prefetch.reader_for`) while one is tracked
        (0: in turn). A camera is always read in turn, so that the tracker gets its
        newest frame, not a queued one.
    progress : callable, optional
        Wraps the frame iterator (e.g. a tqdm bar); gets the frame count if known.

    Returns
    -------
    RunSummary
    """
    folder = None if out is None else Path(out)
    started = time.perf_counter()
    fps = source.fps or 30.0
    source_frames: Iterator[Frame] = iter(source)
    frames: Iterator[Frame | PreparedFrame] = source_frames
    reader = None
    if read_ahead > 0 and source.kind not in LIVE_CAMERAS:
        frames = reader = reader_for(map(tracker.prepare, source_frames), depth=read_ahead)
    if progress is not None:
        frames = iter(progress(frames, source.n_frames))
    records: list[dict[str, Any]] = []
    tracking = 0.0
    outputs: dict[str, str] = {}
    video = None
    with contextlib.ExitStack() as files:
        if reader is not None:
            files.callback(reader.close)
        poses = None
        if folder is not None:
            folder.mkdir(parents=True, exist_ok=True)
            _remove_earlier_outputs(folder)
            poses = files.enter_context(open(folder / POSES_FILE, "w"))
            outputs["poses"] = str(folder / POSES_FILE)
            if overlay:
                video = files.enter_context(
                    contextlib.closing(VideoWriter(folder / "overlay.mp4", fps))
                )
        interrupted, waited = False, 0.0
        live = source.kind in LIVE_CAMERAS
        idle = IdleTime(reader.ready if reader is not None else None, fps if live else None)
        loop_started = time.perf_counter()
        try:
            while True:
                between = idle.run(tracker)
                clock = time.perf_counter()
                item = next(frames, None)
                wait = time.perf_counter() - clock
                idle.arrived(wait)
                waited += wait
                if item is None:
                    break
                frame = item.frame if isinstance(item, PreparedFrame) else item
                clock = time.perf_counter()
                result = tracker.track(item)
                tracking += time.perf_counter() - clock
                record = result.as_record()
                # The time this frame's input kept the loop waiting (not in "total").
                record["timing_ms"]["read"] = round(1000.0 * wait, 3)
                if between > 0.0:
                    record["timing_ms"]["between"] = round(between, 3)
                if poses is not None:
                    poses.write(json.dumps(record) + "\n")
                    poses.flush()
                for sink in sinks:
                    sink.write(frame, record)
                records.append(record)
                if video is not None:
                    video.write(
                        draw_record(
                            frame.color, record, frame.intrinsics, mesh=tracker.mesh, fps=fps
                        )
                    )
        except KeyboardInterrupt:
            interrupted = True  # the outputs below are still written for what was tracked
        timing = (time.perf_counter() - loop_started, waited)
    if video is not None and records:
        outputs["overlay"] = str(video.output_path)
    if folder is None:
        return _summary(records, tracking, started, outputs, interrupted, timing)
    if bvh and any(r["hand_found"] for r in records):
        arrays = pose_arrays(records)
        path = write_bvh(
            folder / "hand.bvh", arrays.postures_rad, arrays.rotations, arrays.translations_m,
            fps=fps, skeleton=tracker.skeleton, found=arrays.found,
        )  # fmt: skip
        outputs["bvh"] = str(path)
    outputs["hand"] = str(
        save_proportions(
            folder / HAND_FILE,
            tracker.proportions,
            extra={
                "source": "given" if tracker.settings.hand_proportions else "estimated online",
                "complete": not tracker.calibrating,
            },
        )
    )
    summary = _summary(records, tracking, started, outputs, interrupted, timing)
    (folder / "timing.json").write_text(json.dumps(summary.as_dict(), indent=1))
    outputs["timing"] = str(folder / "timing.json")
    return summary


def _summary(
    records: list[dict[str, Any]],
    tracking_s: float,
    started: float,
    outputs: dict[str, str],
    interrupted: bool,
    loop_and_wait_s: tuple[float, float],
) -> RunSummary:
    return RunSummary(
        frames=len(records),
        found=sum(bool(r["hand_found"]) for r in records),
        tracking_seconds=tracking_s,
        wall_seconds=time.perf_counter() - started,
        timing=timing_summary(r["timing_ms"] for r in records),
        outputs=outputs,
        interrupted=interrupted,
        loop_seconds=loop_and_wait_s[0],
        read_wait_seconds=loop_and_wait_s[1],
    )
