"""Compiled loop of :mod:`glovedb.chamfer`, which documents and checks.

The kernel assumes checked, C-contiguous inputs of the documented dtypes.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray


@numba.njit(nogil=True, cache=True)
def cell_means(maps: NDArray[np.float32], out: NDArray[np.float32]) -> None:
    """``out[c, y, x]``: mean of ``maps[c]`` over cell ``(y, x)``, divided by the
    cell's side (coarse pixels).

    ``maps (C, S, S) float32``, ``out (C, s, s) float32`` with ``s`` dividing ``S``.
    A tenth of the time of NumPy's reshaped mean (10 against 106 microseconds for
    ten 64 x 64 maps to 8 x 8).
    """
    classes, fine, _ = maps.shape
    size = out.shape[1]
    factor = fine // size
    scale = np.float32(1.0 / (factor * factor * factor))
    for label in range(classes):
        for y in range(size):
            for x in range(size):
                total = np.float32(0.0)
                for dy in range(factor):
                    row = maps[label, y * factor + dy]
                    for dx in range(factor):
                        total += row[x * factor + dx]
                out[label, y, x] = total * scale
