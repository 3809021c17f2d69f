"""A hand pose from fingertip detections recovers a known pose and names the fingers."""

import numpy as np
import pytest

from fingertips import FINGER_NAMES
from fingertips.pose_guess import (
    _hand_capsules,
    guess_hand_pose,
    hand_points_from_depth,
)
from glovedb.capsules import pose_capsules
from glovedb.hand_model import FINGERTIP_KEYPOINTS, forward_kinematics, make_skeleton
from glovedb.postures import load_named_postures
from tracker.icp import batch_rigid_fit


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _rotation_error_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(a.T @ b) - 1) / 2, -1, 1))))


def _surface_points(posture: np.ndarray, rotation, translation, rng) -> np.ndarray:
    """Points on the posed capsules' surfaces, camera frame."""
    skeleton = make_skeleton()
    capsules = _hand_capsules(skeleton)
    start, end = pose_capsules(capsules, forward_kinematics(posture).bone_transforms[0])
    t = rng.uniform(size=(len(start), 40))
    axis = start[:, None] + t[..., None] * (end - start)[:, None]
    radius = (
        capsules.radius_start_m[:, None]
        + t * (capsules.radius_end_m - capsules.radius_start_m)[:, None]
    )
    direction = rng.normal(size=axis.shape)
    direction /= np.linalg.norm(direction, axis=2, keepdims=True)
    local = (axis + radius[..., None] * direction).reshape(-1, 3)
    return local @ rotation.T + translation


def test_batch_rigid_fit_recovers_rotations() -> None:
    rng = np.random.default_rng(0)
    source = rng.normal(size=(20, 4, 3))
    rotation = np.stack([_random_rotation(rng) for _ in range(20)])
    shift = rng.normal(size=(20, 3))
    target = np.einsum("hij,hmj->hmi", rotation, source) + shift[:, None]
    fitted, moved = batch_rigid_fit(source, target)
    np.testing.assert_allclose(fitted, rotation, atol=1e-9)
    np.testing.assert_allclose(moved, shift, atol=1e-9)


@pytest.mark.parametrize("name", ["open", "peace", "pinch"])
def test_recovers_a_known_pose_with_a_missing_tip_and_a_false_detection(name: str) -> None:
    rng = np.random.default_rng(len(name))
    posture = load_named_postures()[name]
    rotation, translation = _random_rotation(rng), np.array([0.02, -0.03, 0.5])
    tips = forward_kinematics(posture).keypoints_m[0, list(FINGERTIP_KEYPOINTS)]
    camera_tips = tips @ rotation.T + translation + rng.normal(scale=0.003, size=(5, 3))
    order = rng.permutation(5)[:4]  # one finger missed
    detections = np.vstack([camera_tips[order], translation + [0.0, 0.0, -0.03]])
    cloud = _surface_points(posture, rotation, translation, rng)
    guess = guess_hand_pose(detections, posture_rad=posture, hand_points_m=cloud)
    assert guess is not None
    assert _rotation_error_deg(guess.rotation, rotation) < 5.0
    # The wrist is 15-19 cm from the tips: 3 mm of tip noise moves it by about 1 cm.
    assert np.linalg.norm(guess.translation_m - translation) < 0.012
    assert guess.fingers == tuple(FINGER_NAMES[i] for i in order) + (None,)
    assert guess.tip_rms_m < 0.008
    assert guess.surface_rms_m < 0.004
    np.testing.assert_allclose(
        guess.keypoints_3d_m[list(FINGERTIP_KEYPOINTS)][order], camera_tips[order], atol=0.012
    )


def test_hand_points_resolve_a_mirrored_three_tip_fit() -> None:
    rng = np.random.default_rng(4)
    posture = load_named_postures()["open"]
    wrong = 0
    for _ in range(5):
        rotation, translation = _random_rotation(rng), np.array([0.0, 0.0, 0.45])
        tips = forward_kinematics(posture).keypoints_m[0, list(FINGERTIP_KEYPOINTS)]
        detections = (tips @ rotation.T + translation)[1:4]  # index, middle, ring
        cloud = _surface_points(posture, rotation, translation, rng)
        guess = guess_hand_pose(detections, posture_rad=posture, hand_points_m=cloud)
        assert guess is not None
        wrong += _rotation_error_deg(guess.rotation, rotation) > 5.0
    assert wrong == 0


def test_too_few_detections_give_no_guess() -> None:
    assert guess_hand_pose(np.zeros((2, 3)) + [0, 0, 0.5]) is None
    with pytest.raises(ValueError, match="min_matched"):
        guess_hand_pose(np.zeros((4, 3)), min_matched=2)


def test_hand_points_from_depth_keep_the_nearest_object() -> None:
    depth = np.zeros((60, 80), np.float32)
    depth[:, :] = 1.5  # a wall
    depth[20:40, 30:50] = 0.5  # the hand
    points = hand_points_from_depth(depth, (100.0, 100.0, 40.0, 30.0), max_points=100)
    assert 50 <= len(points) <= 100
    np.testing.assert_allclose(points[:, 2], 0.5)
