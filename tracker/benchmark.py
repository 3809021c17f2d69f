"""End-to-end tracking speed: the job behind ``glove bench track``.

Times what a user waits for, not an inner loop: opening the database and the hand
model (startup), the first pose, and the whole frame loop with reading and decoding
the input, tracking and the per-stage latency. The figures the README states come
from here.
"""

from __future__ import annotations

import os
import platform
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tracker.pipeline import Tracker, TrackerSettings
from tracker.run import RunSummary, track_source
from tracker.sources import open_source


@dataclass(frozen=True)
class TrackingBenchmark:
    """What :func:`benchmark_tracking` measured.

    Attributes
    ----------
    run : RunSummary
        The tracking run: frames, hands found, end-to-end and tracking frames/s, the
        wait for input, per-stage timing.
    startup_s : float
        Opening the database and preparing the hand model (``Tracker(...)``).
    first_pose_s : float
        From the start (before ``Tracker(...)``) to the first frame's result.
    read_ahead : int
        Frames read ahead while one is tracked (0: read in turn).
    first_pose_since_launch_s : float or None
        From the launch of this process (Python's start and imports included) to the
        first frame's result; None where the system does not tell (not Linux).
    """

    run: RunSummary
    startup_s: float
    first_pose_s: float
    read_ahead: int
    first_pose_since_launch_s: float | None = None

    def as_dict(self) -> dict[str, Any]:
        run = self.run
        since_launch = self.first_pose_since_launch_s
        return {
            "frames": run.frames,
            "hand_found": run.found,
            "startup_s": round(self.startup_s, 3),
            "first_pose_s": round(self.first_pose_s, 3),
            "first_pose_since_launch_s": None if since_launch is None else round(since_launch, 3),
            "end_to_end_fps": round(run.end_to_end_fps, 2),
            "tracking_fps": round(run.fps, 2),
            "read_wait_ms_per_frame": round(run.read_wait_ms, 2),
            "read_ahead": self.read_ahead,
            "stages_ms": run.timing.as_dict(),
            "machine": machine(),
        }


def benchmark_tracking(
    source: str | Path,
    database: str | Path,
    *,
    settings: TrackerSettings | None = None,
    read_ahead: int = 2,
) -> TrackingBenchmark:
    """Track every frame of ``source`` with ``database`` and time it.

    Parameters
    ----------
    source : str or Path
        What :func:`tracker.sources.open_source` opens (an RGB-D folder, a ``.bag``).
    database : str or Path
    settings : TrackerSettings, optional
    read_ahead : int
        See :func:`tracker.run.track_source`.

    Returns
    -------
    TrackingBenchmark
    """
    started = time.perf_counter()
    launched = process_age_s()
    frames = open_source(source)
    first: list[float] = []

    def note_first(items: Any, total: int | None) -> Any:
        for item in items:
            yield item
            if not first:
                first.append(time.perf_counter() - started)

    with Tracker(database, settings=settings) as tracker:
        startup = time.perf_counter() - started
        summary = track_source(frames, tracker, None, read_ahead=read_ahead, progress=note_first)
    return TrackingBenchmark(
        run=summary,
        startup_s=startup,
        first_pose_s=first[0] if first else float("nan"),
        read_ahead=read_ahead,
        first_pose_since_launch_s=(None if launched is None or not first else launched + first[0]),
    )


def process_age_s() -> float | None:
    """Seconds since this process was launched (Linux ``/proc``), else None."""
    try:
        fields = Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()
        started_ticks = int(fields[19])  # field 22 of stat(5): starttime, in clock ticks
        uptime_s = float(Path("/proc/uptime").read_text().split()[0])
        return uptime_s - started_ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


def machine() -> dict[str, Any]:
    """The processor and core count, to state beside the figures."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu": model, "cores": os.cpu_count()}
