"""Sphere-swept segments ("round cones") that approximate the hand's volume.

Every capsule belongs to one bone and is given in that bone's frame, so posing the
capsules is one rigid transform per capsule. The same finger capsules define the
fingers of the glove mesh (:mod:`glovedb.shape`), so the mesh and this approximation
agree; the palm is a swept polygon in the mesh and a fan of capsules here.

A capsule from ``a`` to ``b`` with radii ``r_a``, ``r_b`` is the union of the spheres
centred on the segment with linearly varying radius (a round cone; a capsule when the
radii are equal).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array
from glovedb.hand_model import N_BONES, Skeleton

# Radii at (proximal joint, middle of the segment, distal joint or tip) per finger
# segment, metres for a hand of 0.19 m (scaled with hand length). The middle radius
# is smaller than the joint radii so that knuckles show.
_SEGMENT_RADII_M = (
    ((0.0150, 0.0135, 0.0110), (0.0105, 0.0098, 0.0096), (0.0096, 0.0092, 0.0082)),
    ((0.0092, 0.0085, 0.0084), (0.0084, 0.0078, 0.0078), (0.0078, 0.0075, 0.0068)),
    ((0.0096, 0.0088, 0.0087), (0.0087, 0.0081, 0.0080), (0.0080, 0.0077, 0.0070)),
    ((0.0090, 0.0083, 0.0082), (0.0082, 0.0076, 0.0075), (0.0075, 0.0072, 0.0066)),
    ((0.0082, 0.0076, 0.0074), (0.0074, 0.0069, 0.0068), (0.0068, 0.0065, 0.0060)),
)
_REFERENCE_LENGTH_M = 0.19


@dataclass(frozen=True)
class CapsuleSet:
    """Round cones attached to bones.

    Attributes
    ----------
    bone : (C,) int64
        Bone each capsule moves with.
    start_m, end_m : (C, 3) float64
        Segment end points in the bone's frame.
    radius_start_m, radius_end_m : (C,) float64
        Radii at the two end points.
    """

    bone: NDArray[np.int64]
    start_m: NDArray[np.float64]
    end_m: NDArray[np.float64]
    radius_start_m: NDArray[np.float64]
    radius_end_m: NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.bone)


def finger_capsules(skeleton: Skeleton) -> CapsuleSet:
    """Two round cones per finger segment (joint to middle, middle to distal end).

    The distal segment ends one radius short of the fingertip keypoint so that the
    rounded end of the finger touches the keypoint.
    """
    scale = skeleton.hand_length_m / _REFERENCE_LENGTH_M
    rows = []
    for finger in range(5):
        for segment in range(3):
            bone = 1 + 3 * finger + segment
            r0, r_mid, r1 = (r * scale for r in _SEGMENT_RADII_M[finger][segment])
            length = skeleton.lengths_m[bone]
            end = length - r1 if segment == 2 else length
            mid = 0.5 * end
            rows.append((bone, 0.0, mid, r0, r_mid))
            rows.append((bone, mid, end, r_mid, r1))
    table = np.array(rows)
    y_axis = np.array([0.0, 1.0, 0.0])
    return CapsuleSet(
        bone=table[:, 0].astype(np.int64),
        start_m=table[:, 1:2] * y_axis,
        end_m=table[:, 2:3] * y_axis,
        radius_start_m=table[:, 3],
        radius_end_m=table[:, 4],
    )


def palm_capsules(skeleton: Skeleton, half_thickness_m: float) -> CapsuleSet:
    """A fan of capsules that fills the palm: wrist to every finger base, and across."""
    bases = skeleton.offsets_m[[1, 4, 7, 10, 13]]
    wrist = (
        np.array([[-0.06, 0.04, 0.0], [-0.02, 0.02, 0.0], [0.02, 0.02, 0.0], [0.06, 0.04, 0.0]])
        * skeleton.hand_length_m
    )
    starts = np.concatenate([wrist, bases[1:4], wrist[:3]])
    ends = np.concatenate([bases[1:], bases[2:], wrist[1:]])
    radius = np.full(len(starts), half_thickness_m)
    return CapsuleSet(
        bone=np.zeros(len(starts), dtype=np.int64),
        start_m=starts,
        end_m=ends,
        radius_start_m=radius,
        radius_end_m=radius.copy(),
    )


def concatenate(*sets: CapsuleSet) -> CapsuleSet:
    """One capsule set holding all capsules of ``sets`` in order."""
    return CapsuleSet(
        bone=np.concatenate([s.bone for s in sets]),
        start_m=np.concatenate([s.start_m for s in sets]),
        end_m=np.concatenate([s.end_m for s in sets]),
        radius_start_m=np.concatenate([s.radius_start_m for s in sets]),
        radius_end_m=np.concatenate([s.radius_end_m for s in sets]),
    )


def pose_capsules(
    capsules: CapsuleSet, bone_transforms: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """End points of the capsules for one posed skeleton.

    Parameters
    ----------
    capsules : CapsuleSet
    bone_transforms : (16, 4, 4) float
        ``frame_T_bone`` for every bone (e.g. one posture of
        :attr:`~glovedb.hand_model.Kinematics.bone_transforms`).

    Returns
    -------
    start_m, end_m : (C, 3) float64
        In the frame the bone transforms map to.
    """
    transforms = as_array("bone_transforms", bone_transforms, (N_BONES, 4, 4), np.float64)
    selected = transforms[capsules.bone]
    rotate, shift = selected[:, :3, :3], selected[:, :3, 3]
    start = np.einsum("cij,cj->ci", rotate, capsules.start_m) + shift
    end = np.einsum("cij,cj->ci", rotate, capsules.end_m) + shift
    return start, end


def round_cone_distance(
    points: ArrayLike,
    start_m: ArrayLike,
    end_m: ArrayLike,
    radius_start_m: ArrayLike,
    radius_end_m: ArrayLike,
) -> NDArray[np.float64]:
    """Signed distance from points to round cones (negative inside).

    Exact for capsules (equal radii); for round cones it uses the sphere of the
    closest axis point, which is exact on the axis-perpendicular band and within
    ``|r_a - r_b|`` elsewhere, plenty for radii that differ by a millimetre or two.

    Parameters
    ----------
    points : (N, 3) float
    start_m, end_m : (C, 3) float
    radius_start_m, radius_end_m : (C,) float

    Returns
    -------
    (N, C) float64
    """
    p = as_array("points", points, (None, 3), np.float64)
    a = as_array("start_m", start_m, (None, 3), np.float64)
    b = as_array("end_m", end_m, (len(a), 3), np.float64)
    ra = as_array("radius_start_m", radius_start_m, (len(a),), np.float64)
    rb = as_array("radius_end_m", radius_end_m, (len(a),), np.float64)
    axis = b - a
    length_sq = np.maximum(np.einsum("ci,ci->c", axis, axis), 1e-18)
    # |p - a - t (b - a)|^2 expanded so that no (N, C, 3) temporary is needed.
    along = p @ axis.T - np.einsum("ci,ci->c", a, axis)
    t = np.clip(along / length_sq, 0.0, 1.0)
    rel_sq = np.einsum("ni,ni->n", p, p)[:, None] - 2.0 * (p @ a.T) + np.einsum("ci,ci->c", a, a)
    dist_sq = rel_sq - 2.0 * t * along + t * t * length_sq
    return np.sqrt(np.maximum(dist_sq, 0.0)) - (ra + t * (rb - ra))


def closest_capsule_points(
    points: NDArray[np.float64],
    start_m: NDArray[np.float64],
    end_m: NDArray[np.float64],
    radius_start_m: NDArray[np.float64],
    radius_end_m: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Nearest surface point ``(N, 3)`` of a set of round cones, and its distance ``(N,)``.

    The surface point lies on the nearest cone's sphere at its closest axis point, as
    in :func:`round_cone_distance`.
    """
    distance = round_cone_distance(points, start_m, end_m, radius_start_m, radius_end_m)
    nearest = np.argmin(distance, axis=1)
    a, b = start_m[nearest], end_m[nearest]
    axis = b - a
    t = np.clip(
        np.einsum("ni,ni->n", points - a, axis)
        / np.maximum(np.einsum("ni,ni->n", axis, axis), 1e-18),
        0.0,
        1.0,
    )
    centre = a + t[:, None] * axis
    radius = radius_start_m[nearest] + t * (radius_end_m[nearest] - radius_start_m[nearest])
    away = points - centre
    length = np.maximum(np.linalg.norm(away, axis=1), 1e-12)
    surface = centre + away * (radius / length)[:, None]
    return surface, np.abs(distance[np.arange(len(points)), nearest])
