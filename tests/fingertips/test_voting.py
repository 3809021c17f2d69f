"""Hough votes of a hand-made forest peak at the planted fingertip."""

import numpy as np
import pytest
from fingertip_toys import INTRINSICS, STRIDE_1, Z_M, bar_scene, toy_forest

from fingertips import (
    Detection,
    DetectorConfig,
    VotingConfig,
    detect_fingertips,
    fingertip_votes,
    fingertips_output,
)
from fingertips._voting_kernels import sorted_cubes, window_sums
from fingertips.voting import Votes, apart_in_order, find_peaks


def test_votes_peak_at_the_planted_tip() -> None:
    depth, tip_m = bar_scene()
    forest = toy_forest()
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
    depth, _ = bar_scene()
    forest = toy_forest()
    full = detect_fingertips(depth, INTRINSICS, forest, config=STRIDE_1)
    coarse = detect_fingertips(depth, INTRINSICS, forest, config=DetectorConfig(stride=2))
    np.testing.assert_allclose(coarse[0].confidence, full[0].confidence, rtol=1e-5)
    too_high = full[0].confidence * 1.01
    stricter = DetectorConfig(stride=1, c_thr=too_high)
    assert detect_fingertips(depth, INTRINSICS, forest, config=stricter) == ()


def test_model_tips_name_the_finger_and_output_follows_conventions() -> None:
    depth, tip_m = bar_scene()
    shifts_m = np.array([[0.1, 0, 0], [0.005, 0, 0], [0.2, 0, 0], [0.3, 0, 0], [0.4, 0, 0]])
    model_tips = tip_m + shifts_m
    detections = detect_fingertips(depth, INTRINSICS, toy_forest(), model_tips_m=model_tips)
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
    half = np.full(len(positions), 0.5, np.float32)
    votes = Votes(positions, half, half, positions)
    config = VotingConfig(bandwidth_m=0.006, min_separation_m=0.015)
    peaks = find_peaks(votes, c_thr=3.0, config=config)
    assert peaks.confidences.shape == (2,)
    assert np.all(np.diff(peaks.confidences) <= 0)
    np.testing.assert_allclose(peaks.positions_m[0], centres[1], atol=0.003)
    np.testing.assert_allclose(peaks.positions_m[1], centres[0], atol=0.003)
    np.testing.assert_allclose(peaks.confidences[1], 15.0, atol=1.5)


def test_window_sums_are_the_sums_over_every_vote_within_the_radius() -> None:
    # Votes around the origin (negative cube indices), some on cube faces and one at
    # the radius from a centre: the cubes must lose none of them.
    rng = np.random.default_rng(3)
    radius = 0.01
    positions = rng.uniform(-0.03, 0.03, size=(400, 3)).astype(np.float32)
    positions[:20] = np.round(positions[:20] / radius) * radius  # on cube faces
    centres = np.concatenate([positions[::25], rng.uniform(-0.03, 0.03, (8, 3))])
    centres = centres.astype(np.float32)
    positions[20] = centres[1] + np.float32([radius, 0.0, 0.0])  # on the sphere (to rounding)
    weights = rng.uniform(0.1, 1.0, 400).astype(np.float32)
    mass, moment = window_sums(
        centres, positions, weights, *sorted_cubes(positions, radius), radius
    )
    p64, c64 = positions.astype(np.float64), centres.astype(np.float64)
    inside = ((p64[None] - c64[:, None]) ** 2).sum(axis=2) <= radius**2
    w64 = weights.astype(np.float64)
    np.testing.assert_allclose(mass, inside @ w64, rtol=1e-12)
    np.testing.assert_allclose(moment, inside @ (w64[:, None] * p64), rtol=1e-12, atol=1e-15)
    assert inside.sum() > 2 * len(centres)  # the windows hold votes


def test_points_kept_apart_are_those_of_the_numpy_greedy_loop() -> None:
    """The compiled greedy separation against the loop it replaced (NumPy's float32
    norm and comparison), with points placed exactly at the radius and just inside."""
    rng = np.random.default_rng(5)
    radius = 0.015
    for trial in range(20):
        points = rng.uniform(-0.03, 0.03, (30, 3)).astype(np.float32)
        points[:3] = 0.0
        points[1, 0] = radius  # exactly at the radius in float32: kept
        points[2, 1] = np.nextafter(np.float32(radius), np.float32(0))  # just inside
        order = np.r_[0, 1, 2, 3 + rng.permutation(27)[: 7 + trial]]
        kept: list[int] = []
        for index in order:
            if not np.any(np.linalg.norm(points[kept] - points[index], axis=1) < radius):
                kept.append(int(index))
        expected = np.zeros(30, bool)
        expected[kept] = True
        np.testing.assert_array_equal(apart_in_order(points, order, radius), expected)
    with pytest.raises(ValueError, match="order"):
        apart_in_order(points, np.array([30]), radius)
    assert not apart_in_order(points, np.zeros(0, np.int64), radius).any()


def test_no_votes_give_no_detections() -> None:
    none, no_points = np.zeros(0, np.float32), np.zeros((0, 3), np.float32)
    empty = Votes(no_points, none, none, no_points)
    assert find_peaks(empty).confidences.shape == (0,)
    depth = np.zeros((20, 20), np.float32)
    assert detect_fingertips(depth, INTRINSICS, toy_forest()) == ()


def test_detection_is_frozen() -> None:
    detection = Detection(1.0, 2.0, 0.0, 0.0, 0.4, 5.0)
    with pytest.raises(AttributeError):
        detection.confidence = 1.0  # type: ignore[misc]


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("min_probability", 5.0),
        ("min_probability", -5.0),
        ("bandwidth_m", 0.0),
        ("vote_unit_area_m2", float("inf")),
        ("min_separation_m", -0.01),
        ("seed_fraction", 0.0),
        ("max_seeds", 0),
        ("iterations", 0),
    ],
)
def test_voting_settings_out_of_range_are_refused(name: str, value: float) -> None:
    """A model trained with min_probability 5 would never detect anything."""
    with pytest.raises(ValueError, match=name):
        VotingConfig(**{name: value})
