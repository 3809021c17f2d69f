"""Compiled loops of :mod:`glovedb.tiny_images`, which documents and checks the inputs.

One roll at a time: rotate the glove pixels, count the sub-pixels of each class in
every cell of the largest size (integers: exact in any order), take the majority,
then sum 2 x 2 cells for the next smaller size. Only the classes an image shows get a
plane of counters, and the counters are as narrow as the counts allow, so that one
roll's counts stay in the cache and the loops over them take many cells a step: 8-bit
at the largest size when no cell can hold more than 255 sub-pixels, 16-bit at the
smaller sizes when the roll has fewer than 2**16 sub-pixels (no count can exceed
that), else 32-bit. The images go straight into the caller's output arrays.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

# (counts of the largest size, counts of the smaller sizes, best count per cell, glove
# total per cell); the last three of one dtype.
Counters = tuple[NDArray[Any], NDArray[Any], NDArray[Any], NDArray[Any]]


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
    1..n_labels-1 (at most 255). ``outs`` holds one ``(M, s, s) uint8`` array per size,
    largest first, every size a power-of-two fraction of the one before.
    """
    _rolls_into(u, v, labels, np.arange(u.shape[0]), cos, sin, outs, first, n_labels)


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
    # The first and last glove pixel of every row: they bound the rest (see _rotate).
    extremes = np.empty(2 * height, dtype=np.int64)
    for p in range(n_images):
        n = 0
        n_extremes = 0
        sum_u = 0
        sum_v = 0
        for row in range(height):
            row_glove = np.uint8(0)
            for col in range(width):
                row_glove |= images[p, row, col]
            if row_glove == 0:
                continue
            extremes[n_extremes] = n
            for col in range(width):
                label = images[p, row, col]
                if label != 0:
                    u[n] = col
                    v[n] = row
                    labels[n] = label
                    sum_u += col
                    sum_v += row
                    n += 1
            extremes[n_extremes + 1] = n - 1
            n_extremes += 2
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
        _rolls_into(
            u[:n],
            v[:n],
            labels[:n],
            extremes[:n_extremes],
            cos,
            sin,
            outs,
            p * cos.shape[0],
            n_labels,
        )


@numba.njit(cache=True, nogil=True)
def _rolls_into(
    u: NDArray[np.float64],
    v: NDArray[np.float64],
    labels: NDArray[np.int64],
    extremes: NDArray[np.int64],
    cos: NDArray[np.float64],
    sin: NDArray[np.float64],
    outs: tuple[NDArray[np.uint8], ...],
    first: int,
    n_labels: int,
) -> None:
    """:func:`tiny_images_into`, given pixels whose rotations bound all of them."""
    size = outs[0].shape[1]
    n = u.shape[0]
    present = np.zeros(n_labels, dtype=np.bool_)
    for label in labels:
        present[label] = True
    classes = np.flatnonzero(present)
    planes = np.zeros(n_labels, dtype=np.int64)
    planes[classes] = np.arange(len(classes))
    label_offsets = planes[labels] * (size * size)
    n_top = len(classes) * size * size
    n_rest = len(classes) * _cells_down_to(size // 2, outs[len(outs) - 1].shape[1])
    small = _counters(np.uint8, np.uint16, n_top, n_rest, size)
    large = _counters(np.int32, np.int32, 0, 0, size)
    ru = np.empty(n)
    rv = np.empty(n)
    cells = np.empty(n, dtype=np.int64)
    best = np.empty(size * size, dtype=np.uint8)
    background = np.empty((2, size * size), dtype=np.float32)
    for r in range(cos.shape[0]):
        scale, origin_u, origin_v = _rotate(u, v, extremes, cos[r], sin[r], ru, rv, size)
        k = 1 if scale <= 0.5 else int(np.ceil(2.0 * scale))
        area = k * k / (scale * scale)  # of a cell, in sub-pixels
        geometry = (cos[r], sin[r], scale, origin_u, origin_v)
        # No count, at any size, exceeds the roll's number of sub-pixels; a cell of
        # the largest size, w = 1 / scale pixels wide, holds at most (w k + 1)**2 of
        # them (lattice points of spacing 1 / k in a square, turned or not; one more
        # for rounding).
        if n * k * k < 1 << 16 and (k / scale + 2.0) ** 2 <= 255.0:
            _count(ru, rv, label_offsets, geometry, k, size, len(classes), cells, small[0])
            _levels_into(small, classes, area, best, background, outs, first + r)
        else:
            if len(large[0]) == 0:
                large = _counters(np.int32, np.int32, n_top, n_rest, size)
            _count(ru, rv, label_offsets, geometry, k, size, len(classes), cells, large[0])
            _levels_into(large, classes, area, best, background, outs, first + r)


@numba.njit(cache=True, nogil=True)
def _cells_down_to(size: int, smallest: int) -> int:
    """The cells of every size from ``size`` down to ``smallest``, halving."""
    cells = 0
    while size >= smallest:
        cells += size * size
        size //= 2
    return cells


@numba.njit(cache=True, nogil=True)
def _counters(top: type, rest: type, n_top: int, n_rest: int, size: int) -> Counters:
    """Zeroed counts of the largest size and of the others, scratch for the best count
    and total per cell (of the wider type)."""
    return (
        np.zeros(n_top, dtype=top),
        np.zeros(n_rest, dtype=rest),
        np.empty(size * size, dtype=rest),
        np.empty(size * size, dtype=rest),
    )


@numba.njit(cache=True, nogil=True)
def _rotate(
    u: NDArray[np.float64],
    v: NDArray[np.float64],
    extremes: NDArray[np.int64],
    cos: float,
    sin: float,
    ru: NDArray[np.float64],
    rv: NDArray[np.float64],
    size: int,
) -> tuple[float, float, float]:
    """Rotate the pixel centres into ``ru, rv``; return the scale (cells per pixel)
    and origin (pixels) of the square crop about their bounding box.

    The box is searched among the pixels ``extremes`` only. Of pixels that come row by
    row, the first and last of every row suffice: rounding is monotonic, so for one
    ``v`` the computed ``ru`` and ``rv`` are monotonic in ``u``.
    """
    for i in range(u.shape[0]):
        ru[i] = u[i] * cos - v[i] * sin
        rv[i] = u[i] * sin + v[i] * cos
    low_u = low_v = np.inf
    high_u = high_v = -np.inf
    for i in extremes:
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
    label_offsets: NDArray[np.int64],
    geometry: tuple[float, float, float, float, float],
    k: int,
    size: int,
    n_planes: int,
    cells: NDArray[np.int64],
    hits: NDArray[Any],
) -> None:
    """Sub-pixel hits of every class in every cell of the crop, for one roll, into
    the first ``n_planes`` planes of ``hits``; ``label_offsets`` is each pixel's plane.

    A pixel is a unit square split into k x k sub-pixels (k = 1 when cells are at
    least two pixels wide); each sub-pixel centre, rotated, hits one cell. Counting
    integers keeps the sums exact in any order.
    """
    cos, sin, scale, origin_u, origin_v = geometry
    n = ru.shape[0]
    hits[: n_planes * size * size] = 0
    quarter = n // 4
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
                cells[i] = label_offsets[i] + row * size + col
            # Neighbouring pixels often hit one cell: four distant runs interleaved
            # keep the increments of one counter apart.
            for i in range(quarter):
                hits[cells[i]] += 1
                hits[cells[quarter + i]] += 1
                hits[cells[2 * quarter + i]] += 1
                hits[cells[3 * quarter + i]] += 1
            for i in range(4 * quarter, n):
                hits[cells[i]] += 1


@numba.njit(cache=True, nogil=True)
def _levels_into(
    counters: Counters,
    classes: NDArray[np.int64],
    area: float,
    best: NDArray[np.uint8],
    background: NDArray[np.float32],
    outs: tuple[NDArray[np.uint8], ...],
    index: int,
) -> None:
    """Majority images of every size into ``outs[j][index]``, from the counts of the
    largest size, ``len(classes)`` planes in ``counters[0]``; the smaller sizes' counts
    go one after another into ``counters[1]``. ``area`` is a cell's, in sub-pixels."""
    top, hits, best_count, totals = counters
    n_planes = len(classes)
    side = outs[0].shape[1]
    cells = side * side
    _tally(top[: n_planes * cells], classes, best[:cells], best_count[:cells], totals[:cells])
    for cell in range(cells):
        background[0, cell] = np.float32(max(area - totals[cell], 0.0))
    _majority(best[:cells], best_count[:cells], background[0, :cells], outs[0][index])
    # Where the current size's planes start in ``hits``; -1: in ``top``, whose narrower
    # dtype a compiled variable cannot share with ``hits``' slices, hence two calls.
    current = -1
    level = 0
    for j in range(1, len(outs)):
        while side > outs[j].shape[1]:
            side //= 2
            start = 0 if current < 0 else current + 4 * n_planes * side * side
            below = hits[start : start + n_planes * side * side]
            if current < 0:
                _halve(top, background[level], n_planes, side, below, background[1 - level])
            else:
                above = hits[current:start]
                _halve(above, background[level], n_planes, side, below, background[1 - level])
            current = start
            cells = side * side
            level = 1 - level
        planes = hits[current : current + n_planes * cells]
        _tally(planes, classes, best[:cells], best_count[:cells], totals[:cells])
        _majority(best[:cells], best_count[:cells], background[level, :cells], outs[j][index])


@numba.njit(cache=True, nogil=True)
def _tally(
    hits: NDArray[Any],
    classes: NDArray[np.int64],
    best: NDArray[np.uint8],
    best_count: NDArray[Any],
    totals: NDArray[Any],
) -> None:
    """Per cell: the class with the most hits (ties: the lowest), its count, and the
    glove total, from one plane of counts per class, in increasing class order."""
    cells = best.shape[0]
    best[:] = 0
    best_count[:] = 0
    totals[:] = 0
    for plane, label in enumerate(classes):
        counts = hits[plane * cells : (plane + 1) * cells]
        for cell in range(cells):
            count = counts[cell]
            better = count > best_count[cell]
            best_count[cell] = count if better else best_count[cell]
            best[cell] = label if better else best[cell]
            totals[cell] += count


@numba.njit(cache=True, nogil=True)
def _majority(
    best: NDArray[np.uint8],
    best_count: NDArray[Any],
    background: NDArray[np.float32],
    out: NDArray[np.uint8],
) -> None:
    """The best class of every cell of ``out (s, s)`` where its count reaches the
    background's area, else 0 (a cell without hits has a positive background)."""
    flat_out = out.reshape(best.shape[0])
    for cell in range(best.shape[0]):
        flat_out[cell] = best[cell] if best_count[cell] >= background[cell] else 0


@numba.njit(cache=True, nogil=True)
def _halve(
    hits: NDArray[Any],
    background: NDArray[np.float32],
    n_planes: int,
    half: int,
    out_hits: NDArray[Any],
    out_background: NDArray[np.float32],
) -> None:
    """Sum 2 x 2 blocks of cells into half the size: ``n_planes`` planes of counts,
    and the background (float32, in the same order as ever)."""
    side = 2 * half
    for plane in range(n_planes):
        source = hits[plane * side * side : (plane + 1) * side * side]
        target = out_hits[plane * half * half : (plane + 1) * half * half]
        _halve_plane(source, half, target)
    _halve_plane(background[: side * side], half, out_background)


@numba.njit(cache=True, nogil=True)
def _halve_plane(plane: NDArray[Any], half: int, out: NDArray[Any]) -> None:
    side = 2 * half
    for row in range(half):
        top = 2 * row * side
        for col in range(half):
            out[row * half + col] = (
                plane[top + 2 * col]
                + plane[top + 2 * col + 1]
                + plane[top + side + 2 * col]
                + plane[top + side + 2 * col + 1]
            )
