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
joint's rotation (:func:`glovedb.hand_model.bone_angles`).

The model surface is a set of samples of the skinned glove mesh (vertex positions,
rest normals and color classes), posed without the mesh's faces: normals follow the
blended bone rotations. Hand proportions (:mod:`glovedb.proportions`) re-rest the
samples; their derivatives (:meth:`PosedHand.proportion_jacobian`,
:mod:`tracker.generative.proportion_derivatives`) are forward differences, used only
while a user's proportions are estimated.

The fit poses the hand several times per frame: posing the samples, their Jacobian
rows and the keypoints' Jacobians are compiled loops (:mod:`tracker.generative._kernels`),
and what does not change with the pose (the inverse rest transforms, the weights) is
kept with the samples.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array
from glovedb.capsules import CapsuleSet, finger_capsules
from glovedb.hand_model import (
    BONE_PARENTS,
    N_BONES,
    N_JOINTS,
    N_KEYPOINTS,
    Skeleton,
    forward_kinematics,
)
from glovedb.mesh import HandMesh, vertex_normals
from glovedb.pattern import LabeledVertices
from glovedb.proportions import HandProportions, proportioned_mesh
from glovedb.rotations import axis_angle_to_matrix
from tracker.generative import _kernels
from tracker.generative.proportion_derivatives import ProportionDerivatives

N_PARAMS = 6 + N_JOINTS
"""Unknowns of one frame's fit: rotation step (3), translation step (3), angles (20)."""


def _dof_table() -> tuple[NDArray[np.int64], NDArray[np.bool_], NDArray[np.float64]]:
    """For every joint angle: its bone, whether it is the bone's z (else x) rotation,
    and its sign in :func:`glovedb.hand_model.bone_angles`."""
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
_DOF_PARENT = np.array([BONE_PARENTS[b] for b in DOF_BONE], dtype=np.int64)
"""The parent bone of every joint angle's bone (-1 for none)."""
_Z_JOINT = np.array(
    [max(np.flatnonzero(DOF_ABOUT_Z & (DOF_BONE == bone)), default=-1) for bone in DOF_BONE]
)
"""The angle that turns every joint angle's bone about z (-1 for none)."""


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


def _movers() -> NDArray[np.int64]:
    """``(16, K)``: the joint angles that move each bone (:data:`MOVES`), -1 padded."""
    movers = np.full((N_BONES, int(MOVES.sum(axis=0).max())), -1, dtype=np.int64)
    for bone in range(N_BONES):
        joints = np.flatnonzero(MOVES[:, bone])
        movers[bone, : len(joints)] = joints
    return movers


MOVERS = _movers()

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
        """The same samples re-rested for a personal hand.

        What does not depend on the proportions (the skinning weights and their bone
        lists, the model's rest transforms) is computed once, on these samples, and
        carried over: a calibrating fit makes new samples at every step, and the
        tracker makes new ones from its model's at every calibrating frame (computing
        them for each cost 0.8 ms a frame).
        """
        samples = replace(
            self, mesh=proportioned_mesh(self.model, proportions), proportions=proportions
        )
        if samples.mesh.weights is self.mesh.weights:  # proportioned_mesh keeps them
            for name in _SHAPE_FREE:
                samples.__dict__[name] = getattr(self, name)
        return samples

    @cached_property
    def finger_capsules(self) -> CapsuleSet:
        """The round cones of the fingers on the samples' skeleton
        (:func:`glovedb.capsules.finger_capsules`)."""
        return finger_capsules(self.skeleton)

    @cached_property
    def _weights(self) -> NDArray[np.float64]:
        """``(S, 16)`` the skinning weights as float64, C order."""
        return np.ascontiguousarray(self.mesh.weights, dtype=np.float64)

    @cached_property
    def _bone_lists(self) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Each sample's bones of non-zero weight, ascending, and those weights, as
        ``(S, B)`` arrays (``B`` the most bones of one sample; -1 and 0 pad), the
        model's as well as the mesh's (re-resting keeps the weights): the compiled
        passes blend over these instead of testing all 16 weights (0.145 -> 0.107 ms
        to pose the 3,771 samples of the default mesh, the same sums)."""
        weights = self._weights
        used = weights != 0.0
        width = max(int(used.sum(axis=1).max(initial=0)), 1)
        # A stable sort puts each row's used bones first, in ascending order.
        order = np.argsort(~used, axis=1, kind="stable")[:, :width]
        kept = np.take_along_axis(used, order, axis=1)
        bones = np.where(kept, order, -1).astype(np.int64)
        return bones, np.where(kept, np.take_along_axis(weights, order, axis=1), 0.0)

    @cached_property
    def model_rest_inverse(self) -> NDArray[np.float64]:
        """``(16, 4, 4)`` inverse bone transforms at rest of the model's skeleton."""
        rest = forward_kinematics(np.zeros(N_JOINTS), self.model.skeleton).bone_transforms[0]
        return np.asarray(np.linalg.inv(rest), dtype=np.float64)

    @cached_property
    def _rest_inverse(self) -> NDArray[np.float64]:
        """``(16, 4, 4)`` inverse bone transforms at rest: the skinning matrices of a
        pose are its ``hand_T_bone`` times these (the same for every pose)."""
        rest = forward_kinematics(np.zeros(N_JOINTS), self.skeleton).bone_transforms[0]
        return np.asarray(np.linalg.inv(rest), dtype=np.float64)


_SHAPE_FREE = ("_weights", "_bone_lists", "model_rest_inverse")
"""The cached properties of :class:`HandSamples` that its proportions do not change."""


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
    proportion_derivatives : ProportionDerivatives, optional
        The samples' derivatives by the proportions at a nearby pose (a fit's start),
        for :meth:`proportion_jacobian`; by default those at this pose.

    Attributes
    ----------
    points_m : (S, 3) float64
        Samples, camera frame.
    normals : (S, 3) float64
        Their unit normals, camera frame.
    facing : (S,) bool
        Samples whose outward normal points toward the camera (``n . p < 0``).
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
        proportion_derivatives: ProportionDerivatives | None = None,
    ) -> None:
        self.samples = samples
        self.pose = pose
        self._proportion_derivatives = proportion_derivatives
        R, t = pose.rotation, pose.translation_m
        kinematics = forward_kinematics(pose.posture_rad, samples.skeleton)
        world = kinematics.bone_transforms[0]  # (16, 4, 4) hand_T_bone
        self.bone_transforms = world
        self._skinning = np.ascontiguousarray((world @ samples._rest_inverse)[:, :3, :])
        self._bones, self._bone_weights = samples._bone_lists
        self._rest = np.ascontiguousarray(samples.mesh.rest_vertices_m, dtype=np.float64)
        self._rotation = np.ascontiguousarray(R, dtype=np.float64)
        count = len(samples)
        self.points_m = np.empty((count, 3))
        self.normals = np.empty((count, 3))
        self.facing = np.empty(count, dtype=bool)
        _kernels.pose_samples(
            self._bones, self._bone_weights, self._rest,
            np.ascontiguousarray(samples.rest_normals, dtype=np.float64), self._skinning,
            self._rotation, np.ascontiguousarray(t, dtype=np.float64), self.points_m,
            self.normals, self.facing,
        )  # fmt: skip
        self.keypoints_m = kinematics.keypoints_m[0] @ R.T + t
        self._hand_keypoints = kinematics.keypoints_m[0]
        # Joint axes and pivots (hand frame).
        parent_rotation = world[np.maximum(_DOF_PARENT, 0), :3, :3]
        frame = parent_rotation @ samples.skeleton.rest_before[DOF_BONE]
        z_axes = frame[:, :, 2]
        x_after_z = _x_after_z(frame, pose.posture_rad)
        axes = np.where(DOF_ABOUT_Z[:, None], z_axes, x_after_z) * DOF_SIGN[:, None]
        self._axes_hand = axes
        self._pivots_hand = world[DOF_BONE, :3, 3]

    def vertex_jacobian(self, sample_ids: ArrayLike) -> NDArray[np.float64]:
        """``(P, 3, 26)`` derivatives of samples (camera frame) by the 26 unknowns."""
        ids = np.asarray(sample_ids, dtype=np.int64)
        weights = self.samples._weights[ids]
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
            ids, self._bones, self._bone_weights, self._rest, self._skinning, MOVERS,
            self._axes_hand, self._pivots_hand, self._rotation, self.pose.translation_m,
            np.ascontiguousarray(self.points_m[ids]), along, rows,
        )  # fmt: skip
        return rows

    def plane_distances(self, sample_ids: ArrayLike, targets_m: ArrayLike) -> NDArray[np.float64]:
        """``(P,)`` distances ``(p_s - q) . n_s`` of points to the tangent planes of
        samples, positive where the point lies behind the plane: :meth:`plane_rows`'s
        first output, to the bit, without the rows.

        Parameters
        ----------
        sample_ids : (P,) int
        targets_m : (P, 3) float
            Camera frame.
        """
        ids = np.ascontiguousarray(sample_ids, dtype=np.int64)
        targets = np.ascontiguousarray(targets_m, dtype=np.float64)
        distance = np.empty(len(ids))
        _kernels.plane_distances(ids, targets, self.points_m, self.normals, distance)
        return distance

    def plane_rows(
        self, sample_ids: ArrayLike, targets_m: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Distances of points to the tangent planes of samples, and their derivatives.

        ``(p_s - q) . n_s`` for every pair of a sample ``s`` and a point ``q``, and the
        rows ``n_s . J_s`` of :meth:`directional_rows` along each sample's normal (the
        normal held fixed, as point-to-plane ICP does), in one compiled pass that
        computes the row of a sample paired several times once.

        Parameters
        ----------
        sample_ids : (P,) int
        targets_m : (P, 3) float
            Camera frame.

        Returns
        -------
        distance_m : (P,) float64
            Positive where the point lies behind the plane (against the normal).
        rows : (P, 26) float64
        """
        ids = np.ascontiguousarray(sample_ids, dtype=np.int64)
        targets = np.ascontiguousarray(targets_m, dtype=np.float64)
        distance = np.empty(len(ids))
        rows = np.empty((len(ids), N_PARAMS))
        _kernels.plane_rows(
            ids, targets, self._bones, self._bone_weights, self._rest, self._skinning, MOVERS,
            self._axes_hand, self._pivots_hand, self._rotation, self.pose.translation_m,
            self.points_m, self.normals, distance, rows,
        )  # fmt: skip
        return distance, rows

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
        the hand proportions (:mod:`tracker.generative.proportion_derivatives`), from
        :attr:`proportion_derivatives`."""
        return self.proportion_derivatives.rows(sample_ids)

    @property
    def proportion_derivatives(self) -> ProportionDerivatives:
        """The samples' derivatives by the proportions: those given when posing (at a
        nearby pose), else at this pose, made when first asked for; each sample's are
        computed when first asked for and kept."""
        if self._proportion_derivatives is None:
            samples = self.samples
            self._proportion_derivatives = ProportionDerivatives(
                self._bones, self._bone_weights, samples.model.rest_vertices_m,
                samples.model.skeleton, samples.model_rest_inverse, samples.proportions,
                self.pose.posture_rad, self.pose.rotation,
            )  # fmt: skip
        return self._proportion_derivatives

    def _jacobian(
        self, points: NDArray[np.float64], moved_hand: NDArray[np.float64], share: NDArray
    ) -> NDArray[np.float64]:
        """Assemble ``(P, 3, 26)`` from camera points, and per joint the summed
        bone-moved positions ``(P, 20, 3)`` and weight shares ``(P, 20)`` (hand frame)."""
        jacobian = np.zeros((len(points), 3, N_PARAMS))
        _kernels.point_jacobians(
            np.ascontiguousarray(points, dtype=np.float64),
            np.ascontiguousarray(moved_hand, dtype=np.float64),
            np.ascontiguousarray(share, dtype=np.float64), self._axes_hand, self._pivots_hand,
            self._rotation, self.pose.translation_m, jacobian,
        )  # fmt: skip
        return jacobian


def _x_after_z(frame: NDArray[np.float64], posture_rad: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(20, 3)``: the x axis of ``frame @ Rz(z_angle)`` for every joint angle, with the
    z angle of that angle's bone (0 for bones without one)."""
    z_angle = np.where(_Z_JOINT >= 0, DOF_SIGN[_Z_JOINT] * posture_rad[_Z_JOINT], 0.0)
    # Rz(z) @ e_x = (cos z, sin z, 0)
    return frame[:, :, 0] * np.cos(z_angle)[:, None] + frame[:, :, 1] * np.sin(z_angle)[:, None]
