"""The geodesic candidate stage alone on frames with known fingertips.

A check of :mod:`fingertips.geodesic` on rendered examples
(:func:`fingertips.data.generate_examples`): how many visible fingertips have a
finger candidate within 15 mm, and how many candidates a frame gets, per distance.
The hand is segmented as the detector's first step does, without a model: the
working range and the depth band behind the nearest surface
(:func:`segment_nearest`).
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fingertips.evaluation import match_within
from fingertips.features import mask_depth_range, nearest_band
from fingertips.geodesic import DEFAULT_GEODESIC, GeodesicConfig, geodesic_candidates
from fingertips.heatmap import HAND_BAND_M, HAND_DEPTH_RANGE_M

if TYPE_CHECKING:
    from fingertips.data import FingertipExample

DISTANCE_BANDS_M = (0.3, 0.6, 0.9, 1.25)
"""Edges of the distance bands scores are reported in, metres."""


def segment_nearest(depth_m: ArrayLike) -> NDArray[np.float32]:
    """The detector's hand pixels without a model: working range, then the nearest band.

    Parameters
    ----------
    depth_m : (H, W) float
        Metres, 0 where missing.

    Returns
    -------
    (H, W) float32
        0 outside.
    """
    near, far = HAND_DEPTH_RANGE_M
    return nearest_band(mask_depth_range(depth_m, near_m=near, far_m=far), band_m=HAND_BAND_M)


@dataclass(frozen=True)
class CandidateScores:
    """Per-frame counts of :func:`score_candidates`.

    Attributes
    ----------
    distance_m : (F,) float64
        Mean depth of the hand's 21 keypoints, metres.
    n_tips : (F,) int64
        Visible fingertips.
    n_found : (F,) int64
        Visible fingertips matched to a finger candidate within the gate (one-to-one).
    n_fingers : (F,) int64
        Candidates flagged as fingers.
    n_candidates : (F,) int64
        All candidates.
    seconds : (F,) float64
        Time of :func:`fingertips.geodesic.geodesic_candidates`, seconds.
    """

    distance_m: NDArray[np.float64]
    n_tips: NDArray[np.int64]
    n_found: NDArray[np.int64]
    n_fingers: NDArray[np.int64]
    n_candidates: NDArray[np.int64]
    seconds: NDArray[np.float64]

    def by_band(self, edges_m: Sequence[float] = DISTANCE_BANDS_M) -> list[dict[str, float]]:
        """Recall, candidates per frame and time in each band ``[edges_m[i], edges_m[i+1])``.

        Returns
        -------
        list of dict
            Per band: ``low_m``, ``high_m``, ``frames``, ``tips``, ``recall``,
            ``fingers_per_frame``, ``extra_per_frame`` (finger candidates matching no
            tip), ``candidates_per_frame`` and ``median_ms``; NaN where undefined.
        """
        rows = []
        for low, high in itertools.pairwise(edges_m):
            inside = (self.distance_m >= low) & (self.distance_m < high)
            tips = int(self.n_tips[inside].sum())
            rows.append(
                {
                    "low_m": float(low),
                    "high_m": float(high),
                    "frames": int(inside.sum()),
                    "tips": tips,
                    "recall": int(self.n_found[inside].sum()) / tips if tips else math.nan,
                    "fingers_per_frame": _mean(self.n_fingers[inside]),
                    "extra_per_frame": _mean(self.n_fingers[inside] - self.n_found[inside]),
                    "candidates_per_frame": _mean(self.n_candidates[inside]),
                    "median_ms": 1000 * float(np.median(self.seconds[inside]))
                    if inside.any()
                    else math.nan,
                }
            )
        return rows


def _mean(values: NDArray) -> float:
    return float(values.mean()) if values.size else math.nan


def score_candidates(
    examples: Iterable[FingertipExample],
    *,
    config: GeodesicConfig = DEFAULT_GEODESIC,
    gate_m: float = 0.015,
) -> CandidateScores:
    """Run the stage on examples with known fingertips and count what it finds.

    Parameters
    ----------
    examples : iterable of FingertipExample
        Depth, intrinsics, visible tips (NaN when hidden) and keypoints, such as
        :func:`fingertips.data.generate_examples` yields.
    config : GeodesicConfig
    gate_m : float
        Largest 3D distance of a found tip from its finger candidate, metres.

    Returns
    -------
    CandidateScores
    """
    counts: dict[str, list[float]] = {
        "distance_m": [], "n_tips": [], "n_found": [], "n_fingers": [], "n_candidates": [],
        "seconds": [],
    }  # fmt: skip
    for example in examples:
        hand = segment_nearest(example.depth_m)
        start = time.perf_counter()
        candidates = geodesic_candidates(hand, example.intrinsics, config=config)
        counts["seconds"].append(time.perf_counter() - start)
        fingers = candidates.fingers()
        tips = example.tips_m[np.isfinite(example.tips_m).all(axis=1)]
        gaps = np.linalg.norm(fingers.points_m[:, None].astype(np.float64) - tips[None], axis=2)
        counts["n_found"].append(len(match_within(gaps, gate_m)[0]))
        counts["n_tips"].append(len(tips))
        counts["n_fingers"].append(len(fingers))
        counts["n_candidates"].append(len(candidates))
        counts["distance_m"].append(float(example.keypoints_m[:, 2].mean()))
    return CandidateScores(
        distance_m=np.array(counts["distance_m"], np.float64),
        n_tips=np.array(counts["n_tips"], np.int64),
        n_found=np.array(counts["n_found"], np.int64),
        n_fingers=np.array(counts["n_fingers"], np.int64),
        n_candidates=np.array(counts["n_candidates"], np.int64),
        seconds=np.array(counts["seconds"], np.float64),
    )
