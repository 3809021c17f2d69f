"""Tracking a whole source into an output folder: the job behind ``glove track``.

The folder gets

- ``poses.jsonl``: one CONVENTIONS.md record per input frame, in order, never
  skipping one, each line flushed as soon as its frame is done (an interrupted run
  keeps every finished frame);
- ``overlay.mp4`` (or a PNG sequence where the codec is missing): the color frames
  with the model's outline, skeleton and fingertips;
- ``hand.bvh``: the skeleton's motion for animation tools;
- ``timing.json``: per-stage median and p95 milliseconds, and the frame rate;
- ``hand.json``: the hand proportions the tracker ended with (estimated online over
  the first frames unless given), which ``--hand`` takes back.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from glovedb.proportions import save_proportions
from tracker.bvh import pose_arrays, write_bvh
from tracker.frames import Frame
from tracker.overlay import (
    TimingSummary,
    VideoWriter,
    draw_record,
    frames_folder,
    timing_summary,
)
from tracker.pipeline import Tracker
from tracker.sources import Source

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
        What was written where.
    """

    frames: int
    found: int
    tracking_seconds: float
    wall_seconds: float
    timing: TimingSummary
    outputs: dict[str, str]

    @property
    def fps(self) -> float:
        """Frames per second of tracking (reading and writing excluded)."""
        return self.frames / self.tracking_seconds if self.tracking_seconds > 0 else 0.0

    def as_dict(self) -> dict[str, Any]:
        return {
            "frames": self.frames,
            "hand_found": self.found,
            "fps": round(self.fps, 2),
            "wall_seconds": round(self.wall_seconds, 2),
            "timing_ms": self.timing.as_dict(),
            "outputs": self.outputs,
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


def track_source(
    source: Source,
    tracker: Tracker,
    out: str | Path,
    *,
    overlay: bool = True,
    bvh: bool = True,
    progress: Callable[[Iterator[Frame], int | None], Iterator[Frame]] | None = None,
) -> RunSummary:
    """Track every frame of ``source`` and write the outputs into ``out``.

    Parameters
    ----------
    source : Source
        From :func:`tracker.sources.open_source`.
    tracker : Tracker
    out : str or Path
        Output folder (created; existing outputs in it are replaced).
    overlay, bvh : bool
        Whether to write the overlay video and the BVH file.
    progress : callable, optional
        Wraps the frame iterator (e.g. a tqdm bar); gets the frame count if known.

    Returns
    -------
    RunSummary
    """
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    _remove_earlier_outputs(folder)
    started = time.perf_counter()
    fps = source.fps or 30.0
    frames: Iterator[Frame] = iter(source)
    if progress is not None:
        frames = progress(frames, source.n_frames)
    records: list[dict[str, Any]] = []
    tracking = 0.0
    outputs = {"poses": str(folder / POSES_FILE)}
    video = VideoWriter(folder / "overlay.mp4", fps) if overlay else None
    try:
        with open(folder / POSES_FILE, "w") as poses:
            for frame in frames:
                clock = time.perf_counter()
                result = tracker.track(frame)
                tracking += time.perf_counter() - clock
                record = result.as_record()
                poses.write(json.dumps(record) + "\n")
                poses.flush()
                records.append(record)
                if video is not None:
                    video.write(
                        draw_record(
                            frame.color, record, frame.intrinsics, mesh=tracker.mesh, fps=fps
                        )
                    )
    finally:
        if video is not None:
            video.close()
            if records:
                outputs["overlay"] = str(video.output_path)
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
    timing = timing_summary(r["timing_ms"] for r in records)
    summary = RunSummary(
        frames=len(records),
        found=sum(bool(r["hand_found"]) for r in records),
        tracking_seconds=tracking,
        wall_seconds=time.perf_counter() - started,
        timing=timing,
        outputs=outputs,
    )
    (folder / "timing.json").write_text(json.dumps(summary.as_dict(), indent=1))
    outputs["timing"] = str(folder / "timing.json")
    return summary
