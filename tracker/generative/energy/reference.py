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

Joints whose finger an object hides (:func:`hidden_joints`) are held firmly instead
(``hidden_weight``, no saturation): behind the object nothing is observed, and
without it the posture prior would curl the hidden fingers a little more every frame.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from glovedb.hand_model import N_BONES, N_JOINTS
from tracker.generative.energy.residuals import Residuals
from tracker.generative.model import MOVES, N_PARAMS, PosedHand
from tracker.generative.observation import Observation, look_up

NAME = "reference"


def hidden_joints(
    hand: PosedHand, observation: Observation, *, margin_px: float, depth_margin_m: float
) -> NDArray[np.bool_]:
    """``(20,)``: joints whose bones' camera-facing samples are mostly hidden by
    something in front that is not the glove (more than ``margin_px`` outside the
    observed hand mask, nearer than the sample in the observed depth), judged at the
    pose of ``hand``. The margin keeps the mask's edge, where colors blur and depth
    flies, from counting as an object."""
    facing = np.flatnonzero(hand.facing)
    points = hand.points_m[facing]
    pixels = look_up(observation, points)
    hidden = (
        pixels.inside
        & (pixels.outside_px > margin_px)
        & (pixels.seen_m > 0)
        & (pixels.seen_m < np.maximum(points[:, 2], 1e-3) - depth_margin_m)
    )
    bone = hand.samples.mesh.dominant_bone[facing]
    per_bone = np.bincount(bone, weights=hidden, minlength=N_BONES)
    count = np.bincount(bone, minlength=N_BONES)
    hidden_bone = (count >= 5) & (per_bone > 0.5 * np.maximum(count, 1))
    return np.asarray((MOVES * hidden_bone).any(axis=1), dtype=bool)


def reference_residuals(
    hand: PosedHand,
    reference_rad: NDArray[np.float64],
    *,
    weight: float,
    scale_rad: float,
    hidden: NDArray[np.bool_] | None = None,
    hidden_weight: float = 0.0,
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
    hidden : (20,) bool, optional
        Joints held with ``hidden_weight`` per radian instead, without saturation.
    hidden_weight : float
    """
    departure = hand.pose.posture_rad - reference_rad
    rows = weight / np.sqrt(1.0 + (departure / scale_rad) ** 2)
    if hidden is not None:
        rows = np.where(hidden, hidden_weight, rows)
    jacobian = np.zeros((N_JOINTS, N_PARAMS))
    jacobian[np.arange(N_JOINTS), 6 + np.arange(N_JOINTS)] = rows
    return Residuals(NAME, rows * departure, jacobian)
