"""The articulated hand the generative fit moves: pose, posed samples, Jacobians.

The fit's unknowns are 26 numbers, :data:`N_PARAMS`: a rotation step (axis-angle,
camera frame, about the wrist), a translation step (metres) and the 20 joint angles
(radians). :meth:`HandPose.step` applies a step::

    R <- exp([w]x) @ R,    t <- t + dt,    theta <- theta + dtheta

A model point ``p = R @ p_hand + t`` then moves, to first order, by
``w x (p - t) + dt + sum_j dtheta_j * dp/dtheta_j``. The joint derivatives are exact
derivatives of linear blend skinning along the kinematic chain: angle ``j`` turns
every bone below its joint about the joint's current axis ``a_j`` through its pivot
``c_j``, so a skinned vertex moves by::

    dv/dtheta_j = s_j * a_j x (sum_b w_b [j moves b] (M_b @ v_rest) - (sum_b w_b [j moves b]) c_j)

with ``M_b`` the bone's skinning matrix and ``s_j = +-1`` the sign of the angle in the
joint's rotation (:func:`glovedb.hand_model.joint_rotations`).

The model surface is a set of samples of the skinned glove mesh (vertex positions,
rest normals and color classes), posed without the mesh's faces: normals follow the
blended bone rotations. Hand proportions (:mod:`glovedb.proportions`) re-rest the
samples; their derivatives (:meth:`PosedHand.proportion_jacobian`) are forward
differences, used only while a user's proportions are estimated.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array
from glovedb.hand_model import (
    BONE_PARENTS,
    N_BONES,
    N_JOINTS,
    N_KEYPOINTS,
    Skeleton,
    forward_kinematics,
)
from glovedb.mesh import HandMesh, skin, skinning_matrices, vertex_normals
from glovedb.pattern import LabeledVertices
from glovedb.proportions import N_PROPORTIONS, HandProportions, proportioned_mesh
from glovedb.rotations import axis_angle_to_matrix
from tracker.generative import _kernels

N_PARAMS = 6 + N_JOINTS
"""Unknowns of one frame's fit: rotation step (3), translation step (3), angles (20)."""

_PROPORTION_STEP = 1e-3


def _dof_table() -> tuple[NDArray[np.int64], NDArray[np.bool_], NDArray[np.float64]]:
    """For every joint angle: its bone, whether it is the bone's z (else x) rotation,
    and its sign in :func:`glovedb.hand_model.joint_rotations`."""
    bone = np.zeros(N_JOINTS, dtype=np.int64)
    about_z = np.zeros(N_JOINTS, dtype=bool)
    sign = -np.ones(N_JOINTS)
    bone[:4] = (1, 1, 2, 3)
    about_z[1] = True  # thumb CMC: Rz(-cmc_flex) @ Rx(-cmc_abd)
    for finger in range(1, 5):
        first, base = 1 + 3 * finger, 4 * finger
        bone[base : base + 4] = (first, first, first + 1, first + 2)
        about_z[base] = True
        sign[base] = 1.0  # finger MCP: Rz(abduction) @ Rx(-flexion)
    return bone, about_z, sign


DOF_BONE, DOF_ABOUT_Z, DOF_SIGN = _dof_table()


def _moves() -> NDArray[np.float64]:
    """``(20, 16)``: 1 where joint angle ``j`` moves bone ``b`` (its bone and below)."""
    moves = np.zeros((N_JOINTS, N_BONES))
    for joint, own in enumerate(DOF_BONE):
        for bone in range(N_BONES):
            walk = bone
            while walk != -1 and walk != own:
                walk = BONE_PARENTS[walk]
            moves[joint, bone] = walk == own
    return moves


MOVES = _moves()

KEYPOINT_BONES = np.array(
    [0] + [1 + 3 * f + s for f in range(5) for s in (0, 1, 2, 2)], dtype=np.int64
)
"""Bone each keypoint rides on (a joint keypoint on the bone it starts, a tip on its
distal bone); N_KEYPOINTS entries."""
assert len(KEYPOINT_BONES) == N_KEYPOINTS


@dataclass(frozen=True)
class HandPose:
    """Posture and global pose of the hand.

    Attributes
    ----------
    posture_rad : (20,) float64
    rotation : (3, 3) float64
        ``cam_R_hand``.
    translation_m : (3,) float64
        Wrist in the camera frame.
    """

    posture_rad: NDArray[np.float64]
    rotation: NDArray[np.float64]
    translation_m: NDArray[np.float64]

    @classmethod
    def of(cls, posture_rad: ArrayLike, rotation: ArrayLike, translation_m: ArrayLike) -> HandPose:
        """Checked constructor."""
        return cls(
            as_array("posture_rad", posture_rad, (N_JOINTS,), np.float64, finite=True).copy(),
            as_array("rotation", rotation, (3, 3), np.float64, finite=True).copy(),
            as_array("translation_m", translation_m, (3,), np.float64, finite=True).copy(),
        )

    def step(self, delta: NDArray[np.float64]) -> HandPose:
        """The pose moved by a ``(26,)`` step (module docstring)."""
        angle = float(np.linalg.norm(delta[:3]))
        turn = axis_angle_to_matrix(delta[:3], angle) if angle > 0 else np.eye(3)
        return HandPose(
            self.posture_rad + delta[6:], turn @ self.rotation, self.translation_m + delta[3:6]
        )


@dataclass(frozen=True)
class HandSamples:
    """Samples of the glove surface, rigged like the mesh they come from.

    Attributes
    ----------
    mesh : HandMesh
        The samples as a mesh without faces (rest vertices and skinning weights), on
        the hand's skeleton (the model's or a personal one).
    rest_normals : (S, 3) float64
        Outward unit normals at rest, hand frame.
    labels : (S,) uint8
        Color class 1..10 of every sample.
    proportions : HandProportions
        Of ``mesh`` against the model's samples ``model``.
    model : HandMesh
        The samples on the model's skeleton (what proportions stretch).
    """

    mesh: HandMesh
    rest_normals: NDArray[np.float64]
    labels: NDArray[np.uint8]
    proportions: HandProportions
    model: HandMesh

    @property
    def skeleton(self) -> Skeleton:
        return self.mesh.skeleton

    def __len__(self) -> int:
        return len(self.labels)

    def with_proportions(self, proportions: HandProportions) -> HandSamples:
        """The same samples re-rested for a personal hand."""
        return replace(
            self, mesh=proportioned_mesh(self.model, proportions), proportions=proportions
        )


def hand_samples(mesh: HandMesh, split: LabeledVertices, *, spacing: int = 1) -> HandSamples:
    """Labeled samples of a glove mesh: every ``spacing``-th vertex of its class split.

    Parameters
    ----------
    mesh : HandMesh
        The model's mesh at rest.
    split : LabeledVertices
        Its vertices split by class (:func:`glovedb.pattern.split_by_label`).
    spacing : int
        Keep every n-th split vertex (1: all).

    Returns
    -------
    HandSamples
    """
    if spacing < 1:
        raise ValueError(f"spacing: expected >= 1, got {spacing}")
    chosen = split.source_vertex[::spacing]
    normals = vertex_normals(mesh.rest_vertices_m, mesh.faces)[chosen]
    samples = HandMesh(
        mesh.skeleton,
        mesh.rest_vertices_m[chosen],
        np.zeros((0, 3), dtype=np.int64),
        mesh.weights[chosen],
    )
    return HandSamples(samples, normals, split.labels[::spacing].copy(), HandProportions(), samples)


class PosedHand:
    """The samples and keypoints of a hand in one pose, camera frame, with Jacobians.

    Parameters
    ----------
    samples : HandSamples
    pose : HandPose
    proportion_jacobian : (S, 3, 7) float, optional
        Derivatives of all samples by the proportions, computed before (at a nearby
        pose): :meth:`proportion_jacobian` then picks from them instead of computing.

    Attributes
    ----------
    points_m : (S, 3) float64
        Samples, camera frame.
    normals : (S, 3) float64
        Their unit normals, camera frame.
    facing : (S,) bool
        Samples whose normal faces the camera (computed on first use).
    keypoints_m : (21, 3) float64
        Camera frame.
    bone_transforms : (16, 4, 4) float64
        ``hand_T_bone`` of every bone.
    """

    def __init__(
        self,
        samples: HandSamples,
        pose: HandPose,
        *,
        proportion_jacobian: NDArray[np.float64] | None = None,
    ) -> None:
        self.samples = samples
        self.pose = pose
        self._proportion_jacobian = proportion_jacobian
        R, t = pose.rotation, pose.translation_m
        both = forward_kinematics(
            np.vstack([pose.posture_rad, np.zeros(N_JOINTS)]), samples.skeleton
        )
        world = both.bone_transforms[0]  # (16, 4, 4) hand_T_bone
        self.bone_transforms = world
        self._skinning = (world @ np.linalg.inv(both.bone_transforms[1]))[:, :3, :]
        weights = samples.mesh.weights.astype(np.float64)
        blended = (weights @ self._skinning.reshape(N_BONES, 12)).reshape(-1, 3, 4)
        rest = samples.mesh.rest_vertices_m
        hand_points = np.einsum("sij,sj->si", blended[..., :3], rest) + blended[..., 3]
        normals = np.einsum("sij,sj->si", blended[..., :3], samples.rest_normals)
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        self._weights = weights
        self.points_m = hand_points @ R.T + t
        self.normals = normals @ R.T
        self.keypoints_m = both.keypoints_m[0] @ R.T + t
        self._hand_keypoints = both.keypoints_m[0]
        # Joint axes and pivots (camera frame).
        parents = np.array([BONE_PARENTS[b] for b in DOF_BONE])
        parent_rotation = world[np.maximum(parents, 0), :3, :3]
        frame = parent_rotation @ samples.skeleton.rest_before[DOF_BONE]
        z_axes = frame[:, :, 2]
        x_after_z = _x_after_z(frame, pose.posture_rad)
        axes = np.where(DOF_ABOUT_Z[:, None], z_axes, x_after_z) * DOF_SIGN[:, None]
        self._axes_hand = axes
        self._pivots_hand = world[DOF_BONE, :3, 3]

    @cached_property
    def facing(self) -> NDArray[np.bool_]:
        """``(S,)`` samples whose outward normal points toward the camera."""
        return np.einsum("ij,ij->i", self.normals, self.points_m) < 0

    def vertex_jacobian(self, sample_ids: ArrayLike) -> NDArray[np.float64]:
        """``(P, 3, 26)`` derivatives of samples (camera frame) by the 26 unknowns."""
        ids = np.asarray(sample_ids, dtype=np.int64)
        weights = self._weights[ids]
        rest = self.samples.mesh.rest_vertices_m[ids]
        # Every sample as each of its bones alone would move it (hand frame).
        linear = self._skinning[..., :3].reshape(N_BONES * 3, 3)
        by_bone = (rest @ linear.T).reshape(-1, N_BONES, 3) + self._skinning[:, :, 3]
        moved = (weights[:, None, :] * MOVES[None]) @ by_bone  # (P, 20, 3)
        share = weights @ MOVES.T  # (P, 20)
        return self._jacobian(self.points_m[ids], moved, share)

    def directional_rows(self, sample_ids: ArrayLike, directions: ArrayLike) -> NDArray[np.float64]:
        """``(P, 26)`` rows ``d_p . J_p``: the derivatives of samples' positions along
        given directions (a point-to-plane residual's normal, a silhouette residual's
        image gradient), by the 26 unknowns.

        The same as projecting :meth:`vertex_jacobian` onto ``directions``, in one
        compiled pass over the samples' bones.

        Parameters
        ----------
        sample_ids : (P,) int
        directions : (P, 3) float
            Camera frame.
        """
        ids = np.ascontiguousarray(sample_ids, dtype=np.int64)
        along = np.ascontiguousarray(directions, dtype=np.float64)
        rows = np.empty((len(ids), N_PARAMS))
        _kernels.directional_vertex_rows(
            ids, self._weights, self.samples.mesh.rest_vertices_m,
            np.ascontiguousarray(self._skinning), MOVES, self._axes_hand, self._pivots_hand,
            self.pose.rotation, self.pose.translation_m,
            np.ascontiguousarray(self.points_m[ids]), along, rows,
        )  # fmt: skip
        return rows

    def keypoint_jacobian(self, keypoint_ids: ArrayLike) -> NDArray[np.float64]:
        """``(K, 3, 26)`` derivatives of keypoints (camera frame) by the 26 unknowns."""
        ids = np.asarray(keypoint_ids, dtype=np.int64)
        share = MOVES[:, KEYPOINT_BONES[ids]].T  # (K, 20)
        moved = share[:, :, None] * self._hand_keypoints[ids][:, None, :]
        return self._jacobian(self.keypoints_m[ids], moved, share)

    def bone_point_jacobian(self, points_m: ArrayLike, bones: ArrayLike) -> NDArray[np.float64]:
        """``(P, 3, 26)`` derivatives of camera-frame points rigidly on given bones."""
        points = as_array("points_m", points_m, (None, 3), np.float64)
        bone = np.asarray(bones, dtype=np.int64)
        share = MOVES[:, bone].T
        hand = (points - self.pose.translation_m) @ self.pose.rotation
        return self._jacobian(points, share[:, :, None] * hand[:, None, :], share)

    def proportion_jacobian(self, sample_ids: ArrayLike) -> NDArray[np.float64]:
        """``(P, 3, 7)`` forward-difference derivatives of samples (camera frame) by
        the hand proportions (:meth:`glovedb.proportions.HandProportions.as_vector`)."""
        ids = np.asarray(sample_ids, dtype=np.int64)
        if self._proportion_jacobian is not None:
            return self._proportion_jacobian[ids]
        model = self.samples.model
        chosen = HandMesh(
            model.skeleton, model.rest_vertices_m[ids], model.faces, model.weights[ids]
        )
        base = self.samples.proportions.as_vector()
        columns = []
        for k in range(N_PROPORTIONS):
            stepped = base.copy()
            stepped[k] += _PROPORTION_STEP
            moved = proportioned_mesh(chosen, HandProportions.from_vector(stepped))
            hand = skin(moved, skinning_matrices(self.pose.posture_rad, moved.skeleton))[0]
            points = hand @ self.pose.rotation.T + self.pose.translation_m
            columns.append(points - self.points_m[ids])
        return np.stack(columns, axis=2) / _PROPORTION_STEP

    def _jacobian(
        self, points: NDArray[np.float64], moved_hand: NDArray[np.float64], share: NDArray
    ) -> NDArray[np.float64]:
        """Assemble ``(P, 3, 26)`` from camera points, and per joint the summed
        bone-moved positions ``(P, 20, 3)`` and weight shares ``(P, 20)`` (hand frame)."""
        R, t = self.pose.rotation, self.pose.translation_m
        arm = moved_hand - share[..., None] * self._pivots_hand  # (P, 20, 3)
        d_angles = np.cross(self._axes_hand[None], arm) @ R.T  # (P, 20, 3)
        d = points - t
        jacobian = np.zeros((len(points), 3, N_PARAMS))
        jacobian[:, 0, 1], jacobian[:, 0, 2] = d[:, 2], -d[:, 1]
        jacobian[:, 1, 0], jacobian[:, 1, 2] = -d[:, 2], d[:, 0]
        jacobian[:, 2, 0], jacobian[:, 2, 1] = d[:, 1], -d[:, 0]
        jacobian[:, [0, 1, 2], [3, 4, 5]] = 1.0
        jacobian[:, :, 6:] = d_angles.transpose(0, 2, 1)
        return jacobian


def _x_after_z(frame: NDArray[np.float64], posture_rad: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(20, 3)``: the x axis of ``frame @ Rz(z_angle)`` for every joint angle, with the
    z angle of that angle's bone (0 for bones without one)."""
    z_angle = np.zeros(N_JOINTS)
    z_of_bone = {1: -posture_rad[1]}
    for finger in range(1, 5):
        z_of_bone[1 + 3 * finger] = posture_rad[4 * finger]
    for joint, bone in enumerate(DOF_BONE):
        z_angle[joint] = z_of_bone.get(int(bone), 0.0)
    # Rz(z) @ e_x = (cos z, sin z, 0)
    return frame[:, :, 0] * np.cos(z_angle)[:, None] + frame[:, :, 1] * np.sin(z_angle)[:, None]
