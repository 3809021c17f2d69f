"""The candidates' fused probability: the peak verifier's and the heatmap's together.

The peak verifier (:mod:`fingertips.verify`) judges a candidate of the forest or the
geodesic stage from the depth 3 cm around it; the heatmap network
(:mod:`fingertips.heatmap`) sees the whole hand. A fingertip and a knuckle, a wrist
corner or a palm rim look alike up close, and the verifier keeps its precision by
dropping both; the heat where the candidate lies tells them apart. With a model whose
heatmap stage has a fusion (``HeatmapStage.fusion``) the detector keeps a candidate
by

    sigmoid(w0 + w1 log_odds(verifier probability) + w2 log_odds(heat of its cell))

(:func:`fused_probability`; :func:`candidate_heat` reads the cell), a logistic
regression fitted on the heatmap verifier's training frames
(:func:`fit_candidate_fusion`, called by
:func:`fingertips.heatmap_training.train_heatmap`). On the 200 ``validation.toml``
frames, fitted on one half and scored on the other, it kept 0.33 and 0.50 of the
tips at precision 0.95 where the verifier alone kept 0.30 and 0.34
(docs/fingertips.md, "Candidates judged with the heat").
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fingertips.heatmap import GRID, HandHeatmaps, crop_units
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


def log_odds(probability: ArrayLike) -> NDArray[np.float64]:
    """``log(p / (1 - p))`` of probabilities clipped to [1e-4, 1 - 1e-4]."""
    p = np.clip(np.asarray(probability, dtype=np.float64), 1e-4, 1 - 1e-4)
    return np.log(p / (1 - p))


def fused_probability(
    fusion: ArrayLike, verifier_probability: ArrayLike, heat: ArrayLike
) -> NDArray[np.float32]:
    """Candidates' probabilities ``(K,)`` from their peak verifier's and the heat there.

    ``sigmoid(fusion[0] + fusion[1] log_odds(verifier_probability) + fusion[2]
    log_odds(heat))``: a logistic regression fitted on the heatmap verifier's frames
    (:func:`fit_candidate_fusion`). The verifier sees 3 cm
    around a candidate, the network the whole hand: the heat tells a fingertip from a
    knuckle or a wrist corner that look alike up close.
    """
    weights = as_array("fusion", fusion, (3,), np.float64, finite=True)
    z = weights[0] + weights[1] * log_odds(verifier_probability) + weights[2] * log_odds(heat)
    return (1.0 / (1.0 + np.exp(-z))).astype(np.float32)


def fit_candidate_fusion(
    probability: NDArray[np.float32], heat: NDArray[np.float32], labels: NDArray[np.bool_]
) -> NDArray[np.float64]:
    """The fusion's ``(3,)`` weights (:func:`fused_probability`): a logistic regression
    (L2, C = 1) of the candidates' labels on the log-odds of their peak verifier
    probability and of the heat there.

    Raises
    ------
    ValueError
        Unless there are both true and false candidates.
    """
    from sklearn.linear_model import LogisticRegression

    if labels.all() or not labels.any():
        raise ValueError("heatmap: need both true and false candidates to fit the fusion")
    inputs = np.column_stack([log_odds(probability), log_odds(heat)])
    model = LogisticRegression(C=1.0, max_iter=1000).fit(inputs, labels)
    return np.array([model.intercept_[0], *model.coef_[0]], dtype=np.float64)
