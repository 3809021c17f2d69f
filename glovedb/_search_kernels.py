"""Compiled inner loop of the database scan; :mod:`glovedb.search` documents and checks.

The kernel releases the GIL, so the caller runs it on chunks from a thread pool. It
assumes checked, C-contiguous inputs of the documented dtypes.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

# Reassociation lets LLVM interleave the sums; infinities must stay legal.
_FASTMATH = {"reassoc", "contract"}


@numba.njit(nogil=True, cache=True, fastmath=_FASTMATH, inline="always")
def _row_error(
    codes: NDArray[np.uint16],
    glove_pixels: NDArray[np.uint16],
    table: NDArray[np.float32],
    row: int,
) -> np.float32:
    """The mean looked-up distance of one row (``inf`` without glove pixels)."""
    positions = codes.shape[1]
    unrolled = positions - positions % 4
    # Four independent sums: the adds overlap instead of waiting on each other.
    sum0 = sum1 = sum2 = sum3 = np.float32(0.0)
    for position in range(0, unrolled, 4):
        sum0 += table[position, codes[row, position]]
        sum1 += table[position + 1, codes[row, position + 1]]
        sum2 += table[position + 2, codes[row, position + 2]]
        sum3 += table[position + 3, codes[row, position + 3]]
    for position in range(unrolled, positions):
        sum0 += table[position, codes[row, position]]
    count = glove_pixels[row]
    total = (sum0 + sum1) + (sum2 + sum3)
    return np.float32(np.inf) if count == 0 else total / np.float32(count)


@numba.njit(nogil=True, cache=True, fastmath=_FASTMATH)
def score_rows(
    codes: NDArray[np.uint16],
    glove_pixels: NDArray[np.uint16],
    table: NDArray[np.float32],
    start: int,
    stop: int,
    errors: NDArray[np.float32],
) -> None:
    """Fill ``errors[start:stop]`` with the mean looked-up distance of each row.

    ``codes (M, P) uint16`` are pixel-group codes, ``table (P, C) float32`` the query's
    summed chamfer distances per group position and code, ``glove_pixels (M,) uint16``
    the glove pixel counts (0 gives ``inf``).
    """
    for row in range(start, stop):
        errors[row] = _row_error(codes, glove_pixels, table, row)


@numba.njit(nogil=True, cache=True, fastmath=_FASTMATH)
def score_ranges(
    codes: NDArray[np.uint16],
    glove_pixels: NDArray[np.uint16],
    table: NDArray[np.float32],
    starts: NDArray[np.int64],
    stops: NDArray[np.int64],
    errors: NDArray[np.float32],
) -> None:
    """Like :func:`score_rows` over the rows of each range ``starts[i]:stops[i]``, the
    errors of all ranges written one after the other into ``errors`` (the few hundred
    lists a query probes, in one call)."""
    out = 0
    for index in range(len(starts)):
        for row in range(starts[index], stops[index]):
            errors[out] = _row_error(codes, glove_pixels, table, row)
            out += 1


@numba.njit(nogil=True, cache=True, fastmath=_FASTMATH)
def score_label_rows(
    labels: NDArray[np.uint8],
    lookup: NDArray[np.float32],
    start: int,
    stop: int,
    errors: NDArray[np.float32],
) -> None:
    """Fill ``errors[start:stop]`` from unpacked label rows.

    ``labels (M, P) uint8`` are flattened label images, ``lookup (11, P) float32`` the
    query's chamfer maps with a zero row 0 for the background.
    """
    positions = labels.shape[1]
    unrolled = positions - positions % 4
    for row in range(start, stop):
        sum0 = sum1 = sum2 = sum3 = np.float32(0.0)
        count = 0
        for position in range(0, unrolled, 4):
            a = labels[row, position]
            b = labels[row, position + 1]
            c = labels[row, position + 2]
            d = labels[row, position + 3]
            sum0 += lookup[a, position]
            sum1 += lookup[b, position + 1]
            sum2 += lookup[c, position + 2]
            sum3 += lookup[d, position + 3]
            count += (a > 0) + (b > 0) + (c > 0) + (d > 0)
        for position in range(unrolled, positions):
            label = labels[row, position]
            sum0 += lookup[label, position]
            count += label > 0
        total = (sum0 + sum1) + (sum2 + sum3)
        errors[row] = np.float32(np.inf) if count == 0 else total / np.float32(count)


@numba.njit(nogil=True, cache=True)
def entries_at_most(
    errors: NDArray[np.float32],
    entry_ids: NDArray[np.int64],
    starts: NDArray[np.int64],
    lengths: NDArray[np.int64],
    bound: np.float32,
    kept_ids: NDArray[np.int64],
    kept_errors: NDArray[np.float32],
) -> int:
    """Keep the entries whose error is at most ``bound``; return how many.

    ``errors`` are those of the images ``starts[i] .. starts[i] + lengths[i] - 1``,
    range after range; image ``j`` shows entry ``entry_ids[j]``. The kept entries and
    their errors go to the front of ``kept_ids`` and ``kept_errors``, in scan order.
    """
    out = 0
    position = 0
    for index in range(len(starts)):
        first = starts[index]
        for offset in range(lengths[index]):
            error = errors[position]
            if error <= bound:
                kept_ids[out] = entry_ids[first + offset]
                kept_errors[out] = error
                out += 1
            position += 1
    return out
