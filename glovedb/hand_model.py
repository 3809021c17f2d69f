"""Kinematic model of the right hand: skeleton, joint limits, forward kinematics.

The hand has 26 degrees of freedom: a global rigid pose (6) and the 20 posture angles
of docs/conventions.md. The skeleton is 16 rigid bones: the palm (bone 0) and three
segments per finger (thumb: metacarpal, proximal, distal; other fingers: proximal,
middle, distal). Bone ``1 + 3 * finger + segment`` is segment ``segment`` of finger
``finger`` in the order of :data:`FINGERS`.

Every bone has a local frame with its origin at its proximal joint, +y along the bone
toward the distal joint, +z out of the back of the hand and +x = y x z. The palm's
frame is the hand frame (origin at the wrist joint centre, +y toward the middle MCP,
+z dorsal). A bone's transform is::

    hand_T_bone = hand_T_parent @ Trans(offset) @ rest_before @ joint(theta) @ rest_after

Joint rotations:

- finger MCP: ``Rz(abduction) @ Rx(-flexion)`` (abduction toward the thumb side is a
  right-handed turn about +z for a right hand; flexion turns the finger toward -z, the
  palm);
- finger PIP, DIP and thumb MCP, IP: ``Rx(-flexion)``;
- thumb CMC: ``Rz(-cmc_flex) @ Rx(-cmc_abd)``: flexion moves the thumb across the palm
  toward the little finger, abduction lifts it out of the palm plane on the palm side;
  the thumb is then rolled about its own axis (pronated) so that its MCP and IP
  flexion curl it toward the palm and the other fingers.

Bone lengths are fractions of the hand length (wrist crease to the tip of the middle
finger), after the anthropometric ratios of Buchholz, Armstrong and Goldstein (1992),
"Anthropometric data for describing the kinematics of the human hand", Ergonomics 35.
Joint limits are the usual active ranges of motion, in degrees in :data:`JOINT_LIMITS_DEG`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb import _kinematics_kernels
from glovedb._validate import as_array
from glovedb.rotations import rotation_y, rotation_z

FINGERS: tuple[str, ...] = ("thumb", "index", "middle", "ring", "little")

JOINT_NAMES: tuple[str, ...] = (
    "thumb_cmc_abd", "thumb_cmc_flex", "thumb_mcp_flex", "thumb_ip_flex",
    "index_mcp_abd", "index_mcp_flex", "index_pip_flex", "index_dip_flex",
    "middle_mcp_abd", "middle_mcp_flex", "middle_pip_flex", "middle_dip_flex",
    "ring_mcp_abd", "ring_mcp_flex", "ring_pip_flex", "ring_dip_flex",
    "little_mcp_abd", "little_mcp_flex", "little_pip_flex", "little_dip_flex",
)  # fmt: skip
N_JOINTS = len(JOINT_NAMES)

KEYPOINT_NAMES: tuple[str, ...] = ("wrist",) + tuple(
    f"{finger}_{joint}"
    for finger, joints in zip(
        FINGERS, [("cmc", "mcp", "ip", "tip")] + [("mcp", "pip", "dip", "tip")] * 4, strict=True
    )
    for joint in joints
)
N_KEYPOINTS = len(KEYPOINT_NAMES)
FINGERTIP_KEYPOINTS: tuple[int, ...] = (4, 8, 12, 16, 20)

N_BONES = 16
BONE_NAMES: tuple[str, ...] = ("palm",) + tuple(
    f"{finger}_{segment}"
    for finger, segments in zip(
        FINGERS,
        [("metacarpal", "proximal", "distal")] + [("proximal", "middle", "distal")] * 4,
        strict=True,
    )
    for segment in segments
)
BONE_PARENTS: tuple[int, ...] = (-1,) + tuple(
    0 if segment == 0 else 1 + 3 * finger + segment - 1
    for finger in range(5)
    for segment in range(3)
)

# (lower, upper) active range of every posture angle, degrees, docs/conventions.md order.
JOINT_LIMITS_DEG: tuple[tuple[float, float], ...] = (
    (-10.0, 70.0), (-25.0, 55.0), (-15.0, 70.0), (-25.0, 85.0),   # thumb
    (-20.0, 25.0), (-25.0, 95.0), (0.0, 110.0), (-10.0, 85.0),    # index
    (-20.0, 20.0), (-25.0, 95.0), (0.0, 110.0), (-10.0, 85.0),    # middle
    (-20.0, 15.0), (-25.0, 95.0), (0.0, 110.0), (-10.0, 85.0),    # ring
    (-30.0, 15.0), (-25.0, 95.0), (0.0, 110.0), (-10.0, 85.0),    # little
)  # fmt: skip

DEFAULT_HAND_LENGTH_M = 0.19

# Rest skeleton in units of hand length. Per finger: proximal joint position in the
# hand frame (thumb CMC, finger MCPs), rest yaw about +z in degrees (positive toward
# the thumb), and segment lengths (the last one ends at the fingertip).
_BASE_JOINTS = (
    (-0.115, 0.130, -0.035),
    (-0.110, 0.440, 0.0),
    (0.000, 0.456, 0.0),
    (0.100, 0.425, 0.0),
    (0.190, 0.385, 0.0),
)
_REST_YAW_DEG = (38.0, 6.0, 0.0, -5.0, -12.0)
_SEGMENT_LENGTHS = (
    (0.251, 0.196, 0.158),
    (0.245, 0.143, 0.097),
    (0.266, 0.170, 0.108),
    (0.244, 0.165, 0.107),
    (0.204, 0.117, 0.093),
)
# Thumb: pronation about its own axis, degrees; negative turns its flexion toward the
# little finger side.
_THUMB_ROLL_DEG = -55.0


def joint_limits_rad() -> NDArray[np.float64]:
    """Joint limits as a ``(20, 2)`` float64 array of (lower, upper) in radians."""
    return np.radians(np.array(JOINT_LIMITS_DEG))


def clip_to_limits(posture_rad: ArrayLike) -> NDArray[np.float64]:
    """Clip ``(..., 20)`` postures to the joint limits."""
    posture = as_array("posture_rad", posture_rad, (..., N_JOINTS), np.float64)
    limits = joint_limits_rad()
    return np.clip(posture, limits[:, 0], limits[:, 1])


def within_limits(posture_rad: ArrayLike, *, tolerance_rad: float = 1e-9) -> NDArray[np.bool_]:
    """Whether each ``(..., 20)`` posture lies inside the joint limits; returns ``(...)``."""
    posture = as_array("posture_rad", posture_rad, (..., N_JOINTS), np.float64)
    limits = joint_limits_rad()
    inside = (posture >= limits[:, 0] - tolerance_rad) & (posture <= limits[:, 1] + tolerance_rad)
    return np.all(inside, axis=-1)


@dataclass(frozen=True)
class Skeleton:
    """The rest skeleton of a hand of a given size.

    Attributes
    ----------
    hand_length_m : float
        Wrist crease to the tip of the middle finger.
    offsets_m : (16, 3) float64
        Origin of each bone in its parent's frame (the palm's in the hand frame: zero).
    rest_before : (16, 3, 3) float64
        Fixed rotation applied before the joint rotation (rest direction of the bone).
    rest_after : (16, 3, 3) float64
        Fixed rotation applied after the joint rotation (the thumb's pronation).
    lengths_m : (16,) float64
        Length of each bone along its +y axis (the palm's: wrist to middle MCP).
    """

    hand_length_m: float
    offsets_m: NDArray[np.float64]
    rest_before: NDArray[np.float64]
    rest_after: NDArray[np.float64]
    lengths_m: NDArray[np.float64]


def make_skeleton(hand_length_m: float = DEFAULT_HAND_LENGTH_M) -> Skeleton:
    """Build the rest skeleton of a right hand with the given overall length.

    Parameters
    ----------
    hand_length_m : float
        Wrist crease to the tip of the middle finger, metres (adults: 0.16-0.21).

    Returns
    -------
    Skeleton
    """
    if not 0.05 <= float(hand_length_m) <= 0.5:
        raise ValueError(f"hand_length_m: expected 0.05-0.5 m, got {hand_length_m}")
    scale = float(hand_length_m)
    offsets = np.zeros((N_BONES, 3))
    rest_before = np.tile(np.eye(3), (N_BONES, 1, 1))
    rest_after = np.tile(np.eye(3), (N_BONES, 1, 1))
    lengths = np.zeros(N_BONES)
    lengths[0] = _BASE_JOINTS[2][1] * scale
    for finger in range(5):
        first = 1 + 3 * finger
        offsets[first] = np.array(_BASE_JOINTS[finger]) * scale
        rest_before[first] = rotation_z(np.radians(_REST_YAW_DEG[finger]))
        for segment in range(3):
            lengths[first + segment] = _SEGMENT_LENGTHS[finger][segment] * scale
            if segment > 0:
                offsets[first + segment] = (0.0, lengths[first + segment - 1], 0.0)
    rest_after[1] = rotation_y(np.radians(_THUMB_ROLL_DEG))
    return Skeleton(scale, offsets, rest_before, rest_after, lengths)


def bone_angles(
    posture_rad: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(N, 16)`` z and x angles of every bone's joint for ``(N, 20)`` postures (0 for
    the palm and for joints without that part): the joint rotates its bone by
    ``Rz(z) @ Rx(x)`` about the parent's axes."""
    n = len(posture_rad)
    z_angle = np.zeros((n, N_BONES))
    x_angle = np.zeros((n, N_BONES))
    z_angle[:, 1] = -posture_rad[:, 1]
    x_angle[:, 1] = -posture_rad[:, 0]
    x_angle[:, 2:4] = -posture_rad[:, 2:4]
    for finger in range(1, 5):
        first, base = 1 + 3 * finger, 4 * finger
        z_angle[:, first] = posture_rad[:, base]
        x_angle[:, first : first + 3] = -posture_rad[:, base + 1 : base + 4]
    return z_angle, x_angle


@dataclass(frozen=True)
class Kinematics:
    """Result of forward kinematics for a batch of postures, in the hand frame.

    Attributes
    ----------
    keypoints_m : (N, 21, 3) float64
        MediaPipe-order keypoints (docs/conventions.md).
    bone_transforms : (N, 16, 4, 4) float64
        ``hand_T_bone`` for every bone.
    """

    keypoints_m: NDArray[np.float64]
    bone_transforms: NDArray[np.float64]


def forward_kinematics(posture_rad: ArrayLike, skeleton: Skeleton | None = None) -> Kinematics:
    """Keypoints and bone transforms of a batch of postures.

    Parameters
    ----------
    posture_rad : (20,) or (N, 20) float
        Joint angles in docs/conventions.md order, radians. Not clipped to the limits.
    skeleton : Skeleton, optional
        Defaults to :func:`make_skeleton` with the default hand length.

    Returns
    -------
    Kinematics
        With a leading batch axis of length N (1 for a single posture).
    """
    posture = as_array("posture_rad", posture_rad, (..., N_JOINTS), np.float64, finite=True)
    posture = posture.reshape(-1, N_JOINTS)
    skeleton = skeleton or make_skeleton()
    n = len(posture)
    z_angle, x_angle = bone_angles(posture)
    world = np.empty((n, N_BONES, 4, 4))
    keypoints = np.empty((n, N_KEYPOINTS, 3))
    _chain(z_angle, x_angle, skeleton, world, keypoints)
    return Kinematics(keypoints, world)


def bone_transforms_per_skeleton(
    posture_rad: ArrayLike, skeletons: Sequence[Skeleton]
) -> NDArray[np.float64]:
    """``(K, N, 16, 4, 4)`` ``hand_T_bone`` of ``(N, 20)`` postures on each of K
    skeletons: :func:`forward_kinematics`'s bone transforms, the same numbers, with the
    postures' joint angles worked out once (a fit that differentiates by the hand
    proportions poses 8 skeletons per frame)."""
    posture = as_array("posture_rad", posture_rad, (..., N_JOINTS), np.float64, finite=True)
    posture = posture.reshape(-1, N_JOINTS)
    z_angle, x_angle = bone_angles(posture)
    world = np.empty((len(skeletons), len(posture), N_BONES, 4, 4))
    keypoints = np.empty((len(posture), N_KEYPOINTS, 3))
    for k, skeleton in enumerate(skeletons):
        _chain(z_angle, x_angle, skeleton, world[k], keypoints)
    return world


def _chain(
    z_angle: NDArray[np.float64],
    x_angle: NDArray[np.float64],
    skeleton: Skeleton,
    world: NDArray[np.float64],
    keypoints: NDArray[np.float64],
) -> None:
    """Fill ``world (N, 16, 4, 4)`` and ``keypoints (N, 21, 3)`` for the joint angles
    ``(N, 16)`` of :func:`bone_angles` on ``skeleton``."""
    _kinematics_kernels.chain(
        z_angle, x_angle,
        np.ascontiguousarray(skeleton.rest_before, dtype=np.float64),
        np.ascontiguousarray(skeleton.rest_after, dtype=np.float64),
        np.ascontiguousarray(skeleton.offsets_m, dtype=np.float64),
        _PARENTS, np.ascontiguousarray(skeleton.lengths_m[_LAST_BONES], dtype=np.float64),
        world, keypoints,
    )  # fmt: skip


_PARENTS = np.asarray(BONE_PARENTS, dtype=np.int64)
_LAST_BONES = np.array([3 + 3 * finger for finger in range(5)])
"""The last bone of every finger (its tip lies along that bone's y axis)."""


def transform_points(points: ArrayLike, rotation: ArrayLike, translation_m: ArrayLike) -> NDArray:
    """Apply ``p' = R @ p + t`` to ``(..., 3)`` points; returns float64 of the same shape."""
    points = as_array("points", points, (..., 3), np.float64)
    rotation = as_array("rotation", rotation, (3, 3), np.float64, finite=True)
    translation = as_array("translation_m", translation_m, (3,), np.float64, finite=True)
    return points @ rotation.T + translation
