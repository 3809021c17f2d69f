"""The heat at the candidates, and the logistic fusion of models trained before the judge.

The peak verifier (:mod:`fingertips.verify`) judges a candidate of the forest or the
geodesic stage from the depth 3 cm around it; the heatmap network
(:mod:`fingertips.heatmap`) sees the whole hand. :func:`candidate_heat` reads the heat
of the map cell a candidate falls in, one input of the candidate judge
(:mod:`fingertips.judge`) that models trained now carry.

Models trained before the judge (format 4) carry a fusion (``HeatmapStage.fusion``)
instead, with which the detector keeps a candidate by

    sigmoid(w0 + w1 log_odds(verifier probability) + w2 log_odds(heat of its cell))

(:func:`fused_probability`), a logistic regression that was fitted on the heatmap
verifier's training frames (docs/fingertips.md, "Candidates judged with the heat").
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fingertips.heatmap import GRID, HandHeatmaps, crop_units
from fingertips.judge import log_odds
from glovedb._validate import as_array


def candidate_heat(heatmaps: HandHeatmaps, points_m: ArrayLike) -> NDArray[np.float32]:
    """The mean heat ``(K,)`` of the map cell each point ``(K, 3)`` (metres) falls in.

    0 for a point outside the crop, and for every point when the frame has no maps.
    """
    points = as_array("points_m", points_m, (None, 3), np.float64)
    heat = np.zeros(len(points), np.float32)
    if heatmaps.centre is None or heatmaps.maps is None or not len(points):
        return heat
    cells = np.rint((crop_units(points, heatmaps.centre) + 1) / 2 * GRID - 0.5)
    inside = ((cells >= 0) & (cells < GRID)).all(axis=1) & (points[:, 2] > 0)
    column, row = cells[inside].astype(np.intp).T
    heat[inside] = heatmaps.maps.mean(axis=0)[row, column]
    return heat


def fused_probability(
    fusion: ArrayLike, verifier_probability: ArrayLike, heat: ArrayLike
) -> NDArray[np.float32]:
    """Candidates' probabilities ``(K,)`` from their peak verifier's and the heat there.

    ``sigmoid(fusion[0] + fusion[1] log_odds(verifier_probability) + fusion[2]
    log_odds(heat))``, the logistic regression of models trained before the candidate
    judge (:mod:`fingertips.judge`).
    """
    weights = as_array("fusion", fusion, (3,), np.float64, finite=True)
    z = weights[0] + weights[1] * log_odds(verifier_probability) + weights[2] * log_odds(heat)
    return (1.0 / (1.0 + np.exp(-z))).astype(np.float32)
