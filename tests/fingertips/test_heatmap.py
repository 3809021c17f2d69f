"""The heatmap stage: crop, turns, peaks, boosted verifier, model file, detection.

The network is ``tests/data/fingertips/tiny_heatmap.onnx`` (made by the script beside
it): ``logits = 40 * (-crop averaged over 2 x 2 blocks) - 10``, hot where the depth
lies more than 3.75 cm in front of the crop centre.
"""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from fingertip_toys import INTRINSICS, STRIDE_1, Z_M, constant_verifier, toy_forest
from numpy.typing import NDArray
from sklearn.ensemble import HistGradientBoostingClassifier

from fingertips import (
    Detection,
    DetectorConfig,
    FingertipForest,
    assign_detections,
    detect_fingertips,
    name_fingers,
)
from fingertips.calibration_training import calibration_samples
from fingertips.data import FingertipDataConfig, generate_examples
from fingertips.detect import detection_points, detector_config_from_dict
from fingertips.evaluation import AnnotatedDepth
from fingertips.forest import load_forest, save_forest
from fingertips.geodesic import no_candidates
from fingertips.heat_fusion import candidate_heat, fused_probability
from fingertips.heatmap import (
    CROP_HALF_M,
    CROP_PX,
    GRID,
    HEAT_PEAK_FEATURES,
    HandHeatmaps,
    HeatmapNetwork,
    HeatmapStage,
    HeatPeaks,
    boosted_probability,
    crop_cell_pixels,
    crop_centre,
    crop_views,
    finger_centre,
    frame_crop_centre,
    hand_centre,
    hand_crop,
    hand_heatmaps,
    heat_peaks,
    heatmap_peaks,
    unturn_maps,
)
from fingertips.judge import JUDGE_FEATURES, CandidateJudge, log_odds
from fingertips.tree_export import pack_boosted_table

TINY_ONNX = Path(__file__).resolve().parents[1] / "data" / "fingertips" / "tiny_heatmap.onnx"
CAMERA = np.asarray(INTRINSICS)
VALUE = HEAT_PEAK_FEATURES.index("value")


def _sigmoid(x: NDArray) -> NDArray:
    return 1.0 / (1.0 + np.exp(-x))


def _block_mean(images: NDArray) -> NDArray:
    """2 x 2 block means of ``(..., 2 G, 2 G)`` images: ``(..., G, G)``."""
    *lead, h, w = images.shape
    return images.reshape(*lead, h // 2, 2, w // 2, 2).mean(axis=(-3, -1))


def _tiny_network() -> NDArray[np.uint8]:
    return np.frombuffer(TINY_ONNX.read_bytes(), dtype=np.uint8)


def _stage(
    *,
    network: NDArray[np.uint8] | None = None,
    split_value: float | None = None,
    leaf_values: tuple[float, float] = (0.0, 0.0),
    baseline: float = 0.0,
    passes: int = 8,
    min_value: float = 0.3,
) -> HeatmapStage:
    """The tiny network with a one-tree verifier: a single leaf (probability
    ``sigmoid(baseline)``), or a split on the heat ``value`` at ``split_value`` whose
    leaves add ``leaf_values`` (at or below, above) to ``baseline``."""
    if split_value is None:
        table = {
            "node_feature": np.array([-1], np.int32),
            "node_threshold": np.zeros(1, np.float32),
            "node_left": np.array([-1], np.int32),
            "node_right": np.array([-1], np.int32),
            "node_value": np.zeros(1, np.float32),
        }
    else:
        table = {
            "node_feature": np.array([VALUE, -1, -1], np.int32),
            "node_threshold": np.array([split_value, 0, 0], np.float32),
            "node_left": np.array([1, -1, -1], np.int32),
            "node_right": np.array([2, -1, -1], np.int32),
            "node_value": np.array([0.0, *leaf_values], np.float32),
        }
    return HeatmapStage(
        network_onnx=_tiny_network() if network is None else network,
        tree_roots=np.array([0], np.int32),
        baseline=baseline,
        passes=passes,
        min_value=min_value,
        **table,
    )


# --- turns --------------------------------------------------------------------------


@pytest.mark.parametrize("passes", [1, 2, 4, 8])
def test_unturn_maps_undoes_crop_views_for_an_equivariant_network(passes: int) -> None:
    crop = np.random.default_rng(0).uniform(-1, 1, (CROP_PX, CROP_PX)).astype(np.float32)
    views = crop_views(crop, passes)
    assert views.shape == (passes, 1, CROP_PX, CROP_PX) and views.dtype == np.float32
    assert views.flags.c_contiguous

    def network(images: NDArray) -> NDArray:  # per pixel, then 2 x 2 blocks: equivariant
        return _block_mean(np.tanh(3 * images) - images**2)

    maps = unturn_maps(network(views[:, 0]), passes)
    assert maps.shape == (passes, GRID, GRID)
    np.testing.assert_allclose(maps, np.broadcast_to(network(crop), maps.shape), atol=1e-6)


def test_crop_views_are_the_eight_turns_and_mirrors() -> None:
    crop = np.random.default_rng(1).uniform(-1, 1, (CROP_PX, CROP_PX)).astype(np.float32)
    views = crop_views(crop, 8)[:, 0]
    np.testing.assert_array_equal(views[0], crop)
    for a in range(8):
        for b in range(a):
            assert not np.array_equal(views[a], views[b]), (a, b)
    expected = [np.rot90(image, k) for image in (crop, crop[:, ::-1]) for k in range(4)]
    np.testing.assert_array_equal(views, expected)
    np.testing.assert_array_equal(crop_views(crop, 4)[:, 0], views[[0, 1, 4, 5]])
    with pytest.raises(ValueError, match="passes"):
        crop_views(crop, 3)


# --- crop ---------------------------------------------------------------------------


def test_hand_centre_and_crop_of_a_box_on_a_plate() -> None:
    """A 40 px square box at 0.50 m on a 60 px square plate at 0.55 m, same centre."""
    camera = np.array([300.0, 300.0, 80.0, 60.0])
    depth = np.zeros((120, 160), np.float32)
    u0, v0 = 99.5, 49.5  # centre of both squares, pixels
    depth[20:80, 70:130] = 0.55
    depth[30:70, 80:120] = 0.50
    z_mean = (40**2 * 0.50 + (60**2 - 40**2) * 0.55) / 60**2
    expected = [(u0 - 80.0) * z_mean / 300.0, (v0 - 60.0) * z_mean / 300.0, z_mean]
    centre = hand_centre(depth, camera)
    assert centre is not None
    np.testing.assert_allclose(centre, expected, atol=0.002)

    crop = hand_crop(depth, camera, centre)
    assert crop.shape == (CROP_PX, CROP_PX) and crop.dtype == np.float32
    np.testing.assert_array_equal(crop, crop.astype(np.float16))  # rounded as in training
    box = crop < 0
    np.testing.assert_allclose(crop[box], (0.50 - centre[2]) / CROP_HALF_M, atol=1e-3)
    rows, cols = np.nonzero(box)
    side_px = 40 * centre[2] / 300.0 * CROP_PX / (2 * CROP_HALF_M)  # 40 px seen at centre z
    for index in (rows, cols):  # one square in the middle of the crop
        assert abs(index.min() + index.max() - (CROP_PX - 1)) <= 2
        assert abs(index.max() - index.min() + 1 - side_px) <= 1.5
    assert len(rows) == (rows.max() - rows.min() + 1) * (cols.max() - cols.min() + 1)
    assert crop[0, 0] == 1 and crop[-1, -1] == 1  # no depth at the corners
    plate = (crop > 0) & (crop < 1)
    np.testing.assert_allclose(crop[plate], (0.55 - centre[2]) / CROP_HALF_M, atol=1e-3)


def test_hand_centre_needs_twenty_points() -> None:
    depth = np.zeros((60, 80), np.float32)
    depth[10, 10:29] = 0.5
    assert hand_centre(depth, CAMERA) is None


def test_finger_centre_is_the_fingers_mean_moved_onto_the_points_within_8_cm() -> None:
    fingers = np.array([[0.0, -0.10, 0.50], [0.04, -0.08, 0.50]])  # mean (0.02, -0.09)
    near = np.column_stack([np.full(30, 0.03), np.linspace(-0.12, -0.04, 30), np.full(30, 0.52)])
    far = np.tile([0.0, 0.25, 0.55], (500, 1))  # a forearm's points, 34 cm away: ignored
    points = np.concatenate([near, far])
    centre = finger_centre([0.0, 0.0, 0.5], fingers, points)
    np.testing.assert_allclose(centre, near.mean(axis=0))
    # Without fingers the palm centre is the start; with too few points near, it stays.
    np.testing.assert_allclose(finger_centre([0.0, 0.0, 0.5], np.zeros((0, 3)), far), [0, 0, 0.5])
    np.testing.assert_allclose(
        finger_centre([0.0, 0.0, 0.5], fingers, near[:19]), [0.02, -0.09, 0.5]
    )


def test_crop_centre_falls_back_to_the_density_rule_without_a_palm() -> None:
    camera = np.array([300.0, 300.0, 80.0, 60.0])
    depth = np.zeros((120, 160), np.float32)
    depth[30:70, 80:120] = 0.50
    no_palm = no_candidates()
    expected = hand_centre(depth, camera)
    assert expected is not None
    np.testing.assert_array_equal(crop_centre(depth, camera), expected)
    np.testing.assert_array_equal(crop_centre(depth, camera, geodesic=no_palm), expected)
    np.testing.assert_array_equal(frame_crop_centre(depth, camera, "density"), expected)
    with pytest.raises(ValueError, match="rule"):
        frame_crop_centre(depth, camera, "middle")  # type: ignore[arg-type]


def test_the_fingers_rule_centres_a_rendered_hand_whose_forearm_pulls_the_density_rule() -> None:
    """Open hands with a forearm, facing the camera at 0.4-0.8 m: the forearm's points
    pull the densest 12 cm off the hand; the fingers' mean stays on it."""
    config = FingertipDataConfig(
        n_images=8,
        noise=("none",),
        seed=5,
        forearm_probability=1.0,
        plane_probability=0.0,
        distance_range_m=(0.4, 0.8),
        posture_mix=(1.0, 0.0, 0.0),
        facing_fraction=1.0,
    )
    errors = {"density": [], "fingers": []}
    for example in generate_examples(config):
        truth = example.keypoints_m.mean(axis=0)
        visible = example.tips_m[np.isfinite(example.tips_m).all(axis=1)]
        for rule, found in errors.items():
            centre = frame_crop_centre(example.depth_m, example.intrinsics, rule)  # type: ignore[arg-type]
            assert centre is not None
            found.append(np.linalg.norm(centre - truth))
            if rule == "fingers":
                assert (np.abs(visible - centre) < CROP_HALF_M).all()  # every tip in the crop
    assert max(errors["fingers"]) < 0.05
    assert max(errors["density"]) > 0.08  # the forearm pulls it off the hand
    assert np.median(errors["fingers"]) < 0.6 * np.median(errors["density"])


# --- peaks --------------------------------------------------------------------------


def _blob(planted: tuple[float, float], height: float = 0.9) -> NDArray[np.float32]:
    """A Gaussian blob of sigma 1 cell centred at sub-cell ``planted`` (column, row)."""
    rows, cols = np.mgrid[:GRID, :GRID]
    distance2 = (cols - planted[0]) ** 2 + (rows - planted[1]) ** 2
    return (height * np.exp(-distance2 / 2.0)).astype(np.float32)


@pytest.mark.parametrize("planted", [(12.0, 20.0), (12.3, 20.8), (5.7, 9.35)])
def test_heat_peaks_finds_a_planted_blob_and_lifts_it_onto_the_surface(
    planted: tuple[float, float],
) -> None:
    camera = np.array([300.0, 300.0, 80.0, 60.0])
    centre = np.array([0.01, -0.02, 0.5])
    depth = np.full((120, 160), 0.5, np.float32)
    depth[:, ::3] = 0.0  # missing depth and surfaces beyond the crop are not looked at
    depth[::4, 1::3] = 0.9
    heat = _blob(planted)
    peaks = heat_peaks(heat, centre, depth, camera, min_value=0.3)
    cell = np.rint(planted).astype(np.int64)
    np.testing.assert_array_equal(peaks.cells, [cell])
    assert peaks.cells.dtype == np.int64
    np.testing.assert_allclose(peaks.values, [heat[cell[1], cell[0]]])

    # The sub-cell position, read back from its pixel through the crop's projection.
    fx, fy, cx, cy = camera
    offset_m = (peaks.uv_px - [cx, cy]) * centre[2] / [fx, fy] - centre[:2]
    refined = (offset_m / CROP_HALF_M + 1) / 2 * GRID - 0.5
    np.testing.assert_allclose(refined, [planted], atol=0.3)
    np.testing.assert_allclose(peaks.uv_px, crop_cell_pixels(refined, centre, camera), atol=1e-9)
    if np.array_equal(cell, planted):  # a symmetric neighbourhood keeps the cell centre
        np.testing.assert_allclose(
            peaks.uv_px, crop_cell_pixels(cell[None].astype(float), centre, camera), atol=1e-9
        )

    z = 0.5 + 0.008  # the 10th percentile of the flat surface, plus 8 mm
    expected = [(peaks.uv_px[0, 0] - cx) * z / fx, (peaks.uv_px[0, 1] - cy) * z / fy, z]
    np.testing.assert_allclose(peaks.xyz_m, [expected], atol=1e-6)

    # Only the shape of the neighbourhood places the peak, not the map's scale or floor.
    rescaled = heat_peaks(0.5 * heat + 0.4, centre, depth, camera, min_value=0.5)
    np.testing.assert_allclose(rescaled.uv_px, peaks.uv_px, atol=1e-9)

    none = heat_peaks(heat, centre, depth, camera, min_value=float(heat.max()))
    assert none.cells.shape == (0, 2) and none.uv_px.shape == (0, 2)
    assert none.xyz_m.shape == (0, 3) and none.values.shape == (0,)


def test_crop_cell_pixels_of_the_middle_of_the_map_is_the_centre() -> None:
    camera = np.array([300.0, 300.0, 80.0, 60.0])
    centre = np.array([0.02, -0.01, 0.4])
    middle = np.array([[(GRID - 1) / 2, (GRID - 1) / 2], [-0.5, GRID - 0.5]])
    uv = crop_cell_pixels(middle, centre, camera)
    np.testing.assert_allclose(uv[0], [80 + 300 * 0.02 / 0.4, 60 - 300 * 0.01 / 0.4])
    # The outer edge of the map is CROP_HALF_M from the centre.
    np.testing.assert_allclose(
        uv[1], [80 + 300 * (0.02 - CROP_HALF_M) / 0.4, 60 + 300 * (-0.01 + CROP_HALF_M) / 0.4]
    )


# --- boosted verifier ---------------------------------------------------------------


def test_packed_boosted_trees_equal_scikit_learn() -> None:
    rng = np.random.default_rng(5)
    n_features = len(HEAT_PEAK_FEATURES)
    features = rng.normal(size=(800, n_features)).astype(np.float32)
    noise = 0.3 * rng.normal(size=800)
    labels = features[:, 0] - 0.7 * features[:, 3] + 0.5 * features[:, 10] * features[:, 2]
    classifier = HistGradientBoostingClassifier(max_iter=30, max_leaf_nodes=15, random_state=0)
    classifier.fit(features, labels + noise > 0)
    stage = HeatmapStage(network_onnx=_tiny_network(), **pack_boosted_table(classifier))
    test = np.concatenate([rng.normal(size=(300, n_features)).astype(np.float32), features])
    probability = boosted_probability(stage, test)
    assert probability.dtype == np.float32 and probability.shape == (len(test),)
    np.testing.assert_allclose(probability, classifier.predict_proba(test)[:, 1], atol=1e-6)


def test_pack_boosted_table_refuses_more_than_two_classes() -> None:
    rng = np.random.default_rng(6)
    features = rng.normal(size=(90, 3))
    classifier = HistGradientBoostingClassifier(max_iter=3, random_state=0)
    classifier.fit(features, np.arange(90) % 3)
    with pytest.raises(ValueError, match="binary"):
        pack_boosted_table(classifier)


def test_boosted_probability_checks_the_feature_count() -> None:
    with pytest.raises(ValueError, match="features"):
        boosted_probability(_stage(), np.zeros((2, len(HEAT_PEAK_FEATURES) - 1), np.float32))


# --- the stage ----------------------------------------------------------------------


@pytest.mark.parametrize("passes", [1, 2, 4, 8])
def test_tiny_network_is_hot_in_front_of_the_crop_centre(passes: int) -> None:
    crop = np.zeros((CROP_PX, CROP_PX), np.float32)
    crop[9:25, 40:56] = -0.5  # 16 x 16 px, off-centre, on odd rows: two half-covered rows
    crop[48:, :] = 1.0  # missing depth
    maps = _stage(passes=passes).heatmaps(crop)
    assert maps.shape == (passes, GRID, GRID) and maps.dtype == np.float32
    expected = _sigmoid(-40 * _block_mean(crop.astype(np.float64)) - 10)
    np.testing.assert_allclose(maps, np.broadcast_to(expected, maps.shape), atol=1e-6)
    assert (maps[:, 5:12, 20:28] > 0.9999).all()  # fully in front
    np.testing.assert_allclose(maps[:, [4, 12], 20:28], 0.5, atol=1e-6)  # half in front
    cold = np.ones((GRID, GRID), bool)
    cold[4:13, 20:28] = False
    assert (maps[:, cold] < 1e-4).all()


def test_the_network_alone_takes_bytes_and_matches_the_stage() -> None:
    crop = np.random.default_rng(2).uniform(-1, 1, (CROP_PX, CROP_PX)).astype(np.float32)
    network = HeatmapNetwork(TINY_ONNX.read_bytes(), 2)
    np.testing.assert_array_equal(network(crop), _stage(passes=2).heatmaps(crop))
    with pytest.raises(ValueError, match="passes"):
        HeatmapNetwork(TINY_ONNX.read_bytes(), 3)


def test_a_network_that_is_not_onnx_fails_clearly() -> None:
    junk = b"certainly not an ONNX model"
    stage = _stage(network=np.frombuffer(junk, np.uint8))  # loaded on first use
    with pytest.raises(ValueError, match="not a loadable ONNX model"):
        stage.heatmaps(np.zeros((CROP_PX, CROP_PX), np.float32))
    with pytest.raises(ValueError, match="not a loadable ONNX model"):
        HeatmapNetwork(junk, 8)


def test_stage_settings_are_checked() -> None:
    with pytest.raises(ValueError, match="passes"):
        _stage(passes=3)
    with pytest.raises(ValueError, match="min_value"):
        _stage(min_value=1.0)


# --- model file ---------------------------------------------------------------------


def test_model_file_keeps_the_heatmap_stage(tmp_path: Path) -> None:
    stage = _stage(split_value=0.75, leaf_values=(-1.5, 2.0), baseline=0.25, passes=2)
    stage = replace(stage, min_value=0.4)
    forest = replace(toy_forest(), verifier=constant_verifier(0.9), heatmap=stage)
    save_forest(forest, tmp_path / "m.npz")
    loaded = load_forest(tmp_path / "m.npz").heatmap
    assert loaded is not None
    for name in (
        "network_onnx",
        "tree_roots",
        "node_feature",
        "node_threshold",
        "node_left",
        "node_right",
        "node_value",
    ):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(stage, name), err_msg=name)
        assert getattr(loaded, name).dtype == getattr(stage, name).dtype, name
    assert (loaded.baseline, loaded.passes, loaded.min_value) == (0.25, 2, 0.4)
    assert loaded.fusion is None
    fused = replace(forest, heatmap=replace(stage, fusion=np.array([-1.0, 0.75, 0.5])))
    save_forest(fused, tmp_path / "f.npz")
    fused_stage = load_forest(tmp_path / "f.npz").heatmap
    assert fused_stage is not None and fused_stage.fusion is not None
    np.testing.assert_array_equal(fused_stage.fusion, [-1.0, 0.75, 0.5])
    with pytest.raises(ValueError, match="fusion"):
        replace(stage, fusion=np.array([1.0, np.nan, 0.0]))
    judge = _judge_on_heat(threshold=0.5, below=-1.25, above=2.5, baseline=0.125)
    judged = replace(forest, heatmap=replace(stage, judge=judge))
    save_forest(judged, tmp_path / "j.npz")
    judged_stage = load_forest(tmp_path / "j.npz").heatmap
    assert judged_stage is not None and judged_stage.judge is not None
    for name in ("tree_roots", "node_feature", "node_threshold", "node_left", "node_right"):
        loaded_table = getattr(judged_stage.judge, name)
        np.testing.assert_array_equal(loaded_table, getattr(judge, name), err_msg=name)
        assert loaded_table.dtype == getattr(judge, name).dtype, name
    np.testing.assert_array_equal(judged_stage.judge.node_value, judge.node_value)
    assert judged_stage.judge.baseline == 0.125 and judged_stage.fusion is None
    with np.load(tmp_path / "j.npz") as data:
        judged_arrays = dict(data)
    assert int(judged_arrays["format_version"]) == 5
    other = np.array(["other"] * len(JUDGE_FEATURES))
    np.savez(tmp_path / "other_judge.npz", **{**judged_arrays, "heatmap_judge_features": other})
    with pytest.raises(ValueError, match="candidate judge uses other features"):
        load_forest(tmp_path / "other_judge.npz")

    with np.load(tmp_path / "m.npz") as data:
        arrays = dict(data)
    older = {k: v for k, v in arrays.items() if not k.startswith("heatmap_")}
    np.savez(tmp_path / "v2.npz", **{**older, "format_version": np.array(2)})
    assert load_forest(tmp_path / "v2.npz").heatmap is None
    renamed = np.array(["other"] * len(HEAT_PEAK_FEATURES))
    np.savez(tmp_path / "other.npz", **{**arrays, "heatmap_features": renamed})
    with pytest.raises(ValueError, match="other peak features"):
        load_forest(tmp_path / "other.npz")
    unverified = {k: v for k, v in arrays.items() if not k.startswith("verifier_")}
    np.savez(tmp_path / "unverified.npz", **unverified)
    with pytest.raises(ValueError, match="needs the forest's peak verifier"):
        load_forest(tmp_path / "unverified.npz")


def test_a_heatmap_stage_needs_the_peak_verifier() -> None:
    with pytest.raises(ValueError, match="needs the forest's peak verifier"):
        replace(toy_forest(), heatmap=_stage())


# --- detection ----------------------------------------------------------------------

PLATE_M = 0.46
COOL_DOME = ((15, 50), 0.41)  # (u, v) of the apex, pixels; apex depth, metres
HOT_DOME = ((62, 66), 0.395)


def _stub_and_domes() -> NDArray[np.float32]:
    """A plate with a fingertip stub and two domes in front of it.

    The stub is the toy forest's bar (:func:`fingertip_toys.bar_scene`) cut to 6 px
    below its tip, with missing depth above it: the forest finds its tip and nothing
    else. The stub and the domes lie more than 4 cm in front of the crop centre, so the
    tiny network is hot on all three; the nearer dome is hotter than the other.
    """
    depth = np.full((80, 80), PLATE_M, np.float32)
    depth[20:30, 37:43] = 0.0
    depth[30:36, 37:43] = Z_M
    rows, cols = np.mgrid[:80, :80]
    for (u, v), apex_m in (COOL_DOME, HOT_DOME):
        r2 = (cols - u) ** 2 + (rows - v) ** 2
        depth[r2 <= 25] = apex_m + 0.0006 * r2[r2 <= 25]
    return depth


def _heatmap_model() -> FingertipForest:
    """The toy forest, verified with 0.9, and the tiny network whose verifier gives
    sigmoid(1) to a heat above 0.97 and sigmoid(-1) to the rest."""
    stage = _stage(split_value=0.97, leaf_values=(-1.0, 1.0))
    return replace(toy_forest(), verifier=constant_verifier(0.9), heatmap=stage)


def test_detection_adds_heatmap_peaks_apart_from_the_forest() -> None:
    depth = _stub_and_domes()
    model = _heatmap_model()
    forest_only = replace(STRIDE_1, min_tip_probability=0.5)
    (tip,) = detect_fingertips(depth, INTRINSICS, model, config=forest_only)
    assert tip.source == "forest" and tip.tip_probability == pytest.approx(0.9)
    tip_m = np.array([(39.5 - 40) * Z_M / 200, (29.5 - 40) * Z_M / 200, Z_M])
    np.testing.assert_allclose([tip.x_m, tip.y_m, tip.z_m], tip_m, atol=0.0015)

    detections = detect_fingertips(
        depth, INTRINSICS, model, config=replace(forest_only, heatmap_min_probability=0.2)
    )
    assert detections[0] == tip
    assert [d.source for d in detections] == ["forest", "heatmap", "heatmap"]
    # Strongest first: the hot dome, though its cell comes later in row-major order.
    for detection, ((u, v), apex_m), probability in zip(
        detections[1:], (HOT_DOME, COOL_DOME), _sigmoid(np.array([1.0, -1.0])), strict=True
    ):
        assert detection.tip_probability == pytest.approx(probability, abs=1e-6)
        assert np.hypot(detection.u_px - u, detection.v_px - v) < 4  # one cell is 4.1 px
        assert apex_m + 0.008 <= detection.z_m <= apex_m + 0.008 + 0.0006 * 18 + 1e-6
        assert 0.3 < detection.confidence <= 1.0  # the mean heat
    gaps = np.linalg.norm(detection_points(detections[1:]) - detection_points([tip]), axis=1)
    assert (gaps > forest_only.voting.min_separation_m).all()

    # The stub's own heat peak, accepted by the verifier, is dropped for lying too close.
    assert model.heatmap is not None
    peaks, probability = heatmap_peaks(
        depth,
        INTRINSICS,
        model.heatmap,
        np.array([tip_m]),
        np.array([tip.confidence]),
        np.array([0.9]),
        min_tip_probability=0.5,
    )
    near = np.linalg.norm(peaks.xyz_m - tip_m, axis=1) < forest_only.voting.min_separation_m
    assert near.sum() == 1 and probability[near][0] > 0.5
    assert len(peaks.cells) == 3

    only_high = replace(forest_only, heatmap_min_probability=0.5)
    high = detect_fingertips(depth, INTRINSICS, model, config=only_high)
    assert high == detections[:2]


def test_detection_without_the_heatmap_threshold_ignores_the_stage() -> None:
    depth = _stub_and_domes()
    config = replace(STRIDE_1, min_tip_probability=0.5)
    with_stage = detect_fingertips(depth, INTRINSICS, _heatmap_model(), config=config)
    plain = replace(toy_forest(), verifier=constant_verifier(0.9))
    assert with_stage == detect_fingertips(depth, INTRINSICS, plain, config=config)
    assert [d.source for d in with_stage] == ["forest"]
    with pytest.raises(ValueError, match="no heatmap stage"):
        detect_fingertips(
            depth, INTRINSICS, plain, config=replace(config, heatmap_min_probability=0.5)
        )


def test_detection_in_an_empty_or_cold_frame_adds_nothing() -> None:
    config = replace(STRIDE_1, min_tip_probability=0.5, heatmap_min_probability=0.2)
    empty = np.zeros((80, 80), np.float32)
    assert detect_fingertips(empty, INTRINSICS, _heatmap_model(), config=config) == ()
    flat = np.full((80, 80), PLATE_M, np.float32)  # in view, but nothing in front
    assert detect_fingertips(flat, INTRINSICS, _heatmap_model(), config=config) == ()


def test_the_crop_centre_rule_is_a_checked_recorded_setting() -> None:
    config = DetectorConfig(heatmap_centre="fingers")
    assert detector_config_from_dict(config.as_dict()) == config
    assert DetectorConfig().heatmap_centre == "density"  # models recorded without it
    with pytest.raises(ValueError, match="heatmap_centre"):
        DetectorConfig(heatmap_centre="palm")  # type: ignore[arg-type]


# --- fusion of the candidates ---------------------------------------------------------


def test_candidate_heat_reads_the_cell_a_point_falls_in() -> None:
    centre = np.array([0.02, -0.01, 0.6])
    maps = np.zeros((2, GRID, GRID), np.float32)
    maps[0, 5, 20], maps[1, 5, 20] = 0.5, 0.9  # row 5, column 20: mean 0.7
    heatmaps = HandHeatmaps(centre, maps)
    # Cell (column 20, row 5) centre, in the crop's units, seen along its ray at 0.5 m.
    unit = (np.array([20, 5]) + 0.5) / GRID * 2 - 1
    ray = centre[:2] / centre[2] + unit * CROP_HALF_M / centre[2]
    inside = np.array([*ray * 0.5, 0.5])
    outside = np.array([*(centre[:2] / centre[2] + 1.2 * CROP_HALF_M / centre[2]) * 0.6, 0.6])
    heat = candidate_heat(heatmaps, np.stack([inside, outside, centre]))
    np.testing.assert_allclose(heat, [0.7, 0.0, 0.0], atol=1e-7)
    assert candidate_heat(HandHeatmaps(None, None), [inside]).tolist() == [0.0]
    assert candidate_heat(heatmaps, np.zeros((0, 3))).shape == (0,)


def test_fused_probability_is_the_logistic_of_both_log_odds() -> None:
    p, heat = np.array([0.5, 0.9, 0.2, 1.0]), np.array([0.5, 0.5, 0.99, 0.0])
    fused = fused_probability([0.3, 1.5, -0.5], p, heat)
    z = 0.3 + 1.5 * np.log(p.clip(1e-4, 1 - 1e-4) / (1 - p.clip(1e-4, 1 - 1e-4)))
    z -= 0.5 * np.log(heat.clip(1e-4, 1 - 1e-4) / (1 - heat.clip(1e-4, 1 - 1e-4)))
    np.testing.assert_allclose(fused, 1 / (1 + np.exp(-z)), rtol=1e-6)
    np.testing.assert_allclose(
        fused_probability([0.0, 1.0, 0.0], p[:3], heat[:3]), p[:3], rtol=1e-6
    )
    np.testing.assert_allclose(log_odds([0.0, 0.5, 1.0]), [-9.2102, 0.0, 9.2102], atol=1e-4)


def test_detection_keeps_candidates_by_their_fused_probability() -> None:
    """The toy forest's one candidate (verifier 0.9) on the stub, whose cell the tiny
    network leaves cold: fusion [0, 1, 0] leaves the verifier's probability, [0, 0, 1]
    makes it the cold heat and drops the candidate (the stub's own heat peak, no longer
    beside a detection, then joins), [12, 0, 1] keeps it at sigmoid(12 +
    log_odds(heat)); the heat peaks keep reading the verifier's 0.9."""
    depth = _stub_and_domes()
    config = replace(STRIDE_1, min_tip_probability=0.5, heatmap_min_probability=0.2)
    model = _heatmap_model()
    assert model.heatmap is not None
    plain = detect_fingertips(depth, INTRINSICS, model, config=config)
    (tip,) = [d for d in plain if d.source == "forest"]
    heatmaps = hand_heatmaps(depth, INTRINSICS, model.heatmap.heatmaps)
    (heat,) = candidate_heat(heatmaps, detection_points([tip]))
    assert heat < 0.01

    def with_fusion(weights: list[float]) -> tuple[Detection, ...]:
        stage = replace(model.heatmap, fusion=np.array(weights))
        return detect_fingertips(depth, INTRINSICS, replace(model, heatmap=stage), config=config)

    assert with_fusion([0.0, 1.0, 0.0]) == plain
    dropped = with_fusion([0.0, 0.0, 1.0])
    assert [d.source for d in dropped] == ["heatmap"] * 3
    assert set(plain[1:]) < set(dropped)
    kept = with_fusion([12.0, 0.0, 1.0])
    assert kept[0].source == "forest" and kept[1:] == plain[1:]
    expected = 1 / (1 + np.exp(-(12.0 + log_odds(heat))))
    assert kept[0].tip_probability == pytest.approx(expected, rel=1e-5)


def _judge_on_heat(
    *, threshold: float, below: float, above: float, baseline: float = 0.0
) -> CandidateJudge:
    """A judge of one tree that splits on the heat's log-odds at ``threshold``'s."""
    return CandidateJudge(
        tree_roots=np.array([0], np.int32),
        node_feature=np.array([JUDGE_FEATURES.index("heat_log_odds"), -1, -1], np.int32),
        node_threshold=np.array([log_odds(threshold), 0, 0], np.float32),
        node_left=np.array([1, -1, -1], np.int32),
        node_right=np.array([2, -1, -1], np.int32),
        node_value=np.array([0.0, below, above], np.float32),
        baseline=baseline,
    )


def test_detection_keeps_candidates_by_the_judges_probability() -> None:
    """The toy forest's one candidate (verifier 0.9) lies in a cold cell of the tiny
    network: a judge that trusts a cold cell keeps it at its own probability, one that
    does not drops it (the stub's own heat peak then joins), and the judge rules where a
    model has both a judge and a fusion; the heat peaks keep reading the verifier's 0.9."""
    depth = _stub_and_domes()
    config = replace(STRIDE_1, min_tip_probability=0.5, heatmap_min_probability=0.2)
    model = _heatmap_model()
    assert model.heatmap is not None
    plain = detect_fingertips(depth, INTRINSICS, model, config=config)

    def judged(judge: CandidateJudge, fusion: list[float] | None = None) -> tuple[Detection, ...]:
        weights = None if fusion is None else np.array(fusion)
        stage = replace(model.heatmap, judge=judge, fusion=weights)
        return detect_fingertips(depth, INTRINSICS, replace(model, heatmap=stage), config=config)

    kept = judged(_judge_on_heat(threshold=0.5, below=3.0, above=-3.0))
    assert kept[0].source == "forest" and kept[1:] == plain[1:]
    assert kept[0].tip_probability == pytest.approx(1 / (1 + np.exp(-3.0)), rel=1e-6)
    dropped = judged(_judge_on_heat(threshold=0.5, below=-3.0, above=3.0))
    assert [d.source for d in dropped] == ["heatmap"] * 3
    assert set(plain[1:]) < set(dropped)
    assert judged(_judge_on_heat(threshold=0.5, below=3.0, above=-3.0), [-12.0, 0, 0]) == kept


def test_the_peak_verifier_map_is_fitted_on_the_fused_probabilities() -> None:
    """The calibration's "verifier" run keeps the heatmap on for a fused model (its
    candidates' probabilities need the heat) and scores only their detections."""
    depth = _stub_and_domes()
    model = _heatmap_model()
    assert model.heatmap is not None
    config = replace(STRIDE_1, min_tip_probability=0.5, heatmap_min_probability=0.2)
    tip = np.array([(39.5 - 40) * Z_M / 200, (29.5 - 40) * Z_M / 200, Z_M])
    tips = np.full((1, 5, 3), np.nan)
    tips[0, 1] = tip
    frames = AnnotatedDepth(depth[None], CAMERA, tips, np.full((1, 5, 2), np.nan), np.array([0]))
    plain = calibration_samples(frames, model, min_probability=0.05, config=config)
    np.testing.assert_allclose(plain["verifier"][0], [0.9], rtol=1e-6)
    fused_model = replace(model, heatmap=replace(model.heatmap, fusion=np.array([12.0, 0, 1])))
    fused = calibration_samples(frames, fused_model, min_probability=0.05, config=config)
    (forest,) = [
        d
        for d in detect_fingertips(depth, INTRINSICS, fused_model, config=config)
        if d.source == "forest"
    ]
    np.testing.assert_allclose(fused["verifier"][0], [forest.tip_probability], rtol=1e-6)
    assert fused["verifier"][1].tolist() == [True]
    assert 0.9 < float(fused["verifier"][0][0]) < 0.95
    judge = _judge_on_heat(threshold=0.5, below=1.5, above=-3.0)
    judged_model = replace(model, heatmap=replace(model.heatmap, judge=judge))
    judged = calibration_samples(frames, judged_model, min_probability=0.05, config=config)
    np.testing.assert_allclose(judged["verifier"][0], [1 / (1 + np.exp(-1.5))], rtol=1e-6)


def test_heatmap_threshold_needs_the_forest_verifier_threshold() -> None:
    with pytest.raises(ValueError, match="needs min_tip_probability"):
        DetectorConfig(heatmap_min_probability=0.5)
    with pytest.raises(ValueError, match="heatmap_min_probability"):
        DetectorConfig(min_tip_probability=0.5, heatmap_min_probability=1.5)


# --- assignment ---------------------------------------------------------------------

TIPS = np.array([[0.1, 0, 0.5], [0.0, 0, 0.5], [0.03, 0, 0.5], [0.06, 0, 0.5], [0.09, 0, 0.5]])
NEAR = Detection(0, 0, 0.005, 0.0, 0.5, confidence=5.0, tip_probability=0.9)
HEAT = Detection(0, 0, 0.03, 0.03, 0.5, confidence=0.95, tip_probability=0.6, source="heatmap")


@pytest.mark.parametrize(("heatmap_min_probability", "finger"), [(0.35, "middle"), (0.5, None)])
def test_heatmap_detections_are_weighed_by_their_own_threshold(
    heatmap_min_probability: float, finger: str | None
) -> None:
    # HEAT is 3 cm from the middle tip: it is paired only when leaving it out costs more,
    # 1.2 * w + 1.2 (a missed finger) > 3, i.e. w = 0.6 / threshold > 1.5. Weighed by the
    # forest's threshold 0.75 it would never be.
    named = name_fingers(
        (NEAR, HEAT),
        TIPS,
        c_thr=0.5,
        min_tip_probability=0.75,
        heatmap_min_probability=heatmap_min_probability,
    )
    assert [d.finger for d in named] == ["index", finger]
    by_hand = assign_detections(
        np.array([[0.005, 0.0, 0.5], [0.03, 0.03, 0.5]]),
        [0.9 / 0.75, 0.6 / heatmap_min_probability],
        TIPS,
        c_thr=1.0,
    )
    np.testing.assert_array_equal(by_hand.finger_of_detection, [1, 2 if finger else -1])


def test_heatmap_detections_need_the_heatmap_threshold() -> None:
    with pytest.raises(ValueError, match="heatmap_min_probability"):
        name_fingers((NEAR, HEAT), TIPS, c_thr=0.5, min_tip_probability=0.75)


def test_unverified_detections_still_need_a_positive_confidence_threshold() -> None:
    plain = Detection(0, 0, 0.005, 0.0, 0.5, confidence=5.0)
    with pytest.raises(ValueError, match="c_thr"):
        name_fingers((plain,), TIPS, c_thr=-1.0)


def test_a_saturated_plateau_is_one_peak() -> None:
    camera = np.array([300.0, 300.0, 80.0, 60.0])
    depth = np.full((120, 160), 0.5, np.float32)
    heat = np.zeros((GRID, GRID), np.float32)
    heat[10, 10:12] = 1.0  # a sigmoid of a large logit is exactly 1 in float32
    heat[11, 10:12] = 1.0
    heat[20, 5] = 1.0
    peaks = heat_peaks(heat, np.array([0.0, 0.0, 0.5]), depth, camera, min_value=0.3)
    np.testing.assert_array_equal(peaks.cells, [[10, 10], [5, 20]])


def test_heatmap_detections_keep_apart_from_each_other(monkeypatch) -> None:
    # Three accepted heat peaks: two 5 mm apart (refined toward each other from cells two
    # apart), one far; the less probable of the close pair is dropped.
    xyz = np.array([[0.0, 0.0, 0.4], [0.005, 0.0, 0.4], [0.08, 0.0, 0.4]])
    peaks = HeatPeaks(
        np.array([[10, 10], [12, 10], [25, 10]]), xyz[:, :2] * 500, xyz, np.full(3, 0.9)
    )
    probability = np.array([0.6, 0.8, 0.7], np.float32)
    monkeypatch.setattr("fingertips.detect.heatmap_peaks", lambda *args, **kw: (peaks, probability))
    flat = np.full((80, 80), PLATE_M, np.float32)  # no forest detection
    config = replace(STRIDE_1, min_tip_probability=0.5, heatmap_min_probability=0.5)
    found = detect_fingertips(flat, INTRINSICS, _heatmap_model(), config=config)
    np.testing.assert_allclose(detection_points(found), xyz[[1, 2]])
    assert [d.tip_probability for d in found] == pytest.approx([0.8, 0.7])
