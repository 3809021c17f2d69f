"""Assignment of fingertip detections to the fingertips of a posed hand model.

Tzionas et al. (GCPR 2014), Eq. 11 and Table 1: minimise::

    sum_st e_st w_st + lambda * sum_s alpha_s w_s + lambda * sum_t beta_t

where ``w_st`` is the 3D distance between detection ``s`` and model fingertip ``t``
in units of ``distance_unit_m``,
``alpha_s = 1`` leaves detection ``s`` unassigned (a false positive, cost
``lambda * w_s`` with ``w_s = c_s / c_thr``) and ``beta_t = 1`` leaves finger ``t``
without a detection (cost ``lambda``). Each detection and each finger is used exactly
once. Padding the S x T cost table with S "unassigned" columns and T "no detection"
rows makes it a square assignment problem, which
:func:`scipy.optimize.linear_sum_assignment` solves exactly.

The paper does not state the unit of ``w_st``. Leaving detection ``s`` out instead of
pairing it with finger ``t`` pays off only when ``w_st > lambda * (1 + w_s)``, so the
unit sets the association gate: in metres ``lambda = 1.2`` would pair detections up to
more than a metre away, in centimetres (the default here) the gate is 2.4 cm for a
detection at the threshold and grows with its confidence, which fits fingers about
2 cm apart.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment

from glovedb._validate import as_array

FINGER_NAMES = ("thumb", "index", "middle", "ring", "little")
"""Finger order of the five fingertips (docs/conventions.md)."""


@dataclass(frozen=True)
class Assignment:
    """Solution of Eq. 11.

    Attributes
    ----------
    finger_of_detection : (S,) int64
        Index of the model fingertip each detection is assigned to, -1 if unassigned.
    cost : float
        Value of the objective at the solution (distances in ``distance_unit_m``).
    """

    finger_of_detection: NDArray[np.int64]
    cost: float


def assign_detections(
    detections_m: ArrayLike,
    confidences: ArrayLike,
    model_tips_m: ArrayLike,
    *,
    c_thr: float = 3.0,
    lam: float = 1.2,
    distance_unit_m: float = 0.01,
) -> Assignment:
    """Solve the detection-to-fingertip integer program exactly.

    Parameters
    ----------
    detections_m : (S, 3) float
        Detected fingertip positions in the camera frame, metres.
    confidences : (S,) float
        Detection confidences ``c_s``.
    model_tips_m : (T, 3) float
        Fingertips of the posed model in the camera frame, metres.
    c_thr : float
        Confidence threshold; ``w_s = c_s / c_thr``.
    lam : float
        Weight ``lambda`` of the unassigned-detection and missing-finger costs.
    distance_unit_m : float
        Unit of the distances ``w_st`` in metres (0.01: centimetres).

    Returns
    -------
    Assignment
    """
    detections = as_array("detections_m", detections_m, (None, 3), np.float64, finite=True)
    n_det = detections.shape[0]
    conf = as_array("confidences", confidences, (n_det,), np.float64, finite=True)
    tips = as_array("model_tips_m", model_tips_m, (None, 3), np.float64, finite=True)
    if not c_thr > 0:
        raise ValueError(f"c_thr: expected a positive threshold, got {c_thr}")
    if lam < 0:
        raise ValueError(f"lam: expected a non-negative weight, got {lam}")
    if not distance_unit_m > 0:
        raise ValueError(f"distance_unit_m: expected a positive length, got {distance_unit_m}")
    n_tip = tips.shape[0]
    cost = np.zeros((n_det + n_tip, n_tip + n_det))
    distance = np.linalg.norm(detections[:, None] - tips[None], axis=2)
    cost[:n_det, :n_tip] = distance / distance_unit_m
    cost[:n_det, n_tip:] = (lam * conf / c_thr)[:, None]
    cost[n_det:, :n_tip] = lam
    rows, cols = linear_sum_assignment(cost)
    finger = np.full(n_det, -1, dtype=np.int64)
    real = (rows < n_det) & (cols < n_tip)
    finger[rows[real]] = cols[real]
    return Assignment(finger_of_detection=finger, cost=float(cost[rows, cols].sum()))
