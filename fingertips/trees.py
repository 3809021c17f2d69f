"""Decision trees packed into one node table, and their descent.

The fingertip forest (:mod:`fingertips.forest`), the peak verifier
(:mod:`fingertips.verify`), the heatmap's verifier (:mod:`fingertips.heatmap`) and the
candidate judge (:mod:`fingertips.judge`) store their trees this way: node ``i`` tests
feature ``node_feature[i]`` (-1 at a leaf) against ``node_threshold[i]`` and continues
at ``node_left[i]`` (value <= threshold) or ``node_right[i]``; tree ``t`` starts at
``tree_roots[t]``. :func:`descend` moves every (sample, tree) pair at once, level by
level, asking for features on demand (the reference); :func:`descend_matrix` walks
each pair down in a compiled loop over a feature matrix. The compiled descents read the
nodes from :func:`pack_nodes`' table, each node's four fields side by side (one cache
line a step instead of four), which the classes holding trees keep through
:class:`PackedNodes`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from fingertips._tree_kernels import descend_rows
from glovedb._validate import as_array

FeatureLookup = Callable[[NDArray[np.intp], NDArray[np.int32]], NDArray[np.float32]]
"""``(rows, feature_index) -> values``: feature ``feature_index[k]`` of row ``rows[k]``."""


class TreeTable(Protocol):
    """Trees packed into one node table (see the module docstring)."""

    @property
    def tree_roots(self) -> NDArray[np.int32]: ...
    @property
    def node_feature(self) -> NDArray[np.int32]: ...
    @property
    def node_threshold(self) -> NDArray[np.float32]: ...
    @property
    def node_left(self) -> NDArray[np.int32]: ...
    @property
    def node_right(self) -> NDArray[np.int32]: ...
    @property
    def packed_nodes(self) -> NDArray[np.int32]: ...


def pack_nodes(table: TreeTable) -> NDArray[np.int32]:
    """``(n, 4) int32``: each node's feature, threshold (its float32 bits), left and right
    child side by side."""
    nodes = np.empty((len(table.node_feature), 4), np.int32)
    nodes[:, 0] = table.node_feature
    nodes[:, 1] = np.asarray(table.node_threshold, np.float32).view(np.int32)
    nodes[:, 2] = table.node_left
    nodes[:, 3] = table.node_right
    return nodes


class PackedNodes:
    """For the frozen dataclasses that hold a node table: its :func:`pack_nodes` form,
    made on first use (a copy made by ``dataclasses.replace`` packs its own)."""

    node_feature: NDArray[np.int32]
    node_threshold: NDArray[np.float32]
    node_left: NDArray[np.int32]
    node_right: NDArray[np.int32]

    @functools.cached_property
    def packed_nodes(self) -> NDArray[np.int32]:
        """``(n, 4) int32`` (:func:`pack_nodes`)."""
        return pack_nodes(self)  # type: ignore[arg-type]


def check_tree_table(table: TreeTable, n_features: int) -> None:
    """Raise ValueError unless ``table`` is a consistent node table over ``n_features``.

    Children must come after their parent, which rules out cycles, so every descent
    ends at a leaf.
    """
    n = table.node_feature.shape[0]
    for name in ("node_threshold", "node_left", "node_right"):
        as_array(name, getattr(table, name), (n,))
    roots = as_array("tree_roots", table.tree_roots, (None,))
    if roots.size == 0 or np.any(roots < 0) or np.any(roots >= n):
        raise ValueError("tree_roots: expected at least one root, each a valid node index")
    split = table.node_feature >= 0
    index = np.arange(n)
    for name in ("node_left", "node_right"):
        child = getattr(table, name)[split]
        if np.any(child <= index[split]) or np.any(child >= n):
            raise ValueError(f"{name}: each split's child must be a later node index")
    if np.any(table.node_feature >= n_features):
        raise ValueError("node_feature: index beyond the number of features")


def descend_matrix(table: TreeTable, values: NDArray[np.float32]) -> NDArray[np.int32]:
    """Leaves ``(N, T)`` of the rows of a float32 feature matrix ``(N, F)`` in every tree.

    A compiled loop (:func:`fingertips._tree_kernels.descend_rows`) that reaches
    the leaves :func:`descend` does.
    """
    return descend_rows(
        np.ascontiguousarray(values, dtype=np.float32), table.tree_roots, table.packed_nodes
    )


class BoostedTable(TreeTable, Protocol):
    """Boosted trees: a node table whose leaves add ``node_value`` to ``baseline``."""

    @property
    def node_value(self) -> NDArray[np.float32]: ...
    @property
    def baseline(self) -> float: ...


def boosted_probability(table: BoostedTable, values: NDArray[np.float32]) -> NDArray[np.float32]:
    """Probabilities ``(N,)`` of the rows of a float32 feature matrix ``(N, F)``: the
    sigmoid of ``baseline`` plus the values of the leaves reached in every tree."""
    leaves = descend_matrix(table, values)
    log_odds = table.baseline + table.node_value[leaves].astype(np.float64).sum(axis=1)
    return (1.0 / (1.0 + np.exp(-log_odds))).astype(np.float32)


def descend(table: TreeTable, n_rows: int, lookup: FeatureLookup) -> NDArray[np.int32]:
    """Drop ``n_rows`` samples down every tree; features come from ``lookup`` on demand.

    Only the (sample, tree) pairs still at a split node are processed at each level.

    Returns
    -------
    leaves : (n_rows, T) int32
        Global index of the leaf each sample reaches in each tree.
    """
    n_trees = int(table.tree_roots.size)
    children = np.stack([table.node_left, table.node_right], axis=1)
    leaves = np.tile(table.tree_roots, n_rows)
    # The state of the (sample, tree) pairs still at a split, compacted every level.
    pair = np.flatnonzero(table.node_feature[leaves] >= 0)
    node = leaves[pair]
    row = pair // n_trees
    feature = table.node_feature[node]
    while pair.size:
        go_right = lookup(row, feature) > table.node_threshold[node]
        node = children[node, go_right.astype(np.intp)]
        feature = table.node_feature[node]
        done = feature < 0
        leaves[pair[done]] = node[done]
        going = ~done
        pair, node, row, feature = pair[going], node[going], row[going], feature[going]
    return leaves.reshape(n_rows, n_trees).astype(np.int32)
