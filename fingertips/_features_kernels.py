"""Compiled per-pixel passes over a depth frame (for :mod:`fingertips.features`).

Each is the NumPy expression its caller documents, in one pass without temporaries:
the same comparisons in float32, so the same pixels are kept.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray


@numba.njit(cache=True, nogil=True)
def depth_within(
    depth_m: NDArray[np.float32], low_m: np.float32, high_m: np.float32
) -> NDArray[np.float32]:
    """``np.where((depth_m >= low_m) & (depth_m <= high_m), depth_m, 0)`` ``(H, W) float32``."""
    height, width = depth_m.shape
    kept = np.empty((height, width), dtype=np.float32)
    for i in range(height):
        for j in range(width):
            d = depth_m[i, j]
            kept[i, j] = d if d >= low_m and d <= high_m else np.float32(0.0)
    return kept


@numba.njit(cache=True, nogil=True)
def measured_on_grid(depth_m: NDArray[np.float32], step: int) -> NDArray[np.float32]:
    """``depth_m[::step, ::step]`` values above 0, in row-major order ``(M,) float32``."""
    height, width = depth_m.shape
    values = np.empty(((height + step - 1) // step) * ((width + step - 1) // step), np.float32)
    count = 0
    for i in range(0, height, step):
        for j in range(0, width, step):
            d = depth_m[i, j]
            if d > 0:
                values[count] = d
                count += 1
    return values[:count]


@numba.njit(cache=True, nogil=True)
def filled_with_edge(depth_m: NDArray[np.float32], missing_m: np.float32) -> NDArray[np.float32]:
    """Depth with values not above 0 set to ``missing_m``, padded by a 1-pixel edge copy,
    ``(H + 2, W + 2) float32``.

    Row by row through slices, which the compiler vectorises (0.19 -> 0.09 ms a VGA
    frame against clamping both indices of every pixel)."""
    height, width = depth_m.shape
    padded = np.empty((height + 2, width + 2), dtype=np.float32)
    for i in range(height + 2):
        source = depth_m[min(max(i - 1, 0), height - 1)]
        target = padded[i, 1 : width + 1]
        for j in range(width):
            d = source[j]
            target[j] = d if d > 0 else missing_m
        padded[i, 0] = padded[i, 1]
        padded[i, width + 1] = padded[i, width]
    return padded


@numba.njit(cache=True, nogil=True)
def count_measured(depth_m: NDArray[np.float32]) -> int:
    """``np.count_nonzero(depth_m)`` of an ``(H, W) float32`` depth (NaN counts, as
    there): NumPy has no fast path for floats (0.68 against 0.05 ms a VGA frame)."""
    count = 0
    for i in range(depth_m.shape[0]):
        row = depth_m[i]
        for j in range(len(row)):
            count += row[j] != 0
    return count


@numba.njit(cache=True, nogil=True)
def measured_pixels(depth_m: NDArray[np.float32], stride: int) -> NDArray[np.int32]:
    """``(N, 2) int32`` ``(u, v)`` of the pixels above 0 on the grid of step ``stride``,
    row-major: :func:`numpy.nonzero` of the strided view, stacked."""
    height, width = depth_m.shape
    rows = (height + stride - 1) // stride
    cols = (width + stride - 1) // stride
    pixels = np.empty((rows * cols, 2), np.int32)
    count = 0
    for i in range(0, height, stride):
        row = depth_m[i]
        for j in range(0, width, stride):
            if row[j] > 0:
                pixels[count, 0] = j
                pixels[count, 1] = i
                count += 1
    return pixels[:count].copy()
