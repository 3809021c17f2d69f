"""Compiled loops of :mod:`glovedb.inverted_lists`, which documents and checks.

The kernels assume checked, C-contiguous inputs of the documented dtypes.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray


@numba.njit(nogil=True, cache=True)
def project_rows(
    labels: NDArray[np.uint8], weights: NDArray[np.float32], out: NDArray[np.float32]
) -> None:
    """``out[m] = sum_p weights[labels[m, p] - 1, p] / n_m`` over the glove pixels.

    ``labels (M, P) uint8`` are flattened label images (0 is background), ``weights
    (10, P, F) float32`` a linear map of the one-hot labels, ``out (M, F) float32``;
    ``n_m`` is row ``m``'s glove pixel count (rows without any get 0).
    """
    features = weights.shape[2]
    for row in range(labels.shape[0]):
        total = np.zeros(features, np.float32)
        count = 0
        for pixel in range(labels.shape[1]):
            label = labels[row, pixel]
            if label > 0:
                count += 1
                total += weights[label - 1, pixel]
        out[row] = total / np.float32(max(count, 1))


@numba.njit(nogil=True, cache=True)
def add_list_sums(
    labels: NDArray[np.uint8],
    list_of_row: NDArray[np.int64],
    sums: NDArray[np.float64],
    squares: NDArray[np.float64],
) -> None:
    """``sums[list_of_row[m], (label - 1) * P + p] += 1 / n_m`` for every glove pixel,
    and ``squares`` the same with ``1 / n_m ** 2``.

    ``labels (M, P) uint8``, ``list_of_row (M,) int64``, ``sums, squares (L, 10 * P)
    float64``.
    """
    pixels = labels.shape[1]
    for row in range(labels.shape[0]):
        count = 0
        for pixel in range(pixels):
            count += labels[row, pixel] > 0
        if count == 0:
            continue
        share = 1.0 / count
        target = sums[list_of_row[row]]
        squared = squares[list_of_row[row]]
        for pixel in range(pixels):
            label = labels[row, pixel]
            if label > 0:
                target[(label - 1) * pixels + pixel] += share
                squared[(label - 1) * pixels + pixel] += share * share


@numba.njit(nogil=True, cache=True, fastmath={"reassoc", "contract"})
def list_distances(
    support_offsets: NDArray[np.int64],
    support: NDArray[np.uint16],
    means: NDArray[np.float32],
    variances: NDArray[np.float32],
    maps: NDArray[np.float32],
    mean: NDArray[np.float32],
    spread: NDArray[np.float32],
) -> None:
    """``mean[l] = sum means[j] * maps[support[j]]`` and ``spread[l] = sqrt(sum
    variances[j] * maps[support[j]] ** 2)`` over list ``l``'s support ``j``.

    Indexing through each list's slices lets the compiler use vector gathers (no
    negative index to check): 0.43 against 0.74 ms for 3,969 lists of 601,248
    components (6 MB read)."""
    for index in range(len(support_offsets) - 1):
        first, last = support_offsets[index], support_offsets[index + 1]
        components = support[first:last]
        weights = means[first:last]
        spreads = variances[first:last]
        total = np.float32(0.0)
        squared = np.float32(0.0)
        for j in range(last - first):
            value = maps[np.intp(components[j])]
            total += weights[j] * value
            squared += spreads[j] * value * value
        mean[index] = total
        spread[index] = np.sqrt(squared)


_BINS = 1024


@numba.njit(nogil=True, cache=True)
def probe_prefix(
    score: NDArray[np.float32],
    images: NDArray[np.int64],
    entries: NDArray[np.int64],
    wanted_images: float,
    min_entries: int,
    chosen: NDArray[np.bool_],
) -> None:
    """Mark the shortest prefix of the lists ranked by ``(score, list)`` ascending that
    holds at least ``wanted_images`` images and ``min_entries`` entries (every list
    when none does), without sorting them all.

    ``score (L,) float32`` finite, ``images, entries (L,) int64`` per list, ``chosen
    (L,) bool`` the result. The scores are binned by value (a monotone map, so a bin
    holds a contiguous stretch of the ranking); the bins' running sums find the bin
    in which the prefix ends, and only that bin's lists are sorted.
    """
    count = len(score)
    low = score.min()
    high = score.max()
    scale = (_BINS - 1) / (high - low) if high > low else 0.0
    bin_images = np.zeros(_BINS, np.int64)
    bin_entries = np.zeros(_BINS, np.int64)
    bins = np.empty(count, np.int64)
    for index in range(count):
        which = min(_BINS - 1, int((score[index] - low) * scale))
        bins[index] = which
        bin_images[which] += images[index]
        bin_entries[which] += entries[index]
    held_images = 0
    held_entries = 0
    last = _BINS
    for which in range(_BINS):
        if held_images + bin_images[which] >= wanted_images and (
            held_entries + bin_entries[which] >= min_entries
        ):
            last = which
            break
        held_images += bin_images[which]
        held_entries += bin_entries[which]
    if last == _BINS:
        chosen[:] = True
        return
    members = np.flatnonzero(bins == last)
    keys = np.empty(len(members), np.float64)
    for position in range(len(members)):
        keys[position] = score[members[position]]
    order = np.argsort(keys, kind="mergesort")  # stable: ties stay in list order
    for index in range(count):
        chosen[index] = bins[index] < last
    for position in order:
        member = members[position]
        chosen[member] = True
        held_images += images[member]
        held_entries += entries[member]
        if held_images >= wanted_images and held_entries >= min_entries:
            return
