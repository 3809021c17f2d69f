"""Posture prior: natural postures, and the task's, are likely (thesis ch. 6.3, the PCA prior).

The residual is ``weight`` times the Mahalanobis residual of the posture under the
cheapest component of :mod:`glovedb.posture_prior`'s max-mixture: the Gaussian
learned from the project's natural postures, or a narrower one around a posture of
the task the database was built for. It is not a pull toward the database's nearest
posture: a posture far from every task posture costs what its naturalness says.
"""

from __future__ import annotations

import numpy as np

from glovedb.posture_prior import PosturePrior
from tracker.generative.energy.residuals import Residuals
from tracker.generative.model import N_PARAMS, PosedHand

NAME = "prior"


def prior_residuals(hand: PosedHand, prior: PosturePrior, *, weight: float) -> Residuals:
    """``(21,)`` weighted Mahalanobis residuals of the hand's posture (the last is the
    chosen component's offset, constant).

    Parameters
    ----------
    hand : PosedHand
    prior : PosturePrior
    weight : float
        Per standard deviation.
    """
    residual, whitening = prior.whitened(hand.pose.posture_rad)
    jacobian = np.zeros((len(residual), N_PARAMS))
    jacobian[:-1, 6:] = weight * whitening
    return Residuals(NAME, weight * residual, jacobian)
