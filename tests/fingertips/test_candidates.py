"""The union of vote peaks and geodesic candidates: merging, features, rendered hands."""

from dataclasses import replace

import numpy as np
import pytest
from fingertip_toys import (
    INTRINSICS,
    STRIDE_1,
    bar_scene,
    constant_verifier,
    render_named_hand,
    toy_forest,
)

from fingertips import DetectorConfig, detect_fingertips, load_forest, model_detector_config
from fingertips.candidates import (
    candidate_features,
    forest_candidates,
    merge_candidates,
    vote_weight_near,
)
from fingertips.detect import candidate_peaks
from fingertips.features import probe_image
from fingertips.forest import save_forest
from fingertips.geodesic import GeodesicCandidates
from fingertips.verify import GEODESIC_FEATURES, PEAK_FEATURES, UNION_FEATURES, verify_peaks
from fingertips.voting import Peaks, Votes

COLUMN = {name: k for k, name in enumerate(UNION_FEATURES)}
CAMERA = np.asarray(INTRINSICS)
TIP_GATE_M = 0.015


def _geodesic(points_m, is_finger, reach_m) -> GeodesicCandidates:
    points = np.asarray(points_m, np.float32)
    n = len(points)
    return GeodesicCandidates(
        points_m=points,
        pixels_uv=np.zeros((n, 2), np.float32),
        reach_m=np.asarray(reach_m, np.float32),
        separation_m=np.full(n, 0.05, np.float32),
        width_m=np.full(n, 0.02, np.float32),
        is_finger=np.asarray(is_finger, bool),
        palm_m=np.array([0.0, 0.05, 0.5], np.float32),
        palm_uv=np.zeros(2, np.float32),
        palm_radius_m=0.04,
        cell_m=0.004,
    )


def _votes(points_m, weights) -> Votes:
    points = np.asarray(points_m, np.float32).reshape(-1, 3)
    return Votes(
        positions_m=points,
        weights=np.asarray(weights, np.float32),
        probability=np.full(len(points), 0.8, np.float32),
        sources_m=points + np.float32([0.0, 0.01, 0.0]),
    )


def test_duplicates_within_the_bandwidth_merge_and_keep_their_sources() -> None:
    peaks = Peaks(np.array([[0.0, 0, 0.5], [0.05, 0, 0.5]], np.float32), np.float32([4.0, 2.0]))
    geodesic = _geodesic(
        # 6 mm from the first peak; 12 mm from the second (beyond 10 mm); far away;
        # a wide end (not a finger) that is dropped.
        [[0.006, 0, 0.5], [0.062, 0, 0.5], [0.0, -0.1, 0.5], [0.0, 0.1, 0.5]],
        [True, True, True, False],
        [0.12, 0.11, 0.10, 0.08],
    )
    votes = _votes([[0.062, 0.0, 0.5], [0.065, 0.0, 0.5]], [3.0, 1.0])
    merged = merge_candidates(peaks, geodesic, votes, bandwidth_m=0.01)
    assert len(merged) == 4
    # Ordered by confidence: the first peak (4), the geodesic point with 4 of votes
    # within 10 mm (3 + 1) after it (ties keep the earlier), the second peak, the
    # unvoted point.
    np.testing.assert_allclose(merged.confidences, [4.0, 4.0, 2.0, 0.0])
    np.testing.assert_array_equal(merged.from_forest, [True, False, True, False])
    np.testing.assert_array_equal(merged.from_geodesic, [True, True, False, True])
    np.testing.assert_array_equal(merged.positions_m[0], peaks.positions_m[0])  # the peak's
    np.testing.assert_allclose(merged.reach_m, [0.12, 0.11, 0.0, 0.10])
    np.testing.assert_allclose(merged.width_m, [0.02, 0.02, 0.0, 0.02])
    assert merged.positions_m.dtype == np.float32 and merged.confidences.dtype == np.float32


def test_one_peak_takes_at_most_one_geodesic_candidate() -> None:
    peaks = Peaks(np.array([[0.0, 0, 0.5]], np.float32), np.float32([3.0]))
    geodesic = _geodesic([[0.008, 0, 0.5], [-0.004, 0, 0.5]], [True, True], [0.1, 0.12])
    merged = merge_candidates(peaks, geodesic, _votes(np.zeros((0, 3)), []), bandwidth_m=0.01)
    # The nearer one (4 mm) merges; the other stays a candidate of its own.
    np.testing.assert_array_equal(merged.from_forest, [True, False])
    np.testing.assert_allclose(merged.reach_m, [0.12, 0.1])
    np.testing.assert_allclose(vote_weight_near(merged.positions_m, _votes([], []), radius_m=1), 0)


def test_features_of_geodesic_candidates_are_finite_and_flag_their_source() -> None:
    depth, tip_m = bar_scene()
    peaks = Peaks(tip_m[None].astype(np.float32), np.float32([2.0]))
    votes = _votes(tip_m[None] + [[0.001, 0, 0], [-0.001, 0, 0]], [1.0, 1.0])
    below = tip_m + [0.0, 0.03, 0.0]  # on the bar, 3 cm below its end, no votes near
    geodesic = _geodesic([tip_m + [0.003, 0, 0], below], [True, True], [0.1, 0.07])
    candidates = merge_candidates(peaks, geodesic, votes, bandwidth_m=0.01)
    features = candidate_features(candidates, votes, probe_image(depth), CAMERA, bandwidth_m=0.01)
    assert features.shape == (2, len(UNION_FEATURES)) and features.dtype == np.float32
    assert np.isfinite(features).all()
    assert UNION_FEATURES[: len(PEAK_FEATURES)] == PEAK_FEATURES
    assert UNION_FEATURES[len(PEAK_FEATURES) :] == GEODESIC_FEATURES
    merged, alone = features
    assert merged[COLUMN["from_forest"]] == 1 and merged[COLUMN["from_geodesic"]] == 1
    assert alone[COLUMN["from_forest"]] == 0 and alone[COLUMN["from_geodesic"]] == 1
    assert alone[COLUMN["confidence"]] == 0 and alone[COLUMN["n_votes"]] == 0
    assert alone[COLUMN["rank"]] == 1 and alone[COLUMN["voter_offset_mm"]] == 0
    assert merged[COLUMN["geodesic_reach_m"]] == pytest.approx(0.1)
    assert alone[COLUMN["palm_distance_m"]] == pytest.approx(
        np.linalg.norm(below - [0.0, 0.05, 0.5]), abs=1e-6
    )
    assert alone[COLUMN["palm_radius_m"]] == pytest.approx(0.04)
    # Only vote peaks: the geodesic columns say so, without a palm.
    only = candidate_features(
        forest_candidates(peaks), votes, probe_image(depth), CAMERA, bandwidth_m=0.01
    )
    np.testing.assert_array_equal(only[0, len(PEAK_FEATURES) :], [1, 0, 0, 0, 0, 0])
    same = [k for k, name in enumerate(PEAK_FEATURES) if name != "nearest_peak_m"]
    np.testing.assert_array_equal(only[0, same], merged[same])


def test_union_on_the_bar_scene_and_the_setting() -> None:
    depth, tip_m = bar_scene()
    union = replace(STRIDE_1, candidates="union")
    candidates, features = candidate_peaks(depth, INTRINSICS, toy_forest(), config=union)
    assert features.shape == (len(candidates), len(UNION_FEATURES))
    assert np.isfinite(features).all() and candidates.from_forest.any()
    assert np.linalg.norm(candidates.positions_m - tip_m, axis=1).min() < 0.0015
    with pytest.raises(ValueError, match="candidates"):
        DetectorConfig(candidates="everything")  # type: ignore[arg-type]


@pytest.mark.gl
def test_union_holds_the_geodesic_tips_a_forest_misses(renderer) -> None:
    example = render_named_hand(renderer, "open", "palm", 0.6)
    blind = toy_forest()  # a forest that votes for no pixel of this hand
    blind = replace(blind, node_probability=np.zeros_like(blind.node_probability))
    forest_only, _ = candidate_peaks(example.depth_m, example.intrinsics, blind, config=STRIDE_1)
    assert len(forest_only) == 0
    union = replace(STRIDE_1, candidates="union")
    candidates, features = candidate_peaks(example.depth_m, example.intrinsics, blind, config=union)
    gaps = np.linalg.norm(candidates.positions_m[:, None] - example.tips_m[None], axis=2)
    assert (gaps.min(axis=0) < TIP_GATE_M).sum() >= 4
    assert candidates.from_geodesic.all() and not candidates.from_forest.any()
    assert np.isfinite(features).all()


@pytest.mark.gl
@pytest.mark.parametrize("distance_m", [0.3, 0.6, 1.0])
def test_detector_with_the_geodesic_stage_finds_an_open_hands_tips(renderer, distance_m) -> None:
    example = render_named_hand(renderer, "open", "palm", distance_m, noise="kinect_v1")
    model = load_forest()
    config = replace(model_detector_config(model), candidates="union")
    detections = detect_fingertips(example.depth_m, example.intrinsics, model, config=config)
    points = np.array([[d.x_m, d.y_m, d.z_m] for d in detections]).reshape(-1, 3)
    gaps = np.linalg.norm(points[:, None] - example.tips_m[None], axis=2)
    assert (gaps.min(axis=0, initial=np.inf) < TIP_GATE_M).sum() >= 4
    assert len(detections) <= 5 + 1


def test_model_file_keeps_a_union_verifier_and_old_verifiers_read_their_columns(
    tmp_path,
) -> None:
    union = replace(constant_verifier(0.25), feature_names=UNION_FEATURES)
    save_forest(replace(toy_forest(), verifier=union), tmp_path / "m.npz")
    loaded = load_forest(tmp_path / "m.npz").verifier
    assert loaded is not None and loaded.feature_names == UNION_FEATURES
    features = np.zeros((2, len(UNION_FEATURES)), np.float32)
    np.testing.assert_allclose(verify_peaks(loaded, features), [0.25, 0.25])
    # A verifier of the vote peaks reads the leading PEAK_FEATURES columns.
    np.testing.assert_allclose(verify_peaks(constant_verifier(0.5), features), [0.5, 0.5])
    with pytest.raises(ValueError, match="features"):
        verify_peaks(loaded, features[:, : len(PEAK_FEATURES)])
    with pytest.raises(ValueError, match="feature_names"):
        replace(constant_verifier(0.5), feature_names=("confidence",))
