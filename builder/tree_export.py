"""Fitted scikit-learn forests as plain node tables (:mod:`tracker.fingertips.trees`).

Inference then needs neither scikit-learn nor pickle.
"""

from __future__ import annotations

from typing import TypeAlias, TypedDict

import numpy as np
from numpy.typing import NDArray
from sklearn.ensemble import (
    ExtraTreesClassifier,
    ExtraTreesRegressor,
    HistGradientBoostingClassifier,
    RandomForestClassifier,
)

SklearnForest: TypeAlias = ExtraTreesClassifier | RandomForestClassifier | ExtraTreesRegressor
"""The scikit-learn forests that can be exported."""


class TreeArrays(TypedDict):
    """A node table (:mod:`tracker.fingertips.trees`) with each node's probability."""

    tree_roots: NDArray[np.int32]
    node_feature: NDArray[np.int32]
    node_threshold: NDArray[np.float32]
    node_left: NDArray[np.int32]
    node_right: NDArray[np.int32]
    node_probability: NDArray[np.float32]


def _threshold_float32(threshold: NDArray[np.float64]) -> NDArray[np.float32]:
    """Largest float32 not above each threshold: ``x <= t`` is unchanged for float32 ``x``."""
    rounded = threshold.astype(np.float32)
    above = rounded.astype(np.float64) > threshold
    rounded[above] = np.nextafter(rounded[above], np.float32(-np.inf))
    return rounded


def node_probability(classifier: SklearnForest, tree_index: int) -> NDArray[np.float64]:
    """Positive-class probability ``(n_nodes,)`` of every node of one fitted tree.

    The share of positive samples among the training samples reaching the node: the
    class fraction of a classifier, the mean of the 0/1 label target (the first output)
    of a Hough regression forest.
    """
    value = classifier.estimators_[tree_index].tree_.value
    if isinstance(classifier, ExtraTreesRegressor):
        return np.asarray(value[:, 0, 0], dtype=np.float64)
    counts = value[:, 0, :]
    return np.asarray(counts[:, 1] / counts.sum(axis=1), dtype=np.float64)


def pack_tree_table(classifier: SklearnForest) -> TreeArrays:
    """The trees of a fitted forest as one node table (:mod:`tracker.fingertips.trees`).

    Returns
    -------
    TreeArrays
        ``node_probability`` is :func:`node_probability` of every node.
    """
    columns: dict[str, list[NDArray]] = {
        k: [] for k in ("feature", "threshold", "left", "right", "probability")
    }
    roots = []
    start = 0
    for t, estimator in enumerate(classifier.estimators_):
        tree = estimator.tree_
        split = tree.children_left >= 0
        roots.append(start)
        columns["feature"].append(np.where(split, tree.feature, -1))
        columns["threshold"].append(
            np.where(split, _threshold_float32(tree.threshold), np.float32(0.0))
        )
        columns["left"].append(np.where(split, tree.children_left + start, -1))
        columns["right"].append(np.where(split, tree.children_right + start, -1))
        columns["probability"].append(node_probability(classifier, t))
        start += tree.node_count
    return TreeArrays(
        tree_roots=np.asarray(roots, dtype=np.int32),
        node_feature=np.concatenate(columns["feature"]).astype(np.int32),
        node_threshold=np.concatenate(columns["threshold"]).astype(np.float32),
        node_left=np.concatenate(columns["left"]).astype(np.int32),
        node_right=np.concatenate(columns["right"]).astype(np.int32),
        node_probability=np.concatenate(columns["probability"]).astype(np.float32),
    )


class BoostedTreeArrays(TypedDict):
    """Boosted trees as a node table with each leaf's log-odds contribution."""

    tree_roots: NDArray[np.int32]
    node_feature: NDArray[np.int32]
    node_threshold: NDArray[np.float32]
    node_left: NDArray[np.int32]
    node_right: NDArray[np.int32]
    node_value: NDArray[np.float32]
    baseline: float


def pack_boosted_table(classifier: HistGradientBoostingClassifier) -> BoostedTreeArrays:
    """A fitted binary histogram gradient boosting classifier as one node table.

    Its positive-class probability is the sigmoid of ``baseline`` plus the
    ``node_value`` of the leaf reached in every tree
    (:func:`tracker.fingertips.heatmap.boosted_probability`). Categorical splits and
    missing values are not supported.

    Raises
    ------
    ValueError
        For a multi-class classifier or one with categorical splits.
    """
    if len(classifier.classes_) != 2:
        raise ValueError("classifier: expected a binary classifier")
    columns: dict[str, list[NDArray]] = {k: [] for k in ("feature", "threshold", "left", "right")}
    values, roots = [], []
    start = 0
    for (predictor,) in classifier._predictors:
        nodes = predictor.nodes
        if nodes["is_categorical"].any():
            raise ValueError("classifier: categorical splits cannot be exported")
        split = nodes["is_leaf"] == 0
        roots.append(start)
        columns["feature"].append(np.where(split, nodes["feature_idx"], -1))
        columns["threshold"].append(
            np.where(split, _threshold_float32(nodes["num_threshold"]), np.float32(0.0))
        )
        columns["left"].append(np.where(split, nodes["left"].astype(np.int64) + start, -1))
        columns["right"].append(np.where(split, nodes["right"].astype(np.int64) + start, -1))
        values.append(np.where(split, 0.0, nodes["value"]))
        start += len(nodes)
    return BoostedTreeArrays(
        tree_roots=np.asarray(roots, dtype=np.int32),
        node_feature=np.concatenate(columns["feature"]).astype(np.int32),
        node_threshold=np.concatenate(columns["threshold"]).astype(np.float32),
        node_left=np.concatenate(columns["left"]).astype(np.int32),
        node_right=np.concatenate(columns["right"]).astype(np.int32),
        node_value=np.concatenate(values).astype(np.float32),
        baseline=float(np.ravel(classifier._baseline_prediction)[0]),
    )
