"""Posture sampling: the pruned farthest-point selection picks what the plain loop picks."""

import numpy as np
import pytest

from builder.sampling import farthest_point_selection, posture_features, synergy_postures
from glovedb.postures import load_named_postures


def plain_farthest_points(postures_rad: np.ndarray, count: int, first: int = 0) -> np.ndarray:
    """The straightforward greedy loop: every distance computed every step."""
    features = posture_features(postures_rad)
    picks = [first]
    nearest = np.linalg.norm(features - features[first], axis=1)
    for _ in range(1, count):
        picks.append(int(np.argmax(nearest)))
        nearest = np.minimum(nearest, np.linalg.norm(features - features[picks[-1]], axis=1))
    return np.array(picks)


@pytest.mark.parametrize("kind", ["synergies", "uniform", "repeated"])
def test_pruned_selection_equals_the_plain_loop(kind):
    rng = np.random.default_rng(3)
    named = np.array(list(load_named_postures().values()))
    if kind == "synergies":  # low-dimensional, as the databases draw them: most pruned
        postures = synergy_postures(3000, named, synergies=5, spread=1.0, noise_deg=5.0, seed=4)
    elif kind == "uniform":
        postures = np.radians(rng.uniform(-10.0, 90.0, size=(2000, 20)))
    else:  # exact duplicates: ties go to the lowest index
        postures = np.repeat(named, 40, axis=0)[rng.permutation(400)]
    count = 150 if kind != "repeated" else 10
    picks = farthest_point_selection(postures, count, first=1)
    np.testing.assert_array_equal(picks, plain_farthest_points(postures, count, first=1))
    assert len(set(picks.tolist())) == count
