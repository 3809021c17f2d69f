"""Data-to-model term: every observed glove point to the model surface of its color.

Each observed point is paired with the nearest camera-facing model sample of its own
color class (one k-d tree for all classes, :func:`tracker.icp.class_tree`); pairs
farther apart than ``gate_m`` are dropped. "Nearest" counts the distance along the
optical axis ``depth_scale`` times (0.5 by default): a depth sensor's noise lies along
its rays, and with plain 3D distances a point measured too deep near a finger's
silhouette pairs with the surface receding beside it, whose normal points sideways;
its residual then pulls that surface inward, and over many points and frames the
hand's estimated size shrinks (1.2 % under Kinect-like noise, with 0.3 mm more
position error). The residual is the point's distance to the
sample's tangent plane (point-to-plane, Tzionas et al. 2014 found it better than
point-to-point), under a Huber loss so that a few wrong colors or flying pixels do not
drag the hand. Its share of the observed points that found a partner is the fit's
main quality signal (:func:`tracker.generative.fit.FrameFit`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from tracker.generative.energy.residuals import Residuals, huber_weights, project_rows
from tracker.generative.model import PosedHand
from tracker.icp import class_coordinate, class_tree

NAME = "data"


def data_residuals(
    hand: PosedHand,
    observed_m: NDArray[np.float64],
    observed_labels: NDArray[np.uint8],
    *,
    weight: float,
    huber_m: float,
    gate_m: float,
    depth_scale: float = 1.0,
    proportions: bool = False,
) -> tuple[Residuals, float]:
    """Point-to-plane residuals of the observed points against the posed model.

    Parameters
    ----------
    hand : PosedHand
    observed_m : (N, 3) float64
        Glove points, camera frame.
    observed_labels : (N,) uint8
        Their classes.
    weight : float
        Per point; the residuals are metres times ``weight / sqrt(N)``, so the term
        does not grow with the number of points.
    huber_m : float
        Residuals beyond this count linearly.
    gate_m : float
        Pairs farther apart (in the pairing distance) are dropped.
    depth_scale : float
        Weight of the distance along the optical axis (z) in the pairing distance;
        1 pairs by plain 3D distance.
    proportions : bool
        Also give the derivatives by the hand proportions.

    Returns
    -------
    residuals : Residuals
    matched : float
        Share of the observed points that found a partner within the gate.
    """
    members = np.flatnonzero(hand.facing)
    if len(members) == 0 or len(observed_m) == 0:
        return Residuals.empty(NAME, proportions=proportions), 0.0
    squash = np.array([1.0, 1.0, depth_scale])
    tree = class_tree(hand.points_m[members] * squash, hand.samples.labels[members])
    query = np.column_stack([observed_m * squash, class_coordinate(observed_labels)])
    distance, nearest = tree.query(query)
    kept = np.flatnonzero(distance < gate_m)  # another class is 100 m away
    matched = len(kept) / len(observed_m)
    if len(kept) == 0:
        return Residuals.empty(NAME, proportions=proportions), matched
    sample = members[nearest[kept]]
    normals = hand.normals[sample]
    raw = np.einsum("ij,ij->i", hand.points_m[sample] - observed_m[kept], normals)
    rows = weight / np.sqrt(len(observed_m)) * huber_weights(raw, huber_m)
    jacobian = rows[:, None] * hand.directional_rows(sample, normals)
    by_proportions = None
    if proportions:
        by_proportions = rows[:, None] * project_rows(hand.proportion_jacobian(sample), normals)
    return Residuals(NAME, rows * raw, jacobian, by_proportions), matched
