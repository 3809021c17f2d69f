"""Generative refinement of posture and pose: articulated, color-sensitive ICP.

After the database lookup and the rigid ICP, the looked-up posture is only as good as
the database's nearest postures and their blend. This step fits all 26 degrees of
freedom (20 joint angles and the 6D pose) to the labeled point cloud:

- correspondences as in :mod:`tracker.icp`: each observed point with the nearest
  camera-facing model vertex of its own color class (one k-d tree for all classes,
  :func:`tracker.icp.class_tree`), pairs beyond a gate dropped;
- residuals: distance of the observed point to the model vertex's tangent plane;
- Jacobians: the rigid part as in point-to-plane ICP; for the joint angles,
  derivatives of the skinned vertices ``sum_b w_b dM_b/dtheta v_rest`` with the
  skinning matrices' derivatives taken by finite differences (exact for linear
  blend skinning up to O(h));
- optionally, fingertip detections (:mod:`tracker.fingertips`) named by Eq. 11 of
  Tzionas et al. 2014 pull the model's fingertips toward them: three residuals per
  named finger, the 3D distance of the model's tip to its detection beyond a dead
  band (``tip_deadband_m``), weighted by ``tip_weight`` (the salient-point term of
  Tzionas et al.);
- a prior pulls the angles toward the looked-up posture (``prior_weight`` per radian,
  against residuals in metres), Levenberg-Marquardt damping keeps steps small, and
  the joint limits clip every step.

A few Gauss-Newton iterations suffice because the rigid ICP has already aligned the
hand; each iteration costs one skinning of the mesh.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array
from glovedb.hand_model import FINGERTIP_KEYPOINTS, N_JOINTS, clip_to_limits, forward_kinematics
from glovedb.mesh import HandMesh, skin, skinning_matrices, vertex_normals
from glovedb.pattern import LabeledVertices
from glovedb.rotations import axis_angle_to_matrix
from tracker.icp import class_coordinate, class_tree

_STEP_RAD = 1e-4


@dataclass(frozen=True)
class RefinementResult:
    """Outcome of :func:`refine`.

    Attributes
    ----------
    posture_rad : (20,) float64
    rotation : (3, 3) float64
    translation_m : (3,) float64
    cost_m : float
        RMS point-to-plane distance of the kept pairs before the last step.
    iterations : int
    """

    posture_rad: NDArray[np.float64]
    rotation: NDArray[np.float64]
    translation_m: NDArray[np.float64]
    cost_m: float
    iterations: int


def posture_jacobian(
    mesh: HandMesh, matrices: NDArray[np.float64], vertices: NDArray[np.int64]
) -> NDArray[np.float64]:
    """Derivatives of skinned vertices with respect to the joint angles.

    Parameters
    ----------
    mesh : HandMesh
    matrices : (21, 16, 3, 4) float
        Skinning matrices of the posture and of the posture with each angle in turn
        raised by ``_STEP_RAD`` (:func:`_stepped_postures`).
    vertices : (P,) int
        Mesh vertex indices.

    Returns
    -------
    (P, 20, 3) float64
        Hand frame, metres per radian.
    """
    derivative = (matrices[1:] - matrices[0]) / _STEP_RAD  # (20, 16, 3, 4)
    rest = np.concatenate([mesh.rest_vertices_m[vertices], np.ones((len(vertices), 1))], axis=1)
    weights = mesh.weights[vertices].astype(np.float64)
    # Blend per vertex with one (P, 16) @ (16, 20 * 12) product, then apply to the vertex.
    flat = derivative.transpose(1, 0, 2, 3).reshape(derivative.shape[1], -1)
    blended = (weights @ flat).reshape(len(vertices), N_JOINTS, 3, 4)
    return np.einsum("pjkl,pl->pjk", blended, rest)


def _stepped_postures(posture_rad: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(21, 20)``: the posture and the posture with each angle in turn raised by a step."""
    return posture_rad + np.vstack([np.zeros(N_JOINTS), _STEP_RAD * np.eye(N_JOINTS)])


def tip_residuals(
    mesh: HandMesh,
    stepped_rad: NDArray[np.float64],
    rotation: NDArray[np.float64],
    translation_m: NDArray[np.float64],
    targets_m: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Residuals and Jacobian of the model's fingertips against their targets.

    Parameters
    ----------
    mesh : HandMesh
        Its skeleton gives the fingertips (keypoints 4, 8, 12, 16, 20).
    stepped_rad : (21, 20) float
        The posture and its single-angle steps (:func:`_stepped_postures`).
    rotation, translation_m : (3, 3), (3,) float
        Pose ``p_cam = R @ p_hand + t``.
    targets_m : (5, 3) float
        Camera-frame target of each finger's tip, thumb first; NaN rows have none.

    Returns
    -------
    residual : (3F,) float64
        Model tip minus target, metres, for the F fingers with a target.
    jacobian : (3F, 26) float64
        Derivatives with respect to the rotation step (axis-angle, applied on the
        left), the translation step and the 20 joint angles, as in :func:`refine`.
    """
    named = np.flatnonzero(np.isfinite(targets_m).all(axis=1))
    if len(named) == 0:
        return np.zeros(0), np.zeros((0, 6 + N_JOINTS))
    tips = forward_kinematics(stepped_rad, mesh.skeleton).keypoints_m[:, FINGERTIP_KEYPOINTS]
    tips = tips[:, named]  # (21, F, 3), hand frame
    points = tips[0] @ rotation.T + translation_m
    d_tips = ((tips[1:] - tips[0]) / _STEP_RAD) @ rotation.T  # (20, F, 3), camera frame
    skew = np.zeros((len(named), 3, 3))  # d(turn @ x)/d(axis) = -[x]_x
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = points[:, 2], -points[:, 1], points[:, 0]
    skew[:, 1, 0], skew[:, 2, 0], skew[:, 2, 1] = -points[:, 2], points[:, 1], -points[:, 0]
    jacobian = np.concatenate(
        [skew, np.broadcast_to(np.eye(3), skew.shape), d_tips.transpose(1, 2, 0)], axis=2
    )
    residual = points - targets_m[named]
    return residual.reshape(-1), jacobian.reshape(-1, 6 + N_JOINTS)


def deadband_weights(residual: ArrayLike, deadband_m: float) -> NDArray[np.float64]:
    """Row weights that make 3D residuals cost ``(|r| - deadband)**2`` beyond the band.

    Iteratively reweighted least squares for the loss ``max(0, |r| - deadband)**2``:
    each 3D residual's rows get the weight ``sqrt(max(0, 1 - deadband / |r|))``, so a
    residual within the band adds nothing and a long one is pulled back to the band's
    edge, not to zero.

    Parameters
    ----------
    residual : (3F,) float
        F stacked 3D residuals, metres.
    deadband_m : float
        Metres; 0 gives weights of 1 (plain least squares).

    Returns
    -------
    (3F,) float64
    """
    size = np.linalg.norm(np.asarray(residual, dtype=np.float64).reshape(-1, 3), axis=1)
    if deadband_m == 0:
        return np.ones(3 * len(size))
    share = 1.0 - deadband_m / np.maximum(size, np.finfo(np.float64).tiny)
    return np.sqrt(np.clip(share, 0.0, None)).repeat(3)


def refine(
    observed_m: ArrayLike,
    observed_labels: ArrayLike,
    mesh: HandMesh,
    split: LabeledVertices,
    posture_rad: ArrayLike,
    rotation: ArrayLike,
    translation_m: ArrayLike,
    *,
    iterations: int = 4,
    prior_weight: float = 0.004,
    damping: float = 1e-6,
    gate_m: float = 0.015,
    start_surface: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
    tip_targets_m: ArrayLike | None = None,
    tip_weight: float = 4.0,
    tip_deadband_m: float = 0.015,
) -> RefinementResult:
    """Fit posture and pose to the labeled point cloud (see the module docstring).

    Parameters
    ----------
    observed_m : (N, 3) float
        Point cloud, camera frame.
    observed_labels : (N,) uint8
    mesh : HandMesh
    split : LabeledVertices
        The mesh's vertices split by class (:func:`glovedb.pattern.split_by_label`).
    posture_rad : (20,) float
        Start, and the prior's centre.
    rotation, translation_m : (3, 3), (3,) float
        Start pose ``p_cam = R @ p_hand + t``.
    iterations : int
    prior_weight : float
        Metres of residual one radian of departure from the start posture is worth.
    damping : float
        Levenberg-Marquardt damping added to the normal equations' diagonal.
    gate_m : float
        Pairs farther apart are not used.
    start_surface : ((V, 3), (V, 3)) float, optional
        The mesh's vertices and normals (hand frame) already skinned for
        ``posture_rad``, to save the first iteration's skinning.
    tip_targets_m : (5, 3) float, optional
        Camera-frame targets of the model's fingertips (thumb first), e.g. fingertip
        detections named by :func:`tracker.fingertips.detect.name_fingers`; NaN rows
        (fingers without a detection) add nothing.
    tip_weight : float
        Weight of a fingertip residual against one point-to-plane residual: a named
        detection counts like ``tip_weight**2`` cloud points on each axis.
    tip_deadband_m : float
        A model fingertip this close to its target is not pulled (see
        :func:`deadband_weights`). The named detections of the shipped model lie a
        median 8-9 mm from the true tips on the synthetic sequences, farther than the
        color fit's tips (5-6 mm), so they should only correct larger errors.

    Returns
    -------
    RefinementResult
    """
    observed = as_array("observed_m", observed_m, (None, 3), np.float64, finite=True)
    labels = as_array("observed_labels", observed_labels, (len(observed),), kind="iu")
    prior = as_array("posture_rad", posture_rad, (N_JOINTS,), np.float64, finite=True)
    theta = prior.copy()
    R = as_array("rotation", rotation, (3, 3), np.float64, finite=True).copy()
    t = as_array("translation_m", translation_m, (3,), np.float64, finite=True).copy()
    targets = np.full((len(FINGERTIP_KEYPOINTS), 3), np.nan)
    if tip_targets_m is not None:
        targets = as_array("tip_targets_m", tip_targets_m, targets.shape, np.float64)
    if not 0 <= tip_weight < np.inf:
        raise ValueError(f"tip_weight: expected 0 or more, got {tip_weight}")
    if not 0 <= tip_deadband_m < np.inf:
        raise ValueError(f"tip_deadband_m: expected 0 or more, got {tip_deadband_m}")
    observed_class_m = class_coordinate(labels)
    cost = np.inf
    done = 0
    for iteration in range(1, iterations + 1):
        done = iteration
        stepped = _stepped_postures(theta)
        matrices = skinning_matrices(stepped, mesh.skeleton)
        if iteration == 1 and start_surface is not None:
            hand, normals = start_surface
        else:
            hand = skin(mesh, matrices[:1])[0]
            normals = vertex_normals(hand, mesh.faces)
        model, model_normals = hand[split.source_vertex], normals[split.source_vertex]
        camera_in_hand = -R.T @ t
        front = np.einsum("ij,ij->i", model_normals, model - camera_in_hand) < 0
        in_hand = (observed - t) @ R
        members = np.flatnonzero(front)
        if len(members) == 0:
            break
        tree = class_tree(model[members], split.labels[members])
        distance, nearest = tree.query(np.column_stack([in_hand, observed_class_m]))
        row = np.flatnonzero(distance < gate_m)  # another class is 100 m away
        if len(row) < 30:
            break
        vertex = members[nearest[row]]
        points = model[vertex] @ R.T + t
        plane_normals = model_normals[vertex] @ R.T
        residual = np.einsum("ij,ij->i", points - observed[row], plane_normals)
        cost = float(np.sqrt(np.mean(residual**2)))
        d_points = posture_jacobian(mesh, matrices, split.source_vertex[vertex]) @ R.T
        jacobian = np.concatenate(
            [
                np.cross(points, plane_normals),
                plane_normals,
                np.einsum("pjk,pk->pj", d_points, plane_normals),
            ],
            axis=1,
        )
        tip_residual, tip_jacobian = tip_residuals(mesh, stepped, R, t, targets)
        tip_rows = tip_weight * deadband_weights(tip_residual, tip_deadband_m)
        jacobian = np.concatenate([jacobian, tip_rows[:, None] * tip_jacobian])
        residual = np.concatenate([residual, tip_rows * tip_residual])
        normal = jacobian.T @ jacobian
        gradient = jacobian.T @ residual
        normal[6:, 6:] += prior_weight**2 * np.eye(N_JOINTS)
        gradient[6:] += prior_weight**2 * (theta - prior)
        normal += damping * np.eye(len(normal))
        step = -np.linalg.solve(normal, gradient)
        angle = float(np.linalg.norm(step[:3]))
        turn = axis_angle_to_matrix(step[:3], angle) if angle > 0 else np.eye(3)
        R, t = turn @ R, turn @ t + step[3:6]
        theta = clip_to_limits(theta + step[6:])
    return RefinementResult(theta, R, t, cost, done)
