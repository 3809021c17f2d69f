"""Compiled loops of :mod:`glovedb.tiny_images`, which documents and checks the inputs.

One roll at a time: rotate the glove pixels, count the sub-pixels of each class in
every cell of the largest size (integers: exact in any order), take the majority,
then sum 2 x 2 cells for the next smaller size. The counts of one roll stay in the
cache, and the images go straight into the caller's output arrays.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray


@numba.njit(cache=True, nogil=True)
def tiny_images_into(
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
        scale, origin_u, origin_v = _rotate(u, v, cos[r], sin[r], ru, rv, size)
        k = 1 if scale <= 0.5 else int(np.ceil(2.0 * scale))
        area = k * k / (scale * scale)  # of a cell, in sub-pixels
        out = outs[0][first + r]
        hits = level_hits[0, : n_labels * half * half].reshape((n_labels, half, half))
        halved = level_background[0, : half * half].reshape((half, half))
        _count(ru, rv, labels, cos[r], sin[r], scale, origin_u, origin_v, k, cells, top_hits)
        _background(top_hits, area, background)
        _majority(top_hits, background, best, best_count, out)
        _halve(top_hits, background, hits, halved)
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
                _halve(hits, halved, smaller, smaller_background)
                hits, halved = smaller, smaller_background
            _majority(hits, halved, best, best_count, outs[j][first + r])


@numba.njit(cache=True, nogil=True)
def _rotate(
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


@numba.njit(cache=True, nogil=True)
def _count(
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


@numba.njit(cache=True, nogil=True)
def _background(hits: NDArray[np.int32], area: float, background: NDArray[np.float32]) -> None:
    """The area of every cell the glove does not cover, in sub-pixels."""
    size = hits.shape[1]
    glove = np.zeros((size, size), dtype=np.int32)
    for label in range(1, hits.shape[0]):
        glove += hits[label]
    for row in range(size):
        for col in range(size):
            background[row, col] = np.float32(max(area - glove[row, col], 0.0))


@numba.njit(cache=True, nogil=True)
def _halve(
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


@numba.njit(cache=True, nogil=True)
def _majority(
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


@numba.njit(cache=True, nogil=True)
def label_images_into(
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
        tiny_images_into(u[:n], v[:n], labels[:n], cos, sin, outs, p * cos.shape[0], n_labels)
