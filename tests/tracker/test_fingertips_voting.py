"""Hough votes of a hand-made forest peak at the planted fingertip."""

import numpy as np
import pytest

from tracker.fingertips import (
    Detection,
    DetectorConfig,
    FingertipForest,
    VotingConfig,
    detect_fingertips,
    fingertip_votes,
    fingertips_output,
)
from tracker.fingertips.voting import Votes, find_peaks

STRIDE_1 = DetectorConfig(stride=1)

INTRINSICS = (200.0, 200.0, 40.0, 40.0)
Z_M = 0.4
PROBE_M = 0.008


def _bar_scene() -> tuple[np.ndarray, np.ndarray]:
    """A vertical bar ("finger") at 0.4 m whose upper end is the planted tip."""
    depth = np.zeros((80, 80), np.float32)
    depth[30:, 37:43] = Z_M
    fx, _, cx, cy = INTRINSICS
    tip_m = np.array([(39.5 - cx) * Z_M / fx, (29.5 - cy) * Z_M / fx, Z_M])
    return depth, tip_m


def _toy_forest() -> FingertipForest:
    """One split: a probe PROBE_M above the pixel off the bar means "near the tip".

    Pixels within PROBE_M of the upper end vote PROBE_M / 2 upwards, so their votes
    centre on the end.
    """
    offsets = np.zeros((1, 2, 2), np.float32)
    offsets[0, 0] = (0.0, -PROBE_M)
    return FingertipForest(
        offsets_m=offsets,
        depth_range_m=(0.1, 1.0),
        tree_roots=np.array([0], np.int32),
        node_feature=np.array([0, -1, -1], np.int32),
        node_threshold=np.array([1.0, 0.0, 0.0], np.float32),
        node_left=np.array([1, -1, -1], np.int32),
        node_right=np.array([2, -1, -1], np.int32),
        node_probability=np.array([0.1, 0.0, 1.0], np.float32),
        node_offset_m=np.array([[0, 0, 0], [0, 0, 0], [0, -PROBE_M / 2, 0]], np.float32),
    )


def test_votes_peak_at_the_planted_tip() -> None:
    depth, tip_m = _bar_scene()
    forest = _toy_forest()
    votes = fingertip_votes(depth, INTRINSICS, forest, config=STRIDE_1)
    # 4 rows (8 mm / 2 mm per pixel) x 6 columns of pixels vote with probability 1.
    assert votes.weights.size == 24
    pixel_area = (Z_M / INTRINSICS[0]) ** 2
    np.testing.assert_allclose(votes.weights, pixel_area / 25e-6, rtol=1e-5)
    detections = detect_fingertips(depth, INTRINSICS, forest, config=STRIDE_1)
    assert len(detections) == 1
    found = detections[0]
    position = np.array([found.x_m, found.y_m, found.z_m])
    np.testing.assert_allclose(position, tip_m, atol=0.0015)
    np.testing.assert_allclose(found.confidence, votes.weights.sum(), rtol=1e-5)
    np.testing.assert_allclose([found.u_px, found.v_px], [39.5, 29.5], atol=0.8)
    assert found.finger is None


def test_confidence_does_not_depend_on_stride_and_c_thr_filters() -> None:
    depth, _ = _bar_scene()
    forest = _toy_forest()
    full = detect_fingertips(depth, INTRINSICS, forest, config=STRIDE_1)
    coarse = detect_fingertips(depth, INTRINSICS, forest, config=DetectorConfig(stride=2))
    np.testing.assert_allclose(coarse[0].confidence, full[0].confidence, rtol=1e-5)
    too_high = full[0].confidence * 1.01
    stricter = DetectorConfig(stride=1, c_thr=too_high)
    assert detect_fingertips(depth, INTRINSICS, forest, config=stricter) == ()


def test_model_tips_name_the_finger_and_output_follows_conventions() -> None:
    depth, tip_m = _bar_scene()
    shifts_m = np.array([[0.1, 0, 0], [0.005, 0, 0], [0.2, 0, 0], [0.3, 0, 0], [0.4, 0, 0]])
    model_tips = tip_m + shifts_m
    detections = detect_fingertips(depth, INTRINSICS, _toy_forest(), model_tips_m=model_tips)
    assert [d.finger for d in detections] == ["index"]
    (record,) = fingertips_output(detections)
    assert set(record) == {"finger", "u_px", "v_px", "x_m", "y_m", "z_m", "confidence"}
    assert record["finger"] == "index" and isinstance(record["confidence"], float)


def test_peaks_are_separated_and_sorted() -> None:
    rng = np.random.default_rng(8)
    centres = np.array([[0.0, 0.0, 0.4], [0.03, 0.0, 0.4], [0.036, 0.0, 0.4]])
    counts = [30, 60, 20]
    positions = np.concatenate(
        [c + rng.normal(scale=0.002, size=(n, 3)) for c, n in zip(centres, counts, strict=True)]
    ).astype(np.float32)
    votes = Votes(positions, np.full(len(positions), 0.5, np.float32))
    config = VotingConfig(bandwidth_m=0.006, min_separation_m=0.015)
    peaks = find_peaks(votes, c_thr=3.0, config=config)
    assert peaks.confidences.shape == (2,)
    assert np.all(np.diff(peaks.confidences) <= 0)
    np.testing.assert_allclose(peaks.positions_m[0], centres[1], atol=0.003)
    np.testing.assert_allclose(peaks.positions_m[1], centres[0], atol=0.003)
    np.testing.assert_allclose(peaks.confidences[1], 15.0, atol=1.5)


def test_no_votes_give_no_detections() -> None:
    empty = Votes(np.zeros((0, 3), np.float32), np.zeros(0, np.float32))
    assert find_peaks(empty).confidences.shape == (0,)
    depth = np.zeros((20, 20), np.float32)
    assert detect_fingertips(depth, INTRINSICS, _toy_forest()) == ()


def test_detection_is_frozen() -> None:
    detection = Detection(1.0, 2.0, 0.0, 0.0, 0.4, 5.0)
    with pytest.raises(AttributeError):
        detection.confidence = 1.0  # type: ignore[misc]
