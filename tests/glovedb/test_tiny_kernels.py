"""The compiled tiny-image kernels give the same bytes as the dense kernels they replaced.

The reference below is the previous implementation, unchanged but for its names: one
(class, row, column) plane of counts per roll, every cell visited at every size. The fast kernels
must reproduce it bit for bit (majority ties, the float32 background sums, sub-pixel
sampling, the rounded crop) on renders of the database builder, random label images,
degenerate inputs and both counter widths.
"""

from __future__ import annotations

import numba
import numpy as np
import pytest
from numpy.typing import NDArray

from builder.build import PostureRenderer, make_plan
from builder.config import config_from_dict
from glovedb import _tiny_kernels
from glovedb.tiny_images import N_LABELS, tiny_images_from_pixels, tiny_images_of_label_images


@numba.njit(nogil=True)
def reference_tiny_images_into(
    u: NDArray[np.float64],
    v: NDArray[np.float64],
    labels: NDArray[np.int64],
    cos: NDArray[np.float64],
    sin: NDArray[np.float64],
    outs: tuple[NDArray[np.uint8], ...],
    first: int,
    n_labels: int,
) -> None:
    """Write the tiny images of every roll into ``outs[j][first + r]``.

    ``u, v`` are pixel centres relative to their centroid, ``labels`` their classes
    1..n_labels-1. ``outs`` holds one ``(M, s, s) uint8`` array per size, largest
    first, every size a power-of-two fraction of the one before.
    """
    size = outs[0].shape[1]
    n = u.shape[0]
    ru = np.empty(n)
    rv = np.empty(n)
    cells = np.empty(n, dtype=np.int64)
    # One plane of hits per class (plane 0 unused): the per-cell loops vectorise.
    top_hits = np.empty((n_labels, size, size), dtype=np.int32)
    background = np.empty((size, size), dtype=np.float32)
    best = np.empty(size * size, dtype=np.int32)
    best_count = np.empty(size * size, dtype=np.int32)
    # Smaller sizes alternate between two buffers, reshaped (contiguous) per size.
    half = max(size // 2, 1)
    level_hits = np.empty((2, n_labels * half * half), dtype=np.int32)
    level_background = np.empty((2, half * half), dtype=np.float32)
    for r in range(cos.shape[0]):
        scale, origin_u, origin_v = reference_rotate(u, v, cos[r], sin[r], ru, rv, size)
        k = 1 if scale <= 0.5 else int(np.ceil(2.0 * scale))
        area = k * k / (scale * scale)  # of a cell, in sub-pixels
        out = outs[0][first + r]
        hits = level_hits[0, : n_labels * half * half].reshape((n_labels, half, half))
        halved = level_background[0, : half * half].reshape((half, half))
        reference_count(
            ru, rv, labels, cos[r], sin[r], scale, origin_u, origin_v, k, cells, top_hits
        )
        reference_background(top_hits, area, background)
        reference_majority(top_hits, background, best, best_count, out)
        reference_halve(top_hits, background, hits, halved)
        side = half
        level = 0
        for j in range(1, len(outs)):
            while side > outs[j].shape[1]:
                side //= 2
                level = 1 - level
                smaller = level_hits[level, : n_labels * side * side].reshape(
                    (n_labels, side, side)
                )
                smaller_background = level_background[level, : side * side].reshape((side, side))
                reference_halve(hits, halved, smaller, smaller_background)
                hits, halved = smaller, smaller_background
            reference_majority(hits, halved, best, best_count, outs[j][first + r])


@numba.njit(nogil=True)
def reference_rotate(
    u: NDArray[np.float64],
    v: NDArray[np.float64],
    cos: float,
    sin: float,
    ru: NDArray[np.float64],
    rv: NDArray[np.float64],
    size: int,
) -> tuple[float, float, float]:
    """Rotate the pixel centres into ``ru, rv``; return the scale (cells per pixel)
    and origin (pixels) of the square crop about their bounding box."""
    low_u = low_v = np.inf
    high_u = high_v = -np.inf
    for i in range(u.shape[0]):
        ru[i] = u[i] * cos - v[i] * sin
        rv[i] = u[i] * sin + v[i] * cos
        low_u = min(low_u, ru[i])
        high_u = max(high_u, ru[i])
        low_v = min(low_v, rv[i])
        high_v = max(high_v, rv[i])
    side = max(high_u - low_u, high_v - low_v) + 1.0
    origin_u = (low_u + high_u + 1.0 - side) / 2.0 - 0.5
    origin_v = (low_v + high_v + 1.0 - side) / 2.0 - 0.5
    return size / side, origin_u, origin_v


@numba.njit(nogil=True)
def reference_count(
    ru: NDArray[np.float64],
    rv: NDArray[np.float64],
    labels: NDArray[np.int64],
    cos: float,
    sin: float,
    scale: float,
    origin_u: float,
    origin_v: float,
    k: int,
    cells: NDArray[np.int64],
    hits: NDArray[np.int32],
) -> None:
    """Sub-pixel hits of every class in every cell of the crop, for one roll.

    A pixel is a unit square split into k x k sub-pixels (k = 1 when cells are at
    least two pixels wide); each sub-pixel centre, rotated, hits one cell. Counting
    integers keeps the sums exact in any order.
    """
    size = hits.shape[1]
    n = ru.shape[0]
    hits[:] = 0
    flat = hits.reshape(-1)
    plane = size * size
    for a in range(k):
        for b in range(k):
            du = (a + 0.5) / k - 0.5
            dv = (b + 0.5) / k - 0.5
            shift_u = du * cos - dv * sin - origin_u
            shift_v = du * sin + dv * cos - origin_v
            # Cell indices first (a loop that vectorises), then the increments.
            for i in range(n):
                col = min(max(int((ru[i] + shift_u) * scale), 0), size - 1)
                row = min(max(int((rv[i] + shift_v) * scale), 0), size - 1)
                cells[i] = labels[i] * plane + row * size + col
            for i in range(n):
                flat[cells[i]] += 1


@numba.njit(nogil=True)
def reference_background(
    hits: NDArray[np.int32], area: float, background: NDArray[np.float32]
) -> None:
    """The area of every cell the glove does not cover, in sub-pixels."""
    size = hits.shape[1]
    glove = np.zeros((size, size), dtype=np.int32)
    for label in range(1, hits.shape[0]):
        glove += hits[label]
    for row in range(size):
        for col in range(size):
            background[row, col] = np.float32(max(area - glove[row, col], 0.0))


@numba.njit(nogil=True)
def reference_halve(
    hits: NDArray[np.int32],
    background: NDArray[np.float32],
    out_hits: NDArray[np.int32],
    out_background: NDArray[np.float32],
) -> None:
    """Sum 2 x 2 blocks of cells: ``(L, s, s)`` and ``(s, s)`` into half the size."""
    half = out_hits.shape[1]
    for label in range(1, hits.shape[0]):
        for row in range(half):
            for col in range(half):
                out_hits[label, row, col] = (
                    hits[label, 2 * row, 2 * col]
                    + hits[label, 2 * row, 2 * col + 1]
                    + hits[label, 2 * row + 1, 2 * col]
                    + hits[label, 2 * row + 1, 2 * col + 1]
                )
    for row in range(half):
        for col in range(half):
            out_background[row, col] = (
                background[2 * row, 2 * col]
                + background[2 * row, 2 * col + 1]
                + background[2 * row + 1, 2 * col]
                + background[2 * row + 1, 2 * col + 1]
            )


@numba.njit(nogil=True)
def reference_majority(
    hits: NDArray[np.int32],
    background: NDArray[np.float32],
    best: NDArray[np.int32],
    best_count: NDArray[np.int32],
    out: NDArray[np.uint8],
) -> None:
    """Class with the most hits per cell (ties: lowest class), or 0 when the
    background covers more. ``best`` and ``best_count`` are scratch space of at least
    ``s * s`` values."""
    n_labels, size, _ = hits.shape
    cells = size * size
    flat_hits = hits.reshape((n_labels, cells))
    flat_background = background.reshape(cells)
    flat_out = out.reshape(cells)
    best[:cells] = 1
    best_count[:cells] = flat_hits[1]
    for label in range(2, n_labels):
        for cell in range(cells):
            count = flat_hits[label, cell]
            if count > best_count[cell]:
                best_count[cell] = count
                best[cell] = label
    for cell in range(cells):
        glove_wins = best_count[cell] >= flat_background[cell]
        flat_out[cell] = best[cell] if glove_wins else 0


@numba.njit(nogil=True)
def reference_label_images_into(
    images: NDArray[np.uint8],
    cos: NDArray[np.float64],
    sin: NDArray[np.float64],
    outs: tuple[NDArray[np.uint8], ...],
    n_labels: int,
) -> None:
    """Tiny images of every roll of every label image ``(P, H, W)``: image ``p``, roll
    ``r`` goes to ``outs[j][p * R + r]``. Glove pixels are taken in row-major order and
    centred on their mean, as :func:`numpy.nonzero` and :func:`numpy.mean` would."""
    n_images, height, width = images.shape
    u = np.empty(height * width)
    v = np.empty(height * width)
    labels = np.empty(height * width, dtype=np.int64)
    for p in range(n_images):
        n = 0
        sum_u = 0
        sum_v = 0
        for row in range(height):
            for col in range(width):
                label = images[p, row, col]
                if label != 0:
                    u[n] = col
                    v[n] = row
                    labels[n] = label
                    sum_u += col
                    sum_v += row
                    n += 1
        if n == 0:
            for j in range(len(outs)):
                outs[j][p * cos.shape[0] : (p + 1) * cos.shape[0]] = 0
            continue
        # Integer sums are exact, so this is the correctly rounded mean numpy gives.
        mean_u = sum_u / n
        mean_v = sum_v / n
        for i in range(n):
            u[i] -= mean_u
            v[i] -= mean_v
        reference_tiny_images_into(
            u[:n], v[:n], labels[:n], cos, sin, outs, p * cos.shape[0], n_labels
        )


def reference_images(
    label_images: NDArray[np.uint8], sizes: tuple[int, ...], rolls: NDArray[np.float64]
) -> dict[int, NDArray[np.uint8]]:
    """The previous kernels' tiny images of ``(P, H, W)`` label images."""
    largest_first = sorted(sizes, reverse=True)
    outs = tuple(np.empty((len(label_images) * len(rolls), s, s), np.uint8) for s in largest_first)
    reference_label_images_into(
        np.ascontiguousarray(label_images), np.cos(rolls), np.sin(rolls), outs, N_LABELS
    )
    return dict(zip(largest_first, outs, strict=True))


def assert_same_as_reference(
    label_images: NDArray[np.uint8],
    sizes: tuple[int, ...] = (8, 16, 32, 64),
    rolls: NDArray[np.float64] | tuple[float, ...] = (0.0,),
) -> None:
    rolls = np.asarray(rolls, np.float64)
    fast = tiny_images_of_label_images(label_images, sizes, rolls_rad=rolls)
    expected = reference_images(label_images, sizes, rolls)
    assert sorted(fast) == sorted(sizes)
    for size in sizes:
        assert fast[size].dtype == np.uint8
        assert fast[size].shape == (len(label_images) * len(rolls), size, size)
        np.testing.assert_array_equal(fast[size], expected[size], err_msg=f"size {size}")


def random_label_images(rng: np.random.Generator, count: int, shape: tuple[int, int]) -> NDArray:
    """Label images from empty to full: speckle, and rectangles of one class."""
    images = np.zeros((count, *shape), np.uint8)
    for image in images:
        density = rng.uniform(0.0, 1.0)
        speckle = rng.uniform(size=shape) < density * 0.3
        image[speckle] = rng.integers(1, N_LABELS, speckle.sum())
        for _ in range(rng.integers(0, 6)):
            top, left = rng.integers(0, shape[0]), rng.integers(0, shape[1])
            height, width = rng.integers(1, shape[0] + 1), rng.integers(1, shape[1] + 1)
            image[top : top + height, left : left + width] = rng.integers(1, N_LABELS)
    return images


@pytest.fixture(scope="module")
def natural1000_renders() -> NDArray[np.uint8]:
    """Label renders as natural1000 makes them (192 x 192, 42 camera positions) of
    three named postures."""
    plan = make_plan(
        config_from_dict(
            {
                "name": "natural_views",
                "postures": {"named": ["open", "fist", "ok"]},
                "views": {"subdivisions": 1, "rolls": 18, "distance_m": 0.5},
                "images": {"sizes": [8, 16, 32, 64], "render_size": 192},
            }
        )
    )
    renderer = PostureRenderer(plan)
    rolls = len(plan.roll_rad)
    return np.concatenate(
        [
            renderer.label_images(
                posture, plan.view_rotations[::rolls], plan.view_translations_m[::rolls]
            )
            for posture in plan.postures_rad
        ]
    )


def test_builder_renders_every_roll(natural1000_renders):
    rolls = np.radians(np.arange(18) * 20.0)
    assert natural1000_renders.shape == (126, 192, 192) and natural1000_renders.any()
    assert_same_as_reference(natural1000_renders, rolls=rolls)


def test_builder_renders_shrunk_and_other_sizes(natural1000_renders):
    """Fewer render pixels per cell: cells narrower than two pixels, k = 2 to 5."""
    shrunk = natural1000_renders[::6, ::3, ::3]
    rolls = np.linspace(-np.pi, np.pi, 11)
    for sizes in [(8, 16, 32, 64), (4, 128), (256,), (16, 32)]:
        assert_same_as_reference(shrunk, sizes, rolls)


@pytest.mark.parametrize("seed", range(6))
def test_random_label_images(seed):
    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(1, 80)), int(rng.integers(1, 80)))
    images = random_label_images(rng, 8, shape)
    rolls = rng.uniform(-2 * np.pi, 2 * np.pi, int(rng.integers(1, 12)))
    for sizes in [(8, 16, 32, 64), (4,), (8, 64), (4, 32, 256)]:
        assert_same_as_reference(images, sizes, rolls)


def test_tiny_inputs_and_lines():
    rolls = np.concatenate([np.arange(8) * np.pi / 4, [0.1, -0.3, 1e-9]])
    images = np.zeros((9, 7, 9), np.uint8)
    images[0, 3, 4] = 5  # one pixel
    images[1, 2, 1:8] = 2  # a row
    images[2, :, 6] = 9  # a column
    images[3, np.arange(7), np.arange(7)] = 1  # a diagonal
    images[4, 0, 0] = images[4, 6, 8] = 3  # two far corners
    images[5, 3, 3:5] = [4, 6]  # two neighbours, a tie at every size
    images[6] = 10  # full
    images[7, 1:3, 1:3] = [[1, 2], [3, 4]]  # four classes, one pixel each
    for sizes in [(8, 16, 32, 64), (4,), (256,), (4, 256)]:
        assert_same_as_reference(images, sizes, rolls)


def test_empty_images_between_others():
    images = np.zeros((4, 30, 40), np.uint8)
    images[1, 5:20, 10:12] = 7
    images[3, 25, 3] = 1
    assert_same_as_reference(images, rolls=np.linspace(0, 3, 5))
    fast = tiny_images_of_label_images(images, (8, 64), rolls_rad=np.linspace(0, 3, 5))
    assert not fast[64][:5].any() and not fast[8][10:15].any()


def test_many_rolls():
    rng = np.random.default_rng(7)
    images = random_label_images(rng, 2, (40, 30))
    assert_same_as_reference(images, rolls=np.linspace(-10.0, 10.0, 301))


def test_both_counter_widths_in_one_call():
    """16-bit counters while a roll has under 2**16 sub-pixels, 32-bit beyond: a large
    glove (k = 1) and a small one at size 256 (k = 13 and more) next to small rolls."""
    images = np.zeros((3, 300, 300), np.uint8)
    images[0, 10:290, 20:280] = 4  # 72,800 pixels, k = 1
    images[0, 100:200, 50:60] = 2
    images[1, 140:180, 140:160] = 6  # 800 pixels
    images[1, 150:160, 140:145] = 3
    images[2, 5:250, 5:7] = 8  # a thin bar
    rolls = np.array([0.0, 0.4, 2.0])
    assert_same_as_reference(images, (32, 64, 128, 256), rolls)
    assert_same_as_reference(images[1:], (8, 16, 32, 64), rolls)


def test_pixel_path_off_the_grid():
    """tiny_images_from_pixels: pixel centres anywhere, in any order, every pixel a
    candidate for the crop's bounding box."""
    rng = np.random.default_rng(3)
    for count in (1, 2, 50, 3000):
        pixels = rng.normal(0.0, 20.0, (count, 2)) * rng.uniform(0.1, 1.0, 2)
        labels = rng.integers(1, N_LABELS, count)
        rolls = rng.uniform(-4.0, 4.0, 9)
        fast = tiny_images_from_pixels(pixels, labels, (4, 8, 16, 32, 64, 128), rolls_rad=rolls)
        centred = pixels - pixels.mean(axis=0)
        outs = tuple(np.empty((len(rolls), s, s), np.uint8) for s in (128, 64, 32, 16, 8, 4))
        reference_tiny_images_into(
            np.ascontiguousarray(centred[:, 0]),
            np.ascontiguousarray(centred[:, 1]),
            labels.astype(np.int64),
            np.cos(rolls),
            np.sin(rolls),
            outs,
            0,
            N_LABELS,
        )
        for out in outs:
            np.testing.assert_array_equal(fast[out.shape[1]], out)


def test_kernel_writes_only_its_rows():
    """Images go to rows ``p * R + r`` of the caller's arrays and nowhere else."""
    images = np.zeros((2, 20, 20), np.uint8)
    images[0, 4:9, 4:15] = 3
    images[1, 2:18, 9:11] = 5
    rolls = np.array([0.0, 1.0])
    outs = tuple(np.full((4, s, s), 99, np.uint8) for s in (16, 8))
    _tiny_kernels.label_images_into(images, np.cos(rolls), np.sin(rolls), outs, N_LABELS)
    expected = reference_images(images, (8, 16), rolls)
    np.testing.assert_array_equal(outs[0], expected[16])
    np.testing.assert_array_equal(outs[1], expected[8])


def test_counts_beyond_8_bits():
    """8-bit counters at the largest size only while no cell can hold 256 sub-pixels:
    here one cell of 50 x 50 pixels holds a block of 1,600, in a roll of far fewer than
    2**16."""
    images = np.zeros((1, 201, 201), np.uint8)
    images[0, 5:45, 5:45] = 7
    images[0, 200, 200] = 1  # stretches the crop: cells of the 4 x 4 image 50 pixels wide
    images[0, 120:130, 60:180] = 3
    assert_same_as_reference(images, (4,), np.array([0.0, 0.05]))
    assert_same_as_reference(images, (4, 8), np.array([0.0, 0.3]))
    assert tiny_images_of_label_images(images, (4,))[4][0, 0, 0] == 7


def test_counts_beyond_16_bits():
    """A cell of 4 x 4 with more than 2**16 pixels of one class."""
    images = np.zeros((1, 1101, 1101), np.uint8)
    images[0, :300, :300] = 5
    images[0, 1100, 1100] = 2  # stretches the crop: one cell is 275 pixels wide
    assert_same_as_reference(images, (4,), np.array([0.0, 0.05]))
    assert tiny_images_of_label_images(images, (4,))[4][0, 0, 0] == 5
