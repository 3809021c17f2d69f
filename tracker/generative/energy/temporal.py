"""Temporal smoothness: the hand moves little from one frame to the next (thesis 6.3).

Residuals are the differences of the keypoints (camera frame, metres) from where the
previous frame's fit put them, times ``weight / sqrt(21)``, under a Cauchy loss of
scale ``scale_m``: keypoints weigh a rotation about the wrist by what it moves, unlike
raw angles, and a keypoint that moved far (a fast hand, or a start from the database
lookup far from the last frame's pose) costs nearly a constant instead of being held
back. A small weight removes the sensor noise's jitter while the data terms still
follow a moving hand.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from glovedb.hand_model import N_KEYPOINTS
from tracker.generative.energy.residuals import Derivatives, Residuals
from tracker.generative.model import PosedHand

NAME = "temporal"
_ALL = np.arange(N_KEYPOINTS)


def temporal_residuals(
    hand: PosedHand,
    previous_keypoints_m: NDArray[np.float64],
    *,
    weight: float,
    scale_m: float = 0.02,
) -> Residuals:
    """``(63,)`` weighted keypoint displacements from the previous frame's ``(21, 3)``.

    The rows of a keypoint displaced by ``d`` are weighted by
    ``1 / sqrt(1 + |d|**2 / scale_m**2)`` (iteratively reweighted Cauchy loss; the
    weight's derivative is left out of the Jacobian, as in IRLS).
    """
    moved = hand.keypoints_m - previous_keypoints_m
    robust = 1.0 / np.sqrt(1.0 + np.sum(moved**2, axis=1) / scale_m**2)
    rows = (weight / np.sqrt(N_KEYPOINTS) * robust).repeat(3)

    def derivatives() -> Derivatives:
        return rows[:, None] * hand.keypoint_jacobian(_ALL).reshape(3 * N_KEYPOINTS, -1), None

    return Residuals.deferred(NAME, rows * moved.reshape(-1), derivatives)
