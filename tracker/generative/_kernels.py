"""Compiled loops of :mod:`tracker.generative.model`, which documents and checks them."""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray


@numba.njit(nogil=True, cache=True)
def directional_vertex_rows(
    ids: NDArray[np.int64],
    weights: NDArray[np.float64],
    rest: NDArray[np.float64],
    skinning: NDArray[np.float64],
    moves: NDArray[np.float64],
    axes: NDArray[np.float64],
    pivots: NDArray[np.float64],
    rotation: NDArray[np.float64],
    translation: NDArray[np.float64],
    points: NDArray[np.float64],
    directions: NDArray[np.float64],
    out: NDArray[np.float64],
) -> None:
    """Rows ``direction . dp/dx`` ``(P, 26)`` into ``out`` for samples ``ids``: see
    :meth:`tracker.generative.model.PosedHand.directional_rows`."""
    n_joints, n_bones = moves.shape
    arm = np.zeros((n_joints, 3))
    for row in range(ids.shape[0]):
        sample = ids[row]
        nx, ny, nz = directions[row, 0], directions[row, 1], directions[row, 2]
        dx = points[row, 0] - translation[0]
        dy = points[row, 1] - translation[1]
        dz = points[row, 2] - translation[2]
        out[row, 0] = dy * nz - dz * ny
        out[row, 1] = dz * nx - dx * nz
        out[row, 2] = dx * ny - dy * nx
        out[row, 3], out[row, 4], out[row, 5] = nx, ny, nz
        # The direction in the hand frame: R^T n.
        hx = rotation[0, 0] * nx + rotation[1, 0] * ny + rotation[2, 0] * nz
        hy = rotation[0, 1] * nx + rotation[1, 1] * ny + rotation[2, 1] * nz
        hz = rotation[0, 2] * nx + rotation[1, 2] * ny + rotation[2, 2] * nz
        arm[:] = 0.0
        for bone in range(n_bones):
            w = weights[sample, bone]
            if w == 0.0:
                continue
            m = skinning[bone]
            vx = (
                m[0, 0] * rest[sample, 0]
                + m[0, 1] * rest[sample, 1]
                + m[0, 2] * rest[sample, 2]
                + m[0, 3]
            )
            vy = (
                m[1, 0] * rest[sample, 0]
                + m[1, 1] * rest[sample, 1]
                + m[1, 2] * rest[sample, 2]
                + m[1, 3]
            )
            vz = (
                m[2, 0] * rest[sample, 0]
                + m[2, 1] * rest[sample, 1]
                + m[2, 2] * rest[sample, 2]
                + m[2, 3]
            )
            for joint in range(n_joints):
                if moves[joint, bone] != 0.0:
                    arm[joint, 0] += w * (vx - pivots[joint, 0])
                    arm[joint, 1] += w * (vy - pivots[joint, 1])
                    arm[joint, 2] += w * (vz - pivots[joint, 2])
        for joint in range(n_joints):
            ax, ay, az = axes[joint, 0], axes[joint, 1], axes[joint, 2]
            rx, ry, rz = arm[joint, 0], arm[joint, 1], arm[joint, 2]
            # n_hand . (a x arm)
            out[row, 6 + joint] = (
                hx * (ay * rz - az * ry) + hy * (az * rx - ax * rz) + hz * (ax * ry - ay * rx)
            )
