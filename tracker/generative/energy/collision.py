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
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array
from glovedb.capsules import CapsuleSet, finger_capsules
from glovedb.hand_model import N_JOINTS, Skeleton, forward_kinematics, make_skeleton
from tracker.generative import _kernels
from tracker.generative.energy.residuals import Derivatives, Residuals
from tracker.generative.model import PosedHand

NAME = "collision"


def segment_closest_points(
    a0: ArrayLike, a1: ArrayLike, b0: ArrayLike, b1: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Parameters of the closest points of pairs of segments.

    Parameters
    ----------
    a0, a1, b0, b1 : (P, 3) float
        End points of the segments ``a0-a1`` and ``b0-b1`` of ``P`` pairs.

    Returns
    -------
    s, t : (P,) float64
        In [0, 1]: the closest points are ``a0 + s (a1 - a0)`` and ``b0 + t (b1 - b0)``
        (for parallel segments, one of the closest pairs).
    """
    first = np.ascontiguousarray(as_array("a0", a0, (None, 3), np.float64))
    count = len(first)
    a_end, b_start, b_end = (
        np.ascontiguousarray(as_array(name, value, (count, 3), np.float64))
        for name, value in (("a1", a1), ("b0", b0), ("b1", b1))
    )
    s, t = np.empty(count), np.empty(count)
    _kernels.segment_parameters(first, a_end, b_start, b_end, s, t)
    return s, t


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
    """Overlaps ``(Q,)`` of the capsule pairs ``first, second`` posed by ``transforms
    (16, 4, 4)`` and the closest points of their axes ``(Q, 3)`` each, in the frame the
    transforms map into."""
    overlap = np.empty(len(first))
    pa, pb = np.empty((len(first), 3)), np.empty((len(first), 3))
    _kernels.capsule_overlaps(
        np.ascontiguousarray(transforms, dtype=np.float64), capsules.bone, capsules.start_m,
        capsules.end_m, capsules.radius_start_m, capsules.radius_end_m,
        np.ascontiguousarray(first, dtype=np.int64), np.ascontiguousarray(second, dtype=np.int64),
        overlap, pa, pb,
    )  # fmt: skip
    return overlap, pa, pb


@cache
def _model_pairs() -> NDArray[np.int64]:
    """The pairs of the model's skeleton, found on first use; proportions within their
    range do not change which cones overlap in the open hand."""
    return _pairs(make_skeleton())


def collision_residuals(hand: PosedHand, *, weight: float, tolerance_m: float = 0.002) -> Residuals:
    """Residuals ``weight * (overlap - tolerance_m)`` (per metre) of cones of two
    fingers that overlap by more than ``tolerance_m``."""
    pairs = _model_pairs()
    capsules = hand.samples.finger_capsules
    # Overlaps do not change with the hand's rigid pose: found in the hand frame.
    overlap, pa, pb = _overlaps(capsules, hand.bone_transforms, pairs[:, 0], pairs[:, 1])
    hit = np.flatnonzero(overlap > tolerance_m)
    if len(hit) == 0:
        return Residuals.empty(NAME)

    def derivatives() -> Derivatives:
        first, second = pairs[hit, 0], pairs[hit, 1]
        R, t = hand.pose.rotation, hand.pose.translation_m
        point_a, point_b = pa[hit] @ R.T + t, pb[hit] @ R.T + t  # camera frame
        away = point_a - point_b
        away /= np.maximum(np.linalg.norm(away, axis=1, keepdims=True), 1e-12)
        ja = hand.bone_point_jacobian(point_a, capsules.bone[first])
        jb = hand.bone_point_jacobian(point_b, capsules.bone[second])
        return -weight * np.einsum("pi,pik->pk", away, ja - jb), None

    return Residuals.deferred(NAME, weight * (overlap[hit] - tolerance_m), derivatives)
