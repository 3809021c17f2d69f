"""The One Euro pose filter: less jitter when still, little lag when moving."""

import numpy as np
import pytest

from glovedb.rotations import axis_angle_to_matrix, geodesic_angle
from tracker.smoothing import (
    OneEuroFilter,
    OneEuroSettings,
    PoseFilter,
    smoothing_factor,
)

DT = 1 / 30


def test_smoothing_factor_is_the_exponential_filters():
    # cutoff f: alpha = 1 / (1 + 1 / (2 pi f dt)); a very high cutoff passes everything.
    assert smoothing_factor(1e9, DT) == pytest.approx(1.0)
    assert smoothing_factor(1.0, DT) == pytest.approx(1 / (1 + 1 / (2 * np.pi * DT)))


def test_one_euro_removes_noise_from_a_still_signal_and_follows_a_moving_one():
    rng = np.random.default_rng(0)
    still = 1.0 + 0.001 * rng.normal(size=(300, 3))
    smooth = OneEuroFilter(OneEuroSettings(min_cutoff_hz=0.3, beta=300.0))
    out = np.array([smooth(x, DT) for x in still])
    assert np.std(np.diff(out[30:], axis=0)) < 0.4 * np.std(np.diff(still[30:], axis=0))
    ramp = 0.2 * DT * np.arange(120)[:, None] * np.ones(3)  # 0.2 units per second
    smooth.reset()
    out = np.array([smooth(x, DT) for x in ramp + 0.001 * rng.normal(size=ramp.shape)])
    assert np.abs(out[60:] - ramp[60:]).mean() < 0.002  # under half a frame's motion


def test_pose_filter_keeps_a_still_rotation_and_follows_a_turning_one():
    rng = np.random.default_rng(1)
    base = axis_angle_to_matrix(np.array([0.0, 0.6, 0.8]), 2.0)
    pose_filter = PoseFilter()
    errors, raw = [], []
    for k in range(90):
        noise = axis_angle_to_matrix(rng.normal(size=3), np.radians(0.1))
        turning = axis_angle_to_matrix(np.array([1.0, 0.0, 0.0]), np.radians(2.0) * max(k - 45, 0))
        truth = turning @ base
        _, rotation, _ = pose_filter(np.zeros(20), noise @ truth, np.zeros(3), DT)
        errors.append(np.degrees(geodesic_angle(rotation, truth)))
        raw.append(np.degrees(geodesic_angle(noise @ truth, truth)))
        np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-9)
    assert np.mean(errors[20:45]) < 0.5 * np.mean(raw[20:45])  # still: the noise is damped
    assert np.mean(errors[60:]) < 2.0  # turning 60 deg/s: less than a frame behind


def test_vector_speed_follows_every_coordinate_of_a_moving_point():
    # A wrist moving fast along x and slowly along y: with one speed per coordinate the
    # slow y is filtered hard and lags; with the speed of the whole vector it follows.
    rng = np.random.default_rng(2)
    t = DT * np.arange(90)[:, None]
    path = np.hstack([0.3 * t, 0.003 * t, np.zeros_like(t)])
    settings = OneEuroSettings(min_cutoff_hz=0.4, beta=1500.0)
    lag = {}
    for vector in (False, True):
        smooth = OneEuroFilter(settings, vector=vector)
        out = np.array([smooth(x, DT) for x in path])
        lag[vector] = np.abs(out[30:, 1] - path[30:, 1]).mean()
    assert lag[True] < 0.5 * lag[False]
    # Still, the noise (random in direction) averages out of the velocity: damped.
    smooth = OneEuroFilter(settings, vector=True)
    still = 0.0003 * rng.normal(size=(300, 3))
    out = np.array([smooth(x, DT) for x in still])
    assert np.std(np.diff(out[30:], axis=0)) < 0.5 * np.std(np.diff(still[30:], axis=0))
