"""Compiled table fill of :mod:`glovedb.packed_images`, which documents and checks.

The kernel assumes checked, C-contiguous inputs of the documented dtypes.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray


@numba.njit(cache=True)
def fill_code_table(per_pixel: NDArray[np.float32], group: int, table: NDArray[np.float32]) -> None:
    """``table[p, code]`` = summed ``per_pixel[p * group + i, label_i]`` of the code's labels.

    ``per_pixel (P, L) float32`` holds each pixel's cost per label (``L = 11``),
    ``table (P // group, L ** group) float32``; codes put the first pixel's label in
    the most significant digit. Each row is the sum of the tables of the group's two
    halves, written in order (a contiguous, vectorised inner loop).
    """
    labels = per_pixel.shape[1]
    first_half = group // 2
    left = np.empty(labels**first_half, np.float32)
    right = np.empty(labels ** (group - first_half), np.float32)
    for position in range(table.shape[0]):
        first_pixel = position * group
        _half_table(per_pixel, first_pixel, first_half, left)
        _half_table(per_pixel, first_pixel + first_half, group - first_half, right)
        row = table[position]
        for high in range(len(left)):
            base = left[high]
            start = high * len(right)
            for low in range(len(right)):
                row[start + low] = base + right[low]


@numba.njit(cache=True)
def _half_table(
    per_pixel: NDArray[np.float32], first_pixel: int, pixels: int, out: NDArray[np.float32]
) -> None:
    """``out[code]``: summed costs of ``pixels`` pixels from ``first_pixel`` (0 if none)."""
    labels = per_pixel.shape[1]
    out[0] = 0.0
    length = 1
    for index in range(pixels):
        costs = per_pixel[first_pixel + index]
        for code in range(length - 1, -1, -1):  # descending: writes land above reads
            base = out[code]
            for label in range(labels):
                out[code * labels + label] = base + costs[label]
        length *= labels
