"""The volume of the glove hand in its rest posture, as a signed distance function.

The hand is the union of a palm (a convex polygon swept by a sphere: a slab with
fully rounded edges), a short wrist cuff (a capped elliptic cylinder) and the finger
round cones of :mod:`glovedb.capsules`. Each finger is blended smoothly into the palm
(so there are webs between fingers and a thenar eminence at the thumb) but fingers
are not blended with each other, so they stay separate.

Distances are negative inside, in metres, in the hand frame of the rest posture.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array
from glovedb.capsules import CapsuleSet, finger_capsules, pose_capsules, round_cone_distance
from glovedb.hand_model import N_JOINTS, Skeleton, forward_kinematics

# Inner palm polygon in the hand's xy plane, units of hand length, counter-clockwise
# seen from the back of the hand. The palm surface lies one half-thickness outside.
_PALM_POLYGON = (
    (0.100, 0.020),
    (0.165, 0.330),
    (0.150, 0.385),
    (0.090, 0.420),
    (0.000, 0.440),
    (-0.100, 0.430),
    (-0.125, 0.380),
    (-0.130, 0.200),
    (-0.100, 0.020),
)
_PALM_HALF_THICKNESS = 0.072
_WRIST_HALF_WIDTH, _WRIST_HALF_DEPTH = 0.160, 0.105
_WRIST_Y_RANGE = (-0.20, 0.05)
_BLEND_WRIST, _BLEND_THUMB, _BLEND_FINGER = 0.055, 0.045, 0.022


@dataclass(frozen=True)
class HandShape:
    """Parameters of the rest-posture volume, in metres (see module docstring).

    Attributes
    ----------
    palm_polygon_m : (P, 2) float64
        Counter-clockwise convex polygon swept to make the palm.
    palm_half_thickness_m : float
    wrist_half_axes_m : (2,) float64
        Half width (x) and half depth (z) of the wrist cuff.
    wrist_y_range_m : (2,) float64
        Where the cuff starts and ends along +y.
    fingers : CapsuleSet
        Finger round cones posed at rest, in the hand frame (``bone`` tells the finger).
    blend_m : (3,) float64
        Smooth-union widths for wrist-palm, thumb-palm and finger-palm.
    """

    palm_polygon_m: NDArray[np.float64]
    palm_half_thickness_m: float
    wrist_half_axes_m: NDArray[np.float64]
    wrist_y_range_m: NDArray[np.float64]
    fingers: CapsuleSet
    blend_m: NDArray[np.float64]


def make_hand_shape(skeleton: Skeleton) -> HandShape:
    """Rest-posture volume of a hand with the given skeleton."""
    scale = skeleton.hand_length_m
    local = finger_capsules(skeleton)
    rest = forward_kinematics(np.zeros(N_JOINTS), skeleton).bone_transforms[0]
    start, end = pose_capsules(local, rest)
    fingers = CapsuleSet(local.bone, start, end, local.radius_start_m, local.radius_end_m)
    return HandShape(
        palm_polygon_m=np.array(_PALM_POLYGON) * scale,
        palm_half_thickness_m=_PALM_HALF_THICKNESS * scale,
        wrist_half_axes_m=np.array([_WRIST_HALF_WIDTH, _WRIST_HALF_DEPTH]) * scale,
        wrist_y_range_m=np.array(_WRIST_Y_RANGE) * scale,
        fingers=fingers,
        blend_m=np.array([_BLEND_WRIST, _BLEND_THUMB, _BLEND_FINGER]) * scale,
    )


def polygon_distance(points_xy: ArrayLike, polygon: ArrayLike) -> NDArray[np.float64]:
    """Signed distance from 2D points to a convex counter-clockwise polygon.

    Parameters
    ----------
    points_xy : (N, 2) float
    polygon : (P, 2) float
        Convex, counter-clockwise.

    Returns
    -------
    (N,) float64
        Negative inside.
    """
    p = as_array("points_xy", points_xy, (None, 2), np.float64)
    a = as_array("polygon", polygon, (None, 2), np.float64)
    edge = np.roll(a, -1, axis=0) - a
    rel = p[:, None, :] - a[None]
    t = np.clip(np.einsum("npi,pi->np", rel, edge) / np.einsum("pi,pi->p", edge, edge), 0, 1)
    nearest = np.linalg.norm(rel - t[..., None] * edge, axis=-1).min(axis=1)
    cross = edge[None, :, 0] * rel[..., 1] - edge[None, :, 1] * rel[..., 0]
    inside = np.all(cross >= 0, axis=1)
    return np.where(inside, -nearest, nearest)


def smooth_union(a: NDArray, b: NDArray, width: float | NDArray) -> NDArray:
    """Polynomial smooth minimum of two distance fields, blending over ``width`` (broadcast)."""
    h = np.maximum(width - np.abs(a - b), 0.0) / width
    return np.minimum(a, b) - h * h * width * 0.25


def palm_distance(points: NDArray[np.float64], shape: HandShape) -> NDArray[np.float64]:
    """Signed distance ``(N,)`` to the palm slab for ``(N, 3)`` points."""
    planar = np.maximum(polygon_distance(points[:, :2], shape.palm_polygon_m), 0.0)
    return np.hypot(planar, points[:, 2]) - shape.palm_half_thickness_m


def wrist_distance(points: NDArray[np.float64], shape: HandShape) -> NDArray[np.float64]:
    """Signed distance ``(N,)`` (approximate off the axes) to the capped wrist cuff."""
    half_x, half_z = shape.wrist_half_axes_m
    radial = (np.hypot(points[:, 0] / half_x, points[:, 2] / half_z) - 1.0) * min(half_x, half_z)
    low, high = shape.wrist_y_range_m
    along = np.maximum(low - points[:, 1], points[:, 1] - high)
    outside = np.hypot(np.maximum(radial, 0.0), np.maximum(along, 0.0))
    return outside + np.minimum(np.maximum(radial, along), 0.0)


def hand_distance(points: ArrayLike, shape: HandShape) -> NDArray[np.float64]:
    """Signed distance from points to the rest-posture glove hand.

    Parameters
    ----------
    points : (N, 3) float
        Hand frame, metres.
    shape : HandShape

    Returns
    -------
    (N,) float64
        Negative inside.
    """
    p = as_array("points", points, (None, 3), np.float64)
    wrist_blend, thumb_blend, finger_blend = shape.blend_m
    body = smooth_union(palm_distance(p, shape), wrist_distance(p, shape), wrist_blend)
    cones = round_cone_distance(
        p,
        shape.fingers.start_m,
        shape.fingers.end_m,
        shape.fingers.radius_start_m,
        shape.fingers.radius_end_m,
    )
    # Cones are stored finger by finger, the same number per finger.
    per_finger = cones.reshape(len(p), 5, -1).min(axis=2)
    blends = np.array([thumb_blend] + [finger_blend] * 4)
    return smooth_union(body[:, None], per_finger, blends).min(axis=1)
