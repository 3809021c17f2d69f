"""Generative refinement: the Jacobians, and recovery of a perturbed posture."""

import numpy as np
import pytest

from glovedb.camera import KINECT_V1
from glovedb.hand_model import FINGERTIP_KEYPOINTS, JOINT_NAMES, forward_kinematics, make_skeleton
from glovedb.mesh import make_hand_mesh, pose_mesh, skinning_matrices
from glovedb.pattern import load_pattern, split_by_label
from glovedb.postures import named_posture
from glovedb.rotations import axis_angle_to_matrix, geodesic_angle
from tracker.point_cloud import hand_region, labeled_point_cloud
from tracker.refine import (
    _stepped_postures,
    deadband_weights,
    posture_jacobian,
    refine,
    tip_residuals,
)


@pytest.fixture(scope="module")
def coarse_mesh():
    return make_hand_mesh(make_skeleton(), spacing_m=0.003)


@pytest.fixture(scope="module")
def power_view(renderer):
    """The power grasp from a view that hides the little finger behind the others:
    posture, rotation, translation and the rendered labeled point cloud."""
    posture = named_posture("power")
    rotation = axis_angle_to_matrix([1.0, 0.2, 0.3], 2.7)
    translation = np.array([0.02, 0.03, 0.55])
    rendering = renderer.render_labels(posture, rotation, translation)
    cloud = labeled_point_cloud(hand_region(rendering.labels, rendering.depth_m), KINECT_V1)
    return posture, rotation, translation, cloud


def test_posture_jacobian_matches_central_differences(coarse_mesh):
    posture = named_posture("power")
    vertices = np.arange(0, len(coarse_mesh.rest_vertices_m), 97)
    matrices = skinning_matrices(_stepped_postures(posture), coarse_mesh.skeleton)
    jacobian = posture_jacobian(coarse_mesh, matrices, vertices)
    for joint in (0, 5, 10, 19):
        step = np.zeros(20)
        step[joint] = 1e-5
        numeric = pose_mesh(coarse_mesh, posture + step) - pose_mesh(coarse_mesh, posture - step)
        numeric = numeric[vertices] / 2e-5
        np.testing.assert_allclose(jacobian[:, joint], numeric, atol=1e-5)


@pytest.mark.gl
def test_refinement_recovers_a_perturbed_posture(power_view, coarse_mesh):
    posture, rotation, translation, cloud = power_view
    # Joints whose fingers this view shows (the little finger is hidden behind the
    # others here: nothing could correct it).
    joints = [JOINT_NAMES.index(n) for n in ("index_mcp_flex", "middle_pip_flex", "ring_mcp_flex")]
    wrong = posture.copy()
    wrong[joints] += np.radians([12.0, -12.0, 12.0])
    result = refine(
        cloud.points_m[::3], cloud.labels[::3], coarse_mesh,
        split_by_label(coarse_mesh, load_pattern()), wrong, rotation, translation,
        iterations=6, prior_weight=0.005,
    )  # fmt: skip
    joint_errors = np.degrees(np.abs(result.posture_rad - posture))[joints]
    assert np.all(joint_errors < 4.0), joint_errors
    # From 1.8 degrees mean over all 20 angles to under a third of that.
    assert np.degrees(np.abs(result.posture_rad - posture)).mean() < 0.6
    assert np.degrees(geodesic_angle(result.rotation, rotation)) < 0.5
    assert np.linalg.norm(result.translation_m - translation) < 0.001


@pytest.mark.gl
def test_fingertip_targets_correct_a_finger_the_cloud_does_not_show(power_view, coarse_mesh):
    posture, rotation, translation, cloud = power_view
    # The little finger is hidden in this view (see the test above): only its
    # fingertip target can correct it.
    joints = [JOINT_NAMES.index(n) for n in ("little_mcp_flex", "little_pip_flex")]
    wrong = posture.copy()
    wrong[joints] -= np.radians(25.0)
    truth_tips = _camera_tips(coarse_mesh, posture, rotation, translation)
    targets = np.full((5, 3), np.nan)
    targets[4] = truth_tips[4]
    errors = {}
    runs = {"without": (None, 0.0), "with": (targets, 0.0), "band": (targets, 0.01)}
    for name, (tip_targets, band) in runs.items():
        result = refine(
            cloud.points_m[::3], cloud.labels[::3], coarse_mesh,
            split_by_label(coarse_mesh, load_pattern()), wrong, rotation, translation,
            iterations=6, prior_weight=0.005, tip_targets_m=tip_targets, tip_deadband_m=band,
        )  # fmt: skip
        tips = _camera_tips(coarse_mesh, result.posture_rad, result.rotation, result.translation_m)
        errors[name] = np.linalg.norm(tips - truth_tips, axis=1)
        assert np.degrees(geodesic_angle(result.rotation, rotation)) < 1.0
    assert errors["without"][4] > 0.02  # metres
    assert errors["with"][4] < 0.004
    assert errors["with"][:4].max() < 0.004  # the other fingers stay where the cloud puts them
    # With a 1 cm dead band the tip is pulled to about 1 cm from its target.
    assert 0.006 < errors["band"][4] < 0.013


def test_deadband_weights():
    residual = np.array([0.003, 0.004, 0.0, 0.0, 0.0, 0.02, 0.0, 0.0, 0.0])  # 5 mm, 2 cm, 0
    weights = deadband_weights(residual, 0.01)
    np.testing.assert_allclose(
        weights, [0, 0, 0, np.sqrt(0.5), np.sqrt(0.5), np.sqrt(0.5), 0, 0, 0]
    )
    np.testing.assert_array_equal(deadband_weights(residual, 0.0), np.ones(9))
    # The weighted squared residual is the loss's Gauss-Newton form: |r| (|r| - band).
    weighted = weights[3:6] * residual[3:6]
    assert weighted @ weighted == pytest.approx(0.02 * (0.02 - 0.01))


def _camera_tips(mesh, posture, rotation, translation):
    tips = forward_kinematics(posture, mesh.skeleton).keypoints_m[0, FINGERTIP_KEYPOINTS]
    return tips @ rotation.T + translation


def test_tip_jacobian_matches_central_differences(coarse_mesh):
    posture = named_posture("pinch")
    rotation = axis_angle_to_matrix([0.3, -1.0, 0.4], 1.1)
    translation = np.array([0.01, -0.02, 0.5])
    targets = np.full((5, 3), np.nan)
    targets[[0, 3]] = [[0.0, 0.0, 0.5], [0.02, 0.01, 0.45]]  # thumb and ring only
    residual, jacobian = tip_residuals(
        coarse_mesh, _stepped_postures(posture), rotation, translation, targets
    )
    tips = _camera_tips(coarse_mesh, posture, rotation, translation)[[0, 3]]
    np.testing.assert_allclose(residual, (tips - targets[[0, 3]]).ravel())
    for column in range(26):
        step = np.zeros(26)
        step[column] = 1e-6
        moved = []
        for sign in (1.0, -1.0):
            delta = sign * step
            angle = np.linalg.norm(delta[:3])
            turn = axis_angle_to_matrix(delta[:3], angle) if angle > 0 else np.eye(3)
            moved.append(_camera_tips(coarse_mesh, posture + delta[6:], turn @ rotation,
                                      turn @ translation + delta[3:6])[[0, 3]])  # fmt: skip
        numeric = (moved[0] - moved[1]).ravel() / 2e-6
        np.testing.assert_allclose(jacobian[:, column], numeric, atol=2e-4)


def test_tip_residuals_without_targets_are_empty(coarse_mesh):
    residual, jacobian = tip_residuals(
        coarse_mesh, _stepped_postures(named_posture("open")), np.eye(3), np.zeros(3),
        np.full((5, 3), np.nan),
    )  # fmt: skip
    assert residual.shape == (0,) and jacobian.shape == (0, 26)
