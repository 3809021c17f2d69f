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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from fingertips.features import intrinsics_array, project, read_probes
from fingertips.trees import check_tree_table, descend_matrix
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

    Parameters
    ----------
    peaks : Peaks
        From :func:`fingertips.voting.find_peaks` on ``votes``, strongest first.
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
    if votes.weights.size == 0:
        raise ValueError("votes: peaks need the votes they were found in")
    index = cKDTree(votes.positions_m)
    flat, owner = _members(index, centres, bandwidth_m)
    weight = votes.weights[flat].astype(np.float64)
    confidence = np.bincount(owner, weight, k)
    safe = np.maximum(confidence, 1e-12)
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
    voter_offset = voter_centroid - centres
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
        np.arange(k, dtype=np.float64),
        confidence / confidence.max(),
        np.minimum(separation.min(axis=1), _FAR_PEAK_M),
        1000.0 * np.linalg.norm(voter_offset, axis=1),
        1000.0 * voter_offset[:, 2],
    ]
    features = np.concatenate(
        [np.stack(columns, axis=1), ring_features(probes, centres, camera)], axis=1
    )
    return features.astype(np.float32)


@dataclass(frozen=True)
class PeakVerifier:
    """A classification forest over :data:`PEAK_FEATURES`, as plain arrays.

    The node table is that of :mod:`fingertips.trees`; ``node_probability``
    ``(n,) float32`` is the share of true fingertip peaks among the training peaks
    reaching each node.
    """

    tree_roots: NDArray[np.int32]
    node_feature: NDArray[np.int32]
    node_threshold: NDArray[np.float32]
    node_left: NDArray[np.int32]
    node_right: NDArray[np.int32]
    node_probability: NDArray[np.float32]

    def __post_init__(self) -> None:
        check_tree_table(self, len(PEAK_FEATURES))
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
    features : (K, len(PEAK_FEATURES)) float32
        From :func:`peak_features`.
    """
    values = as_array("features", features, (None, len(PEAK_FEATURES)), np.float32, kind="fiu")
    leaves = descend_matrix(verifier, values)
    return verifier.node_probability[leaves].mean(axis=1).astype(np.float32)
