"""The candidate judge: boosted trees that decide which candidates are fingertips.

Every candidate of the forest and the geodesic stage (:mod:`fingertips.candidates`)
has the peak verifier's probability (:mod:`fingertips.verify`, which sees 3 cm of
depth around it), the heat of its cell in the heatmap network's maps
(:func:`fingertips.heat_fusion.candidate_heat`, the network sees the whole hand) and
the verifier's own features (:data:`fingertips.verify.UNION_FEATURES`). A fingertip
and a knuckle, a wrist corner or a palm rim look alike up close; the heat tells them
apart, and how much to trust either depends on what the features say of the
candidate (its depth, its votes, the finger behind it). With a model whose heatmap
stage has a judge (``HeatmapStage.judge``) the detector keeps a candidate by the
probability of boosted trees over all of them (:data:`JUDGE_FEATURES`,
:func:`judged_probability`), fitted on the heatmap verifier's training frames
(:func:`fit_candidate_judge`, called by
:func:`fingertips.heatmap_training.train_heatmap`).

It replaced a logistic regression on the two log-odds alone
(:func:`fingertips.heat_fusion.fused_probability`, still applied for models that
have it): on the 200 ``validation.toml`` frames the judged candidates alone keep 0.486
of the tips at precision 0.952 where the fused ones kept 0.303 at 0.959, and the whole
detector 0.557 instead of 0.475 at precision 0.937 (docs/fingertips.md, "The
candidate judge").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fingertips.trees import PackedNodes, boosted_probability, check_tree_table
from fingertips.verify import UNION_FEATURES
from glovedb._validate import as_array

JUDGE_FEATURES: tuple[str, ...] = ("verifier_log_odds", "heat_log_odds", *UNION_FEATURES)
"""The judge's inputs, in order: the log-odds of the peak verifier's probability and of
the heat at the candidate (:func:`log_odds`), then every candidate feature."""


def log_odds(probability: ArrayLike) -> NDArray[np.float64]:
    """``log(p / (1 - p))`` of probabilities clipped to [1e-4, 1 - 1e-4]."""
    p = np.clip(np.asarray(probability, dtype=np.float64), 1e-4, 1 - 1e-4)
    return np.log(p / (1 - p))


@dataclass(frozen=True, eq=False)
class CandidateJudge(PackedNodes):
    """Boosted trees over :data:`JUDGE_FEATURES`, as stored in the model file.

    Attributes
    ----------
    tree_roots, node_feature, node_threshold, node_left, node_right
        The node table (:mod:`fingertips.trees`).
    node_value : (n,) float32
        Each leaf's contribution to the log-odds (0 at splits).
    baseline : float
        The log-odds before any tree.
    """

    tree_roots: NDArray[np.int32]
    node_feature: NDArray[np.int32]
    node_threshold: NDArray[np.float32]
    node_left: NDArray[np.int32]
    node_right: NDArray[np.int32]
    node_value: NDArray[np.float32]
    baseline: float

    def __post_init__(self) -> None:
        check_tree_table(self, len(JUDGE_FEATURES))
        as_array("node_value", self.node_value, (self.node_feature.shape[0],), finite=True)
        if not np.isfinite(self.baseline):
            raise ValueError(f"baseline: expected a finite log-odds, got {self.baseline}")


def judge_inputs(
    verifier_probability: ArrayLike, heat: ArrayLike, features: ArrayLike
) -> NDArray[np.float32]:
    """The judge's input rows ``(K, len(JUDGE_FEATURES))`` float32.

    Parameters
    ----------
    verifier_probability : (K,) float
        The peak verifier's probabilities of the candidates.
    heat : (K,) float
        The heat of each candidate's map cell, in [0, 1].
    features : (K, len(UNION_FEATURES)) float
        :func:`fingertips.candidates.candidate_features` of the candidates.
    """
    values = as_array("features", features, (None, len(UNION_FEATURES)), np.float32)
    count = values.shape[0]
    probability = as_array("verifier_probability", verifier_probability, (count,))
    heat_there = as_array("heat", heat, (count,))
    return np.column_stack(
        [log_odds(probability), log_odds(heat_there), values.astype(np.float64)]
    ).astype(np.float32)


def judged_probability(
    judge: CandidateJudge, verifier_probability: ArrayLike, heat: ArrayLike, features: ArrayLike
) -> NDArray[np.float32]:
    """The candidates' probabilities ``(K,)`` of being fingertips: the judge's trees
    (:func:`fingertips.trees.boosted_probability`) on :func:`judge_inputs`."""
    return boosted_probability(judge, judge_inputs(verifier_probability, heat, features))


def fit_candidate_judge(
    inputs: ArrayLike,
    labels: ArrayLike,
    *,
    iterations: int = 300,
    leaf_nodes: int = 31,
    learning_rate: float = 0.05,
    seed: int = 0,
) -> CandidateJudge:
    """Histogram gradient boosting (no early stopping) of the labels on the inputs.

    Parameters
    ----------
    inputs : (N, len(JUDGE_FEATURES)) float32
        :func:`judge_inputs` of labelled candidates.
    labels : (N,) bool
        Which candidates lie on a fingertip.
    iterations, leaf_nodes : int
        Boosting iterations and leaves per tree.
    learning_rate : float
    seed : int

    Raises
    ------
    ValueError
        Unless there are both true and false candidates.
    """
    from sklearn.ensemble import HistGradientBoostingClassifier

    from fingertips.tree_export import pack_boosted_table

    values = as_array("inputs", inputs, (None, len(JUDGE_FEATURES)), np.float32)
    truth = as_array("labels", labels, (values.shape[0],), bool)
    if truth.all() or not truth.any():
        raise ValueError("judge: need both true and false candidates to fit it")
    classifier = HistGradientBoostingClassifier(
        max_iter=iterations,
        learning_rate=learning_rate,
        max_leaf_nodes=leaf_nodes,
        early_stopping=False,
        random_state=seed,
    ).fit(values, truth)
    return CandidateJudge(**pack_boosted_table(classifier))
