"""Depth-invariant pixel-pair features and hand-pixel selection."""

import numpy as np
import pytest

from fingertips.features import (
    BACKGROUND_DEPTH_M,
    foreground_pixels,
    mask_depth_range,
    pixel_features,
    random_offsets,
)

FOCAL_PX = 100.0
D0_M = 0.5


def _scene_pair(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, float]:
    """A blocky object at base depth D0 and the same object moved back to 2 * D0.

    Moving the object back by D0 halves its image about the principal point ``c`` and
    adds D0 to every depth, so ``near(c + 2 (q - c)) + D0 = far(q)`` on the pixel grid.
    """
    size, c = 121, 60
    blocks = rng.uniform(-0.05, 0.05, size=(16, 16)).astype(np.float32)
    blocks[rng.uniform(size=blocks.shape) < 0.2] = np.nan
    near = np.kron(blocks, np.ones((8, 8), np.float32))[:size, :size] + np.float32(D0_M)
    near[c - 20 : c + 21, c - 20 : c + 21] = D0_M
    near = np.nan_to_num(near, nan=0.0)
    far = np.zeros_like(near)
    q = np.arange(size)
    source = c + 2 * (q - c)
    valid = (source >= 0) & (source < size)
    block = near[np.ix_(source[valid], source[valid])]
    far[np.ix_(q[valid], q[valid])] = np.where(block > 0, block + np.float32(D0_M), 0.0)
    return near, far, c


def test_features_invariant_to_moving_the_scene_back() -> None:
    rng = np.random.default_rng(1)
    near, far, c = _scene_pair(rng)
    # Offsets of an even number of pixels at D0 land on pixel centres at 2 * D0 too.
    steps_px = rng.integers(-12, 13, size=(50, 2, 2)) * 2
    offsets_m = (steps_px * D0_M / FOCAL_PX).astype(np.float32)
    offsets_m[::3, 1] = 0.0
    # Reference pixels on the D0 plane, at even distances from the centre.
    grid = np.arange(-20, 21, 2)
    pixels_near = np.stack(np.meshgrid(grid, grid), -1).reshape(-1, 2) + c
    pixels_far = c + (pixels_near - c) // 2
    intrinsics = (FOCAL_PX, FOCAL_PX, float(c), float(c))
    f_near = pixel_features(near, pixels_near, offsets_m, intrinsics)
    f_far = pixel_features(far, pixels_far, offsets_m, intrinsics)
    assert f_near.dtype == np.float32
    assert f_near.shape == (pixels_near.shape[0], 50)
    # A probe on the background reads a constant that does not move with the scene, so
    # exact equality holds where both probes see the object.
    on_object = np.abs(f_near) < 1.0
    np.testing.assert_allclose(f_far[on_object], f_near[on_object], atol=1e-6)
    np.testing.assert_array_equal(np.abs(f_far) < 1.0, on_object)
    assert np.any(np.abs(f_near[on_object]) > 0.01), "the scene must have depth structure"
    assert not np.all(on_object), "some probes must read the background"


def test_probes_on_missing_depth_read_background_off_the_image_the_border() -> None:
    depth = np.full((10, 10), 0.5, np.float32)
    depth[5, 8] = 0.0
    depth[0, 6] = 0.7  # top border pixel above the reference pixel
    depth[9, 6] = 0.0  # bottom border pixel below it: missing
    offsets = np.zeros((5, 2, 2), np.float32)
    offsets[0, 0] = (0.0, -0.05)  # 10 px up, off the image: reads the top border pixel
    offsets[1, 0] = (0.0075, 0.0)  # 1.5 px right: rounds to 2, the missing pixel
    offsets[2, 0] = (0.005, 0.0)  # 1 px right, on the plane
    offsets[3, 0] = (0.0, 0.05)  # 10 px down, off the image, border pixel missing
    offsets[4, 0] = (-0.05, -0.05)  # off the image at the top-left corner
    features = pixel_features(depth, [[6, 5]], offsets, (100.0, 100.0, 5.0, 5.0))
    np.testing.assert_allclose(
        features[0],
        [0.7 - 0.5, BACKGROUND_DEPTH_M - 0.5, 0.0, BACKGROUND_DEPTH_M - 0.5, 0.0],
        atol=1e-6,
    )


def test_random_offsets_are_seeded_and_bounded() -> None:
    a = random_offsets(200, max_offset_m=0.08, unary_fraction=0.5, seed=3)
    b = random_offsets(200, max_offset_m=0.08, unary_fraction=0.5, seed=3)
    c = random_offsets(200, max_offset_m=0.08, unary_fraction=0.5, seed=4)
    assert a.shape == (200, 2, 2) and a.dtype == np.float32
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert np.all(np.linalg.norm(a, axis=2) <= 0.08 + 1e-7)
    unary = np.all(a[:, 1] == 0, axis=1)
    assert 60 < unary.sum() < 140


def test_foreground_selection_with_range_and_stride() -> None:
    depth = np.zeros((6, 8), np.float32)
    depth[1:5, 2:7] = 0.4
    depth[0, 0] = 2.5
    masked = mask_depth_range(depth, near_m=0.1, far_m=1.0)
    assert masked.dtype == np.float32 and masked[0, 0] == 0.0
    np.testing.assert_array_equal(foreground_pixels(masked).shape, (20, 2))
    pixels = foreground_pixels(masked, stride=2)
    assert pixels.dtype == np.int32
    np.testing.assert_array_equal(pixels, [[2, 2], [4, 2], [6, 2], [2, 4], [4, 4], [6, 4]])


@pytest.mark.parametrize(
    ("kwargs", "error"),
    [
        ({"depth_m": np.zeros((2, 2, 2))}, ValueError),
        ({"pixels_uv": np.zeros((3, 3), int)}, ValueError),
        ({"pixels_uv": np.zeros((1, 2))}, TypeError),
        ({"intrinsics": (1.0, 1.0, 0.0)}, ValueError),
        ({"pixels_uv": [[0, 0]]}, ValueError),
    ],
)
def test_pixel_features_rejects_bad_input(kwargs: dict, error: type[Exception]) -> None:
    depth = np.zeros((4, 4), np.float32)
    depth[1:, 1:] = 0.5
    args = {
        "depth_m": depth,
        "pixels_uv": np.array([[2, 2]]),
        "offsets_m": np.zeros((2, 2, 2), np.float32),
        "intrinsics": (100.0, 100.0, 2.0, 2.0),
    }
    with pytest.raises(error):
        pixel_features(**{**args, **kwargs})
