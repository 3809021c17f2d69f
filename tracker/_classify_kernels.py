"""Compiled loop of :mod:`tracker.classify`, which documents and checks the inputs."""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray


@numba.njit(cache=True, nogil=True)
def classify_into(
    rgb: NDArray[np.uint8], table: NDArray[np.uint8], shift: int, out: NDArray[np.uint8]
) -> None:
    """``out[i, j] = table[r >> shift, g >> shift, b >> shift]`` of every pixel of an
    ``(H, W, 3)`` image: one pass, no index arrays."""
    height, width, _ = rgb.shape
    for i in range(height):
        for j in range(width):
            out[i, j] = table[rgb[i, j, 0] >> shift, rgb[i, j, 1] >> shift, rgb[i, j, 2] >> shift]
