"""Posture prior: natural postures are likely (thesis ch. 6.3, the PCA prior).

The residual is ``weight * W @ (theta - mean)``, the Mahalanobis residual of the
posture under the Gaussian of :mod:`glovedb.posture_prior`, which was learned from
the project's natural postures. It is not a pull toward the database's nearest
posture: a posture no database holds costs what its naturalness says.
"""

from __future__ import annotations

import numpy as np

from glovedb.posture_prior import PosturePrior
from tracker.generative.energy.residuals import Residuals
from tracker.generative.model import N_PARAMS, PosedHand

NAME = "prior"


def prior_residuals(hand: PosedHand, prior: PosturePrior, *, weight: float) -> Residuals:
    """``(20,)`` weighted Mahalanobis residuals of the hand's posture.

    Parameters
    ----------
    hand : PosedHand
    prior : PosturePrior
    weight : float
        Per standard deviation.
    """
    jacobian = np.zeros((len(prior.mean_rad), N_PARAMS))
    jacobian[:, 6:] = weight * prior.whitening
    return Residuals(NAME, weight * prior.residual(hand.pose.posture_rad), jacobian)
