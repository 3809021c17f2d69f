"""Eq. 11 of Tzionas et al. 2014: exact assignment versus brute-force enumeration."""

import itertools

import numpy as np
import pytest

from fingertips.assignment import assign_detections


def _objective(finger: tuple[int, ...], distance, weight, lam: float, n_tips: int) -> float:
    """Eq. 11 for one assignment (``finger[s]`` = tip of detection s, -1 = none)."""
    used = [t for t in finger if t >= 0]
    matched = sum(distance[s, t] for s, t in enumerate(finger) if t >= 0)
    unassigned = sum(weight[s] for s, t in enumerate(finger) if t < 0)
    return matched + lam * unassigned + lam * (n_tips - len(used))


def _brute_force(distance, weight, lam: float) -> float:
    n_det, n_tip = distance.shape
    best = np.inf
    for choice in itertools.product(range(-1, n_tip), repeat=n_det):
        used = [t for t in choice if t >= 0]
        if len(used) == len(set(used)):
            best = min(best, _objective(choice, distance, weight, lam, n_tip))
    return best


@pytest.mark.parametrize("n_det", [0, 1, 3, 5, 7])
def test_matches_brute_force(n_det: int) -> None:
    rng = np.random.default_rng(10 + n_det)
    c_thr, lam = 3.0, 1.2
    for _ in range(12):
        n_tip = int(rng.integers(1, 6))
        tips = rng.uniform(-1.0, 1.0, size=(n_tip, 3))
        detections = rng.uniform(-1.0, 1.0, size=(n_det, 3))
        confidences = rng.uniform(c_thr, 4 * c_thr, size=n_det)
        result = assign_detections(
            detections, confidences, tips, c_thr=c_thr, lam=lam, distance_unit_m=0.5
        )
        distance = np.linalg.norm(detections[:, None] - tips[None], axis=2) / 0.5
        weight = confidences / c_thr
        expected = _brute_force(distance, weight, lam)
        np.testing.assert_allclose(result.cost, expected, rtol=1e-12, atol=1e-12)
        own = _objective(tuple(result.finger_of_detection), distance, weight, lam, n_tip)
        np.testing.assert_allclose(own, result.cost, rtol=1e-12, atol=1e-12)
        assert result.finger_of_detection.dtype == np.int64
        assert result.finger_of_detection.shape == (n_det,)


def test_close_detections_take_their_finger_and_outliers_stay_unassigned() -> None:
    tips = np.array([[0.0, 0.0, 0.3], [0.02, 0.0, 0.3], [0.04, 0.0, 0.3]])
    detections = np.array([[0.041, 0.0, 0.3], [0.0, 0.002, 0.3], [0.5, 0.5, 0.8]])
    result = assign_detections(detections, [3.0, 6.0, 3.0], tips)
    np.testing.assert_array_equal(result.finger_of_detection, [2, 0, -1])
    # Distances in cm; the unassigned outlier costs lambda * 1, finger 1 without a
    # detection costs lambda.
    np.testing.assert_allclose(result.cost, 0.1 + 0.2 + 1.2 + 1.2, atol=1e-9)


def test_gate_grows_with_confidence() -> None:
    tips = np.array([[0.0, 0.0, 0.3]])
    detection = np.array([[0.03, 0.0, 0.3]])  # 3 cm off
    # Kept out when lambda * (1 + c / c_thr) = 2.4 cm < 3 cm, paired when 3.6 cm > 3 cm.
    weak = assign_detections(detection, [3.0], tips)
    strong = assign_detections(detection, [6.0], tips)
    np.testing.assert_array_equal(weak.finger_of_detection, [-1])
    np.testing.assert_array_equal(strong.finger_of_detection, [0])


def test_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="confidences"):
        assign_detections(np.zeros((2, 3)), [1.0], np.zeros((5, 3)))
    with pytest.raises(ValueError, match="model_tips_m"):
        assign_detections(np.zeros((2, 3)), [1.0, 1.0], np.zeros((5, 2)))
    with pytest.raises(ValueError, match="c_thr"):
        assign_detections(np.zeros((1, 3)), [1.0], np.zeros((5, 3)), c_thr=0.0)
