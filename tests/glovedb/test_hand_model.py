"""Forward kinematics, joint limits and the skeleton against hand-computed cases."""

import numpy as np
import pytest

from glovedb.hand_model import (
    BONE_PARENTS,
    FINGERTIP_KEYPOINTS,
    JOINT_NAMES,
    KEYPOINT_NAMES,
    clip_to_limits,
    forward_kinematics,
    joint_limits_rad,
    make_skeleton,
    within_limits,
)
from glovedb.rotations import rotation_x, rotation_z

# Keypoint chains: consecutive keypoints of each finger (CMC/MCP ... tip).
CHAINS = [[1 + 4 * f + j for j in range(4)] for f in range(5)]


def random_postures(count: int, seed: int = 0) -> np.ndarray:
    limits = joint_limits_rad()
    return np.random.default_rng(seed).uniform(limits[:, 0], limits[:, 1], (count, 20))


def test_names_follow_conventions():
    assert len(JOINT_NAMES) == 20 and JOINT_NAMES[0] == "thumb_cmc_abd"
    assert JOINT_NAMES[19] == "little_dip_flex"
    assert len(KEYPOINT_NAMES) == 21 and KEYPOINT_NAMES[4] == "thumb_tip"
    assert [KEYPOINT_NAMES[i] for i in FINGERTIP_KEYPOINTS] == [
        "thumb_tip", "index_tip", "middle_tip", "ring_tip", "little_tip",
    ]  # fmt: skip
    assert BONE_PARENTS[1] == 0 and BONE_PARENTS[3] == 2


def test_zero_posture_is_flat_open_hand():
    skeleton = make_skeleton(0.2)
    keypoints = forward_kinematics(np.zeros(20), skeleton).keypoints_m[0]
    np.testing.assert_allclose(keypoints[0], 0.0, atol=1e-12)
    # Middle finger straight along +y, tip at the hand length.
    np.testing.assert_allclose(keypoints[9:13, [0, 2]], 0.0, atol=1e-12)
    np.testing.assert_allclose(keypoints[12, 1], 0.2, atol=1e-9)
    # Every finger lies in the palm plane; the thumb's side is -x (right hand).
    np.testing.assert_allclose(keypoints[5:, 2], 0.0, atol=1e-12)
    assert (
        keypoints[4, 0] < keypoints[8, 0] < keypoints[12, 0] < keypoints[16, 0] < keypoints[20, 0]
    )


def test_mcp_flexion_of_90_degrees_points_the_finger_into_the_palm():
    skeleton = make_skeleton()
    posture = np.zeros(20)
    posture[JOINT_NAMES.index("middle_mcp_flex")] = np.pi / 2
    keypoints = forward_kinematics(posture, skeleton).keypoints_m[0]
    mcp = keypoints[9]
    finger_length = skeleton.lengths_m[7:10].sum()
    np.testing.assert_allclose(keypoints[12], mcp + [0.0, 0.0, -finger_length], atol=1e-12)


def test_single_joint_rotations_match_rotation_matrices():
    skeleton = make_skeleton()
    rest = forward_kinematics(np.zeros(20), skeleton).keypoints_m[0]
    angle = 0.4
    # Index PIP flexion rotates the DIP and tip about the PIP by -angle about the
    # finger's x axis; the index rests yawed by +6 degrees about z.
    posture = np.zeros(20)
    posture[JOINT_NAMES.index("index_pip_flex")] = angle
    keypoints = forward_kinematics(posture, skeleton).keypoints_m[0]
    yaw = rotation_z(np.radians(6.0))
    rotation = yaw @ rotation_x(-angle) @ yaw.T
    pip = rest[6]
    np.testing.assert_allclose(keypoints[7:9], (rest[7:9] - pip) @ rotation.T + pip, atol=1e-12)
    np.testing.assert_allclose(keypoints[:7], rest[:7], atol=1e-12)
    # Abduction turns the whole finger about +z at the MCP, toward the thumb (-x).
    posture = np.zeros(20)
    posture[JOINT_NAMES.index("ring_mcp_abd")] = angle
    keypoints = forward_kinematics(posture, skeleton).keypoints_m[0]
    mcp = rest[13]
    np.testing.assert_allclose(
        keypoints[14:17], (rest[14:17] - mcp) @ rotation_z(angle).T + mcp, atol=1e-12
    )
    assert keypoints[16, 0] < rest[16, 0]


def test_thumb_signs_follow_conventions():
    rest = forward_kinematics(np.zeros(20)).keypoints_m[0]

    def tip(joint: str, degrees: float) -> np.ndarray:
        posture = np.zeros(20)
        posture[JOINT_NAMES.index(joint)] = np.radians(degrees)
        return forward_kinematics(posture).keypoints_m[0, 4]

    assert tip("thumb_cmc_flex", 30)[0] > rest[4, 0] + 0.02  # across toward the little finger
    assert tip("thumb_cmc_abd", 30)[2] < rest[4, 2] - 0.02  # out of the palm plane, palm side
    flexed = tip("thumb_ip_flex", 60)
    assert flexed[2] < rest[4, 2] - 0.01 and flexed[0] > rest[4, 0]  # curls toward the palm


def test_bone_lengths_are_preserved_under_any_posture():
    skeleton = make_skeleton(0.17)
    rest = forward_kinematics(np.zeros(20), skeleton).keypoints_m[0]
    keypoints = forward_kinematics(random_postures(50), skeleton).keypoints_m
    for chain in CHAINS:
        rest_lengths = np.linalg.norm(np.diff(rest[chain], axis=0), axis=-1)
        lengths = np.linalg.norm(np.diff(keypoints[:, chain], axis=1), axis=-1)
        np.testing.assert_allclose(
            lengths, np.broadcast_to(rest_lengths, lengths.shape), atol=1e-12
        )
    # The palm is rigid: wrist, CMC and MCPs do not move with the posture, except the
    # thumb's MCP which the CMC joint moves.
    np.testing.assert_allclose(keypoints[:, [0, 1, 5, 9, 13, 17]], np.broadcast_to(
        rest[[0, 1, 5, 9, 13, 17]], (50, 6, 3)), atol=1e-12)  # fmt: skip


def test_batch_equals_one_by_one_and_transforms_are_rigid():
    postures = random_postures(5, seed=1)
    batch = forward_kinematics(postures)
    for index, posture in enumerate(postures):
        single = forward_kinematics(posture)
        np.testing.assert_allclose(single.keypoints_m[0], batch.keypoints_m[index], atol=1e-12)
    rotations = batch.bone_transforms[..., :3, :3]
    identity = np.broadcast_to(np.eye(3), rotations.shape)
    np.testing.assert_allclose(rotations @ np.swapaxes(rotations, -1, -2), identity, atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(rotations), 1.0, atol=1e-12)


def test_hand_length_scales_the_skeleton():
    small = forward_kinematics(random_postures(3), make_skeleton(0.15)).keypoints_m
    large = forward_kinematics(random_postures(3), make_skeleton(0.21)).keypoints_m
    np.testing.assert_allclose(large, small * 0.21 / 0.15, atol=1e-12)


def test_joint_limits():
    limits = joint_limits_rad()
    assert limits.shape == (20, 2) and np.all(limits[:, 0] < limits[:, 1])
    # Flexion limits allow curling toward the palm and a little hyper-extension.
    flexion = [i for i, name in enumerate(JOINT_NAMES) if name.endswith("pip_flex")]
    assert np.all(limits[flexion, 1] > np.radians(90))
    assert within_limits(np.zeros(20))
    too_far = np.zeros(20)
    too_far[JOINT_NAMES.index("index_pip_flex")] = np.radians(150)
    assert not within_limits(too_far)
    clipped = clip_to_limits(np.stack([too_far, -too_far]))
    assert np.all(within_limits(clipped))
    np.testing.assert_allclose(clipped[0, 6], limits[6, 1])


@pytest.mark.parametrize("bad", [np.zeros(19), np.zeros((2, 21)), np.full(20, np.nan)])
def test_bad_postures_raise_naming_the_argument(bad):
    with pytest.raises(ValueError, match="posture_rad"):
        forward_kinematics(bad)


def test_bad_hand_length_raises():
    with pytest.raises(ValueError, match="hand_length_m"):
        make_skeleton(2.0)


def _numpy_forward_kinematics(posture_rad, skeleton):
    """The straightforward numpy chain the compiled kernel replaced (the reference)."""
    from glovedb.hand_model import N_BONES, N_KEYPOINTS, bone_angles

    n = len(posture_rad)
    z_angle, x_angle = bone_angles(posture_rad)
    cz, sz, cx, sx = np.cos(z_angle), np.sin(z_angle), np.cos(x_angle), np.sin(x_angle)
    joints = np.empty((n, N_BONES, 3, 3))
    joints[..., 0, 0], joints[..., 0, 1], joints[..., 0, 2] = cz, -sz * cx, sz * sx
    joints[..., 1, 0], joints[..., 1, 1], joints[..., 1, 2] = sz, cz * cx, -cz * sx
    joints[..., 2, 0], joints[..., 2, 1], joints[..., 2, 2] = 0.0, sx, cx
    local = np.tile(np.eye(4), (n, N_BONES, 1, 1))
    local[:, :, :3, :3] = skeleton.rest_before @ joints @ skeleton.rest_after
    local[:, :, :3, 3] = skeleton.offsets_m
    world = np.empty_like(local)
    world[:, 0] = local[:, 0]
    for bone in range(1, N_BONES):
        world[:, bone] = world[:, BONE_PARENTS[bone]] @ local[:, bone]
    keypoints = np.zeros((n, N_KEYPOINTS, 3))
    for finger in range(5):
        first = 1 + 3 * finger
        for segment in range(3):
            keypoints[:, 1 + 4 * finger + segment] = world[:, first + segment, :3, 3]
        tip_local = np.array([0.0, skeleton.lengths_m[first + 2], 0.0])
        last = world[:, first + 2]
        keypoints[:, 4 + 4 * finger] = last[:, :3, :3] @ tip_local + last[:, :3, 3]
    return keypoints, world


@pytest.mark.parametrize("hand_length_m", [0.16, 0.19, 0.22])
def test_compiled_chain_is_the_numpy_chain(hand_length_m):
    skeleton = make_skeleton(hand_length_m)
    postures = np.random.default_rng(4).uniform(-1.6, 1.6, (40, 20))  # beyond the limits too
    keypoints, world = _numpy_forward_kinematics(postures, skeleton)
    kinematics = forward_kinematics(postures, skeleton)
    np.testing.assert_allclose(kinematics.bone_transforms, world, rtol=0, atol=1e-14)
    np.testing.assert_allclose(kinematics.keypoints_m, keypoints, rtol=0, atol=1e-14)
