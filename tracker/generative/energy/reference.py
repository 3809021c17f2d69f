"""Reference posture: joints the data does not see keep the start's angles.

From the camera many joint angles are barely observed: the curled fingers of a fist
seen from the back, a finger behind the palm. Their angles move freely within the
sensor's noise, and the posture prior alone pulls them toward the mean posture. This
term keeps them near the start's posture: the previous frame's solution while
tracking, or the database's posture for a start from the lookup. It is weak and
robust (Cauchy loss of scale ``scale_rad``), so that an angle the data does see moves
as far as the data says: it is not the old pull toward the looked-up posture that
kept postures outside the database wrong. Hypotheses are compared by their energy
without this term (:func:`tracker.generative.fit.fit_frame`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from glovedb.hand_model import N_JOINTS
from tracker.generative.energy.residuals import Residuals
from tracker.generative.model import N_PARAMS, PosedHand

NAME = "reference"


def reference_residuals(
    hand: PosedHand, reference_rad: NDArray[np.float64], *, weight: float, scale_rad: float
) -> Residuals:
    """``(20,)`` residuals ``weight * w_j * (theta_j - reference_j)`` with the Cauchy
    weights ``w_j = 1 / sqrt(1 + (d_j / scale_rad)**2)`` (IRLS; their derivative is
    left out of the Jacobian).

    Parameters
    ----------
    hand : PosedHand
    reference_rad : (20,) float64
    weight : float
        Per radian.
    scale_rad : float
    """
    departure = hand.pose.posture_rad - reference_rad
    rows = weight / np.sqrt(1.0 + (departure / scale_rad) ** 2)
    jacobian = np.zeros((N_JOINTS, N_PARAMS))
    jacobian[np.arange(N_JOINTS), 6 + np.arange(N_JOINTS)] = rows
    return Residuals(NAME, rows * departure, jacobian)
