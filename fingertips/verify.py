"""A second look at every vote peak: is it really a fingertip?

The vote weight alone (the paper's confidence) cannot tell a fingertip from the knuckle
of a curled finger or the end of a finger pointing away: all of them collect votes.
Each peak is therefore described by what its votes and the depth around it look like
(:func:`peak_features`), and a small classification forest trained on rendered frames
(:mod:`fingertips.verifier_training`) gives the probability that the peak lies within
15 mm of a visible fingertip (:func:`verify_peaks`). The detector keeps peaks whose
probability reaches ``DetectorConfig.min_tip_probability``.

The features, per peak (all invariant to image resolution and pixel stride, all
metric):

- from the votes within ``bandwidth_m``: their weight (the confidence), their number,
  the largest and the mean fingertip probability of their pixels, their spread, and
  the weight within twice the bandwidth relative to the confidence;
- from the voters' own points: how far their weighted centroid lies from the peak,
  and how far behind it;
- from the other peaks of the frame: the confidence rank, the confidence relative to
  the strongest peak, the distance to the nearest other peak;
- from the depth image: the measured depth at the peak's pixel relative to the peak,
  and on circles of radius 1, 2, 3 and 4.5 cm around the peak (16 probes each, metric
  radii scaled by 1/depth): the share of background (more than 3 cm behind the
  peak), the longest arc of hand, and the mean depth of the hand probes relative to
  the peak. A fingertip is a narrow arc of hand at every radius; a knuckle of a
  curled finger has hand on a half-circle.

The geodesic stage's finger candidates are described the same way when they join the
vote peaks (:mod:`fingertips.candidates`), and :data:`GEODESIC_FEATURES` follow: a
verifier trained on :data:`UNION_FEATURES` scores both kinds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from fingertips.features import intrinsics_array, project, read_probes
from fingertips.trees import PackedNodes, check_tree_table, descend_matrix
from fingertips.voting import Peaks, Votes
from glovedb._validate import as_array

RING_RADII_M: tuple[float, ...] = (0.01, 0.02, 0.03, 0.045)
"""Radii (metres) of the probe circles around a peak."""
RING_PROBES = 16
"""Probes per circle."""
RING_BACKGROUND_M = 0.03
"""A probe more than this far (metres) behind the peak, or without depth, is background."""
_FAR_PEAK_M = 0.2
_GAP_CLIP_M = 0.1

PEAK_FEATURES: tuple[str, ...] = (
    "confidence",
    "n_votes",
    "max_probability",
    "mean_probability",
    "vote_spread_mm",
    "wide_weight_ratio",
    "depth_m",
    "surface_gap_m",
    "rank",
    "relative_confidence",
    "nearest_peak_m",
    "voter_offset_mm",
    "voter_depth_mm",
) + tuple(
    f"ring{round(1000 * r)}_{name}"
    for r in RING_RADII_M
    for name in ("background", "hand_arc", "hand_depth_m")
)
"""Names of the columns of :func:`peak_features`, in order (recorded in the model)."""

GEODESIC_FEATURES: tuple[str, ...] = (
    "from_forest",
    "from_geodesic",
    "geodesic_reach_m",
    "geodesic_width_m",
    "palm_distance_m",
    "palm_radius_m",
)
"""Names of the columns :func:`fingertips.candidates.candidate_features` appends to
:data:`PEAK_FEATURES`: where a candidate came from and the geodesic stage's view of it."""

UNION_FEATURES: tuple[str, ...] = PEAK_FEATURES + GEODESIC_FEATURES
"""All columns of :func:`fingertips.candidates.candidate_features`, in order."""

VERIFIER_FEATURE_SETS: tuple[tuple[str, ...], ...] = (PEAK_FEATURES, UNION_FEATURES)
"""The feature lists a verifier can be trained on: the vote peaks' own (the first
verifiers), or those and the geodesic columns."""


def _members(
    index: cKDTree, centres: NDArray[np.float64], radius_m: float
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Flat vote indices within ``radius_m`` of each centre, and the centre of each."""
    members = index.query_ball_point(centres, radius_m, return_sorted=False)
    counts = np.array([len(m) for m in members], dtype=np.intp)
    flat = np.concatenate([np.asarray(m, dtype=np.intp) for m in members])
    return flat, np.repeat(np.arange(centres.shape[0]), counts)


def _longest_circular_run(flags: NDArray[np.bool_]) -> NDArray[np.int64]:
    """Length of the longest run of True along the last axis, read circularly."""
    n = flags.shape[-1]
    run = np.zeros(flags.shape[:-1], dtype=np.int64)
    best = np.zeros_like(run)
    for k in range(2 * n):
        run = np.where(flags[..., k % n], run + 1, 0)
        best = np.maximum(best, run)
    return np.minimum(best, n)


def ring_features(
    probes_m: NDArray[np.float32],
    peaks_m: NDArray[np.float64],
    intrinsics: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Depth around each peak on circles of :data:`RING_RADII_M`.

    Parameters
    ----------
    probes_m : (H + 2, W + 2) float32
        :func:`~fingertips.features.probe_image` of the hand depth (metres,
        0 where missing or not the hand).
    peaks_m : (K, 3) float64
        Peak positions, camera frame, metres.
    intrinsics : (4,) float64

    Returns
    -------
    (K, 3 * len(RING_RADII_M)) float64
        Per radius: share of background probes, longest arc of hand probes (share of
        the circle), mean depth of the hand probes relative to the peak (metres,
        clipped to ``[-0.05, RING_BACKGROUND_M]``; ``RING_BACKGROUND_M`` without any).
    """
    fx, fy, _, _ = intrinsics
    uv = np.rint(project(peaks_m, intrinsics)).astype(np.int64)
    angles = np.linspace(0.0, 2.0 * np.pi, RING_PROBES, endpoint=False)
    radii = np.asarray(RING_RADII_M)
    z = peaks_m[:, 2]
    # (K, R, P) probe pixels and depth differences.
    du = np.rint(radii[None, :, None] * np.cos(angles) * fx / z[:, None, None]).astype(np.int64)
    dv = np.rint(radii[None, :, None] * np.sin(angles) * fy / z[:, None, None]).astype(np.int64)
    values = read_probes(probes_m, uv[:, 0, None, None] + du, uv[:, 1, None, None] + dv)
    difference = values.astype(np.float64) - z[:, None, None]
    hand = difference <= RING_BACKGROUND_M
    n_hand = hand.sum(axis=2)
    clipped = np.clip(difference, -0.05, RING_BACKGROUND_M)
    mean_hand = np.divide(
        np.where(hand, clipped, 0.0).sum(axis=2),
        n_hand,
        out=np.full(n_hand.shape, RING_BACKGROUND_M),
        where=n_hand > 0,
    )
    columns = np.stack(
        [1.0 - n_hand / RING_PROBES, _longest_circular_run(hand) / RING_PROBES, mean_hand], axis=2
    )
    return columns.reshape(len(peaks_m), -1)


def peak_features(
    peaks: Peaks,
    votes: Votes,
    probes_m: ArrayLike,
    intrinsics: ArrayLike,
    *,
    bandwidth_m: float,
) -> NDArray[np.float32]:
    """Describe each vote peak for the verifier (columns: :data:`PEAK_FEATURES`).

    Any candidate point can be described so, also one without votes near it (a
    geodesic candidate): its vote columns and the voters' offset are then 0, and
    ``wide_weight_ratio`` is the weight within twice the bandwidth itself.

    Parameters
    ----------
    peaks : Peaks
        Candidate points and their confidences (the rank column orders them by
        confidence, ties in the given order), such as
        :func:`fingertips.voting.find_peaks` gives on ``votes``.
    votes : Votes
    probes_m : (H + 2, W + 2) float32
        :func:`~fingertips.features.probe_image` of the hand depth the votes
        were cast from (the forest probed the same image).
    intrinsics : (4,) float
        ``(fx, fy, cx, cy)`` in pixels.
    bandwidth_m : float
        The voting bandwidth (``VotingConfig.bandwidth_m``).

    Returns
    -------
    (K, len(PEAK_FEATURES)) float32
    """
    probes = as_array("probes_m", probes_m, (None, None), np.float32, kind="f")
    camera = intrinsics_array(intrinsics)
    centres = peaks.positions_m.astype(np.float64)
    k = centres.shape[0]
    if k == 0:
        return np.zeros((0, len(PEAK_FEATURES)), np.float32)
    index = cKDTree(votes.positions_m)
    flat, owner = _members(index, centres, bandwidth_m)
    weight = votes.weights[flat].astype(np.float64)
    confidence = np.bincount(owner, weight, k)
    voted = confidence > 0
    safe = np.where(voted, confidence, 1.0)
    count = np.bincount(owner, minlength=k).astype(np.float64)
    probability = votes.probability[flat].astype(np.float64)
    max_probability = np.zeros(k)
    np.maximum.at(max_probability, owner, probability)
    mean_probability = np.bincount(owner, probability, k) / np.maximum(count, 1)
    squared = np.sum((votes.positions_m[flat] - centres[owner]) ** 2, axis=1)
    spread = np.sqrt(np.bincount(owner, weight * squared, k) / safe)
    wide_flat, wide_owner = _members(index, centres, 2.0 * bandwidth_m)
    wide = np.bincount(wide_owner, votes.weights[wide_flat].astype(np.float64), k)
    voter_centroid = (
        np.stack(
            [np.bincount(owner, weight * votes.sources_m[flat, j], k) for j in range(3)], axis=1
        )
        / safe[:, None]
    )
    voter_offset = np.where(voted[:, None], voter_centroid - centres, 0.0)
    uv = np.rint(project(centres, camera)).astype(np.int64)
    surface = read_probes(probes, uv[:, 0], uv[:, 1]).astype(np.float64)
    separation = np.linalg.norm(centres[:, None] - centres[None], axis=2)
    np.fill_diagonal(separation, np.inf)
    columns = [
        confidence,
        count,
        max_probability,
        mean_probability,
        1000.0 * spread,
        wide / safe,
        centres[:, 2],
        np.clip(surface - centres[:, 2], -_GAP_CLIP_M, _GAP_CLIP_M),
        _ranks(peaks.confidences),
        confidence / max(float(confidence.max()), 1e-12),
        np.minimum(separation.min(axis=1), _FAR_PEAK_M),
        1000.0 * np.linalg.norm(voter_offset, axis=1),
        1000.0 * voter_offset[:, 2],
    ]
    features = np.concatenate(
        [np.stack(columns, axis=1), ring_features(probes, centres, camera)], axis=1
    )
    return features.astype(np.float32)


def _ranks(confidences: NDArray[np.float32]) -> NDArray[np.float64]:
    """Rank ``(K,)`` of each confidence, 0 for the largest; ties in the given order."""
    ranks = np.empty(confidences.size, np.float64)
    ranks[np.argsort(-confidences, kind="stable")] = np.arange(confidences.size)
    return ranks


@dataclass(frozen=True)
class PeakVerifier(PackedNodes):
    """A classification forest over peak features, as plain arrays.

    The node table is that of :mod:`fingertips.trees`; ``node_probability``
    ``(n,) float32`` is the share of true fingertip peaks among the training peaks
    reaching each node. ``feature_names`` is one of :data:`VERIFIER_FEATURE_SETS`:
    :data:`PEAK_FEATURES` (a verifier of the forest's vote peaks) or
    :data:`UNION_FEATURES` (also the geodesic columns).
    """

    tree_roots: NDArray[np.int32]
    node_feature: NDArray[np.int32]
    node_threshold: NDArray[np.float32]
    node_left: NDArray[np.int32]
    node_right: NDArray[np.int32]
    node_probability: NDArray[np.float32]
    feature_names: tuple[str, ...] = PEAK_FEATURES

    def __post_init__(self) -> None:
        if tuple(self.feature_names) not in VERIFIER_FEATURE_SETS:
            raise ValueError(
                "feature_names: expected PEAK_FEATURES or UNION_FEATURES of "
                f"fingertips.verify, got {len(self.feature_names)} other names"
            )
        check_tree_table(self, len(self.feature_names))
        as_array("node_probability", self.node_probability, (self.node_feature.shape[0],))

    @property
    def n_trees(self) -> int:
        """Number of trees."""
        return int(self.tree_roots.size)


def verify_peaks(verifier: PeakVerifier, features: ArrayLike) -> NDArray[np.float32]:
    """Probability ``(K,)`` that each peak is a fingertip: the mean of the trees' leaves.

    Parameters
    ----------
    verifier : PeakVerifier
    features : (K, F) float32
        :data:`UNION_FEATURES` columns (:func:`fingertips.candidates.candidate_features`)
        or only the verifier's own (``len(verifier.feature_names)``), which lead them.
    """
    values = as_array("features", features, (None, None), np.float32, kind="fiu")
    n = len(verifier.feature_names)
    if values.shape[1] not in (n, len(UNION_FEATURES)):
        raise ValueError(
            f"features: expected (K, {n}) or (K, {len(UNION_FEATURES)}), got {values.shape}"
        )
    leaves = descend_matrix(verifier, np.ascontiguousarray(values[:, :n]))
    return verifier.node_probability[leaves].mean(axis=1).astype(np.float32)
