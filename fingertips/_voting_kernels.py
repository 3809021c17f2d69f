"""Compiled window sums of the votes' mean-shift (for :mod:`fingertips.voting`).

The votes are bucketed once per frame into cubes of edge ``radius``, sorted by cube;
a centre's window then reads the 27 cubes around its own. Sums are float64 in the
order of the sorted votes, so they can differ from another order's in the last bits.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

# A cube index is packed into 21 bits per axis (offset so that negative indices fit):
# with 1 cm cubes that spans +-10 km, far beyond any depth camera.
_BITS = 21
_OFFSET = 1 << (_BITS - 1)


@numba.njit(cache=True, nogil=True)
def _cube_key(ix: int, iy: int, iz: int) -> int:
    return ((ix + _OFFSET) << (2 * _BITS)) | ((iy + _OFFSET) << _BITS) | (iz + _OFFSET)


@numba.njit(cache=True, nogil=True)
def sorted_cubes(
    positions_m: NDArray[np.float32], radius_m: float
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The votes' order by cube and their cube keys in that order, ``(N,)`` each."""
    n = positions_m.shape[0]
    keys = np.empty(n, dtype=np.int64)
    for i in range(n):
        keys[i] = _cube_key(
            int(np.floor(positions_m[i, 0] / radius_m)),
            int(np.floor(positions_m[i, 1] / radius_m)),
            int(np.floor(positions_m[i, 2] / radius_m)),
        )
    order = np.argsort(keys, kind="mergesort")
    return order, keys[order]


@numba.njit(cache=True, nogil=True)
def window_sums(
    centres_m: NDArray[np.float32],
    positions_m: NDArray[np.float32],
    weights: NDArray[np.float32],
    order: NDArray[np.int64],
    sorted_keys: NDArray[np.int64],
    radius_m: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Vote weight ``(M,)`` and weighted position sum ``(M, 3)`` within ``radius_m``
    (inclusive, float64 distances) of each centre; ``order, sorted_keys`` from
    :func:`sorted_cubes` with the same radius."""
    m = centres_m.shape[0]
    mass = np.zeros(m)
    moment = np.zeros((m, 3))
    limit = radius_m * radius_m
    for j in range(m):
        cx = np.float64(centres_m[j, 0])
        cy = np.float64(centres_m[j, 1])
        cz = np.float64(centres_m[j, 2])
        ix = int(np.floor(centres_m[j, 0] / radius_m))
        iy = int(np.floor(centres_m[j, 1] / radius_m))
        iz = int(np.floor(centres_m[j, 2] / radius_m))
        for a in range(-1, 2):
            for b in range(-1, 2):
                # The three cubes along z are consecutive keys: one range.
                low = np.searchsorted(sorted_keys, _cube_key(ix + a, iy + b, iz - 1))
                high = np.searchsorted(sorted_keys, _cube_key(ix + a, iy + b, iz + 1), side="right")
                for k in range(low, high):
                    i = order[k]
                    px = np.float64(positions_m[i, 0])
                    py = np.float64(positions_m[i, 1])
                    pz = np.float64(positions_m[i, 2])
                    dx = px - cx
                    dy = py - cy
                    dz = pz - cz
                    if dx * dx + dy * dy + dz * dz <= limit:
                        w = np.float64(weights[i])
                        mass[j] += w
                        moment[j, 0] += w * px
                        moment[j, 1] += w * py
                        moment[j, 2] += w * pz
    return mass, moment


@numba.njit(cache=True, nogil=True)
def kept_apart(
    points_m: NDArray[np.float32], order: NDArray[np.int64], radius_m: np.float32
) -> NDArray[np.bool_]:
    """``(K,)`` bool: the points of ``order``, visited in that order, each kept unless
    it lies nearer than ``radius_m`` to one kept before it (the others False).

    Distances as NumPy's ``np.linalg.norm(a - b, axis=1) < radius_m`` on float32
    points: float32 differences and squares summed in axis order, the comparison in
    float32, so the same points are kept.
    """
    keep = np.zeros(points_m.shape[0], np.bool_)
    kept = np.empty(len(order), np.int64)
    count = 0
    for k in order:
        near = False
        for j in range(count):
            other = kept[j]
            total = np.float32(0.0)
            for axis in range(3):
                gap = points_m[other, axis] - points_m[k, axis]
                total += gap * gap
            if np.sqrt(total) < radius_m:
                near = True
                break
        if not near:
            keep[k] = True
            kept[count] = k
            count += 1
    return keep
