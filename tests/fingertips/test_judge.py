"""The candidate judge (:mod:`fingertips.judge`): inputs, fit and export.

Detection with a judge, its model file and its calibration are tested with the
heatmap stage in ``test_heatmap.py``.
"""

import numpy as np
import pytest
from sklearn.ensemble import HistGradientBoostingClassifier

from fingertips.judge import (
    JUDGE_FEATURES,
    CandidateJudge,
    fit_candidate_judge,
    judge_inputs,
    judged_probability,
    log_odds,
)
from fingertips.verify import UNION_FEATURES

DEPTH = UNION_FEATURES.index("depth_m")


def _candidates(count: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Random candidates whose label needs the heat near the camera and the verifier
    far from it: neither log-odds alone, nor a weighted sum of both, separates them."""
    rng = np.random.default_rng(seed)
    probability = rng.uniform(0.01, 0.99, count).astype(np.float32)
    heat = rng.uniform(0.01, 0.99, count).astype(np.float32)
    features = rng.normal(size=(count, len(UNION_FEATURES))).astype(np.float32)
    features[:, DEPTH] = rng.uniform(0.3, 1.5, count)
    near = features[:, DEPTH] < 0.9
    labels = np.where(near, heat > 0.6, probability > 0.7)
    return probability, heat, features, labels


def test_inputs_are_both_log_odds_then_the_features() -> None:
    probability, heat, features, _ = _candidates(5, 1)
    inputs = judge_inputs(probability, heat, features)
    assert inputs.shape == (5, len(JUDGE_FEATURES)) and inputs.dtype == np.float32
    np.testing.assert_allclose(inputs[:, 0], log_odds(probability), rtol=1e-6)
    np.testing.assert_allclose(inputs[:, 1], log_odds(heat), rtol=1e-6)
    np.testing.assert_array_equal(inputs[:, 2:], features)
    np.testing.assert_allclose(log_odds([0.0, 0.5, 1.0]), [-9.2102, 0.0, 9.2102], atol=1e-4)
    assert judge_inputs(np.zeros(0), np.zeros(0), np.zeros((0, len(UNION_FEATURES)))).shape == (
        0,
        len(JUDGE_FEATURES),
    )
    with pytest.raises(ValueError, match="features"):
        judge_inputs(probability, heat, features[:, :-1])
    with pytest.raises(ValueError, match="heat"):
        judge_inputs(probability, heat[:4], features)


def test_the_fitted_judge_is_scikit_learns_boosting_bit_for_bit() -> None:
    probability, heat, features, labels = _candidates(1000, 2)
    inputs = judge_inputs(probability, heat, features)
    judge = fit_candidate_judge(inputs, labels, iterations=20, leaf_nodes=15, seed=3)
    reference = HistGradientBoostingClassifier(
        max_iter=20, learning_rate=0.05, max_leaf_nodes=15, early_stopping=False, random_state=3
    ).fit(inputs, labels)
    test = judge_inputs(*_candidates(1000, 4)[:3])
    np.testing.assert_allclose(
        judged_probability(judge, *_candidates(1000, 4)[:3]),
        reference.predict_proba(test)[:, 1],
        atol=1e-6,
    )


def test_the_judge_learns_what_neither_score_alone_tells() -> None:
    probability, heat, features, labels = _candidates(3000, 5)
    inputs = judge_inputs(probability, heat, features)
    judge = fit_candidate_judge(inputs, labels, iterations=60, learning_rate=0.3)
    probability, heat, features, labels = _candidates(2000, 6)
    kept = judged_probability(judge, probability, heat, features) >= 0.5
    assert (kept == labels).mean() > 0.97
    # The best single threshold on either score, or on their sum, is far worse.
    for score in (log_odds(probability), log_odds(heat), log_odds(probability) + log_odds(heat)):
        thresholds = np.quantile(score, np.linspace(0.02, 0.98, 49))
        best = max(((score >= t) == labels).mean() for t in thresholds)
        assert best < 0.85


def test_a_judge_needs_both_kinds_of_candidate_and_a_valid_table() -> None:
    probability, heat, features, labels = _candidates(200, 7)
    inputs = judge_inputs(probability, heat, features)
    with pytest.raises(ValueError, match="both true and false"):
        fit_candidate_judge(inputs, np.ones(200, bool))
    with pytest.raises(ValueError, match="inputs"):
        fit_candidate_judge(inputs[:, 1:], labels)
    leaf = dict(
        tree_roots=np.array([0], np.int32),
        node_feature=np.array([-1], np.int32),
        node_threshold=np.array([0.0], np.float32),
        node_left=np.array([-1], np.int32),
        node_right=np.array([-1], np.int32),
        node_value=np.array([0.0], np.float32),
    )
    judge = CandidateJudge(**leaf, baseline=2.0)
    np.testing.assert_allclose(
        judged_probability(judge, probability, heat, features), 1 / (1 + np.exp(-2.0)), rtol=1e-6
    )
    with pytest.raises(ValueError, match="baseline"):
        CandidateJudge(**leaf, baseline=float("nan"))
    split = dict(
        tree_roots=np.array([0], np.int32),
        node_feature=np.array([len(JUDGE_FEATURES), -1, -1], np.int32),
        node_threshold=np.zeros(3, np.float32),
        node_left=np.array([1, -1, -1], np.int32),
        node_right=np.array([2, -1, -1], np.int32),
        node_value=np.array([0.0, -1.0, 1.0], np.float32),
    )
    with pytest.raises(ValueError, match="node_feature"):
        CandidateJudge(**split, baseline=0.0)
