"""A hand pose guess from fingertip detections, to (re)initialise a tracker.

Given the 3D fingertip detections of one frame and one or more postures to choose
from (e.g. a tracker's last posture, or the named postures), :func:`guess_hand_pose`
finds the posture and rigid pose of the hand model that put its fingertips on the
detections. Which detection is which finger is not known, so every assignment of at
least ``min_matched`` detections to distinct fingers is tried (at most 3,720 for six
detections, per posture), each solved in closed form (Kabsch) and scored like Eq. 11
of Tzionas et al. (2014): squared residuals, plus a cost for every detection left out
and every finger without a detection. Three fingertips fit a mirrored hand about as
well as the right one, so when the hand's depth points are given, the best
assignments are re-scored by how well the posed hand's capsules
(:mod:`glovedb.capsules`) cover those points, and the winner is aligned to them.

The result uses the conventions of ``poses.jsonl`` (``p_cam = R @ p_hand + t``), so
another tracker can start from it directly.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fingertips.assignment import FINGER_NAMES
from fingertips.features import (
    backproject,
    foreground_pixels,
    intrinsics_array,
    mask_depth_range,
    nearest_band,
    stride_for_budget,
)
from glovedb._validate import as_array
from glovedb.capsules import (
    CapsuleSet,
    closest_capsule_points,
    concatenate,
    finger_capsules,
    palm_capsules,
    pose_capsules,
    round_cone_distance,
)
from glovedb.hand_model import (
    FINGERTIP_KEYPOINTS,
    N_JOINTS,
    Skeleton,
    forward_kinematics,
    make_skeleton,
)
from tracker.icp import batch_rigid_fit, rigid_fit

_PALM_HALF_THICKNESS = 0.06
"""Half thickness of the palm capsules, in hand lengths (11 mm for a 0.19 m hand)."""
_SURFACE_CLIP_M = 0.03
_RESCORED = 24


@dataclass(frozen=True)
class PoseGuess:
    """A rigid hand pose fitted to fingertip detections.

    Attributes
    ----------
    rotation : (3, 3) float64
        Hand to camera rotation (``p_cam = R @ p_hand + t``).
    translation_m : (3,) float64
        Wrist position in the camera frame, metres.
    posture_rad : (20,) float64
        The posture chosen among those offered.
    keypoints_3d_m : (21, 3) float64
        The posed model's keypoints in the camera frame, metres.
    fingers : tuple of (str or None)
        Per detection given, the finger it was matched to, or None (also for the
        detections beyond ``max_detections``).
    tip_rms_m : float
        Root mean square distance of the matched detections to their model fingertips.
    surface_rms_m : float
        Root mean square distance of the hand points to the posed capsules (each
        clipped at 3 cm); NaN when no points were given.
    """

    rotation: NDArray[np.float64]
    translation_m: NDArray[np.float64]
    posture_rad: NDArray[np.float64]
    keypoints_3d_m: NDArray[np.float64]
    fingers: tuple[str | None, ...]
    tip_rms_m: float
    surface_rms_m: float


def hand_points_from_depth(
    depth_m: ArrayLike,
    intrinsics: ArrayLike,
    *,
    depth_range_m: tuple[float, float] = (0.15, 2.0),
    band_m: float = 0.2,
    max_points: int = 600,
) -> NDArray[np.float64]:
    """The 3D points of the nearest object (the hand), subsampled on a pixel grid.

    Parameters
    ----------
    depth_m : (H, W) float
        Depth in metres, 0 where missing.
    intrinsics : (4,) float
        ``(fx, fy, cx, cy)`` in pixels.
    depth_range_m : tuple of float
        Working range; depth outside is ignored.
    band_m : float
        Only depth within this many metres behind the nearest surface is the hand.
    max_points : int
        The pixel stride grows until at most about this many points remain.

    Returns
    -------
    (N, 3) float64
        Camera frame, metres.
    """
    masked = nearest_band(
        mask_depth_range(depth_m, near_m=depth_range_m[0], far_m=depth_range_m[1]), band_m=band_m
    )
    return masked_points(masked, intrinsics, max_points=max_points)


def masked_points(
    hand_depth_m: NDArray[np.float32], intrinsics: ArrayLike, *, max_points: int = 600
) -> NDArray[np.float64]:
    """The 3D points ``(N, 3)`` (metres) of an already segmented hand depth (0 elsewhere),
    on the pixel grid whose stride leaves at most about ``max_points``."""
    stride = stride_for_budget(hand_depth_m, max(max_points, 1))
    pixels = foreground_pixels(hand_depth_m, stride=stride)
    z = hand_depth_m[pixels[:, 1], pixels[:, 0]]
    return backproject(pixels, z, intrinsics_array(intrinsics)).astype(np.float64)


def _align_with_points(
    rotation: NDArray[np.float64],
    translation: NDArray[np.float64],
    model_tips: NDArray[np.float64],
    detections: NDArray[np.float64],
    cloud: NDArray[np.float64],
    posed: tuple[NDArray[np.float64], NDArray[np.float64]],
    capsules: CapsuleSet,
    iterations: int = 10,
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """ICP of the matched tips and the hand points to the posed capsules.

    The tips weigh one each; the points within 3 cm of the surface together weigh as
    much as five tips. Returns the pose and the points' mean squared (clipped) surface
    distance.
    """
    start, end = posed
    for _ in range(iterations):
        local = (cloud - translation) @ rotation
        surface, distance = closest_capsule_points(
            local, start, end, capsules.radius_start_m, capsules.radius_end_m
        )
        near = distance < _SURFACE_CLIP_M
        weights = np.concatenate(
            [np.ones(len(model_tips)), np.full(near.sum(), len(FINGER_NAMES) / max(near.sum(), 1))]
        )
        rotation, translation = rigid_fit(
            np.vstack([model_tips, surface[near]]), np.vstack([detections, cloud[near]]), weights
        )
    local = (cloud - translation) @ rotation
    _, distance = closest_capsule_points(
        local, start, end, capsules.radius_start_m, capsules.radius_end_m
    )
    return rotation, translation, float(np.mean(np.minimum(distance, _SURFACE_CLIP_M) ** 2))


def _hand_capsules(skeleton: Skeleton) -> CapsuleSet:
    thickness = _PALM_HALF_THICKNESS * skeleton.hand_length_m
    return concatenate(finger_capsules(skeleton), palm_capsules(skeleton, thickness))


def _hypotheses(n_detections: int, min_matched: int) -> list[tuple[NDArray, NDArray]]:
    """Per matched count m: (H, m) detection indices and (H, m) finger indices."""
    groups = []
    for m in range(min_matched, min(n_detections, len(FINGER_NAMES)) + 1):
        pairs = [
            (subset, fingers)
            for subset in itertools.combinations(range(n_detections), m)
            for fingers in itertools.permutations(range(len(FINGER_NAMES)), m)
        ]
        groups.append(
            (np.array([p[0] for p in pairs], np.intp), np.array([p[1] for p in pairs], np.intp))
        )
    return groups


def guess_hand_pose(
    detections_m: ArrayLike,
    *,
    posture_rad: ArrayLike | None = None,
    skeleton: Skeleton | None = None,
    hand_points_m: ArrayLike | None = None,
    unmatched_cost_m: float = 0.02,
    missed_cost_m: float = 0.01,
    max_detections: int = 6,
    min_matched: int = 3,
) -> PoseGuess | None:
    """Fit the rigid pose of the hand model to fingertip detections.

    Parameters
    ----------
    detections_m : (K, 3) float
        Detected fingertips in the camera frame, metres, strongest first (e.g.
        :func:`~fingertips.detect.detection_points` of
        :func:`~fingertips.detect_fingertips`).
    posture_rad : (20,) or (P, 20) float, optional
        Posture to assume, or several to choose from (the best fit wins); default
        the open hand (all zeros).
    skeleton : Skeleton, optional
        Hand size; default the default hand.
    hand_points_m : (N, 3) float, optional
        Depth points of the hand (:func:`hand_points_from_depth`); they decide between
        assignments whose fingertips fit about equally well (e.g. a mirrored hand)
        and between postures, and refine the pose of the best one.
    unmatched_cost_m : float
        A detection left out costs as much as a residual of this length.
    missed_cost_m : float
        A finger without a detection costs as much as a residual of this length.
    max_detections : int
        Only the first this many detections are used (the work grows quickly).
    min_matched : int
        Fewest detections matched to fingers (at least 3, which fix a rigid pose).

    Returns
    -------
    PoseGuess or None
        None when fewer than ``min_matched`` detections are given.
    """
    if min_matched < 3:
        raise ValueError(f"min_matched: expected at least 3, got {min_matched}")
    given = as_array("detections_m", detections_m, (None, 3), np.float64, finite=True)
    points = given[:max_detections]
    k = points.shape[0]
    if k < min_matched:
        return None
    skeleton = skeleton or make_skeleton()
    postures = (
        np.zeros((1, N_JOINTS))
        if posture_rad is None
        else as_array("posture_rad", posture_rad, (..., N_JOINTS), np.float64, finite=True)
    ).reshape(-1, N_JOINTS)
    kinematics = forward_kinematics(postures, skeleton)
    all_tips = kinematics.keypoints_m[:, list(FINGERTIP_KEYPOINTS)]
    candidates: list[_Candidate] = []
    for detection_index, finger_index in _hypotheses(k, min_matched):
        m = detection_index.shape[1]
        for p, tips in enumerate(all_tips):
            rotation, translation = batch_rigid_fit(tips[finger_index], points[detection_index])
            fitted = np.einsum("hij,hmj->hmi", rotation, tips[finger_index]) + translation[:, None]
            squared = np.sum((fitted - points[detection_index]) ** 2, axis=(1, 2))
            cost = (
                squared + (k - m) * unmatched_cost_m**2 + (len(FINGER_NAMES) - m) * missed_cost_m**2
            )
            for h in np.argsort(cost, kind="stable")[:_RESCORED]:
                candidates.append(
                    _Candidate(float(cost[h]), p, rotation[h], translation[h],
                               detection_index[h], finger_index[h])
                )  # fmt: skip
    candidates.sort(key=lambda c: c.cost)
    candidates = candidates[:_RESCORED]
    best = candidates[0]
    rotation, translation = best.rotation, best.translation
    model_tips = all_tips[best.posture][best.fingers]
    surface_ms = math.nan
    cloud = (
        None
        if hand_points_m is None
        else as_array("hand_points_m", hand_points_m, (None, 3), np.float64, finite=True)
    )
    if cloud is not None and cloud.shape[0]:
        capsules = _hand_capsules(skeleton)
        posed = [pose_capsules(capsules, bones) for bones in kinematics.bone_transforms]
        total = []
        for candidate in candidates:
            local = (cloud - candidate.translation) @ candidate.rotation  # R^T (p - t)
            start, end = posed[candidate.posture]
            distance = round_cone_distance(
                local, start, end, capsules.radius_start_m, capsules.radius_end_m
            ).min(axis=1)
            clipped = float(np.mean(np.minimum(np.abs(distance), _SURFACE_CLIP_M) ** 2))
            total.append(candidate.cost + len(FINGER_NAMES) * clipped)
        best = candidates[int(np.argmin(total))]
        model_tips = all_tips[best.posture][best.fingers]
        rotation, translation, surface_ms = _align_with_points(
            best.rotation,
            best.translation,
            model_tips,
            points[best.detections],
            cloud,
            posed[best.posture],
            capsules,
        )
    fitted = model_tips @ rotation.T + translation
    tip_ms = float(np.mean(np.sum((fitted - points[best.detections]) ** 2, axis=1)))
    fingers: list[str | None] = [None] * given.shape[0]
    for d, f in zip(best.detections, best.fingers, strict=True):
        fingers[int(d)] = FINGER_NAMES[int(f)]
    return PoseGuess(
        rotation=rotation,
        translation_m=translation,
        posture_rad=postures[best.posture].copy(),
        keypoints_3d_m=kinematics.keypoints_m[best.posture] @ rotation.T + translation,
        fingers=tuple(fingers),
        tip_rms_m=math.sqrt(tip_ms),
        surface_rms_m=math.sqrt(surface_ms) if np.isfinite(surface_ms) else math.nan,
    )


@dataclass(frozen=True)
class _Candidate:
    """One assignment hypothesis: its Eq. 11-like cost, posture index and pose."""

    cost: float
    posture: int
    rotation: NDArray[np.float64]
    translation: NDArray[np.float64]
    detections: NDArray[np.intp]
    fingers: NDArray[np.intp]
