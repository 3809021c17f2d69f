"""Model-to-data term: the model must not show where the camera sees no hand.

Camera-facing model samples are projected into the image:

- a sample that lands outside the observed hand mask, more than ``margin_px`` from it,
  is pulled toward it: the residual is the distance transform of the mask at the
  sample (minus the margin), converted to metres at the sample's depth;
- a sample that lands on the hand but lies more than ``depth_margin_m`` in front of
  the observed depth is pushed back to it (the camera would have seen it there);
- a sample **behind** the observed depth (by more than the margin) is hidden by
  something in front: the hand itself or an object. It costs nothing, inside or
  outside the mask, so an object passing in front of the hand does not drag it.

This is the 2D/3D fitting of the thesis (ch. 6.2) in the robust form htrack uses
(Tagliasacchi et al. 2015): a one-sided silhouette term plus occlusion reasoning.
"""

from __future__ import annotations

import numpy as np

from tracker.generative.energy.residuals import Residuals, project_rows
from tracker.generative.model import PosedHand
from tracker.generative.observation import Observation, look_up

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
    points = hand.points_m[chosen]
    z = np.maximum(points[:, 2], 1e-3)
    fx, fy, _, _ = observation.intrinsics.pinhole
    pixels = look_up(observation, points)
    row, col, inside_crop = pixels.row, pixels.col, pixels.inside
    seen, distance = pixels.seen_m, pixels.outside_px
    hidden = (seen > 0) & (seen < z - depth_margin_m)
    off_mask = (distance > margin_px) & ~hidden
    # Beyond the crop the distance is unknown but large: those samples go through the
    # crop's edge value (the pull's direction is still right).
    off_crop = ~inside_crop & ~hidden
    in_front = inside_crop & ~off_mask & (seen > 0) & (z < seen - depth_margin_m)
    scale = weight / np.sqrt(len(chosen))
    rows = []
    directions = []
    values = []
    pull = np.flatnonzero(off_mask & inside_crop)
    if len(pull):
        metres_per_px = z[pull] / fx
        values.append((distance[pull] - margin_px) * metres_per_px)
        g = observation.gradient[row[pull], col[pull]]
        # d(distance)/dp = g_u du/dp + g_v dv/dp, times metres per pixel.
        direction = np.column_stack(
            [
                g[:, 0] * fx / z[pull],
                g[:, 1] * fy / z[pull],
                -(g[:, 0] * fx * points[pull, 0] + g[:, 1] * fy * points[pull, 1]) / z[pull] ** 2,
            ]
        )
        directions.append(direction * metres_per_px[:, None])
        rows.append(pull)
    push = np.flatnonzero(in_front)
    if len(push):
        values.append(z[push] - (seen[push] - depth_margin_m))
        directions.append(np.tile([0.0, 0.0, 1.0], (len(push), 1)))
        rows.append(push)
    outside_share = float(np.mean(off_mask | off_crop))
    if not rows:
        return Residuals.empty(NAME, proportions=proportions), outside_share
    index = np.concatenate(rows)
    direction = np.concatenate(directions)
    value = scale * np.concatenate(values)
    samples = chosen[index]
    jacobian = scale * hand.directional_rows(samples, direction)
    by_proportions = None
    if proportions:
        by_proportions = scale * project_rows(hand.proportion_jacobian(samples), direction)
    return Residuals(NAME, value, jacobian, by_proportions), outside_share
