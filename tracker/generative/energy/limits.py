"""Joint limits as a penalty (thesis ch. 6.3).

Every angle beyond its limit (:data:`glovedb.hand_model.JOINT_LIMITS_DEG`) costs
``(weight * excess)**2``; within the limits nothing. A stiff penalty instead of a
clip keeps the solver's steps consistent with its linear model.
"""

from __future__ import annotations

import numpy as np

from glovedb.hand_model import joint_limits_rad
from tracker.generative.energy.residuals import Residuals
from tracker.generative.model import N_PARAMS, PosedHand

NAME = "limits"
_LIMITS = joint_limits_rad()


def limit_residuals(hand: PosedHand, *, weight: float) -> Residuals:
    """Residuals ``weight * excess`` (per radian) of the angles beyond their limits."""
    theta = hand.pose.posture_rad
    excess = np.maximum(theta - _LIMITS[:, 1], 0.0) - np.maximum(_LIMITS[:, 0] - theta, 0.0)
    beyond = np.flatnonzero(excess != 0)
    jacobian = np.zeros((len(beyond), N_PARAMS))
    jacobian[np.arange(len(beyond)), 6 + beyond] = weight
    return Residuals(NAME, weight * excess[beyond], jacobian)
