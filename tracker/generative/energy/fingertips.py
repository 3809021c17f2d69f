"""Salient points: model fingertips to fingertip detections (Tzionas et al. 2014, Eq. 12).

Depth fingertip detections (:mod:`fingertips`), named by Eq. 11 against the
model's fingertips, pull those fingertips toward them: three residuals per named
finger, the 3D distance beyond a dead band (:func:`deadband_weights`), since the
detections lie a median 8-9 mm from the true tips on the synthetic sequences.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb.hand_model import FINGERTIP_KEYPOINTS
from tracker.generative.energy.residuals import Derivatives, Residuals
from tracker.generative.model import PosedHand

NAME = "fingertips"


def deadband_weights(residual: ArrayLike, deadband_m: float) -> NDArray[np.float64]:
    """Row weights that make 3D residuals cost ``(|r| - deadband)**2`` beyond the band.

    Iteratively reweighted least squares for the loss ``max(0, |r| - deadband)**2``:
    each 3D residual's rows get the weight ``sqrt(max(0, 1 - deadband / |r|))``, so a
    residual within the band adds nothing and a long one is pulled back to the band's
    edge, not to zero.

    Parameters
    ----------
    residual : (3F,) float
        F stacked 3D residuals, metres.
    deadband_m : float
        Metres; 0 gives weights of 1 (plain least squares).

    Returns
    -------
    (3F,) float64
    """
    size = np.linalg.norm(np.asarray(residual, dtype=np.float64).reshape(-1, 3), axis=1)
    if deadband_m == 0:
        return np.ones(3 * len(size))
    share = 1.0 - deadband_m / np.maximum(size, np.finfo(np.float64).tiny)
    return np.sqrt(np.clip(share, 0.0, None)).repeat(3)


def fingertip_residuals(
    hand: PosedHand, targets_m: NDArray[np.float64], *, weight: float, deadband_m: float
) -> Residuals:
    """Residuals of the model's fingertips against their targets.

    Parameters
    ----------
    hand : PosedHand
    targets_m : (5, 3) float64
        Camera-frame target of each finger's tip, thumb first; NaN rows have none.
    weight : float
        Per metre beyond the dead band.
    deadband_m : float
    """
    named = np.flatnonzero(np.isfinite(targets_m).all(axis=1))
    if len(named) == 0:
        return Residuals.empty(NAME)
    tips = np.asarray(FINGERTIP_KEYPOINTS)[named]
    raw = (hand.keypoints_m[tips] - targets_m[named]).reshape(-1)
    rows = weight * deadband_weights(raw, deadband_m)

    def derivatives() -> Derivatives:
        return rows[:, None] * hand.keypoint_jacobian(tips).reshape(len(raw), -1), None

    return Residuals.deferred(NAME, rows * raw, derivatives)
