"""Model-to-data term: the model must not show where the camera sees no hand.

Camera-facing model samples are projected into the image:

- a sample that lands outside the observed hand mask, more than ``margin_px`` from it,
  is pulled toward it: the residual is the distance transform of the mask at the
  sample (minus the margin), converted to metres at the sample's depth;
- a sample that lands on the hand (on the mask itself) but lies more than
  ``depth_margin_m`` in front of the observed depth is pushed back to it (the camera
  would have seen it there). Samples within the margin but off the mask are not:
  there the camera sees what lies behind the hand, a wall or a table in a real room,
  and pushing the hand's edge back to it dragged the fit by decimetres;
- a sample **behind** the observed depth (by more than the margin) is hidden by
  something in front: the hand itself or an object. It costs nothing, inside or
  outside the mask, so an object passing in front of the hand does not drag it.

This is the 2D/3D fitting of the thesis (ch. 6.2) in the robust form htrack uses
(Tagliasacchi et al. 2015): a one-sided silhouette term plus occlusion reasoning.
The samples are projected, classified and given their residuals in one compiled pass
(:func:`tracker.generative._kernels.silhouette_rows`).
"""

from __future__ import annotations

import numpy as np

from tracker.generative import _kernels
from tracker.generative.energy.residuals import Derivatives, Residuals, project_rows
from tracker.generative.model import PosedHand
from tracker.generative.observation import Observation

NAME = "silhouette"


def silhouette_residuals(
    hand: PosedHand,
    observation: Observation,
    *,
    weight: float,
    margin_px: float,
    depth_margin_m: float,
    max_samples: int,
    proportions: bool = False,
) -> tuple[Residuals, float]:
    """Residuals of model samples outside the observed hand or in front of its depth.

    Parameters
    ----------
    hand : PosedHand
    observation : Observation
    weight : float
        Per sample; residuals are metres times ``weight / sqrt(S)`` for the ``S``
        samples examined.
    margin_px : float
        Distance from the mask that costs nothing (noise of its edge).
    depth_margin_m : float
        Depth tolerance for "in front of" and "behind" the observed surface.
    max_samples : int
        Camera-facing samples examined (evenly chosen).
    proportions : bool
        Also give the derivatives by the hand proportions.

    Returns
    -------
    residuals : Residuals
    outside : float
        Share of the examined samples that lie outside the mask and are not hidden:
        model the camera should see but does not.
    """
    facing = np.flatnonzero(hand.facing)
    if len(facing) == 0:
        return Residuals.empty(NAME, proportions=proportions), 0.0
    chosen = facing[:: max(1, len(facing) // max(max_samples, 1))]
    count = len(chosen)
    kind = np.empty(count, dtype=np.int8)
    value, direction = np.empty(count), np.empty((count, 3))
    outside = _kernels.silhouette_rows(
        np.ascontiguousarray(hand.points_m[chosen]), observation.intrinsics.pinhole,
        observation.origin_uv, observation.outside_px, observation.gradient,
        observation.depth_m, float(margin_px), float(depth_margin_m), kind, value, direction,
    )  # fmt: skip
    outside_share = outside / count
    index = np.concatenate(
        [np.flatnonzero(kind == _kernels.PULL), np.flatnonzero(kind == _kernels.PUSH)]
    )
    if len(index) == 0:
        return Residuals.empty(NAME, proportions=proportions), outside_share
    scale = weight / np.sqrt(count)
    samples = chosen[index]
    along = direction[index]

    def derivatives() -> Derivatives:
        jacobian = scale * hand.directional_rows(samples, along)
        if not proportions:
            return jacobian, None
        return jacobian, scale * project_rows(hand.proportion_jacobian(samples), along)

    return Residuals.deferred(NAME, scale * value[index], derivatives), outside_share
