"""Calibrated detection confidences: how often a detection with a given score is right.

The verifiers' probabilities (:mod:`fingertips.verify`, the heatmap's boosted trees)
rank candidates well but understate how often a detection is right: on validation
frames, detections with a verifier probability of 0.5-0.6 lie within 15 mm of an
annotated tip about three times in four. A :class:`ConfidenceMap` turns such a raw
score into the share of detections with that score that match an annotated tip
(one-to-one within 15 mm, as ``glove fingertips eval`` scores): a non-decreasing
piecewise-linear function through breakpoints, fitted by isotonic regression
(:func:`fit_isotonic`, pool-adjacent-violators) on synthetic frames that neither
the verifiers were trained on nor the thresholds were chosen on
(:mod:`fingertips.calibration_training`). A :class:`Calibration` holds one map per
kind of score: ``"verifier"`` (the peak verifier's probability, of forest and
geodesic detections) and ``"heatmap"`` (the heatmap verifier's).

:func:`reliability_table` scores confidences against the truth: per bin of
confidence the count, the mean confidence and the observed share correct, and the
expected calibration error. Numpy only; the model file stores the maps as plain
float arrays (:mod:`fingertips.forest`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array, check_choice

ScoreKind = Literal["verifier", "heatmap"]
SCORE_KINDS: tuple[ScoreKind, ...] = ("verifier", "heatmap")
"""The calibrated scores: the peak verifier's probability, the heatmap verifier's."""

SOURCE_SCORE: Mapping[str, ScoreKind] = {
    "forest": "verifier",
    "geodesic": "verifier",
    "heatmap": "heatmap",
}
"""Which score a detection of each ``Detection.source`` carries in ``tip_probability``."""

RELIABILITY_EDGES: tuple[float, ...] = tuple(k / 10 for k in range(11))
"""Bin edges of :func:`reliability_table`: ten bins of 0.1 (the last one includes 1)."""


@dataclass(frozen=True)
class ConfidenceMap:
    """A non-decreasing map from a raw score to a probability.

    Attributes
    ----------
    scores : (B,) float64
        Breakpoints, non-decreasing (a score may repeat: a step).
    probabilities : (B,) float64
        The probability at each breakpoint, non-decreasing, in [0, 1]. Between
        breakpoints the map is linear; below the first and above the last it is
        constant.
    """

    scores: NDArray[np.float64]
    probabilities: NDArray[np.float64]

    def __post_init__(self) -> None:
        scores = as_array("scores", self.scores, (None,), np.float64, kind="fiu", finite=True)
        probability = as_array(
            "probabilities", self.probabilities, (scores.size,), np.float64, kind="fiu", finite=True
        )
        if scores.size == 0:
            raise ValueError("scores: expected at least one breakpoint")
        if np.any(np.diff(scores) < 0) or np.any(np.diff(probability) < 0):
            raise ValueError("scores, probabilities: expected both non-decreasing")
        if probability[0] < 0 or probability[-1] > 1:
            raise ValueError("probabilities: expected values in [0, 1]")
        object.__setattr__(self, "scores", scores)
        object.__setattr__(self, "probabilities", probability)

    def __call__(self, score: ArrayLike) -> NDArray[np.float64]:
        """The probabilities of raw scores (any shape), float64."""
        values = as_array("score", score, None, np.float64, kind="fiu")
        return np.interp(values, self.scores, self.probabilities)


def fit_isotonic(
    scores: ArrayLike, correct: ArrayLike, *, clip_to_sample: bool = True
) -> ConfidenceMap:
    """The isotonic regression of ``correct`` on ``scores`` (pool adjacent violators).

    Among non-decreasing step functions of the score, the one with the least squared
    error to the 0/1 outcomes: each step's value is the share correct of the samples
    it covers. Equal scores share one value. Each step becomes two breakpoints (its
    smallest and largest score), so the map is linear between steps, as
    scikit-learn's ``IsotonicRegression`` predicts.

    Parameters
    ----------
    scores : (N,) float
        Raw scores, e.g. verifier probabilities.
    correct : (N,) bool
        Whether each sample was right.
    clip_to_sample : bool
        Keep the probabilities within ``[1 / (N + 1), N / (N + 1)]``: N samples cannot
        show that a score is never (or always) right.

    Returns
    -------
    ConfidenceMap
    """
    x = as_array("scores", scores, (None,), np.float64, kind="fiu", finite=True)
    y = as_array("correct", correct, (x.size,), np.float64, kind="biuf")
    if x.size == 0:
        raise ValueError("scores: expected at least one sample")
    if np.any((y != 0) & (y != 1)):
        raise ValueError("correct: expected 0/1 outcomes")
    order = np.argsort(x, kind="stable")
    x, y = x[order], y[order]
    unique, first = np.unique(x, return_index=True)
    counts = np.diff(np.append(first, x.size)).astype(np.float64)
    sums = np.add.reduceat(y, first)
    # Pool adjacent violators over the distinct scores: a stack of blocks.
    block_sum: list[float] = []
    block_count: list[float] = []
    block_start: list[int] = []
    for k in range(unique.size):
        block_sum.append(float(sums[k]))
        block_count.append(float(counts[k]))
        block_start.append(k)
        while len(block_sum) > 1 and (
            block_sum[-2] / block_count[-2] >= block_sum[-1] / block_count[-1]
        ):
            merged_sum, merged_count = block_sum.pop(), block_count.pop()
            block_sum[-1] += merged_sum
            block_count[-1] += merged_count
            block_start.pop()
    values = np.array(block_sum) / np.array(block_count)
    if clip_to_sample:
        values = np.clip(values, 1.0 / (x.size + 1), x.size / (x.size + 1))
    starts = np.array(block_start, dtype=np.intp)
    ends = np.append(starts[1:], unique.size) - 1
    breakpoints = np.stack([unique[starts], unique[ends]], axis=1).ravel()
    return ConfidenceMap(breakpoints, np.repeat(values, 2))


@dataclass(frozen=True)
class Calibration:
    """The confidence maps of a model, one per kind of score.

    Attributes
    ----------
    maps : mapping of str to ConfidenceMap
        Keys from :data:`SCORE_KINDS`; ``"verifier"`` is needed, ``"heatmap"`` only
        for a model with a heatmap stage.
    """

    maps: Mapping[str, ConfidenceMap]

    def __post_init__(self) -> None:
        for kind in self.maps:
            check_choice("maps", kind, SCORE_KINDS)
        if "verifier" not in self.maps:
            raise ValueError("maps: expected a 'verifier' map")

    def confidence(self, source: str, tip_probability: float) -> float:
        """The calibrated confidence of a detection of ``source`` with this verifier
        probability (see :data:`SOURCE_SCORE`).

        Raises
        ------
        ValueError
            For an unknown source or one whose map the calibration lacks.
        """
        kind = SOURCE_SCORE.get(source)
        if kind is None or kind not in self.maps:
            raise ValueError(f"source: no confidence map for {source!r} detections")
        return float(self.maps[kind](tip_probability))


@dataclass(frozen=True)
class ReliabilityBin:
    """One bin of a :class:`Reliability` table.

    Attributes
    ----------
    low, high : float
        Confidence range ``[low, high)`` (the last bin includes ``high``).
    count : int
        Detections in the bin.
    mean_confidence, share_correct : float
        Their mean confidence and the share of them that are right; NaN if empty.
    """

    low: float
    high: float
    count: int
    mean_confidence: float
    share_correct: float


@dataclass(frozen=True)
class Reliability:
    """A reliability table: confidence against observed share correct.

    Attributes
    ----------
    bins : tuple of ReliabilityBin
    detections : int
        All detections scored.
    ece : float
        Expected calibration error: over the bins, the share of detections times
        ``|mean confidence - share correct|``; NaN without detections.
    """

    bins: tuple[ReliabilityBin, ...]
    detections: int
    ece: float

    def as_dict(self) -> dict[str, Any]:
        """``{"detections", "ece", "bins": [{"low", "high", "count", "mean_confidence",
        "share_correct"}, ...]}``, JSON-ready except for NaN."""
        return {
            "detections": self.detections,
            "ece": self.ece,
            "bins": [vars(b).copy() for b in self.bins],
        }


def reliability_table(
    confidences: ArrayLike, correct: ArrayLike, *, edges: Sequence[float] = RELIABILITY_EDGES
) -> Reliability:
    """Bin detections by confidence and compare each bin's confidence with its outcome.

    Parameters
    ----------
    confidences : (N,) float
        Probabilities in [0, 1].
    correct : (N,) bool
        Whether each detection is right (matched to an annotated tip).
    edges : sequence of float
        Increasing bin edges; the last bin includes its upper edge.

    Returns
    -------
    Reliability
    """
    p = as_array("confidences", confidences, (None,), np.float64, kind="fiu", finite=True)
    y = as_array("correct", correct, (p.size,), bool, kind="b")
    bounds = as_array("edges", edges, (None,), np.float64, kind="fiu", finite=True)
    if bounds.size < 2 or np.any(np.diff(bounds) <= 0):
        raise ValueError(f"edges: expected at least two increasing edges, got {list(edges)}")
    if np.any((p < bounds[0]) | (p > bounds[-1])):
        raise ValueError(f"confidences: expected values in [{bounds[0]}, {bounds[-1]}]")
    index = np.clip(np.searchsorted(bounds, p, side="right") - 1, 0, bounds.size - 2)
    bins = []
    gap = 0.0
    for k in range(bounds.size - 1):
        inside = index == k
        count = int(inside.sum())
        mean = float(p[inside].mean()) if count else math.nan
        share = float(y[inside].mean()) if count else math.nan
        if count:
            gap += count * abs(mean - share)
        bins.append(ReliabilityBin(float(bounds[k]), float(bounds[k + 1]), count, mean, share))
    return Reliability(tuple(bins), int(p.size), gap / p.size if p.size else math.nan)
