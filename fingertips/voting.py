"""Hough voting in 3D: pixels vote for fingertip positions, mean-shift finds the peaks.

Each hand pixel casts one vote at its 3D point plus the forest's offset. The vote
weight is the fingertip probability times the surface area the pixel stands for,
counted in units of ``vote_unit_area_m2`` (default 5 mm x 5 mm). A detection's
confidence is the sum of the weights of the votes near it, so it does not change with
image resolution, pixel stride or distance, and ``c_thr = 3.0`` asks for the equivalent
of three 5 mm x 5 mm patches of surely-fingertip surface agreeing on one point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fingertips._voting_kernels import kept_apart, sorted_cubes, window_sums
from glovedb._validate import as_array


@dataclass(frozen=True)
class VotingConfig:
    """Settings of vote casting and peak finding.

    Attributes
    ----------
    min_probability : float
        Pixels below this fingertip probability do not vote.
    vote_unit_area_m2 : float
        Surface area (m²) that carries vote weight 1 at probability 1.
    bandwidth_m : float
        Radius (m) of the flat mean-shift kernel; also the radius within which votes
        count towards a detection's confidence.
    min_separation_m : float
        Two detections closer than this (m) are one; the weaker is dropped.
    seed_fraction : float
        A seed voxel (edge ``bandwidth_m``) needs at least ``seed_fraction * c_thr`` of
        vote weight to start a mean-shift.
    max_seeds : int
        At most this many seeds, the heaviest first.
    iterations : int
        Mean-shift iterations.
    """

    min_probability: float = 0.2
    vote_unit_area_m2: float = 25e-6
    bandwidth_m: float = 0.01
    min_separation_m: float = 0.015
    seed_fraction: float = 0.25
    max_seeds: int = 64
    iterations: int = 8

    def __post_init__(self) -> None:
        if not 0 <= self.min_probability <= 1:
            raise ValueError(f"min_probability: expected a probability, got {self.min_probability}")
        for name in ("vote_unit_area_m2", "bandwidth_m"):
            if not 0 < getattr(self, name) < math.inf:
                raise ValueError(f"{name}: expected a positive size, got {getattr(self, name)}")
        if not 0 <= self.min_separation_m < math.inf:
            raise ValueError(f"min_separation_m: expected >= 0, got {self.min_separation_m}")
        if not 0 < self.seed_fraction <= 1:
            raise ValueError(f"seed_fraction: expected a share in (0, 1], got {self.seed_fraction}")
        for name in ("max_seeds", "iterations"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}: expected at least 1, got {getattr(self, name)}")


DEFAULT_VOTING = VotingConfig()
"""The default voting settings (immutable)."""


@dataclass(frozen=True)
class Votes:
    """Weighted 3D votes and where they come from.

    Attributes
    ----------
    positions_m : (M, 3) float32
        Voted fingertip positions, camera frame, metres.
    weights : (M,) float32
        Vote weights (see the module docstring).
    probability : (M,) float32
        Fingertip probability of each voting pixel.
    sources_m : (M, 3) float32
        3D point of each voting pixel, metres.
    """

    positions_m: NDArray[np.float32]
    weights: NDArray[np.float32]
    probability: NDArray[np.float32]
    sources_m: NDArray[np.float32]


@dataclass(frozen=True)
class Peaks:
    """Vote peaks, strongest first: ``positions_m`` (K, 3) float32, ``confidences`` (K,) float32."""

    positions_m: NDArray[np.float32]
    confidences: NDArray[np.float32]


def cast_votes(
    points_m: ArrayLike,
    probability: ArrayLike,
    offset_m: ArrayLike,
    pixel_area_m2: ArrayLike,
    *,
    config: VotingConfig = DEFAULT_VOTING,
) -> Votes:
    """Turn per-pixel forest output into weighted 3D votes.

    Parameters
    ----------
    points_m : (N, 3) float32
        Camera-frame 3D points of the voting pixels, metres.
    probability : (N,) float32
        Fingertip probability per pixel.
    offset_m : (N, 3) float32
        Offset from the point to the fingertip, metres.
    pixel_area_m2 : (N,) float32
        Surface area each sampled pixel stands for, m² (``(stride * z)² / (fx * fy)``).
    config : VotingConfig

    Returns
    -------
    Votes
        Only pixels with ``probability >= config.min_probability``.
    """
    points = as_array("points_m", points_m, (None, 3), np.float32, kind="fiu")
    n = points.shape[0]
    prob = as_array("probability", probability, (n,), np.float32, kind="fiu")
    offset = as_array("offset_m", offset_m, (n, 3), np.float32, kind="fiu")
    area = as_array("pixel_area_m2", pixel_area_m2, (n,), np.float32, kind="fiu")
    keep = prob >= config.min_probability
    weights = prob[keep] * area[keep] / np.float32(config.vote_unit_area_m2)
    return Votes(
        positions_m=(points[keep] + offset[keep]).astype(np.float32),
        weights=weights.astype(np.float32),
        probability=prob[keep],
        sources_m=points[keep],
    )


def _seeds(votes: Votes, min_weight: float, config: VotingConfig) -> NDArray[np.float32]:
    """Weighted centroids of the heaviest voxels (edge ``bandwidth_m``)."""
    keys = np.floor(votes.positions_m / config.bandwidth_m).astype(np.int64)
    cell = np.unique(keys, axis=0, return_inverse=True)[1].ravel()
    n_cells = int(cell.max()) + 1
    mass = np.bincount(cell, weights=votes.weights, minlength=n_cells)
    moment = np.stack(
        [np.bincount(cell, votes.weights * votes.positions_m[:, k], n_cells) for k in range(3)],
        axis=1,
    )
    centroid = moment / np.maximum(mass, 1e-12)[:, None]
    order = np.argsort(-mass, kind="stable")[: config.max_seeds]
    order = order[mass[order] >= min_weight]
    return centroid[order].astype(np.float32)


def find_peaks(votes: Votes, *, c_thr: float = 3.0, config: VotingConfig = DEFAULT_VOTING) -> Peaks:
    """Mean-shift the votes from voxel seeds, merge nearby modes, keep confident ones.

    Parameters
    ----------
    votes : Votes
    c_thr : float
        Smallest confidence (sum of vote weights within ``config.bandwidth_m``) kept.
    config : VotingConfig

    Returns
    -------
    Peaks
        Sorted by decreasing confidence, at least ``config.min_separation_m`` apart.
    """
    empty = Peaks(np.zeros((0, 3), np.float32), np.zeros(0, np.float32))
    if votes.weights.size == 0:
        return empty
    modes = _seeds(votes, config.seed_fraction * c_thr, config)
    # The votes within the bandwidth of a mode, by cubes of that edge (compiled).
    positions = np.ascontiguousarray(votes.positions_m, dtype=np.float32)
    weights = np.ascontiguousarray(votes.weights, dtype=np.float32)
    radius = float(config.bandwidth_m)
    cubes = sorted_cubes(positions, radius)
    for _ in range(config.iterations):
        if modes.shape[0] == 0:
            return empty
        mass, moment = window_sums(modes, positions, weights, *cubes, radius)
        alive = mass > 0
        modes = (moment[alive] / mass[alive, None]).astype(np.float32)
    if modes.shape[0] == 0:
        return empty
    confidence, _ = window_sums(modes, positions, weights, *cubes, radius)
    order = np.argsort(-confidence, kind="stable")
    confident = order[confidence[order] >= c_thr]  # a prefix: the order is descending
    keep = apart_in_order(modes, confident, config.min_separation_m)
    kept = confident[keep[confident]]
    return Peaks(modes[kept].astype(np.float32), confidence[kept].astype(np.float32))


def apart_in_order(points_m: ArrayLike, order: ArrayLike, separation_m: float) -> NDArray[np.bool_]:
    """Which points to keep so that the kept ones lie ``separation_m`` apart, earlier
    ones in ``order`` first (the vote peaks by confidence, the candidates by tip
    probability, the geodesic extrema by reach).

    Parameters
    ----------
    points_m : (K, 3) float32
        Points in metres.
    order : (M,) int
        The points to visit, best first; the others are not kept.
    separation_m : float
        A visited point is kept unless it lies nearer than this (compared in float32)
        to one kept before it.

    Returns
    -------
    (K,) bool
    """
    points = np.ascontiguousarray(as_array("points_m", points_m, (None, 3), np.float32))
    visit = as_array("order", order, (None,), np.int64, kind="iu")
    if len(visit) and (visit.min() < 0 or visit.max() >= len(points)):
        raise ValueError(f"order: indices must lie in 0..{len(points) - 1}")
    return kept_apart(points, np.ascontiguousarray(visit), np.float32(separation_m))
