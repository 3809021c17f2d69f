"""Compiled loop of :mod:`tracker.overlay`, which documents and checks the inputs."""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray


@numba.njit(cache=True, nogil=True)
def fill_triangles(triangles: NDArray[np.float64], mask: NDArray[np.bool_]) -> None:
    """Set ``mask`` where a pixel centre lies in any of the ``(F, 3, 2)`` triangles.

    Each triangle is filled on its own, so overlapping triangles add up (unlike one
    ``cv2.fillPoly`` call over many polygons, whose even-odd rule cancels overlaps),
    and tiny triangles cost no per-call overhead.
    """
    height, width = mask.shape
    for f in range(triangles.shape[0]):
        ax, ay = triangles[f, 0, 0], triangles[f, 0, 1]
        bx, by = triangles[f, 1, 0], triangles[f, 1, 1]
        cx, cy = triangles[f, 2, 0], triangles[f, 2, 1]
        area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        if area == 0.0:
            continue
        sign = 1.0 if area > 0.0 else -1.0
        u0 = max(math.ceil(min(ax, bx, cx)), 0)
        u1 = min(math.floor(max(ax, bx, cx)), width - 1)
        v0 = max(math.ceil(min(ay, by, cy)), 0)
        v1 = min(math.floor(max(ay, by, cy)), height - 1)
        for v in range(v0, v1 + 1):
            for u in range(u0, u1 + 1):
                w0 = ((bx - ax) * (v - ay) - (by - ay) * (u - ax)) * sign
                w1 = ((cx - bx) * (v - by) - (cy - by) * (u - bx)) * sign
                w2 = ((ax - cx) * (v - cy) - (ay - cy) * (u - cx)) * sign
                if w0 >= 0.0 and w1 >= 0.0 and w2 >= 0.0:
                    mask[v, u] = True
