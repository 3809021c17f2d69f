"""The candidates of a frame that the peak verifier scores: vote peaks and geodesic tips.

Two stages propose fingertips. The Hough forest's vote peaks
(:func:`fingertips.voting.find_peaks`) see a few centimetres around a pixel; the
geodesic stage (:mod:`fingertips.geodesic`) needs no learning and proposes the far
ends of the hand's surface measured from the palm, every extended finger. With
``DetectorConfig.candidates = "union"`` the verifier scores both
(:func:`merge_candidates`):

- a geodesic finger candidate within ``bandwidth_m`` (the voting bandwidth, 10 mm) of
  a vote peak is the same candidate: the peak keeps its position and confidence and
  is marked as coming from both stages, with the geodesic reach and width;
- the others join as candidates of their own, their confidence the vote weight
  within ``bandwidth_m`` of them (often 0: the forest did not see them).

:func:`candidate_features` describes every candidate by the vote and depth columns
of :func:`fingertips.verify.peak_features`, computed for a geodesic point as for a
peak, followed by :data:`fingertips.verify.GEODESIC_FEATURES`: where it came from,
its geodesic reach from the palm centre and its width (0 unless it came from the
geodesic stage), its 3D distance from the palm centre and the palm's radius (0
without a palm).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from fingertips.geodesic import GeodesicCandidates
from fingertips.verify import UNION_FEATURES, peak_features
from fingertips.voting import Peaks, Votes

CandidateSource = Literal["forest", "union"]
CANDIDATE_SOURCES: tuple[CandidateSource, ...] = ("forest", "union")
"""``"forest"``: the vote peaks; ``"union"``: the vote peaks and the geodesic finger
candidates."""


@dataclass(frozen=True)
class FrameCandidates:
    """Fingertip candidates of one frame, by decreasing confidence.

    Attributes
    ----------
    positions_m : (K, 3) float32
        Camera frame, metres.
    confidences : (K,) float32
        Vote weight within the voting bandwidth (the paper's ``c_s``); 0 for a geodesic
        candidate without votes near it.
    from_forest, from_geodesic : (K,) bool
        Which stages proposed the candidate (both after a merge).
    reach_m, width_m : (K,) float32
        Geodesic distance from the palm centre and width of the surface 3 cm from the
        tip (:class:`fingertips.geodesic.GeodesicCandidates`), metres; 0 where
        ``from_geodesic`` is False.
    palm_m : (3,) float32
        The geodesic stage's palm centre, metres; NaN without one.
    palm_radius_m : float
        Radius of the palm's largest inscribed disc, metres; 0 without a palm.
    """

    positions_m: NDArray[np.float32]
    confidences: NDArray[np.float32]
    from_forest: NDArray[np.bool_]
    from_geodesic: NDArray[np.bool_]
    reach_m: NDArray[np.float32]
    width_m: NDArray[np.float32]
    palm_m: NDArray[np.float32]
    palm_radius_m: float

    def __len__(self) -> int:
        return len(self.confidences)

    @property
    def peaks(self) -> Peaks:
        """Positions and confidences as :class:`fingertips.voting.Peaks`."""
        return Peaks(self.positions_m, self.confidences)


def vote_weight_near(points_m: NDArray, votes: Votes, *, radius_m: float) -> NDArray[np.float32]:
    """Sum ``(K,)`` of the vote weights within ``radius_m`` of each point ``(K, 3)``."""
    if len(points_m) == 0 or votes.weights.size == 0:
        return np.zeros(len(points_m), np.float32)
    members = cKDTree(votes.positions_m).query_ball_point(
        np.asarray(points_m, np.float64), radius_m, return_sorted=False
    )
    weights = votes.weights.astype(np.float64)
    return np.array([weights[m].sum() for m in members], np.float32)


def merge_candidates(
    peaks: Peaks, geodesic: GeodesicCandidates, votes: Votes, *, bandwidth_m: float
) -> FrameCandidates:
    """The union of vote peaks and geodesic finger candidates, duplicates merged.

    Parameters
    ----------
    peaks : Peaks
        The forest's vote peaks, strongest first.
    geodesic : GeodesicCandidates
        The geodesic stage's candidates; only those flagged as fingers join.
    votes : Votes
        The votes the peaks were found in (the confidence of a geodesic candidate).
    bandwidth_m : float
        A geodesic finger candidate within this 3D distance of a peak is merged into
        the nearest one, metres.

    Returns
    -------
    FrameCandidates
        Sorted by decreasing confidence (ties: vote peaks first, in their order).
    """
    fingers = geodesic.fingers()
    n_peaks = len(peaks.confidences)
    from_geodesic = np.zeros(n_peaks, bool)
    reach = np.zeros(n_peaks, np.float32)
    width = np.zeros(n_peaks, np.float32)
    alone = np.ones(len(fingers), bool)
    if n_peaks and len(fingers):
        gap, nearest = cKDTree(peaks.positions_m).query(fingers.points_m.astype(np.float64))
        for k in np.argsort(gap, kind="stable"):  # the closest pair claims a peak first
            if gap[k] <= bandwidth_m and not from_geodesic[nearest[k]]:
                from_geodesic[nearest[k]], alone[k] = True, False
                reach[nearest[k]], width[nearest[k]] = fingers.reach_m[k], fingers.width_m[k]
    extra = fingers.select(alone)
    positions = np.concatenate([peaks.positions_m, extra.points_m]).astype(np.float32)
    confidences = np.concatenate(
        [peaks.confidences, vote_weight_near(extra.points_m, votes, radius_m=bandwidth_m)]
    ).astype(np.float32)
    order = np.argsort(-confidences, kind="stable")
    n_extra = len(extra)
    return FrameCandidates(
        positions_m=positions[order],
        confidences=confidences[order],
        from_forest=np.r_[np.ones(n_peaks, bool), np.zeros(n_extra, bool)][order],
        from_geodesic=np.r_[from_geodesic, np.ones(n_extra, bool)][order],
        reach_m=np.r_[reach, extra.reach_m].astype(np.float32)[order],
        width_m=np.r_[width, extra.width_m].astype(np.float32)[order],
        palm_m=geodesic.palm_m.astype(np.float32),
        palm_radius_m=float(geodesic.palm_radius_m),
    )


def forest_candidates(peaks: Peaks) -> FrameCandidates:
    """The vote peaks alone as :class:`FrameCandidates` (no geodesic stage, no palm)."""
    n = len(peaks.confidences)
    return FrameCandidates(
        positions_m=peaks.positions_m.astype(np.float32),
        confidences=peaks.confidences.astype(np.float32),
        from_forest=np.ones(n, bool),
        from_geodesic=np.zeros(n, bool),
        reach_m=np.zeros(n, np.float32),
        width_m=np.zeros(n, np.float32),
        palm_m=np.full(3, np.nan, np.float32),
        palm_radius_m=0.0,
    )


def candidate_features(
    candidates: FrameCandidates,
    votes: Votes,
    probes_m: NDArray[np.float32],
    intrinsics: NDArray[np.float64],
    *,
    bandwidth_m: float,
) -> NDArray[np.float32]:
    """Describe each candidate for the verifier (columns: :data:`UNION_FEATURES`).

    Parameters
    ----------
    candidates : FrameCandidates
    votes : Votes
        The frame's votes.
    probes_m : (H + 2, W + 2) float32
        :func:`~fingertips.features.probe_image` of the hand depth.
    intrinsics : (4,) float64
        ``(fx, fy, cx, cy)`` in pixels.
    bandwidth_m : float
        The voting bandwidth (``VotingConfig.bandwidth_m``).

    Returns
    -------
    (K, len(UNION_FEATURES)) float32
        Finite.
    """
    if len(candidates) == 0:
        return np.zeros((0, len(UNION_FEATURES)), np.float32)
    base = peak_features(candidates.peaks, votes, probes_m, intrinsics, bandwidth_m=bandwidth_m)
    has_palm = bool(np.isfinite(candidates.palm_m).all())
    palm_distance = (
        np.linalg.norm(candidates.positions_m - candidates.palm_m, axis=1)
        if has_palm
        else np.zeros(len(candidates))
    )
    geodesic = np.stack(
        [
            candidates.from_forest,
            candidates.from_geodesic,
            candidates.reach_m,
            candidates.width_m,
            palm_distance,
            np.full(len(candidates), candidates.palm_radius_m if has_palm else 0.0),
        ],
        axis=1,
    ).astype(np.float32)
    return np.concatenate([base, geodesic], axis=1)
