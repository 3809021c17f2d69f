"""Compiled shortest paths on a CSR graph (for :mod:`fingertips.geodesic`).

:func:`lower_distances` is Dijkstra's algorithm from one source that only lowers an
existing distance array: a node is expanded only when the new source brings it closer
than it already was (and within ``limit``). Started from an array of infinities it is
plain bounded Dijkstra; started from the distances to earlier sources it adds one
source to a multi-source search and visits only the new source's own region, which is
what accumulative geodesic extrema need at every step. SciPy's ``dijkstra`` returns a
new array and checks the graph on every call, which costs more than the search on the
few thousand nodes of a hand.
"""

from __future__ import annotations

import heapq

import numba
import numpy as np
from numpy.typing import NDArray


@numba.njit(cache=True, nogil=True)
def lower_distances(
    indptr: NDArray[np.int32],
    indices: NDArray[np.int32],
    lengths: NDArray[np.float64],
    distance: NDArray[np.float64],
    source: int,
    limit: float,
) -> None:
    """Lower ``distance`` (N,) in place to the path lengths from ``source`` up to ``limit``."""
    distance[source] = 0.0
    heap = [(0.0, np.int64(source))]
    while heap:
        reached, node = heapq.heappop(heap)
        if reached > distance[node]:
            continue
        for k in range(indptr[node], indptr[node + 1]):
            neighbour = np.int64(indices[k])
            candidate = reached + lengths[k]
            if candidate < distance[neighbour] and candidate <= limit:
                distance[neighbour] = candidate
                heapq.heappush(heap, (candidate, neighbour))
