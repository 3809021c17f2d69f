"""The depth noise model: measured statistics follow the configured model."""

import numpy as np
import pytest

from builder.depth_noise import (
    NOISE_PRESETS,
    DepthNoiseConfig,
    apply_depth_noise,
    depth_gradient,
    discontinuities,
    noise_preset,
    quantise_depth,
    viewing_angle,
)

INTRINSICS = np.array([500.0, 500.0, 99.5, 79.5])
SHAPE = (160, 200)
AXIAL_ONLY = DepthNoiseConfig(sigma_base_m=0.0005, sigma_quadratic_per_m=0.004)


def _plane(z_m: float, slope_m_per_px: float = 0.0) -> np.ndarray:
    """A plane facing the camera at ``z_m``, tilted so depth grows along u."""
    u = np.arange(SHAPE[1]) - SHAPE[1] / 2
    return np.broadcast_to(z_m + slope_m_per_px * u, SHAPE).astype(np.float32)


def _measured_sigma(depth: np.ndarray, config: DepthNoiseConfig, seed: int = 0) -> float:
    noisy = apply_depth_noise(depth, INTRINSICS, config, rng=np.random.default_rng(seed))
    inner = (slice(5, -5), slice(5, -5))
    return float(np.std(noisy[inner] - depth[inner]))


def test_none_is_the_identity() -> None:
    depth = _plane(0.6, 0.001)
    depth[:20] = 0.0
    out = apply_depth_noise(depth, INTRINSICS, noise_preset("none"), rng=np.random.default_rng(0))
    assert out.dtype == np.float32 and out is not depth
    np.testing.assert_array_equal(out, depth)
    assert noise_preset("none").is_identity and not noise_preset("kinect_v1").is_identity


@pytest.mark.parametrize("z_m", [0.5, 1.0, 1.5])
def test_noise_grows_with_depth_squared_as_configured(z_m: float) -> None:
    expected = 0.0005 + 0.004 * z_m**2
    np.testing.assert_allclose(_measured_sigma(_plane(z_m), AXIAL_ONLY), expected, rtol=0.03)


def test_noise_grows_with_the_depth_gradient() -> None:
    config = DepthNoiseConfig(sigma_base_m=0.001, lateral_sigma_px=0.5)
    flat = _measured_sigma(_plane(0.8), config)
    slope = 0.004  # metres per pixel
    steep = _measured_sigma(_plane(0.8, slope), config)
    np.testing.assert_allclose(flat, 0.001, rtol=0.03)
    np.testing.assert_allclose(steep, np.hypot(0.001, 0.5 * slope), rtol=0.03)


def test_kinect_preset_is_about_1_5_mm_at_half_a_metre() -> None:
    config = noise_preset("kinect_v1")
    quiet = DepthNoiseConfig(
        sigma_base_m=config.sigma_base_m, sigma_quadratic_per_m=config.sigma_quadratic_per_m
    )
    np.testing.assert_allclose(_measured_sigma(_plane(0.5), quiet), 0.0015, rtol=0.05)


def test_quantisation_step_grows_with_depth() -> None:
    depth = np.linspace(0.4, 1.6, 5000, dtype=np.float32)[None]
    out = quantise_depth(depth, step_at_1m_m=0.003)
    assert out.dtype == np.float32
    for z in (0.5, 1.0, 1.5):
        near = np.unique(out[np.abs(out - z) < 0.05])
        np.testing.assert_allclose(np.median(np.diff(near)), 0.003 * z**2, rtol=0.05)
    np.testing.assert_array_equal(quantise_depth(np.zeros((2, 2)), step_at_1m_m=0.003), 0)


def test_missing_depth_at_edges_and_grazing_angles() -> None:
    depth = _plane(0.7)
    depth[:, :40] = 0.0  # a silhouette edge at u = 40
    depth[:, 150:] = _plane(0.7, 0.02)[:, 150:]  # a surface seen almost edge-on
    edges = discontinuities(depth, edge_jump_m=0.02)
    assert edges[:, 40].all() and not edges[:, 60].any()
    angle = np.degrees(viewing_angle(depth, INTRINSICS, edge_jump_m=0.05))
    assert angle[80, 100] < 15 and angle[80, 170] > 80
    config = DepthNoiseConfig(edge_width_px=2, edge_dropout_probability=1.0, grazing_start_deg=70)
    out = apply_depth_noise(depth, INTRINSICS, config, rng=np.random.default_rng(1))
    assert np.all(out[:, 40:43] == 0) and np.all(out[:, 60:140] > 0)
    assert np.mean(out[:, 160:190] == 0) > 0.9


def test_gradient_ignores_jumps() -> None:
    depth = _plane(0.5, 0.001)
    depth[:, 100:] += 0.3
    gradient = depth_gradient(depth, edge_jump_m=0.02)
    assert gradient.shape == SHAPE + (2,) and gradient.dtype == np.float32
    np.testing.assert_allclose(gradient[50, 90:110, 0], 0.001, rtol=1e-3)
    np.testing.assert_allclose(gradient[50, 90:110, 1], 0.0, atol=1e-7)


def test_dropout_blobs_and_determinism() -> None:
    config = DepthNoiseConfig(sigma_base_m=0.001, dropout_blobs_per_mpx=2000.0)
    depth = _plane(0.9)
    a = apply_depth_noise(depth, INTRINSICS, config, rng=np.random.default_rng(5))
    b = apply_depth_noise(depth, INTRINSICS, config, rng=np.random.default_rng(5))
    c = apply_depth_noise(depth, INTRINSICS, config, rng=np.random.default_rng(6))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert 0.01 < np.mean(a == 0) < 0.9


@pytest.mark.parametrize("name", NOISE_PRESETS)
def test_presets_keep_dtype_shape_and_missing_pixels(name: str) -> None:
    depth = _plane(0.8, 0.0005)
    depth[:30, :30] = 0.0
    out = apply_depth_noise(depth, INTRINSICS, noise_preset(name), rng=np.random.default_rng(0))
    assert out.shape == SHAPE and out.dtype == np.float32
    assert np.all(out[:30, :30] == 0) and np.all(out >= 0)


def test_bad_settings_raise() -> None:
    with pytest.raises(ValueError, match="sigma_base_m"):
        DepthNoiseConfig(sigma_base_m=-1.0)
    with pytest.raises(ValueError, match="noise"):
        noise_preset("kinect_v9")
    with pytest.raises(ValueError, match="depth_m"):
        apply_depth_noise(np.zeros(5), INTRINSICS, AXIAL_ONLY, rng=np.random.default_rng(0))
