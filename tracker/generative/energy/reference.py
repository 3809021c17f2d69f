"""Reference posture: posture directions the data does not observe keep the start's angles.

From the camera many joint angles are barely observed: the curled fingers of a fist
seen from the back, a finger behind the palm, the distal joint of a finger whose
middle joint explains the same points. Their angles move freely within the sensor's
noise, and the posture prior alone pulls them toward the mean posture. This term
keeps them near the start's posture: the previous frame's solution while tracking, or
the database's posture for a start from the lookup. It is not the old pull toward
the looked-up posture that kept postures outside the database wrong: it acts only
where the data is silent.

"Where the data is silent" is measured at the start of each frame's fit
(:func:`posture_information`): the Gauss-Newton information ``J^T J`` of the data and
silhouette residuals about the 20 joint angles, with the 6 global unknowns
eliminated (Schur complement: a posture change that a small hand motion explains
equally well is not observed). Its eigenvectors ``v_k`` with eigenvalues
``lambda_k`` are the posture directions and how well the data sees each; the
reference holds direction ``k`` with the weight (:func:`reference_basis`)::

    w_k = reference_weight / sqrt(1 + lambda_k / observed_information)

so a direction the data sees well (``lambda_k >> observed_information``) is free, and
one it does not see keeps the start's value. Each row is robust (Cauchy loss of scale
``scale_rad``), so a large, well-founded change is not held back. Hypotheses are
compared by their energy without this term (:func:`tracker.generative.fit.fit_frame`).

Joints whose finger an object hides (:func:`hidden_joints`) are held firmly instead
(``hidden_weight``, no saturation): behind the object nothing is observed, and
without it the posture prior would curl the hidden fingers a little more every frame.
When the start is the previous frame's solution, so are the joints of a finger the
camera does not see at all (:func:`unseen_fingers`): a thumb behind the palm, seen
from the back of a power grasp, pairs with fewer than 10 of 1,600 observed points,
and without the hold it drifted 36 degrees over three seconds (the eigen-directions
above weigh what the data sees of all 20 angles; a few points on the thumb still make
its directions look observed). A start from the database is a guess, not something
seen, and is not held.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from glovedb.hand_model import N_BONES, N_JOINTS
from tracker.generative.energy.data import partners
from tracker.generative.energy.residuals import Residuals
from tracker.generative.model import MOVES, N_PARAMS, PosedHand
from tracker.generative.observation import CropLookup, Observation, look_up
from tracker.generative.solver import eliminated_information

NAME = "reference"
_GLOBAL = N_PARAMS - N_JOINTS  # the pose step's rotation and translation come first
UNSEEN_MIN_FACING = 20
"""A finger with fewer camera-facing samples is not judged by :func:`unseen_fingers`
(turned edge-on, it shows the camera too little for a share to mean anything)."""


@dataclass(frozen=True)
class ReferenceBasis:
    """The posture the reference term holds, along which directions and how firmly.

    Attributes
    ----------
    posture_rad : (20,) float64
        The start's joint angles.
    directions : (K, 20) float64
        Unit posture directions (rows).
    weights : (K,) float64
        Per radian along each direction.
    robust : (K,) bool
        Rows with the Cauchy loss; the others are plain squares (hidden joints).
    """

    posture_rad: NDArray[np.float64]
    directions: NDArray[np.float64]
    weights: NDArray[np.float64]
    robust: NDArray[np.bool_]


def hidden_joints(
    hand: PosedHand, observation: Observation, *, margin_px: float, depth_margin_m: float
) -> NDArray[np.bool_]:
    """``(20,)``: joints whose bones' camera-facing samples are mostly hidden by
    something in front that is not the glove (more than ``margin_px`` outside the
    observed hand mask, nearer than the sample in the observed depth), judged at the
    pose of ``hand``. The margin keeps the mask's edge, where colors blur and depth
    flies, from counting as an object."""
    facing, pixels, behind = _behind_observed_depth(hand, observation, depth_margin_m)
    hidden = pixels.inside & (pixels.outside_px > margin_px) & behind
    bone = hand.samples.mesh.dominant_bone[facing]
    per_bone = np.bincount(bone, weights=hidden, minlength=N_BONES)
    count = np.bincount(bone, minlength=N_BONES)
    hidden_bone = (count >= 5) & (per_bone > 0.5 * np.maximum(count, 1))
    return np.asarray((MOVES * hidden_bone).any(axis=1), dtype=bool)


def _behind_observed_depth(
    hand: PosedHand, observation: Observation, depth_margin_m: float
) -> tuple[NDArray[np.int64], CropLookup, NDArray[np.bool_]]:
    """The camera-facing samples of ``hand``, where they project, and whether the
    observed depth there lies more than ``depth_margin_m`` in front of them."""
    facing = np.flatnonzero(hand.facing)
    points = hand.points_m[facing]
    pixels = look_up(observation, points)
    behind = (pixels.seen_m > 0) & (pixels.seen_m < np.maximum(points[:, 2], 1e-3) - depth_margin_m)
    return facing, pixels, behind


def unseen_fingers(
    hand: PosedHand,
    observation: Observation,
    *,
    share: float,
    gate_m: float,
    depth_scale: float,
    depth_margin_m: float,
    nearest: NDArray[np.int64] | None = None,
) -> NDArray[np.bool_]:
    """``(20,)``: the joints of the fingers the camera does not see at the pose of
    ``hand`` because something is in front of them: fewer observed glove points pair
    with the finger's camera-facing samples (as the data term pairs them,
    :func:`tracker.generative.energy.data.nearest_of_class`) than ``share`` of the
    number of those samples, and most of those samples lie more than
    ``depth_margin_m`` behind the observed depth. A thumb behind the palm still faces
    the camera, but the camera sees the palm. A finger that sticks out of the observed
    hand into empty space is not unseen: it is in the wrong place, and the silhouette
    term pulls it in.

    Parameters
    ----------
    hand : PosedHand
    observation : Observation
    share : float
        Paired points per camera-facing sample below which a finger may be unseen.
    gate_m, depth_scale, depth_margin_m : float
        The data term's pairing and the silhouette term's depth margin
        (:class:`tracker.generative.fit.FitSettings`).
    nearest : (N,) int64, optional
        The observed points' partners at this pose
        (:func:`tracker.generative.energy.data.partners`), when already found.
    """
    if nearest is None:
        nearest = partners(
            hand, observation.points_m, observation.labels, gate_m=gate_m,
            depth_scale=depth_scale,
        )  # fmt: skip
    facing, _, covered = _behind_observed_depth(hand, observation, depth_margin_m)
    bone = hand.samples.mesh.dominant_bone

    def per_finger(counts: NDArray[Any]) -> NDArray[np.float64]:
        """Per-bone counts summed over each finger's three bones (bones 1-15)."""
        return np.asarray(counts[1:].reshape(5, 3).sum(axis=1), dtype=np.float64)

    paired = per_finger(np.bincount(bone[nearest[nearest >= 0]], minlength=N_BONES))
    count = per_finger(np.bincount(bone[facing], minlength=N_BONES))
    behind = per_finger(np.bincount(bone[facing], weights=covered, minlength=N_BONES))
    unseen = (count >= UNSEEN_MIN_FACING) & (paired < share * count) & (behind > 0.5 * count)
    return np.repeat(unseen, N_JOINTS // 5)  # 4 joints per finger, thumb first


def posture_information(terms: Sequence[Residuals]) -> NDArray[np.float64]:
    """``(20, 20)`` information of residuals about the joint angles, per radian²,
    with the 6 global unknowns eliminated (Schur complement of ``J^T J``).

    Parameters
    ----------
    terms : sequence of Residuals
        Their Jacobians ``(M, 26)`` are stacked.
    """
    jacobian = np.concatenate([np.zeros((0, N_PARAMS))] + [t.jacobian for t in terms])
    return eliminated_information(jacobian.T @ jacobian, _GLOBAL, ridge=1e-12)


def reference_basis(
    posture_rad: NDArray[np.float64],
    information: NDArray[np.float64],
    *,
    weight: float,
    observed_information: float,
    hidden: NDArray[np.bool_] | None = None,
    hidden_weight: float = 0.0,
) -> ReferenceBasis:
    """The directions and weights of the reference term (module docstring).

    Parameters
    ----------
    posture_rad : (20,) float
        The posture to hold.
    information : (20, 20) float
        From :func:`posture_information`, per radian².
    weight : float
        Per radian along a direction the data does not see.
    observed_information : float
        Information (per radian², in the residuals' units) at which a direction's
        weight is divided by ``sqrt(2)``; must be > 0.
    hidden : (20,) bool, optional
        Joints held with ``hidden_weight`` per radian in addition, without the
        Cauchy loss.
    hidden_weight : float

    Returns
    -------
    ReferenceBasis
    """
    eigenvalues, eigenvectors = np.linalg.eigh(np.asarray(information, dtype=np.float64))
    weights = weight / np.sqrt(1.0 + np.maximum(eigenvalues, 0.0) / observed_information)
    directions = eigenvectors.T
    robust = np.ones(N_JOINTS, dtype=bool)
    if hidden is not None and hidden.any() and hidden_weight > 0:
        held = np.flatnonzero(hidden)
        directions = np.vstack([directions, np.eye(N_JOINTS)[held]])
        weights = np.r_[weights, np.full(len(held), hidden_weight)]
        robust = np.r_[robust, np.zeros(len(held), dtype=bool)]
    return ReferenceBasis(
        np.asarray(posture_rad, dtype=np.float64).copy(), directions, weights, robust
    )


def reference_residuals(hand: PosedHand, basis: ReferenceBasis, *, scale_rad: float) -> Residuals:
    """``(K,)`` residuals ``w_k c_k v_k . (theta - reference)``, with the Cauchy
    weights ``c_k = 1 / sqrt(1 + (d_k / scale_rad)**2)`` of the departure ``d_k`` on
    the robust rows (1 on the others; IRLS: their derivative is left out of the
    Jacobian).

    Parameters
    ----------
    hand : PosedHand
    basis : ReferenceBasis
    scale_rad : float
    """
    departure = basis.directions @ (hand.pose.posture_rad - basis.posture_rad)
    cauchy = np.where(basis.robust, 1.0 / np.sqrt(1.0 + (departure / scale_rad) ** 2), 1.0)
    rows = basis.weights * cauchy
    jacobian = np.zeros((len(rows), N_PARAMS))
    jacobian[:, _GLOBAL:] = rows[:, None] * basis.directions
    return Residuals(NAME, rows * departure, jacobian)
