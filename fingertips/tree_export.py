"""Fitted scikit-learn forests as plain node tables (:mod:`fingertips.trees`).

Inference then needs neither scikit-learn nor pickle.
"""

from __future__ import annotations

from collections.abc import Iterable
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
    """A node table (:mod:`fingertips.trees`) with each node's probability."""

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


def _node_table(
    trees: Iterable[tuple[NDArray, NDArray, NDArray, NDArray, NDArray, NDArray]],
) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray, NDArray]:
    """Trees given as ``(is_split, feature, threshold, left, right, value)`` per-node
    arrays (children as indices within the tree) packed into one node table; ``value``
    is each node's stored number (probability or leaf value).

    Returns the roots and the node feature, threshold, left, right and value columns,
    in the dtypes of :class:`TreeArrays`."""
    columns: dict[str, list[NDArray]] = {
        k: [] for k in ("feature", "threshold", "left", "right", "value")
    }
    roots = []
    start = 0
    for split, feature, threshold, left, right, value in trees:
        roots.append(start)
        columns["feature"].append(np.where(split, feature, -1))
        columns["threshold"].append(np.where(split, _threshold_float32(threshold), np.float32(0)))
        columns["left"].append(np.where(split, left.astype(np.int64) + start, -1))
        columns["right"].append(np.where(split, right.astype(np.int64) + start, -1))
        columns["value"].append(value)
        start += len(split)
    return (
        np.asarray(roots, dtype=np.int32),
        np.concatenate(columns["feature"]).astype(np.int32),
        np.concatenate(columns["threshold"]).astype(np.float32),
        np.concatenate(columns["left"]).astype(np.int32),
        np.concatenate(columns["right"]).astype(np.int32),
        np.concatenate(columns["value"]).astype(np.float32),
    )


def pack_tree_table(classifier: SklearnForest) -> TreeArrays:
    """The trees of a fitted forest as one node table (:mod:`fingertips.trees`).

    Returns
    -------
    TreeArrays
        ``node_probability`` is :func:`node_probability` of every node.
    """
    roots, feature, threshold, left, right, probability = _node_table(
        (
            estimator.tree_.children_left >= 0,
            estimator.tree_.feature,
            estimator.tree_.threshold,
            estimator.tree_.children_left,
            estimator.tree_.children_right,
            node_probability(classifier, t),
        )
        for t, estimator in enumerate(classifier.estimators_)
    )
    return TreeArrays(
        tree_roots=roots,
        node_feature=feature,
        node_threshold=threshold,
        node_left=left,
        node_right=right,
        node_probability=probability,
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
    (:func:`fingertips.heatmap.boosted_probability`). Categorical splits and
    missing values are not supported.

    Raises
    ------
    ValueError
        For a multi-class classifier or one with categorical splits.
    """
    if len(classifier.classes_) != 2:
        raise ValueError("classifier: expected a binary classifier")
    trees = [predictor.nodes for (predictor,) in classifier._predictors]
    if any(nodes["is_categorical"].any() for nodes in trees):
        raise ValueError("classifier: categorical splits cannot be exported")
    roots, feature, threshold, left, right, value = _node_table(
        (
            nodes["is_leaf"] == 0,
            nodes["feature_idx"],
            nodes["num_threshold"],
            nodes["left"],
            nodes["right"],
            np.where(nodes["is_leaf"] == 0, 0.0, nodes["value"]),
        )
        for nodes in trees
    )
    return BoostedTreeArrays(
        tree_roots=roots,
        node_feature=feature,
        node_threshold=threshold,
        node_left=left,
        node_right=right,
        node_value=value,
        baseline=float(np.ravel(classifier._baseline_prediction)[0]),
    )
