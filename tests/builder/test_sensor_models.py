"""The depth sensor models: measured statistics match the documented sources' figures."""

from dataclasses import replace

import numpy as np
import pytest

from builder.depth_noise import (
    NOISE_PRESETS,
    DepthSensorModel,
    apply_depth_noise,
    discontinuities,
    noise_preset,
)
from builder.sensors import (
    SENSOR_PRESETS,
    ActiveStereoConfig,
    StructuredLightConfig,
    TimeOfFlightConfig,
)
from builder.sensors.active_stereo import correlated_noise
from builder.sensors.edges import mix_flying_pixels, occlusion_shadow
from builder.sensors.time_of_flight import multipath_bias

FX = 500.0
INTRINSICS = np.array([FX, FX, 99.5, 79.5])
SHAPE = (160, 200)
BOX_ROWS, BOX_COLUMNS = slice(40, 120), slice(120, 160)
INNER = (slice(10, -10), slice(10, -10))


def _plane(z_m: float) -> np.ndarray:
    return np.full(SHAPE, z_m, np.float32)


def _box_scene(z_box_m: float = 0.6, z_wall_m: float = 1.0) -> np.ndarray:
    """A wall facing the camera with a box in front of it (columns 120-159)."""
    depth = _plane(z_wall_m)
    depth[BOX_ROWS, BOX_COLUMNS] = z_box_m
    return depth


def _rng(seed: int) -> np.random.Generator:
    return np.random.default_rng(seed)


def _simulate(depth: np.ndarray, config: DepthSensorModel, seed: int = 0) -> np.ndarray:
    return apply_depth_noise(depth, INTRINSICS, config, rng=_rng(seed))


def _depth_step(z_m: float, config: StructuredLightConfig) -> float:
    measured = _simulate(_plane(z_m), config)
    levels = np.unique(measured[measured > 0])
    return float(np.median(np.diff(levels)))


def test_presets_are_selectable_by_name() -> None:
    assert set(SENSOR_PRESETS) < set(NOISE_PRESETS)
    assert isinstance(noise_preset("structured_light"), StructuredLightConfig)
    assert isinstance(noise_preset("active_stereo"), ActiveStereoConfig)
    assert isinstance(noise_preset("time_of_flight"), TimeOfFlightConfig)


def test_structured_light_step_grows_with_depth_squared() -> None:
    config = StructuredLightConfig(dropout_blobs_per_mpx=0.0)
    steps = {z: _depth_step(z, config) for z in (0.5, 1.0, 2.0)}
    # 1/8 pixel at f = 580 px and b = 7.5 cm: 2.87 mm at 1 m.
    np.testing.assert_allclose(steps[1.0], 0.125 / (580 * 0.075), rtol=0.05)
    np.testing.assert_allclose(steps[1.0] / steps[0.5], 4.0, rtol=0.1)
    np.testing.assert_allclose(steps[2.0] / steps[0.5], 16.0, rtol=0.1)


def test_structured_light_noise_reaches_4_cm_at_5_m() -> None:
    measured = _simulate(_plane(5.0), StructuredLightConfig(dropout_blobs_per_mpx=0.0))
    error = measured[measured > 0] - 5.0
    np.testing.assert_allclose(np.sqrt(np.mean(error**2)), 0.04, rtol=0.15)


@pytest.mark.parametrize("z_box_m", [0.5, 0.7])
def test_structured_light_shadow_width_and_side(z_box_m: float) -> None:
    config = StructuredLightConfig(dropout_blobs_per_mpx=0.0)
    measured = _simulate(_box_scene(z_box_m), config)
    expected_px = FX * config.baseline_m * (1 / z_box_m - 1.0)
    left = measured[BOX_ROWS, :120] == 0
    widths = left.sum(axis=1)
    assert np.all(left[:, 120 - int(expected_px) + 1 :])  # the band touches the box
    np.testing.assert_allclose(widths, expected_px, atol=1.0)
    assert np.all(measured[BOX_ROWS, 160:] > 0)  # nothing on the +x side
    assert np.all(measured[BOX_ROWS, BOX_COLUMNS] > 0)


def test_shadow_follows_the_second_viewpoint() -> None:
    depth = _box_scene()
    right = occlusion_shadow(depth, focal_length_px=FX, baseline_m=-0.05)
    left = occlusion_shadow(depth, focal_length_px=FX, baseline_m=0.05)
    assert right.dtype == bool and right.shape == SHAPE
    np.testing.assert_array_equal(right[BOX_ROWS, 160:].sum(axis=1), 16)  # 500 * 0.05 * 2/3
    np.testing.assert_array_equal(left[BOX_ROWS, :120].sum(axis=1), 16)
    assert not right[:, :160].any() and not left[:, 120:].any()
    assert not occlusion_shadow(_plane(0.8), focal_length_px=FX, baseline_m=0.075).any()


def test_active_stereo_rms_matches_the_datasheet_formula() -> None:
    config = ActiveStereoConfig(dropout_blobs_per_mpx=0.0)
    for z_m in (0.5, 1.0):
        error = _simulate(_plane(z_m), config)[INNER] - z_m
        # 0.08 px at f = 447 px and b = 50 mm: 3.6 mm at 1 m.
        np.testing.assert_allclose(np.std(error), config.depth_rms_m(z_m), rtol=0.2)
        np.testing.assert_allclose(config.depth_rms_m(1.0), 1.0 * 0.08 / (447 * 0.05))


def test_active_stereo_noise_is_spatially_correlated() -> None:
    stereo = _simulate(_plane(1.0), ActiveStereoConfig(dropout_blobs_per_mpx=0.0))[INNER] - 1.0
    light = _simulate(_plane(1.0), StructuredLightConfig(dropout_blobs_per_mpx=0.0))[INNER] - 1.0
    for residual, low, high in ((stereo, 0.5, 1.0), (light, -0.1, 0.1)):
        across = np.corrcoef(residual[:, :-1].ravel(), residual[:, 1:].ravel())[0, 1]
        down = np.corrcoef(residual[:-1].ravel(), residual[1:].ravel())[0, 1]
        assert low < across < high and low < down < high
    field = correlated_noise((200, 200), correlation_px=1.5, rng=_rng(3))
    np.testing.assert_allclose(np.std(field[20:-20, 20:-20]), 1.0, rtol=0.1)


def test_active_stereo_flying_pixels_and_shadow() -> None:
    config = ActiveStereoConfig(dropout_blobs_per_mpx=0.0, subpixel_rms_px=0.0)
    depth = _box_scene()
    measured = _simulate(depth, config)
    flying = (measured > 0.6 + 1e-4) & (measured < 1.0 - 1e-4)
    edges = discontinuities(depth, edge_jump_m=0.02)
    assert not (flying & ~edges).any()
    assert 0.3 < flying.sum() / edges.sum() < 0.7  # flying_pixel_probability
    np.testing.assert_array_equal((measured[BOX_ROWS, :120] == 0).sum(axis=1), 16)


def test_time_of_flight_flying_pixels_lie_between_the_surfaces_at_edges() -> None:
    quiet = TimeOfFlightConfig(sigma_m=0.0, multipath_strength=0.0)
    depth = _box_scene()
    edges = discontinuities(depth, edge_jump_m=0.02)
    kept = _simulate(depth, replace(quiet, flying_pixel_invalid_probability=0.0))
    flying = (kept > 0.6) & (kept < 1.0)
    np.testing.assert_array_equal(flying, edges)  # every pixel beside the jump, no other
    np.testing.assert_array_equal(kept[~edges], depth[~edges])
    filtered = _simulate(depth, quiet)
    assert 0.3 < np.mean(filtered[edges] == 0) < 0.7  # the confidence filter
    assert np.all(filtered[~edges] > 0)  # and no shadow


def test_mixed_pixels_weight_by_returned_light() -> None:
    depth = _box_scene()
    linear, mixed = mix_flying_pixels(
        depth, edge_jump_m=0.02, probability=1.0, amplitude_weighted=False, rng=_rng(0)
    )
    weighted, _ = mix_flying_pixels(
        depth, edge_jump_m=0.02, probability=1.0, amplitude_weighted=True, rng=_rng(0)
    )
    assert linear.dtype == np.float32
    np.testing.assert_array_equal(mixed, discontinuities(depth, edge_jump_m=0.02))
    # The nearer surface returns more light, so it pulls the mix towards itself.
    assert np.all(weighted[mixed] < linear[mixed])


def test_time_of_flight_noise_varies_little_with_depth() -> None:
    config = TimeOfFlightConfig(multipath_strength=0.0)
    sigma = {z: float(np.std(_simulate(_plane(z), config)[INNER] - z)) for z in (0.5, 1.0, 2.0)}
    np.testing.assert_allclose(sigma[1.0], 0.0015, rtol=0.1)
    for z_m, measured in sigma.items():
        np.testing.assert_allclose(measured, config.sigma_at(z_m), rtol=0.1)
    assert sigma[2.0] / sigma[0.5] < 2.0  # structured light: 16


def test_time_of_flight_multipath_pushes_concave_corners_away() -> None:
    u = np.arange(SHAPE[1], dtype=np.float32)
    valley = np.broadcast_to(1.0 - 0.004 * np.abs(u - 100), SHAPE).astype(np.float32)
    bias = multipath_bias(valley, radius_px=2, range_m=0.05, strength=0.5)
    assert bias.dtype == np.float32 and np.all(bias >= 0)
    assert np.all(bias[:, 100] > 0.001)  # the corner reads farther
    np.testing.assert_allclose(bias[:, 10:95], 0.0, atol=1e-6)  # the walls do not
    ridge = multipath_bias(2.0 - valley, radius_px=2, range_m=0.05, strength=0.5)
    np.testing.assert_allclose(ridge, 0.0, atol=1e-6)  # nor convex shapes


@pytest.mark.parametrize("name", sorted(SENSOR_PRESETS))
def test_sensor_models_are_reproducible_and_keep_missing_pixels(name: str) -> None:
    depth = _box_scene()
    depth[:30, :30] = 0.0
    config = noise_preset(name)
    first, again, other = (_simulate(depth, config, seed) for seed in (4, 4, 5))
    assert first.dtype == np.float32 and first.shape == SHAPE
    np.testing.assert_array_equal(first, again)
    assert not np.array_equal(first, other)
    assert np.all(first[:30, :30] == 0) and np.all(first >= 0)
    assert np.mean(first > 0) > 0.8


def test_bad_sensor_settings_raise() -> None:
    with pytest.raises(ValueError, match="baseline_m"):
        StructuredLightConfig(baseline_m=0.0)
    with pytest.raises(ValueError, match="subpixel_rms_px"):
        ActiveStereoConfig(subpixel_rms_px=-0.1)
    with pytest.raises(ValueError, match="flying_pixel_invalid_probability"):
        TimeOfFlightConfig(flying_pixel_invalid_probability=1.5)
    with pytest.raises(ValueError, match="depth_m"):
        _simulate(np.zeros(5, np.float32), TimeOfFlightConfig())
