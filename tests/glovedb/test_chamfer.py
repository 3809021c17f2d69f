"""Chamfer maps and the tiny-image distance of Eq. 4.2 against a brute-force reference."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.ndimage import distance_transform_edt

from glovedb.chamfer import (
    NUM_CLASSES,
    absent_class_distance_px,
    cell_mean_maps,
    chamfer_maps,
    directed_distance,
    symmetric_distance,
)


def brute_force_distance(labels_a: np.ndarray, labels_b: np.ndarray) -> float:
    """Eq. 4.2 from explicit pairwise pixel distances (float64)."""
    size = labels_a.shape[-1]
    glove_a = np.argwhere(labels_a > 0)
    if len(glove_a) == 0:
        return math.inf
    total = 0.0
    for y, x in glove_a:
        same = np.argwhere(labels_b == labels_a[y, x])
        if len(same) == 0:
            total += absent_class_distance_px(size)
        else:
            total += np.sqrt(((same - (y, x)) ** 2).sum(axis=1)).min()
    return total / len(glove_a)


def random_labels(rng: np.random.Generator, size: int, glove_fraction: float) -> np.ndarray:
    labels = rng.integers(1, NUM_CLASSES + 1, (size, size), dtype=np.uint8)
    return np.where(rng.random((size, size)) < glove_fraction, labels, 0).astype(np.uint8)


@pytest.mark.parametrize("size", [8, 16, 32])
def test_chamfer_maps_shape_dtype_and_known_values(size: int) -> None:
    rng = np.random.default_rng(size)
    labels = random_labels(rng, size, 0.3)
    labels[labels == 7] = 0  # class 7 absent
    maps = chamfer_maps(labels)
    assert maps.shape == (NUM_CLASSES, size, size)
    assert maps.dtype == np.float32
    for label in range(1, NUM_CLASSES + 1):
        if np.any(labels == label):
            np.testing.assert_array_equal(maps[label - 1][labels == label], 0.0)
            assert maps[label - 1].max() <= (size - 1) * math.sqrt(2)
    np.testing.assert_allclose(maps[6], size * math.sqrt(2), rtol=1e-7)


def test_chamfer_maps_of_a_stack_equal_maps_of_each_image() -> None:
    rng = np.random.default_rng(1)
    stack = np.stack([[random_labels(rng, 8, 0.5) for _ in range(3)] for _ in range(2)])
    maps = chamfer_maps(stack)
    assert maps.shape == (2, 3, NUM_CLASSES, 8, 8)
    np.testing.assert_array_equal(maps[1, 2], chamfer_maps(stack[1, 2]))


@pytest.mark.parametrize("size", [8, 16, 64])
@pytest.mark.parametrize("glove_fraction", [0.02, 0.3, 0.95])
def test_chamfer_maps_equal_scipy_exact_transform(size: int, glove_fraction: float) -> None:
    """The compiled transform against SciPy's, bit for bit, on sparse to full images
    (a class in one column, one absent)."""
    rng = np.random.default_rng(size + int(100 * glove_fraction))
    labels = random_labels(rng, size, glove_fraction)
    labels[(labels == 7) | (labels == 9)] = 0  # class 7 absent,
    labels[::3, 3] = 9  # class 9 in one column only
    maps = chamfer_maps(labels)
    for label in range(1, NUM_CLASSES + 1):
        if np.any(labels == label):
            expected = distance_transform_edt(labels != label).astype(np.float32)
        else:
            expected = np.full((size, size), absent_class_distance_px(size), np.float32)
        np.testing.assert_array_equal(maps[label - 1], expected)


def test_single_pixel_map_is_euclidean_distance() -> None:
    labels = np.zeros((16, 16), np.uint8)
    labels[3, 5] = 4
    yy, xx = np.mgrid[0:16, 0:16]
    expected = np.hypot(yy - 3, xx - 5)
    np.testing.assert_allclose(chamfer_maps(labels)[3], expected, rtol=1e-6)


@pytest.mark.parametrize("size", [8, 16])
@pytest.mark.parametrize("seed", range(4))
def test_directed_distance_equals_brute_force(size: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    a = random_labels(rng, size, rng.uniform(0.05, 0.9))
    b = random_labels(rng, size, rng.uniform(0.05, 0.9))
    # Exact EDT: equal up to float32 rounding of the mean.
    np.testing.assert_allclose(
        directed_distance(a, chamfer_maps(b)), brute_force_distance(a, b), rtol=1e-6
    )


def test_directed_distance_of_a_stack() -> None:
    rng = np.random.default_rng(5)
    stack = np.stack([random_labels(rng, 16, 0.4) for _ in range(6)])
    maps = chamfer_maps(random_labels(rng, 16, 0.4))
    result = directed_distance(stack, maps)
    assert result.shape == (6,)
    assert result.dtype == np.float32
    expected = [directed_distance(image, maps) for image in stack]
    np.testing.assert_allclose(result, expected, rtol=1e-6)


def test_distance_to_itself_is_zero() -> None:
    labels = random_labels(np.random.default_rng(2), 16, 0.5)
    assert directed_distance(labels, chamfer_maps(labels)) == 0.0
    assert symmetric_distance(labels, labels) == 0.0


@pytest.mark.parametrize("seed", range(3))
def test_symmetric_distance_is_symmetric_and_the_mean_of_both_directions(seed: int) -> None:
    rng = np.random.default_rng(10 + seed)
    a, b = random_labels(rng, 8, 0.6), random_labels(rng, 8, 0.2)
    forward = symmetric_distance(a, b)
    assert forward == symmetric_distance(b, a)
    expected = 0.5 * (brute_force_distance(a, b) + brute_force_distance(b, a))
    np.testing.assert_allclose(forward, expected, rtol=1e-6)


def test_empty_images_give_infinity_or_the_absent_penalty() -> None:
    empty = np.zeros((8, 8), np.uint8)
    full = np.full((8, 8), 3, np.uint8)
    np.testing.assert_allclose(chamfer_maps(empty), absent_class_distance_px(8), rtol=1e-7)
    assert directed_distance(empty, chamfer_maps(full)) == np.inf
    np.testing.assert_allclose(
        directed_distance(full, chamfer_maps(empty)), 8 * math.sqrt(2), rtol=1e-6
    )
    assert symmetric_distance(empty, full) == np.inf
    assert brute_force_distance(empty, full) == math.inf


def test_cell_mean_maps_average_each_cell_in_coarse_pixels() -> None:
    fine = random_labels(np.random.default_rng(3), 32, 0.3)
    maps = chamfer_maps(fine)
    coarse = cell_mean_maps(maps, 8)
    assert coarse.shape == (NUM_CLASSES, 8, 8) and coarse.dtype == np.float32
    # Cell (2, 5) of an 8x8 grid over 32x32 is rows 8..11, columns 20..23; 4 fine
    # pixels make one coarse pixel.
    expected = maps[:, 8:12, 20:24].mean(axis=(1, 2)) / 4
    np.testing.assert_allclose(coarse[:, 2, 5], expected, rtol=1e-6)
    np.testing.assert_array_equal(cell_mean_maps(maps, 32), maps)


def test_cell_mean_maps_of_a_one_pixel_patch_know_where_in_the_cell_it_is() -> None:
    # A colour on one fine pixel at the corner of its coarse cell: the cell-mean map
    # of that cell is the mean distance from the cell's fine pixels to the corner,
    # not zero, and the neighbouring cells see the true fine distances.
    fine = np.zeros((16, 16), np.uint8)
    fine[0, 0] = 5
    coarse = cell_mean_maps(chamfer_maps(fine), 8)[4]
    corner = np.mean([math.hypot(y, x) for y in range(2) for x in range(2)]) / 2
    assert coarse[0, 0] == pytest.approx(corner, rel=1e-6)
    right = np.mean([math.hypot(y, x) for y in range(2) for x in range(2, 4)]) / 2
    assert coarse[0, 1] == pytest.approx(right, rel=1e-6)


def test_bad_inputs_raise() -> None:
    with pytest.raises(ValueError, match="labels"):
        chamfer_maps(np.full((8, 8), 11, np.uint8))
    with pytest.raises(ValueError, match="square"):
        chamfer_maps(np.zeros((8, 9), np.uint8))
    with pytest.raises(TypeError, match="labels"):
        chamfer_maps(np.zeros((8, 8), np.float32))
    with pytest.raises(ValueError, match="maps_b"):
        directed_distance(np.zeros((8, 8), np.uint8), np.zeros((10, 16, 16), np.float32))
    with pytest.raises(ValueError, match="labels_b"):
        symmetric_distance(np.zeros((8, 8), np.uint8), np.zeros((16, 16), np.uint8))
    with pytest.raises(ValueError, match="must divide"):
        cell_mean_maps(np.zeros((10, 16, 16), np.float32), 5)
