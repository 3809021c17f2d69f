"""The plain-array forest gives exactly what scikit-learn gives, without pickle."""

import re
from pathlib import Path

import numpy as np
import pytest

from fingertips.features import pixel_features, random_offsets
from fingertips.forest import (
    apply_depth,
    apply_features,
    load_forest,
    predict_leaves,
    save_forest,
)
from fingertips.training import (
    FingertipTrainingConfig,
    ForestKind,
    TrainingSamples,
    export_forest,
    fit_classifier,
)


def _samples(rng: np.random.Generator, n: int, n_features: int) -> TrainingSamples:
    features = rng.normal(size=(n, n_features)).astype(np.float32)
    # Neighbouring float32 values: a threshold between two of them must not round
    # onto either when stored as float32.
    features[:, 0] = (1.0 + np.arange(n) % 7 * np.finfo(np.float32).eps).astype(np.float32)
    score = features[:, 1] + 0.5 * features[:, 2] - (features[:, 0] > 1.0 + 3e-7)
    is_tip = score + 0.3 * rng.normal(size=n) > 0.5
    offset = rng.normal(scale=0.02, size=(n, 3)).astype(np.float32)
    return TrainingSamples(features, is_tip, offset)


@pytest.mark.parametrize("kind", ["extra_trees", "random_forest"])
def test_npz_forest_equals_scikit_learn(kind: ForestKind, tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    n_features = 12
    config = FingertipTrainingConfig(
        forest_kind=kind, n_trees=4, max_depth=10, min_samples_leaf=2, max_features=6
    )
    train = _samples(rng, 3000, n_features)
    classifier = fit_classifier(train, config=config)
    offsets = random_offsets(n_features, max_offset_m=0.05, seed=0)
    forest = export_forest(classifier, train, offsets, config=config)
    save_forest(forest, tmp_path / "forest.npz")
    loaded = load_forest(tmp_path / "forest.npz")

    test = _samples(rng, 2000, n_features)
    leaves = apply_features(loaded, test.features)
    assert leaves.dtype == np.int32 and leaves.shape == (2000, 4)
    np.testing.assert_array_equal(leaves - loaded.tree_roots, classifier.apply(test.features))
    prediction = predict_leaves(loaded, leaves)
    assert prediction.probability.dtype == np.float32
    np.testing.assert_allclose(
        prediction.probability, classifier.predict_proba(test.features)[:, 1], atol=1e-6
    )
    assert loaded.settings["forest_kind"] == kind
    assert loaded.version == forest.version != ""


def test_leaf_predictions_are_probability_weighted_means_of_the_leaves(tmp_path: Path) -> None:
    """The compiled combination against its definition: the mean leaf probability and
    the probability-weighted mean offset (zero where every leaf says 0)."""
    from dataclasses import replace

    rng = np.random.default_rng(3)
    toy = load_forest(_saved_toy_forest(tmp_path))
    nodes = len(toy.node_feature)
    probability = rng.uniform(0, 1, nodes).astype(np.float32)
    probability[:4] = 0.0
    forest = replace(
        toy,
        node_probability=probability,
        node_offset_m=rng.uniform(-0.05, 0.05, (nodes, 3)).astype(np.float32),
    )
    leaves = rng.integers(4, nodes, (40, forest.n_trees)).astype(np.int32)
    leaves[0] = np.arange(forest.n_trees)  # every leaf says 0
    prediction = predict_leaves(forest, leaves)
    p = forest.node_probability[leaves].astype(np.float64)
    np.testing.assert_allclose(prediction.probability, p.mean(1), rtol=1e-6)
    weighted = (p[1:, :, None] * forest.node_offset_m[leaves[1:]]).sum(1)
    expected = weighted / p[1:].sum(1)[:, None]
    np.testing.assert_allclose(prediction.offset_m[1:], expected, rtol=1e-5, atol=1e-8)
    np.testing.assert_array_equal(prediction.offset_m[0], 0.0)
    assert prediction.probability[0] == 0.0
    with pytest.raises(ValueError, match="node ids"):
        predict_leaves(forest, np.full((1, forest.n_trees), nodes, np.int32))
    with pytest.raises(ValueError, match="node ids"):  # not wrapped into range by a cast
        predict_leaves(forest, np.full((1, forest.n_trees), 2**32 + 1, np.int64))
    packed = forest.packed_nodes  # the descent's node table
    np.testing.assert_array_equal(packed[:, 2], forest.node_left)
    np.testing.assert_array_equal(packed[:, 1].view(np.float32), forest.node_threshold)


def test_hough_forest_exports_regressor_and_gathers_offsets(tmp_path: Path) -> None:
    rng = np.random.default_rng(8)
    train = _samples(rng, 4000, 12)
    # Each fingertip's offset points one of two ways, told apart by feature 5 alone.
    direction = np.where(train.features[:, 5] > 0, 0.015, -0.015).astype(np.float32)
    train = TrainingSamples(
        train.features, train.is_tip, np.stack([direction, 0 * direction, 0 * direction], 1)
    )
    settings = {"n_trees": 3, "max_depth": 8, "min_samples_leaf": 5, "max_features": 12}
    hough = FingertipTrainingConfig(forest_kind="hough_extra_trees", **settings)
    regressor = fit_classifier(train, config=hough)
    forest = export_forest(regressor, train, random_offsets(12, max_offset_m=0.05), config=hough)
    save_forest(forest, tmp_path / "hough.npz")
    loaded = load_forest(tmp_path / "hough.npz")
    test = _samples(rng, 1000, 12)
    prediction = predict_leaves(loaded, apply_features(loaded, test.features))
    np.testing.assert_allclose(
        prediction.probability, regressor.predict(test.features)[:, 0], atol=1e-6
    )

    def offset_error(config: FingertipTrainingConfig) -> float:
        model = export_forest(
            fit_classifier(train, config=config),
            train,
            random_offsets(12, max_offset_m=0.05),
            config=config,
        )
        tips = train.is_tip
        predicted = predict_leaves(model, apply_features(model, train.features[tips]))
        return float(np.abs(predicted.offset_m[:, 0] - direction[tips]).mean())

    # Splits on the offsets make the leaves agree on the direction; label-only splits
    # mix the two directions.
    classification = FingertipTrainingConfig(forest_kind="extra_trees", **settings)
    assert offset_error(hough) < 0.5 * offset_error(classification)


def test_leaf_offsets_are_means_of_positive_training_offsets() -> None:
    rng = np.random.default_rng(6)
    config = FingertipTrainingConfig(n_trees=2, max_depth=6, max_features=4)
    train = _samples(rng, 1500, 8)
    classifier = fit_classifier(train, config=config)
    forest = export_forest(classifier, train, random_offsets(8, max_offset_m=0.05), config=config)
    leaves = apply_features(forest, train.features)
    for t in range(2):
        leaf = leaves[train.is_tip, t][0]
        members = train.is_tip & (leaves[:, t] == leaf)
        np.testing.assert_allclose(
            forest.node_offset_m[leaf], train.offset_m[members].mean(axis=0), atol=1e-6
        )


def test_depth_inference_equals_feature_matrix_inference() -> None:
    rng = np.random.default_rng(7)
    depth = rng.uniform(0.3, 0.6, size=(60, 80)).astype(np.float32)
    depth[rng.uniform(size=depth.shape) < 0.2] = 0.0
    intrinsics = (90.0, 95.0, 40.0, 30.0)
    offsets = random_offsets(30, max_offset_m=0.06, seed=2)
    pixels = np.argwhere(depth > 0)[:, ::-1].astype(np.int32)
    features = pixel_features(depth, pixels, offsets, intrinsics)
    samples = TrainingSamples(
        features, features[:, 0] > np.median(features[:, 0]), np.zeros((len(pixels), 3), "f4")
    )
    config = FingertipTrainingConfig(n_trees=3, max_depth=8, max_features=10)
    forest = export_forest(fit_classifier(samples, config=config), samples, offsets, config=config)
    np.testing.assert_array_equal(
        apply_depth(forest, depth, pixels, intrinsics), apply_features(forest, features)
    )
    # The compiled descent walks a few pixels at a time: a last, partial batch too.
    np.testing.assert_array_equal(
        apply_depth(forest, depth, pixels[:13], intrinsics), apply_features(forest, features[:13])
    )


def test_load_rejects_other_files(tmp_path: Path) -> None:
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(ValueError, match="not a glove-fingertip-forest"):
        load_forest(tmp_path / "other.npz")


def _saved_toy_forest(tmp_path: Path) -> Path:
    rng = np.random.default_rng(1)
    config = FingertipTrainingConfig(n_trees=2, max_depth=6, max_features=4)
    samples = _samples(rng, 500, 8)
    offsets = random_offsets(8, max_offset_m=0.05, seed=0)
    forest = export_forest(fit_classifier(samples, config=config), samples, offsets, config=config)
    path = tmp_path / "forest.npz"
    save_forest(forest, path)
    return path


def test_load_rejects_damaged_files_in_one_line(tmp_path: Path) -> None:
    whole = _saved_toy_forest(tmp_path).read_bytes()
    cases = {
        "garbage.npz": b"not a model\n",
        "truncated.npz": whole[: len(whole) // 2],
        "empty.npz": b"",
    }
    for name, content in cases.items():
        (tmp_path / name).write_bytes(content)
        expected = f"{re.escape(name)}: not a glove-fingertip-forest file"
        with pytest.raises(ValueError, match=expected):
            load_forest(tmp_path / name)
    np.save(tmp_path / "single.npy", np.zeros(3))
    (tmp_path / "single.npy").rename(tmp_path / "single.npz")
    with pytest.raises(ValueError, match="a single array, not an archive"):
        load_forest(tmp_path / "single.npz")


def test_load_names_a_missing_or_corrupt_member(tmp_path: Path) -> None:
    path = _saved_toy_forest(tmp_path)
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files if k != "node_offset_m"}
    np.savez(tmp_path / "partial.npz", **arrays)
    with pytest.raises(ValueError, match=r"partial\.npz: damaged .*node_offset_m"):
        load_forest(tmp_path / "partial.npz")
    # Members that load but hold values no model has: NaN leaves, settings that are not JSON.
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    nan_leaves = dict(arrays, node_probability=np.full_like(arrays["node_probability"], np.nan))
    np.savez(tmp_path / "nan.npz", **nan_leaves)
    with pytest.raises(ValueError, match=r"nan\.npz: damaged .*node_probability: contains NaN"):
        load_forest(tmp_path / "nan.npz")
    np.savez(tmp_path / "settings.npz", **dict(arrays, settings_json=np.array("{not json")))
    with pytest.raises(ValueError, match=r"settings\.npz: damaged .*settings_json: not JSON"):
        load_forest(tmp_path / "settings.npz")
    # Flip bytes inside the stored members (not the archive's directory at the end).
    damaged = bytearray(path.read_bytes())
    for i in range(len(damaged) // 4, len(damaged) // 2):
        damaged[i] ^= 0x5A
    (tmp_path / "flipped.npz").write_bytes(bytes(damaged))
    with pytest.raises(ValueError, match=r"flipped\.npz: damaged glove-fingertip-forest file"):
        load_forest(tmp_path / "flipped.npz")


def test_save_writes_the_given_path_atomically(tmp_path: Path, monkeypatch) -> None:
    first = load_forest(_saved_toy_forest(tmp_path))
    target = tmp_path / "model.bin"
    save_forest(first, target)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["forest.npz", "model.bin"]
    np.testing.assert_array_equal(load_forest(target).node_feature, first.node_feature)

    def fail(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savez_compressed", fail)
    with pytest.raises(KeyboardInterrupt):
        save_forest(first, target)
    # The interrupted save left neither a temporary file nor a damaged model.
    assert sorted(p.name for p in tmp_path.iterdir()) == ["forest.npz", "model.bin"]
    np.testing.assert_array_equal(load_forest(target).node_feature, first.node_feature)


def test_compiled_matrix_descent_reaches_the_reference_leaves() -> None:
    from fingertips.trees import descend, descend_matrix

    rng = np.random.default_rng(3)
    features = rng.normal(size=(400, 12)).astype(np.float32)
    samples = TrainingSamples(
        features, features[:, 0] + features[:, 1] ** 2 > 0.5, np.zeros((400, 3), "f4")
    )
    config = FingertipTrainingConfig(n_trees=4, max_depth=10, max_features=6)
    forest = export_forest(
        fit_classifier(samples, config=config), samples, np.zeros((12, 2, 2), "f4"), config=config
    )
    query = rng.normal(size=(300, 12)).astype(np.float32)
    split = np.flatnonzero(forest.node_feature >= 0)[:50]  # values on a threshold: left
    query[np.arange(50), forest.node_feature[split]] = forest.node_threshold[split]
    np.testing.assert_array_equal(
        descend_matrix(forest, query),
        descend(forest, len(query), lambda rows, feature: query[rows, feature]),
    )
