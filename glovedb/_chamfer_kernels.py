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


_FAR = 1 << 28
"""A squared distance larger than any inside an image (int32, with room to add a square)."""


@numba.njit(nogil=True, cache=True)
def distance_maps(images: NDArray[np.uint8], absent: float, out: NDArray[np.float32]) -> None:
    """``out[m, c - 1]``: exact Euclidean distance transform of class ``c`` in image
    ``m``, ``absent`` where the class does not occur.

    ``images (M, s, s) uint8`` labels 0..``C``, ``out (M, C, s, s) float32``. Separable:
    each column's squared distance to the class along y, then per row the minimum over
    the class's columns ``x'`` of ``(x - x')**2 + g(x')**2``. Every loop over ``x``
    runs over whole rows, which the compiler turns into vector instructions (indexing
    through slices keeps it from checking for negative indices). Squared distances
    are integers, so each value is the correctly rounded ``sqrt`` of the true squared
    distance (what SciPy's ``distance_transform_edt`` gives in float32; OpenCV's
    precise mask differs in the last bit). 0.17 ms for the ten maps of a 64 x 64
    query, against 0.54 ms for ten calls of OpenCV's.
    """
    count, classes, size, _ = out.shape
    column = np.empty((size, size), np.int32)  # [y, x] squared distance along y
    nearest = np.empty(size, np.int32)  # per x, y of the nearest class pixel so far
    best = np.empty(size, np.int32)  # int32: sixteen lanes per vector instruction
    squares = np.empty(2 * size - 1, np.int32)  # squares[x - x' + s - 1]
    present = np.empty(size, np.bool_)
    for offset in range(2 * size - 1):
        squares[offset] = (offset - size + 1) ** 2
    for index in range(count):
        image = images[index]
        for label in range(1, classes + 1):
            present[:] = False
            nearest[:] = -_FAR
            for y in range(size):  # down: distance to the nearest pixel above
                row, gaps = image[y], column[y]
                for x in range(size):
                    hit = row[x] == label
                    present[x] |= hit
                    nearest[x] = y if hit else nearest[x]
                    gaps[x] = y - nearest[x]
            nearest[:] = _FAR + size
            for y in range(size - 1, -1, -1):  # up: or below, squared
                row, gaps = image[y], column[y]
                for x in range(size):
                    nearest[x] = y if row[x] == label else nearest[x]
                    gap = min(gaps[x], nearest[x] - y)
                    gaps[x] = gap * gap if gap < _FAR else _FAR
            first, last = size, -1
            for x in range(size):
                if present[x]:
                    first, last = min(first, x), x
            target = out[index, label - 1]
            if last < 0:
                target[:, :] = absent
                continue
            for y in range(size):
                best[:] = _FAR
                for source in range(first, last + 1):
                    height = column[y, source]
                    if height >= _FAR:
                        continue
                    shifted = squares[size - 1 - source : 2 * size - 1 - source]
                    for x in range(size):
                        best[x] = min(best[x], shifted[x] + height)
                for x in range(size):
                    target[y, x] = np.sqrt(np.float32(best[x]))
