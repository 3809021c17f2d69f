"""The peak verifier: features of known geometry, exact export, file format, detection."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from fingertip_toys import INTRINSICS, STRIDE_1, Z_M, bar_scene, constant_verifier, toy_forest
from sklearn.ensemble import RandomForestClassifier

from fingertips import Detection, DetectorConfig, detect_fingertips, name_fingers
from fingertips.detect import candidate_peaks
from fingertips.features import probe_image
from fingertips.forest import load_forest, save_forest
from fingertips.verifier_training import (
    VerifierTrainingConfig,
    export_verifier,
    fit_verifier,
    label_peaks,
)
from fingertips.verify import (
    PEAK_FEATURES,
    RING_PROBES,
    UNION_FEATURES,
    peak_features,
    ring_features,
    verify_peaks,
)
from fingertips.voting import Peaks, Votes

COLUMN = {name: k for k, name in enumerate(PEAK_FEATURES)}
CAMERA = np.asarray(INTRINSICS)


def test_ring_features_tell_a_fingertip_from_a_flat_surface() -> None:
    depth, tip_m = bar_scene()  # a 6-pixel (12 mm) wide bar ending at tip_m
    plate = np.full_like(depth, Z_M)
    rings = ring_features(probe_image(depth), tip_m[None], CAMERA)[0].reshape(-1, 3)
    flat = ring_features(probe_image(plate), tip_m[None], CAMERA)[0].reshape(-1, 3)
    np.testing.assert_allclose(flat, [[0.0, 1.0, 0.0]] * len(flat), atol=1e-6)
    # At the end of the bar only the probes pointing down it are on the hand: within
    # asin(6 mm / r) of straight down, 3 of 16 at 1 cm and 1 of 16 at 2 cm.
    expected = [[13 / 16, 3 / 16, 0.0], [15 / 16, 1 / 16, 0.0]]
    np.testing.assert_allclose(rings[:2], expected, atol=1e-6)
    # Missing depth and far surfaces are background alike.
    far = np.where(depth > 0, depth, np.float32(Z_M + 0.5))
    np.testing.assert_allclose(
        ring_features(probe_image(far), tip_m[None], CAMERA), rings[None].reshape(1, -1)
    )


def test_ring_features_do_not_depend_on_distance() -> None:
    depth, tip_m = bar_scene()
    # The same bar twice as far, seen with twice the focal length: the same pixels.
    farther = np.where(depth > 0, depth + np.float32(Z_M), np.float32(0.0))
    double = np.array([2 * INTRINSICS[0], 2 * INTRINSICS[1], INTRINSICS[2], INTRINSICS[3]])
    tip_far = tip_m + [0.0, 0.0, Z_M]
    np.testing.assert_allclose(
        ring_features(probe_image(farther), tip_far[None], double),
        ring_features(probe_image(depth), tip_m[None], CAMERA),
        atol=1e-6,
    )


def test_vote_features_have_known_values() -> None:
    peak = np.array([0.0, 0.0, 0.5])
    positions = np.array([peak, peak + [0.003, 0, 0], peak + [0, 0.004, 0], peak + [0.015, 0, 0]])
    weights = np.array([1.0, 2.0, 1.0, 4.0], np.float32)
    probability = np.array([0.6, 0.9, 0.3, 0.5], np.float32)
    sources = positions + [0.0, 0.01, 0.002]
    votes = Votes(positions.astype("f4"), weights, probability, sources.astype("f4"))
    peaks = Peaks(np.array([peak], np.float32), np.array([4.0], np.float32))
    depth = np.zeros((80, 80), np.float32)
    row = peak_features(peaks, votes, probe_image(depth), CAMERA, bandwidth_m=0.01)[0]
    assert row[COLUMN["confidence"]] == pytest.approx(4.0)
    assert row[COLUMN["n_votes"]] == 3
    assert row[COLUMN["max_probability"]] == pytest.approx(0.9)
    assert row[COLUMN["mean_probability"]] == pytest.approx(0.6)
    spread = np.sqrt((2 * 0.003**2 + 0.004**2) / 4)
    assert row[COLUMN["vote_spread_mm"]] == pytest.approx(1000 * spread, rel=1e-4)
    assert row[COLUMN["wide_weight_ratio"]] == pytest.approx(2.0)
    assert row[COLUMN["voter_offset_mm"]] == pytest.approx(
        1000 * np.linalg.norm([0.006 / 4, 0.01 + 0.004 / 4, 0.002]), rel=1e-4
    )
    assert row[COLUMN["voter_depth_mm"]] == pytest.approx(2.0, rel=1e-4)
    assert row[COLUMN["surface_gap_m"]] == pytest.approx(0.1)  # no depth: clipped
    assert row[COLUMN["rank"]] == 0 and row[COLUMN["relative_confidence"]] == 1
    assert row[COLUMN["nearest_peak_m"]] == pytest.approx(0.2)


def test_exported_verifier_equals_scikit_learn() -> None:
    rng = np.random.default_rng(3)
    features = rng.normal(size=(600, len(PEAK_FEATURES))).astype(np.float32)
    labels = features[:, 0] + 0.5 * features[:, 5] + 0.3 * rng.normal(size=600) > 0
    classifier = RandomForestClassifier(n_estimators=5, max_depth=8, random_state=0)
    classifier.fit(features, labels)
    test = rng.normal(size=(200, len(PEAK_FEATURES))).astype(np.float32)
    np.testing.assert_allclose(
        verify_peaks(export_verifier(classifier), test),
        classifier.predict_proba(test)[:, 1],
        atol=1e-6,
    )


def test_fit_verifier_needs_both_labels() -> None:
    features = np.zeros((10, len(UNION_FEATURES)), np.float32)
    with pytest.raises(ValueError, match="both true and false"):
        fit_verifier(features, np.ones(10, bool), config=VerifierTrainingConfig())


def test_label_peaks_is_one_to_one_and_ignores_hidden_tips() -> None:
    tips = np.full((5, 3), np.nan)
    tips[1] = [0.0, 0.0, 0.5]
    tips[2] = [0.05, 0.0, 0.5]
    peaks = np.array([[0.001, 0, 0.5], [0.004, 0, 0.5], [0.05, 0.014, 0.5], [0.2, 0, 0.5]])
    np.testing.assert_array_equal(
        label_peaks(peaks, tips, radius_m=0.015), [True, False, True, False]
    )
    assert not label_peaks(peaks, np.full((5, 3), np.nan), radius_m=0.015).any()


def test_model_file_keeps_the_verifier_and_reads_format_1(tmp_path: Path) -> None:
    forest = replace(toy_forest(), verifier=constant_verifier(0.25))
    save_forest(forest, tmp_path / "m.npz")
    loaded = load_forest(tmp_path / "m.npz")
    assert loaded.verifier is not None
    np.testing.assert_array_equal(loaded.verifier.node_probability, [0.25])
    with np.load(tmp_path / "m.npz") as data:
        arrays = dict(data)
    old = {k: v for k, v in arrays.items() if not k.startswith("verifier_")}
    np.savez(tmp_path / "v1.npz", **{**old, "format_version": np.array(1)})
    assert load_forest(tmp_path / "v1.npz").verifier is None
    renamed = np.array(["other"] * len(PEAK_FEATURES))
    np.savez(tmp_path / "other.npz", **{**arrays, "verifier_features": renamed})
    with pytest.raises(ValueError, match="other peak features"):
        load_forest(tmp_path / "other.npz")


def test_detection_keeps_the_peaks_the_verifier_accepts() -> None:
    depth, _ = bar_scene()
    plain = detect_fingertips(depth, INTRINSICS, toy_forest(), config=STRIDE_1)
    assert len(plain) == 1 and plain[0].tip_probability is None
    checking = replace(STRIDE_1, min_tip_probability=0.5)
    accept = replace(toy_forest(), verifier=constant_verifier(0.9))
    (kept,) = detect_fingertips(depth, INTRINSICS, accept, config=checking)
    assert kept.tip_probability == pytest.approx(0.9)
    assert (kept.x_m, kept.y_m, kept.z_m, kept.confidence) == (
        plain[0].x_m,
        plain[0].y_m,
        plain[0].z_m,
        plain[0].confidence,
    )
    reject = replace(toy_forest(), verifier=constant_verifier(0.1))
    assert detect_fingertips(depth, INTRINSICS, reject, config=checking) == ()
    with pytest.raises(ValueError, match="no peak verifier"):
        detect_fingertips(depth, INTRINSICS, toy_forest(), config=checking)


def test_candidate_features_describe_the_bar_tip() -> None:
    depth, tip_m = bar_scene()
    peaks, features = candidate_peaks(depth, INTRINSICS, toy_forest(), config=STRIDE_1)
    assert features.shape == (1, len(UNION_FEATURES))
    row = features[0]
    assert row[COLUMN["max_probability"]] == pytest.approx(1.0)
    assert row[COLUMN["ring10_background"]] > 0.7
    assert row[COLUMN["ring45_hand_arc"]] <= 4 / RING_PROBES
    assert DetectorConfig().min_tip_probability == 0.0
    np.testing.assert_allclose(peaks.positions_m[0], tip_m, atol=0.0015)


def test_verified_detections_are_weighed_by_tip_probability_in_eq_11() -> None:
    tips = np.array([[0.1, 0, 0.5], [0.0, 0, 0.5], [0.03, 0, 0.5], [0.06, 0, 0.5], [0.09, 0, 0.5]])
    near = Detection(0, 0, 0.005, 0.0, 0.5, confidence=5.0, tip_probability=0.9)
    far = Detection(0, 0, 0.03, 0.03, 0.5, confidence=5.0, tip_probability=0.76)
    # Verified: leaving `far` out costs 1.2 * 0.76 / 0.75 + a missed middle finger 1.2,
    # less than its 3 cm to the middle tip.
    verified = name_fingers((near, far), tips, c_thr=0.5, min_tip_probability=0.75)
    assert [d.finger for d in verified] == ["index", None]
    # By vote weight over a candidate threshold of 0.5 every detection is costly to drop.
    by_weight = name_fingers((near, far), tips, c_thr=0.5)
    assert [d.finger for d in by_weight] == ["index", "middle"]
