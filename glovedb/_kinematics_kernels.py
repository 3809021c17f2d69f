"""Compiled forward kinematics of :mod:`glovedb.hand_model`, which documents and checks
the inputs: the bone chain runs for every skinning of the hand, tens of times per
tracked frame, where numpy's per-bone calls cost more than the arithmetic."""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray


@numba.njit(nogil=True, cache=True)
def chain(
    z_angle: NDArray[np.float64],
    x_angle: NDArray[np.float64],
    rest_before: NDArray[np.float64],
    rest_after: NDArray[np.float64],
    offsets: NDArray[np.float64],
    parents: NDArray[np.int64],
    tip_lengths: NDArray[np.float64],
    world: NDArray[np.float64],
    keypoints: NDArray[np.float64],
) -> None:
    """Fill ``world (N, 16, 4, 4)`` with ``hand_T_bone`` and ``keypoints (N, 21, 3)``.

    Every bone's joint is ``Rz(z) @ Rx(x)`` (``z_angle``, ``x_angle (N, 16)``) between
    its ``rest_before`` and ``rest_after`` rotations, at ``offsets (16, 3)`` in its
    parent's frame (``parents (16,)``, -1 for the palm, parents before children); each
    finger's tip lies ``tip_lengths (5,)`` along its last bone's y axis.
    """
    bones = z_angle.shape[1]
    joint = np.empty((3, 3))
    turned = np.empty((3, 3))
    local = np.zeros((4, 4))
    local[3, 3] = 1.0
    for item in range(z_angle.shape[0]):
        for bone in range(bones):
            cz, sz = np.cos(z_angle[item, bone]), np.sin(z_angle[item, bone])
            cx, sx = np.cos(x_angle[item, bone]), np.sin(x_angle[item, bone])
            joint[0, 0], joint[0, 1], joint[0, 2] = cz, -sz * cx, sz * sx
            joint[1, 0], joint[1, 1], joint[1, 2] = sz, cz * cx, -cz * sx
            joint[2, 0], joint[2, 1], joint[2, 2] = 0.0, sx, cx
            for r in range(3):
                for c in range(3):
                    total = 0.0
                    for k in range(3):
                        total += rest_before[bone, r, k] * joint[k, c]
                    turned[r, c] = total
            for r in range(3):
                for c in range(3):
                    total = 0.0
                    for k in range(3):
                        total += turned[r, k] * rest_after[bone, k, c]
                    local[r, c] = total
                local[r, 3] = offsets[bone, r]
            parent = parents[bone]
            if parent < 0:
                world[item, bone] = local
                continue
            for r in range(4):
                for c in range(4):
                    total = 0.0
                    for k in range(4):
                        total += world[item, parent, r, k] * local[k, c]
                    world[item, bone, r, c] = total
        keypoints[item, 0] = 0.0
        for finger in range(5):
            first = 1 + 3 * finger
            for segment in range(3):
                for axis in range(3):
                    keypoints[item, 1 + 4 * finger + segment, axis] = world[
                        item, first + segment, axis, 3
                    ]
            last = first + 2
            for axis in range(3):
                keypoints[item, 4 + 4 * finger, axis] = (
                    world[item, last, axis, 1] * tip_lengths[finger] + world[item, last, axis, 3]
                )
