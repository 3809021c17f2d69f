"""Compiled loops of :mod:`glovedb.tiny_images`, which documents and checks the inputs."""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray


@numba.njit(cache=True, nogil=True)
def cell_counts(
    u: NDArray[np.float64],
    v: NDArray[np.float64],
    labels: NDArray[np.int64],
    cos: NDArray[np.float64],
    sin: NDArray[np.float64],
    size: int,
    n_labels: int,
) -> NDArray[np.float32]:
    """Per roll, how much of every cell of the size x size crop each class covers.

    ``u, v`` are pixel centres relative to their centroid; a pixel counts 1 in the
    cell its rotated centre falls in (spread over sub-pixels when cells are smaller
    than pixels); background is the rest of the cell's area.
    Returns ``(R, size, size, n_labels) float32``.
    """
    n_rolls = cos.shape[0]
    counts = np.zeros((n_rolls, size, size, n_labels), dtype=np.float32)
    ru = np.empty(u.shape[0])
    rv = np.empty(u.shape[0])
    for r in range(n_rolls):
        low_u = low_v = np.inf
        high_u = high_v = -np.inf
        for i in range(u.shape[0]):
            ru[i] = u[i] * cos[r] - v[i] * sin[r]
            rv[i] = u[i] * sin[r] + v[i] * cos[r]
            low_u = min(low_u, ru[i])
            high_u = max(high_u, ru[i])
            low_v = min(low_v, rv[i])
            high_v = max(high_v, rv[i])
        side = max(high_u - low_u, high_v - low_v) + 1.0
        origin_u = (low_u + high_u + 1.0 - side) / 2.0 - 0.5
        origin_v = (low_v + high_v + 1.0 - side) / 2.0 - 0.5
        scale = size / side
        # A pixel is a unit square: when cells are smaller than pixels, spread it over
        # k x k sub-pixels so that it covers every cell it overlaps.
        k = 1 if scale <= 0.5 else int(np.ceil(2.0 * scale))
        weight = 1.0 / (k * k)
        for a in range(k):
            for b in range(k):
                du = (a + 0.5) / k - 0.5
                dv = (b + 0.5) / k - 0.5
                shift_u = du * cos[r] - dv * sin[r] - origin_u
                shift_v = du * sin[r] + dv * cos[r] - origin_v
                for i in range(u.shape[0]):
                    col = min(max(int((ru[i] + shift_u) * scale), 0), size - 1)
                    row = min(max(int((rv[i] + shift_v) * scale), 0), size - 1)
                    counts[r, row, col, labels[i]] += weight
        cell_area = 1.0 / (scale * scale)
        for row in range(size):
            for col in range(size):
                glove = 0.0
                for k in range(1, n_labels):
                    glove += counts[r, row, col, k]
                counts[r, row, col, 0] = max(cell_area - glove, 0.0)
    return counts


@numba.njit(cache=True, nogil=True)
def halve(counts: NDArray[np.float32]) -> NDArray[np.float32]:
    """Sum 2 x 2 blocks of cells: ``(R, s, s, L)`` to ``(R, s/2, s/2, L)``."""
    n_rolls, size, _, n_labels = counts.shape
    half = size // 2
    out = np.zeros((n_rolls, half, half, n_labels), dtype=np.float32)
    for r in range(n_rolls):
        for row in range(size):
            for col in range(size):
                for k in range(n_labels):
                    out[r, row // 2, col // 2, k] += counts[r, row, col, k]
    return out


@numba.njit(cache=True, nogil=True)
def majority(counts: NDArray[np.float32]) -> NDArray[np.uint8]:
    """Class with the largest count per cell; ties go to the glove's lowest class."""
    n_rolls, size, _, n_labels = counts.shape
    out = np.zeros((n_rolls, size, size), dtype=np.uint8)
    for r in range(n_rolls):
        for row in range(size):
            for col in range(size):
                best, best_count = 0, -1.0
                for k in range(1, n_labels):
                    if counts[r, row, col, k] > best_count:
                        best, best_count = k, counts[r, row, col, k]
                if best_count >= counts[r, row, col, 0]:
                    out[r, row, col] = best
    return out
