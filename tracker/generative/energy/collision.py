"""Collision: fingers do not pass into each other (thesis ch. 6.3; Tzionas et al. 2014).

The fingers' volumes are the round cones of :mod:`glovedb.capsules`. For every pair
of cones on two different fingers, the closest points of their axes are found; where
the cones overlap by more than ``tolerance_m`` (the sum of their radii there exceeds
the distance), the excess times ``weight`` is a residual that pushes the two axis
points apart. Left out:

- pairs that already overlap in the open flat hand (cones at the fingers' bases,
  which the palm joins);
- the thumb: its cones are fat at the base, where they stand for the thenar
  eminence, and the named postures the databases are built from (``fist``, ``point``)
  lay the thumb 1-2 cm into the curled fingers' cones. Those postures are the truth of
  the synthetic sequences, so a thumb collision would push the fit away from it.
"""

from __future__ import annotations

from functools import cache

import numpy as np
from numpy.typing import NDArray

from glovedb.capsules import CapsuleSet, finger_capsules
from glovedb.hand_model import N_JOINTS, Skeleton, forward_kinematics, make_skeleton
from tracker.generative.energy.residuals import Residuals
from tracker.generative.model import PosedHand

NAME = "collision"


def segment_closest_points(
    a0: NDArray[np.float64],
    a1: NDArray[np.float64],
    b0: NDArray[np.float64],
    b1: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Parameters ``s, t`` in [0, 1] of the closest points of segments ``a0-a1`` and
    ``b0-b1`` (``(P, 3)`` each), for ``P`` pairs at once."""
    da, db, r = a1 - a0, b1 - b0, a0 - b0
    aa, bb = np.einsum("pi,pi->p", da, da), np.einsum("pi,pi->p", db, db)
    ab, ar, br = (
        np.einsum("pi,pi->p", da, db),
        np.einsum("pi,pi->p", da, r),
        np.einsum("pi,pi->p", db, r),
    )
    denominator = aa * bb - ab * ab
    parallel = denominator < 1e-12 * np.maximum(aa * bb, 1e-30)
    s = np.where(
        parallel, 0.0, np.clip((ab * br - bb * ar) / np.where(parallel, 1.0, denominator), 0, 1)
    )
    t = (ab * s + br) / np.maximum(bb, 1e-30)
    t_clipped = np.clip(t, 0.0, 1.0)
    s = np.where(t != t_clipped, np.clip((ab * t_clipped - ar) / np.maximum(aa, 1e-30), 0, 1), s)
    return s, t_clipped


def _posed(capsules: CapsuleSet, transforms: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
    """Capsule axis end points in the frame ``transforms (16, 4, 4)`` map into."""
    m = transforms[capsules.bone]
    start = np.einsum("cij,cj->ci", m[:, :3, :3], capsules.start_m) + m[:, :3, 3]
    end = np.einsum("cij,cj->ci", m[:, :3, :3], capsules.end_m) + m[:, :3, 3]
    return start, end


def _pairs(skeleton: Skeleton) -> NDArray[np.int64]:
    """``(Q, 2)`` capsule pairs on different fingers that do not overlap at rest."""
    capsules = finger_capsules(skeleton)
    finger = (capsules.bone - 1) // 3
    first, second = np.triu_indices(len(capsules), k=1)
    keep = (finger[first] != finger[second]) & (finger[first] > 0) & (finger[second] > 0)
    first, second = first[keep], second[keep]
    rest = forward_kinematics(np.zeros(N_JOINTS), skeleton).bone_transforms[0]
    overlap = _overlaps(capsules, rest, first, second)[0]
    keep = overlap <= 0
    return np.column_stack([first[keep], second[keep]])


def _overlaps(
    capsules: CapsuleSet, transforms: NDArray, first: NDArray, second: NDArray
) -> tuple[NDArray, NDArray, NDArray]:
    start, end = _posed(capsules, transforms)
    s, t = segment_closest_points(start[first], end[first], start[second], end[second])
    pa = start[first] + s[:, None] * (end[first] - start[first])
    pb = start[second] + t[:, None] * (end[second] - start[second])
    ra = capsules.radius_start_m[first] + s * (
        capsules.radius_end_m[first] - capsules.radius_start_m[first]
    )
    rb = capsules.radius_start_m[second] + t * (
        capsules.radius_end_m[second] - capsules.radius_start_m[second]
    )
    return ra + rb - np.linalg.norm(pa - pb, axis=1), pa, pb


@cache
def _model_pairs() -> NDArray[np.int64]:
    """The pairs of the model's skeleton, found on first use; proportions within their
    range do not change which cones overlap in the open hand."""
    return _pairs(make_skeleton())


def collision_residuals(hand: PosedHand, *, weight: float, tolerance_m: float = 0.002) -> Residuals:
    """Residuals ``weight * (overlap - tolerance_m)`` (per metre) of cones of two
    fingers that overlap by more than ``tolerance_m``."""
    skeleton = hand.samples.skeleton
    pairs = _model_pairs()
    capsules = finger_capsules(skeleton)
    R, t = hand.pose.rotation, hand.pose.translation_m
    camera_T_bone = hand.bone_transforms.copy()
    camera_T_bone[:, :3, :3] = R @ camera_T_bone[:, :3, :3]
    camera_T_bone[:, :3, 3] = camera_T_bone[:, :3, 3] @ R.T + t
    overlap, pa, pb = _overlaps(capsules, camera_T_bone, pairs[:, 0], pairs[:, 1])
    hit = np.flatnonzero(overlap > tolerance_m)
    if len(hit) == 0:
        return Residuals.empty(NAME)
    first, second = pairs[hit, 0], pairs[hit, 1]
    away = pa[hit] - pb[hit]
    away /= np.maximum(np.linalg.norm(away, axis=1, keepdims=True), 1e-12)
    ja = hand.bone_point_jacobian(pa[hit], capsules.bone[first])
    jb = hand.bone_point_jacobian(pb[hit], capsules.bone[second])
    jacobian = -weight * np.einsum("pi,pik->pk", away, ja - jb)
    return Residuals(NAME, weight * (overlap[hit] - tolerance_m), jacobian)
