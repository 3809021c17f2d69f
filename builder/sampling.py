"""Posture sampling for databases: natural random postures and low-dispersion selection.

Natural random postures come from a synergy space: the principal components of the
named postures (how real hands co-articulate their joints), sampled with the spread
the named postures show, plus small independent noise per joint, clipped to the
joint limits.

Low-dispersion selection (thesis 4.2) is greedy farthest-point sampling under the
posture distance :func:`posture_distance_matrix`: the root mean square distance
between corresponding keypoints of the two postures in the hand frame, in metres.
It measures how different two postures look, which is what a database must cover,
unlike raw angle differences that weigh a fingertip joint like a knuckle.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array
from glovedb.hand_model import N_JOINTS, Skeleton, clip_to_limits, forward_kinematics


def synergy_postures(
    count: int,
    examples_rad: ArrayLike,
    *,
    synergies: int = 4,
    spread: float = 1.0,
    noise_deg: float = 5.0,
    seed: int = 0,
) -> NDArray[np.float64]:
    """Random natural postures around a set of example postures.

    Parameters
    ----------
    count : int
        How many postures to draw.
    examples_rad : (E, 20) float
        Example postures (e.g. all named postures) that span the synergy space.
    synergies : int
        Principal components kept (at most E - 1).
    spread : float
        Scales the standard deviation along every component.
    noise_deg : float
        Standard deviation of independent per-joint noise, degrees.
    seed : int

    Returns
    -------
    (count, 20) float64
        Within the joint limits.
    """
    examples = as_array("examples_rad", examples_rad, (None, N_JOINTS), np.float64, finite=True)
    if count < 0:
        raise ValueError(f"count: expected >= 0, got {count}")
    if not 1 <= synergies <= len(examples) - 1:
        raise ValueError(f"synergies: expected 1..{len(examples) - 1}, got {synergies}")
    rng = np.random.default_rng(seed)
    mean = examples.mean(axis=0)
    _, singular, components = np.linalg.svd(examples - mean, full_matrices=False)
    deviation = singular[:synergies] / np.sqrt(len(examples) - 1) * spread
    weights = rng.standard_normal((count, synergies)) * deviation
    noise = rng.standard_normal((count, N_JOINTS)) * np.radians(noise_deg)
    return clip_to_limits(mean + weights @ components[:synergies] + noise)


def posture_features(postures_rad: ArrayLike, skeleton: Skeleton | None = None) -> NDArray:
    """``(N, 63)`` keypoint coordinates (hand frame, metres) divided by sqrt(21).

    Euclidean distances between these rows are the posture distance of the module
    docstring.
    """
    keypoints = forward_kinematics(postures_rad, skeleton).keypoints_m
    return keypoints.reshape(len(keypoints), -1) / np.sqrt(keypoints.shape[1])


def posture_distance_matrix(
    postures_a_rad: ArrayLike, postures_b_rad: ArrayLike, skeleton: Skeleton | None = None
) -> NDArray[np.float64]:
    """RMS keypoint distance in metres between every pair: ``(Na, Nb)``."""
    a = posture_features(postures_a_rad, skeleton)
    b = posture_features(postures_b_rad, skeleton)
    return np.linalg.norm(a[:, None] - b[None], axis=-1)


def farthest_point_selection(
    postures_rad: ArrayLike, count: int, skeleton: Skeleton | None = None, *, first: int = 0
) -> NDArray[np.int64]:
    """Greedy farthest-point (low-dispersion) selection of ``count`` postures.

    Starts with posture ``first``; each next pick is the posture farthest from all
    picks so far (ties: the lowest index), so the result is deterministic.

    Parameters
    ----------
    postures_rad : (N, 20) float
    count : int
        At most N.

    Returns
    -------
    (count,) int64
        Indices into ``postures_rad`` in the order picked.
    """
    postures = as_array("postures_rad", postures_rad, (None, N_JOINTS), np.float64, finite=True)
    if not 1 <= count <= len(postures):
        raise ValueError(f"count: expected 1..{len(postures)}, got {count}")
    features = posture_features(postures, skeleton)
    picks = np.empty(count, dtype=np.int64)
    picks[0] = first
    nearest = np.linalg.norm(features - features[first], axis=1)
    owner = np.zeros(len(features), dtype=np.int64)  # which pick is nearest (its order)
    for index in range(1, count):
        pick = int(np.argmax(nearest))
        picks[index] = pick
        # Triangle inequality: a posture whose nearest pick lies more than twice its
        # distance from the new pick is farther from the new pick than from its own,
        # so its distance is not computed (the margin covers rounding). The others get
        # the same row-wise norms as over all rows, so the picks are the plain loop's.
        to_picks = np.linalg.norm(features[picks[:index]] - features[pick], axis=1)
        near = np.flatnonzero(to_picks[owner] <= 2.0 * nearest * (1.0 + 1e-9))
        distance = np.linalg.norm(features[near] - features[pick], axis=1)
        owner[near[distance < nearest[near]]] = index
        nearest[near] = np.minimum(nearest[near], distance)
    return picks
