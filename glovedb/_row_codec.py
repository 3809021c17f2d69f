"""The run-length code of tiny image rows (database format 2), in compiled loops.

A row (one tiny image, in raster order) is stored as

- 4 bytes: the FNV-1a hash (32 bits, little-endian) of the run bytes that follow, so
  that damaged data is refused instead of decoded into a wrong image;
- its runs of equal labels, in order. A head byte ``label << 4 | c`` holds the label
  (0..15) and, when ``c < 15``, the run length ``c + 1``; when ``c == 15`` the length
  is ``16 + n``, ``n`` in the bytes that follow (7 bits a byte, low bits first, the
  high bit set on every byte but the last).

Tiny images are label images, a few hundred runs at 64 x 64: a row takes about a
twelfth of the raw bytes. Encoding scans 8 pixels a step (little-endian words: x86-64
and ARM64), about 2 microseconds a 64 x 64 image; decoding fills each run with one
``memset``, about 1.5 microseconds.
"""

from __future__ import annotations

import sys

import numba
import numpy as np
from numba.cpython.unsafe.numbers import trailing_zeros
from numpy.typing import NDArray

from glovedb._validate import as_array
from glovedb.chamfer import NUM_CLASSES

HEADER_BYTES = 4
LARGEST_LABEL = 15
_FNV_OFFSET = 2166136261
_FNV_PRIME = 16777619
_REASONS = (
    "",
    "its hash does not match its bytes",
    "its runs do not fill the image",
    "a label is not 0..10",
)


def encode_rows(images: NDArray[np.uint8]) -> tuple[NDArray[np.uint8], NDArray[np.int64]]:
    """Encode every image as one row.

    Parameters
    ----------
    images : (M, s, s) uint8
        Labels 0..15; ``s * s`` a multiple of 8.

    Returns
    -------
    data : (B,) uint8
        The rows, one after another.
    lengths : (M,) int64
        Bytes of each row.
    """
    if sys.byteorder != "little":
        raise RuntimeError("the tiny image row code needs a little-endian machine")
    images = as_array("images", images, (None, None, None), np.uint8)
    pixels = images.shape[1] * images.shape[2]
    if pixels % 8:
        raise ValueError(f"images: s * s must be a multiple of 8, got {images.shape}")
    flat = np.ascontiguousarray(images).reshape(len(images), pixels)
    if flat.size and flat.max() > LARGEST_LABEL:
        raise ValueError(f"images: labels must lie in 0..{LARGEST_LABEL}, got {flat.max()}")
    data = np.empty(len(flat) * (HEADER_BYTES + flat.shape[1]), np.uint8)  # a run a pixel
    lengths = np.empty(len(flat), np.int64)
    used = _encode(flat, data, lengths)
    return data[:used].copy(), lengths


def decode_rows(
    data: NDArray[np.uint8], starts: NDArray[np.int64], stops: NDArray[np.int64], size: int
) -> tuple[NDArray[np.uint8], int, str]:
    """Decode the rows ``data[starts[k]:stops[k]]`` (which the caller has checked lie
    inside ``data``) into images.

    Returns
    -------
    images : (M, size, size) uint8
        Undefined from the first damaged row on.
    damaged : int
        Index of the first damaged row; -1 when none is.
    reason : str
        Why it is damaged ("" when none is).
    """
    images = np.empty((len(starts), size, size), np.uint8)
    damaged, reason = _decode(data, starts, stops, images.reshape(len(starts), size * size))
    return images, int(damaged), _REASONS[reason]


def score_rows(
    data: NDArray[np.uint8],
    starts: NDArray[np.int64],
    stops: NDArray[np.int64],
    maps: NDArray[np.float32],
) -> tuple[NDArray[np.float32], int, str]:
    """The directed distance ``m(D, Q)`` of every row ``D`` to a query, from its runs.

    What decoding the rows and looking every glove pixel up in the query's chamfer
    maps gives (:mod:`glovedb.chamfer`), without writing the images: a run of one
    colour costs a difference of the maps' running sums in raster order, so a 64 x 64
    row of a few hundred runs costs a few hundred steps instead of 4,096 lookups.
    The sums are float64, so the errors agree with the per-pixel float32 sums to
    float32 rounding, not bit for bit.

    Parameters
    ----------
    data, starts, stops
        As in :func:`decode_rows`.
    maps : (10, s, s) float32
        The query's chamfer maps at the rows' size.

    Returns
    -------
    errors : (M,) float32
        Pixels; ``inf`` for rows without glove pixels. Undefined from the first
        damaged row on.
    damaged : int
        Index of the first damaged row (a bad hash, runs that do not fill the image,
        a label above 10); -1 when none is.
    reason : str
    """
    cumulative = _running_sums(np.ascontiguousarray(maps.reshape(NUM_CLASSES, -1)))
    errors = np.empty(len(starts), np.float32)
    _touch(data, starts, stops)
    damaged, reason = _score(data, starts, stops, cumulative, errors)
    return errors, int(damaged), _REASONS[reason]


@numba.njit(cache=True, nogil=True)
def _running_sums(flat: NDArray[np.float32]) -> NDArray[np.float64]:
    """(C + 1, P + 1) float64: row 0 zero (the background's: every run costs the same
    steps), row ``c + 1`` the running sums of ``flat[c]`` from 0, in raster order.

    What ``np.cumsum`` of the float64 maps gives, bit for bit (the same sequential
    sums), in a fifth of its time: 0.05 against 0.22 ms for 64 x 64 maps, a fixed cost
    of every 64 x 64 stage.
    """
    classes, pixels = flat.shape
    sums = np.empty((classes + 1, pixels + 1))
    sums[0] = 0.0
    for c in range(classes):
        row = sums[c + 1]
        total = 0.0
        row[0] = total
        for i in range(pixels):
            total += flat[c, i]
            row[i + 1] = total
    return sums


@numba.njit(cache=True, nogil=True)
def _touch(data: NDArray[np.uint8], starts: NDArray[np.int64], stops: NDArray[np.int64]) -> int:
    """Read a byte of every cache line of the rows, and return them combined.

    Rows scattered over a large mapped file are mostly out of the cache. These loads
    do not depend on each other, so the processor keeps many misses in flight, while
    the scoring loop waits on each row's own: 2,000 rows of 16 x 16 that the first
    stage had pushed out of the cache scored in 0.60 ms with this pass, 0.93 without
    (200 of 64 x 64: 0.32 and 0.37 ms).
    """
    combined = 0
    for row in range(len(starts)):
        for at in range(starts[row], stops[row], 64):
            combined ^= data[at]
        if stops[row] > starts[row]:
            combined ^= data[stops[row] - 1]
    return combined


@numba.njit(cache=True, nogil=True)
def _hash(data: NDArray[np.uint8], start: int, stop: int) -> int:
    value = _FNV_OFFSET
    for i in range(start, stop):
        value = ((value ^ data[i]) * _FNV_PRIME) & 0xFFFFFFFF
    return value


@numba.njit(cache=True, nogil=True)
def _encode(flat: NDArray[np.uint8], data: NDArray[np.uint8], lengths: NDArray[np.int64]) -> int:
    pixels = flat.shape[1]
    words = flat.view(np.uint64)
    at = 0
    for row in range(flat.shape[0]):
        first = at
        at += HEADER_BYTES
        line = flat[row]
        previous = np.uint64(line[0])  # the pixel before each word's first
        run_start = 0
        for w in range(words.shape[1]):
            word = words[row, w]
            # Byte k is non-zero where pixel 8w + k differs from the pixel before it.
            starts = word ^ ((word << np.uint64(8)) | previous)
            previous = word >> np.uint64(56)
            while starts != 0:
                bit = int(trailing_zeros(starts))  # type: ignore[call-arg]
                start = 8 * w + (bit >> 3)
                at = _put_run(data, at, line[run_start], start - run_start)
                run_start = start
                starts &= ~(np.uint64(255) << np.uint64(bit & 56))
        at = _put_run(data, at, line[run_start], pixels - run_start)
        value = _hash(data, first + HEADER_BYTES, at)
        for b in range(HEADER_BYTES):
            data[first + b] = (value >> (8 * b)) & 255
        lengths[row] = at - first
    return at


@numba.njit(cache=True, nogil=True, inline="always")
def _put_run(data: NDArray[np.uint8], at: int, label: int, run: int) -> int:
    if run < 16:
        data[at] = (label << 4) | (run - 1)
        return at + 1
    data[at] = (label << 4) | 15
    at += 1
    rest = run - 16
    while rest >= 128:
        data[at] = (rest & 127) | 128
        at += 1
        rest >>= 7
    data[at] = rest
    return at + 1


@numba.njit(cache=True, nogil=True)
def _run(data: NDArray[np.uint8], at: int, stop: int) -> tuple[int, int, int]:
    """The run whose head byte is ``data[at]``: its label, length and the next head's
    position; length 0 when its length bytes run past ``stop`` or overflow."""
    head = data[at]
    at += 1
    run = int(head & 15) + 1
    if run == 16:
        shift = 0
        more = True
        while more:
            if at >= stop or shift > 21:
                return 0, 0, at
            byte = data[at]
            at += 1
            run += int(byte & 127) << shift
            shift += 7
            more = byte >= 128
    return int(np.int64(head)) >> 4, run, at  # signed: unsigned and signed unify to float


@numba.njit(cache=True, nogil=True)
def _checked(data: NDArray[np.uint8], start: int, stop: int) -> int:
    """0 when the row ``data[start:stop]`` has a header and its hash matches, else the
    reason's code."""
    if stop - start <= HEADER_BYTES:
        return 2
    stored = 0
    for b in range(HEADER_BYTES):
        stored |= int(data[start + b]) << (8 * b)
    return 0 if _hash(data, start + HEADER_BYTES, stop) == stored else 1


@numba.njit(cache=True, nogil=True)
def _score(
    data: NDArray[np.uint8],
    starts: NDArray[np.int64],
    stops: NDArray[np.int64],
    cumulative: NDArray[np.float64],
    errors: NDArray[np.float32],
) -> tuple[int, int]:
    pixels = cumulative.shape[1] - 1
    for row in range(starts.shape[0]):
        start = starts[row]
        stop = stops[row]
        problem = _checked(data, start, stop)
        if problem:
            return row, problem
        at = start + HEADER_BYTES
        i = 0
        glove = 0
        total = 0.0
        while at < stop:
            label, run, at = _run(data, at, stop)
            if run == 0 or i + run > pixels:
                return row, 2
            if label > NUM_CLASSES:
                return row, 3
            # No branch on the colour: background and glove runs alternate, and the
            # mispredicted branch cost a quarter of a 16 x 16 row (2,000 rows: 0.43 ->
            # 0.32 ms; 200 of 64 x 64: 0.24 -> 0.22 ms).
            costs = cumulative[label]
            total += costs[i + run] - costs[i]
            glove += run * (label > 0)
            i += run
        if i != pixels:
            return row, 2
        errors[row] = np.float32(np.inf) if glove == 0 else np.float32(total / glove)
    return -1, 0


@numba.njit(cache=True, nogil=True)
def _decode(
    data: NDArray[np.uint8],
    starts: NDArray[np.int64],
    stops: NDArray[np.int64],
    out: NDArray[np.uint8],
) -> tuple[int, int]:
    pixels = out.shape[1]
    for row in range(starts.shape[0]):
        start = starts[row]
        stop = stops[row]
        problem = _checked(data, start, stop)
        if problem:
            return row, problem
        line = out[row]
        at = start + HEADER_BYTES
        i = 0
        while at < stop:
            label, run, at = _run(data, at, stop)
            if run == 0 or i + run > pixels:
                return row, 2
            line[i : i + run] = label
            i += run
        if i != pixels:
            return row, 2
    return -1, 0
