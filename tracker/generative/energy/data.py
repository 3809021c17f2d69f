"""Data-to-model term: every observed glove point to the model surface of its color.

Each observed point is paired with the nearest camera-facing model sample of its own
color class (:func:`nearest_of_class`: a compiled search over the samples binned by
class and by a grid across the image plane; the model moves at every evaluation, and
building a k-d tree each time cost several times the search); pairs farther apart
than ``gate_m`` are dropped. "Nearest" counts the distance along the
optical axis ``depth_scale`` times (0.5 by default): a depth sensor's noise lies along
its rays, and with plain 3D distances a point measured too deep near a finger's
silhouette pairs with the surface receding beside it, whose normal points sideways;
its residual then pulls that surface inward, and over many points and frames the
hand's estimated size shrinks (1.2 % under Kinect-like noise, with 0.3 mm more
position error). The residual is the point's distance to the
sample's tangent plane (point-to-plane, Tzionas et al. 2014 found it better than
point-to-point), under a Huber loss so that a few wrong colors or flying pixels do not
drag the hand; the distances come from one compiled pass
(:meth:`tracker.generative.model.PosedHand.plane_distances`), their Jacobian rows,
when the solver asks for them, from another
(:meth:`tracker.generative.model.PosedHand.plane_rows`). Its share of the observed
points that found a partner is the fit's main quality signal
(:func:`tracker.generative.fit.FrameFit`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array
from tracker.generative import _kernels
from tracker.generative.energy.residuals import (
    Derivatives,
    Residuals,
    huber_weights,
    project_rows,
)
from tracker.generative.model import PosedHand

NAME = "data"

CELL_M = 0.006
"""Side of the grid cells :func:`nearest_of_class` bins the model points into: about
two samples apart, so that a query's nearest sample is mostly within its own and the
eight cells around (any side gives the same pairs; this one was fastest)."""


def nearest_of_class(
    observed_m: ArrayLike,
    observed_labels: ArrayLike,
    model_m: ArrayLike,
    model_labels: ArrayLike,
    *,
    gate_m: float,
    depth_scale: float = 1.0,
    candidates: ArrayLike | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Pair every observed point with the nearest model point of its class.

    The distance is ``|diag(1, 1, depth_scale) (p - q)|``; pairs at ``gate_m`` or
    farther are not made. What a k-d tree over all classes with the class as a far
    fourth coordinate finds, up to ties, without building one (the rigid ICP,
    :mod:`tracker.icp`, pairs with it too): the model points are binned by class and
    by a grid over x and y, and a query visits the cells of its class in rings around
    its own until no nearer point can remain.

    Parameters
    ----------
    observed_m : (N, 3) float
        Query points, metres.
    observed_labels : (N,) uint8
        Their classes.
    model_m : (M, 3) float
        Points to pair with, metres, same frame.
    model_labels : (M,) uint8
        Their classes.
    gate_m : float
        Largest pairing distance (exclusive), metres.
    depth_scale : float
        Weight of the z component in the distance; 1 for plain 3D distances.
    candidates : (M,) bool, optional
        The model points that may pair (default: all).

    Returns
    -------
    distance_m : (N,) float64
        To the partner, in the pairing distance; ``inf`` where none.
    nearest : (N,) int64
        Row of ``model_m`` of the partner; -1 where none.
    """
    observed = as_array("observed_m", observed_m, (None, 3), np.float64)
    observed_classes = as_array("observed_labels", observed_labels, (len(observed),), np.uint8)
    model = as_array("model_m", model_m, (None, 3), np.float64)
    model_classes = as_array("model_labels", model_labels, (len(model),), np.uint8)
    usable = (
        np.ones(len(model), dtype=bool)
        if candidates is None
        else as_array("candidates", candidates, (len(model),), bool)
    )
    return _pair(observed, observed_classes, model, model_classes, usable, gate_m, depth_scale)


def _pair(
    observed: NDArray[np.float64],
    observed_labels: NDArray[np.uint8],
    model: NDArray[np.float64],
    model_labels: NDArray[np.uint8],
    candidates: NDArray[np.bool_],
    gate_m: float,
    depth_scale: float,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """:func:`nearest_of_class` on checked arrays."""
    distance = np.empty(len(observed))
    nearest = np.empty(len(observed), dtype=np.int64)
    _kernels.nearest_of_class(
        np.ascontiguousarray(model, dtype=np.float64),
        np.ascontiguousarray(model_labels, dtype=np.uint8),
        np.ascontiguousarray(candidates, dtype=bool),
        np.ascontiguousarray(observed, dtype=np.float64),
        np.ascontiguousarray(observed_labels, dtype=np.uint8), float(gate_m), float(depth_scale),
        CELL_M,
        nearest, distance,
    )  # fmt: skip
    return distance, nearest


def partners(
    hand: PosedHand,
    observed_m: NDArray[np.float64],
    observed_labels: NDArray[np.uint8],
    *,
    gate_m: float,
    depth_scale: float = 1.0,
) -> NDArray[np.int64]:
    """``(N,)`` the sample each observed point pairs with in the data term: the nearest
    camera-facing sample of its class (:func:`nearest_of_class`), -1 for none."""
    return _pair(
        observed_m, observed_labels, hand.points_m, hand.samples.labels, hand.facing, gate_m,
        depth_scale,
    )[1]  # fmt: skip


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
    nearest: NDArray[np.int64] | None = None,
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
    nearest : (N,) int64, optional
        :func:`partners` of this hand and these points, when already found.

    Returns
    -------
    residuals : Residuals
    matched : float
        Share of the observed points that found a partner within the gate.
    """
    if len(observed_m) == 0 or not hand.facing.any():
        return Residuals.empty(NAME, proportions=proportions), 0.0
    if nearest is None:
        nearest = partners(
            hand, observed_m, observed_labels, gate_m=gate_m, depth_scale=depth_scale
        )
    kept = np.flatnonzero(nearest >= 0)
    matched = len(kept) / len(observed_m)
    if len(kept) == 0:
        return Residuals.empty(NAME, proportions=proportions), matched
    sample = nearest[kept]
    targets = observed_m[kept]
    raw = hand.plane_distances(sample, targets)
    rows = weight / np.sqrt(len(observed_m)) * huber_weights(raw, huber_m)

    def derivatives() -> Derivatives:
        jacobian = rows[:, None] * hand.plane_rows(sample, targets)[1]
        if not proportions:
            return jacobian, None
        by_proportions = project_rows(hand.proportion_jacobian(sample), hand.normals[sample])
        return jacobian, rows[:, None] * by_proportions

    return Residuals.deferred(NAME, rows * raw, derivatives), matched
