"""Tracked hand motion as a BVH file that animation tools (Blender) import.

Layout
------
The hierarchy is the 16 bones of :mod:`glovedb.hand_model`, named by
:data:`~glovedb.hand_model.BONE_NAMES`: ``ROOT palm`` with six channels
(``Xposition Yposition Zposition Zrotation Yrotation Xrotation``), below it the five
finger chains, every other joint with three channels (``Zrotation Yrotation
Xrotation``), and an ``End Site`` at every fingertip. Lengths are centimetres.

- **Rest pose** (all channels zero): the rest skeleton (posture all zeros) in the hand
  frame, every joint frame parallel to the hand frame (BVH's convention), so an
  ``OFFSET`` is the rest position of a joint minus its parent's in hand coordinates.
- **Rotations**: per joint the rotation relative to the rest pose, as Euler angles in
  degrees in the declared order: ``Zrotation Yrotation Xrotation`` means
  ``Rz(a) @ Ry(b) @ Rx(c)``. Finger flexion is mostly ``Xrotation`` and abduction
  ``Zrotation``; this order keeps the middle angle (the twist along the finger) small,
  far from gimbal lock.
- **World axes**: the camera frame turned 180 degrees about its x axis, i.e. the
  OpenGL camera frame: X right, Y up, Z toward the viewer; the camera is at the origin
  looking down -Z. With Blender's default import axes (Y up, -Z forward) the camera
  looks along Blender's +Y, so Blender's Front view shows the hand as the camera saw
  it. A camera point ``p_cam`` is at ``100 * diag(1, -1, -1) @ p_cam``.
- **Root**: ``palm`` position is the wrist in that world frame (``translation_m``),
  its rotation the global pose ``diag(1, -1, -1) @ rotation``.
- **Frames where the hand was not found** repeat the last pose that was found; frames
  before the first found one take the first found pose; if no frame has a hand, every
  frame is the rest posture at the camera origin. The file has exactly one motion line
  per input frame, so BVH frame ``i`` is video frame ``i``.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array
from glovedb.hand_model import (
    BONE_NAMES,
    BONE_PARENTS,
    N_BONES,
    N_JOINTS,
    Skeleton,
    forward_kinematics,
    make_skeleton,
)

CHANNEL_ORDER = "ZYX"
ROTATION_CHANNELS: tuple[str, ...] = tuple(f"{axis}rotation" for axis in CHANNEL_ORDER)
POSITION_CHANNELS: tuple[str, ...] = ("Xposition", "Yposition", "Zposition")
# Camera frame (x right, y down, z forward) to BVH world (x right, y up, z to the viewer).
CAMERA_TO_WORLD = np.diag([1.0, -1.0, -1.0])
CM_PER_M = 100.0
_ORTHONORMAL_TOLERANCE = 1e-3


@dataclass(frozen=True)
class BvhMotion:
    """Everything a BVH file holds, as arrays (centimetres and degrees).

    Attributes
    ----------
    offsets_cm : (16, 3) float64
        Rest position of every joint relative to its parent (the root's: zero).
    end_sites_cm : (16, 3) float64
        Fingertip relative to the joint of every distal bone; NaN for other bones.
    root_position_cm : (T, 3) float64
        Wrist in the BVH world frame (see the module docstring).
    rotations_deg : (T, 16, 3) float64
        Euler angles of every joint in :data:`CHANNEL_ORDER`, degrees.
    """

    offsets_cm: NDArray[np.float64]
    end_sites_cm: NDArray[np.float64]
    root_position_cm: NDArray[np.float64]
    rotations_deg: NDArray[np.float64]

    @property
    def n_frames(self) -> int:
        return len(self.root_position_cm)


@dataclass(frozen=True)
class PoseArrays:
    """The global poses and postures of a tracked sequence, one row per frame.

    Attributes
    ----------
    postures_rad : (T, 20) float64
    rotations : (T, 3, 3) float64
        ``cam_R_hand``.
    translations_m : (T, 3) float64
        Wrist in the camera frame.
    found : (T,) bool
        Whether the hand was found; other rows are NaN.
    """

    postures_rad: NDArray[np.float64]
    rotations: NDArray[np.float64]
    translations_m: NDArray[np.float64]
    found: NDArray[np.bool_]


def pose_arrays(records: Iterable[Mapping[str, Any]]) -> PoseArrays:
    """Stack ``poses.jsonl`` records (docs/conventions.md) into arrays.

    Parameters
    ----------
    records : iterable of mapping
        With ``hand_found`` and, when found, ``posture_rad``, ``rotation``,
        ``translation_m``.

    Returns
    -------
    PoseArrays
    """
    postures, rotations, translations, found = [], [], [], []
    for record in records:
        hit = bool(record.get("hand_found", False))
        found.append(hit)
        postures.append(record["posture_rad"] if hit else np.full(N_JOINTS, np.nan))
        rotations.append(record["rotation"] if hit else np.full((3, 3), np.nan))
        translations.append(record["translation_m"] if hit else np.full(3, np.nan))
    n = len(found)
    return PoseArrays(
        as_array("posture_rad", postures, (n, N_JOINTS), np.float64).reshape(n, N_JOINTS),
        as_array("rotation", rotations, (n, 3, 3), np.float64).reshape(n, 3, 3),
        as_array("translation_m", translations, (n, 3), np.float64).reshape(n, 3),
        np.array(found, dtype=bool),
    )


def euler_from_matrix(rotation: ArrayLike) -> NDArray[np.float64]:
    """Angles ``(a, b, c)`` with ``R = Rz(a) @ Ry(b) @ Rx(c)``, radians.

    Parameters
    ----------
    rotation : (..., 3, 3) float
        Rotation matrices.

    Returns
    -------
    (..., 3) float64
        ``b`` in [-pi/2, pi/2]; at gimbal lock (``|b| = pi/2``) ``c`` is 0.
    """
    r = as_array("rotation", rotation, (..., 3, 3), np.float64)
    cos_b = np.hypot(r[..., 0, 0], r[..., 1, 0])
    b = np.arctan2(-r[..., 2, 0], cos_b)
    locked = cos_b < 1e-9
    a = np.where(
        locked, np.arctan2(-r[..., 0, 1], r[..., 1, 1]), np.arctan2(r[..., 1, 0], r[..., 0, 0])
    )
    c = np.where(locked, 0.0, np.arctan2(r[..., 2, 1], r[..., 2, 2]))
    return np.stack([a, b, c], axis=-1)


def bvh_motion(
    postures_rad: ArrayLike,
    rotations: ArrayLike,
    translations_m: ArrayLike,
    *,
    skeleton: Skeleton | None = None,
    found: ArrayLike | None = None,
) -> BvhMotion:
    """Convert tracked poses to BVH offsets and channels.

    Parameters
    ----------
    postures_rad : (T, 20) float
        Joint angles, docs/conventions.md order.
    rotations : (T, 3, 3) float
        ``cam_R_hand``: hand frame to camera frame.
    translations_m : (T, 3) float
        Wrist in the camera frame, metres.
    skeleton : Skeleton, optional
        The hand the postures belong to; default :func:`make_skeleton`.
    found : (T,) bool, optional
        Frames where the hand was found; default: the rows that are all finite. Other
        frames repeat the last found pose (module docstring).

    Returns
    -------
    BvhMotion
    """
    postures = as_array("postures_rad", postures_rad, (None, N_JOINTS), np.float64)
    n = len(postures)
    rotation = as_array("rotations", rotations, (n, 3, 3), np.float64)
    translation = as_array("translations_m", translations_m, (n, 3), np.float64)
    hit = _found_mask(found, postures, rotation, translation)
    source = _held_indices(hit)
    skeleton = skeleton or make_skeleton()
    if hit.any():
        postures, rotation, translation = postures[source], rotation[source], translation[source]
    else:
        postures, rotation, translation = (
            np.zeros((n, N_JOINTS)),
            np.tile(np.eye(3), (n, 1, 1)),
            np.zeros((n, 3)),
        )

    rest = forward_kinematics(np.zeros(N_JOINTS), skeleton).bone_transforms[0]
    posed = (
        forward_kinematics(postures, skeleton).bone_transforms
        if n
        else np.zeros((0, N_BONES, 4, 4))
    )
    # Orientation of every joint relative to the rest pose, in the hand frame.
    relative = posed[:, :, :3, :3] @ np.swapaxes(rest[:, :3, :3], -1, -2)
    local = np.empty_like(relative)
    local[:, 0] = CAMERA_TO_WORLD @ rotation @ relative[:, 0]
    for bone in range(1, N_BONES):
        parent = BONE_PARENTS[bone]
        local[:, bone] = np.swapaxes(relative[:, parent], -1, -2) @ relative[:, bone]

    offsets = np.zeros((N_BONES, 3))
    for bone in range(1, N_BONES):
        offsets[bone] = rest[bone, :3, 3] - rest[BONE_PARENTS[bone], :3, 3]
    end_sites = np.full((N_BONES, 3), np.nan)
    for bone in _leaf_bones():
        end_sites[bone] = rest[bone, :3, :3] @ np.array([0.0, skeleton.lengths_m[bone], 0.0])
    return BvhMotion(
        offsets * CM_PER_M,
        end_sites * CM_PER_M,
        translation @ CAMERA_TO_WORLD.T * CM_PER_M,
        np.degrees(euler_from_matrix(local)),
    )


def bvh_text(motion: BvhMotion, fps: float) -> str:
    """The BVH file of ``motion`` as a string.

    Parameters
    ----------
    motion : BvhMotion
    fps : float
        Frames per second (``Frame Time`` is ``1 / fps``).

    Returns
    -------
    str
    """
    if not fps > 0:
        raise ValueError(f"fps: expected > 0, got {fps}")
    lines = ["HIERARCHY"]
    order: list[int] = []
    _write_joint(lines, order, motion, 0, 0)
    lines += ["MOTION", f"Frames: {motion.n_frames}", f"Frame Time: {1.0 / fps:.8f}"]
    # Motion lines list the joints' channels in the order the hierarchy declares them.
    rotations = motion.rotations_deg[:, order].reshape(motion.n_frames, 3 * N_BONES)
    channels = np.concatenate([motion.root_position_cm, rotations], axis=1)
    lines += [" ".join(f"{value:.6f}" for value in row) for row in channels]
    return "\n".join(lines) + "\n"


def write_bvh(
    path: str | PathLike[str],
    postures_rad: ArrayLike,
    rotations: ArrayLike,
    translations_m: ArrayLike,
    *,
    fps: float,
    skeleton: Skeleton | None = None,
    found: ArrayLike | None = None,
) -> Path:
    """Write a BVH file of tracked poses; arguments as :func:`bvh_motion`.

    Returns
    -------
    Path
        The file written.
    """
    motion = bvh_motion(postures_rad, rotations, translations_m, skeleton=skeleton, found=found)
    path = Path(path)
    path.write_text(bvh_text(motion, fps))
    return path


def _write_joint(
    lines: list[str], order: list[int], motion: BvhMotion, bone: int, depth: int
) -> None:
    indent = "\t" * depth
    keyword = "ROOT" if bone == 0 else "JOINT"
    channels = (POSITION_CHANNELS if bone == 0 else ()) + ROTATION_CHANNELS
    lines += [
        f"{indent}{keyword} {BONE_NAMES[bone]}",
        f"{indent}{{",
        f"{indent}\tOFFSET {_xyz(motion.offsets_cm[bone])}",
        f"{indent}\tCHANNELS {len(channels)} {' '.join(channels)}",
    ]
    order.append(bone)
    children = [child for child in range(N_BONES) if BONE_PARENTS[child] == bone]
    for child in children:
        _write_joint(lines, order, motion, child, depth + 1)
    if not children:
        lines += [
            f"{indent}\tEnd Site",
            f"{indent}\t{{",
            f"{indent}\t\tOFFSET {_xyz(motion.end_sites_cm[bone])}",
            f"{indent}\t}}",
        ]
    lines.append(f"{indent}}}")


def _xyz(vector: NDArray[np.float64]) -> str:
    return " ".join(f"{value:.6f}" for value in vector)


def _leaf_bones() -> list[int]:
    return [bone for bone in range(N_BONES) if bone not in BONE_PARENTS]


def _found_mask(
    found: ArrayLike | None,
    postures: NDArray[np.float64],
    rotations: NDArray[np.float64],
    translations: NDArray[np.float64],
) -> NDArray[np.bool_]:
    finite = (
        np.isfinite(postures).all(axis=1)
        & np.isfinite(rotations).all(axis=(1, 2))
        & np.isfinite(translations).all(axis=1)
    )
    if found is None:
        hit = np.asarray(finite, dtype=bool)
    else:
        hit = as_array("found", found, (len(postures),)).astype(bool)
        bad = np.flatnonzero(hit & ~finite)
        if len(bad):
            raise ValueError(f"frame {bad[0]}: marked found but has NaN or infinity")
    gram = rotations[hit] @ np.swapaxes(rotations[hit], -1, -2)
    bad = np.flatnonzero(np.abs(gram - np.eye(3)).max(axis=(1, 2)) > _ORTHONORMAL_TOLERANCE)
    if len(bad):
        raise ValueError(f"frame {np.flatnonzero(hit)[bad[0]]}: rotation is not orthonormal")
    return hit


def _held_indices(found: NDArray[np.bool_]) -> NDArray[np.intp]:
    """For every frame, the found frame whose pose it shows (last one, else first)."""
    if not found.any():
        return np.zeros(len(found), dtype=np.intp)
    last = np.maximum.accumulate(np.where(found, np.arange(len(found)), -1))
    return np.where(last >= 0, last, np.argmax(found))
