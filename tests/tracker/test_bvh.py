"""BVH export: the file parses, and evaluating its motion gives forward kinematics back."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pytest

from glovedb.hand_model import (
    BONE_NAMES,
    N_BONES,
    forward_kinematics,
    joint_limits_rad,
    make_skeleton,
)
from glovedb.rotations import quaternion_to_matrix, rotation_x, rotation_y, rotation_z
from tracker.bvh import bvh_motion, bvh_text, euler_from_matrix, pose_arrays, write_bvh

AXIS_ROTATIONS = {"X": rotation_x, "Y": rotation_y, "Z": rotation_z}
CAMERA_TO_WORLD = np.diag([1.0, -1.0, -1.0])


@dataclass
class Joint:
    name: str
    offset: np.ndarray
    channels: list[str]
    parent: int
    end_site: np.ndarray | None = None
    children: list[int] = field(default_factory=list)


def parse_bvh(text: str) -> tuple[list[Joint], np.ndarray, float]:
    """A minimal BVH reader: joints in declaration order, motion (T, C), frame time."""
    tokens = text.split()
    joints: list[Joint] = []
    stack: list[int] = []
    i = tokens.index("HIERARCHY") + 1
    in_end_site = False
    while tokens[i] != "MOTION":
        token = tokens[i]
        if token in ("ROOT", "JOINT"):
            parent = stack[-1] if stack else -1
            joints.append(Joint(tokens[i + 1], np.zeros(3), [], parent))
            if parent >= 0:
                joints[parent].children.append(len(joints) - 1)
            i += 2
        elif token == "End":
            assert tokens[i + 1] == "Site"
            in_end_site = True
            i += 2
        elif token == "{":
            if not in_end_site:
                stack.append(len(joints) - 1)
            i += 1
        elif token == "}":
            if in_end_site:
                in_end_site = False
            else:
                stack.pop()
            i += 1
        elif token == "OFFSET":
            value = np.array(tokens[i + 1 : i + 4], dtype=float)
            if in_end_site:
                joints[stack[-1]].end_site = value
            else:
                joints[-1].offset = value
            i += 4
        elif token == "CHANNELS":
            count = int(tokens[i + 1])
            joints[-1].channels = tokens[i + 2 : i + 2 + count]
            i += 2 + count
        else:
            raise AssertionError(f"unexpected token {token!r}")
    assert not stack
    assert tokens[i + 1] == "Frames:" and tokens[i + 3 : i + 5] == ["Frame", "Time:"]
    n_frames, frame_time = int(tokens[i + 2]), float(tokens[i + 5])
    values = np.array(tokens[i + 6 :], dtype=float)
    return joints, values.reshape(n_frames, -1), frame_time


def evaluate(joints: list[Joint], frame: np.ndarray) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """World positions of the joints and end sites of one motion line (standard BVH)."""
    positions = np.zeros((len(joints), 3))
    orientations = np.zeros((len(joints), 3, 3))
    ends: dict[int, np.ndarray] = {}
    cursor = 0
    for index, joint in enumerate(joints):
        values = frame[cursor : cursor + len(joint.channels)]
        cursor += len(joint.channels)
        translation = joint.offset.copy()
        rotation = np.eye(3)
        for channel, value in zip(joint.channels, values, strict=True):
            if channel.endswith("position"):
                translation[ord(channel[0]) - ord("X")] += value
            else:
                rotation = rotation @ AXIS_ROTATIONS[channel[0]](np.radians(value))
        if joint.parent < 0:
            positions[index], orientations[index] = translation, rotation
        else:
            parent_rotation = orientations[joint.parent]
            positions[index] = positions[joint.parent] + parent_rotation @ translation
            orientations[index] = parent_rotation @ rotation
        if joint.end_site is not None:
            ends[index] = positions[index] + orientations[index] @ joint.end_site
    assert cursor == len(frame)
    return positions, ends


def random_poses(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    limits = joint_limits_rad()
    postures = rng.uniform(limits[:, 0], limits[:, 1], size=(n, 20))
    quats = rng.normal(size=(n, 4))
    rotations = quaternion_to_matrix(quats / np.linalg.norm(quats, axis=1, keepdims=True))
    translations = rng.uniform([-0.2, -0.2, 0.3], [0.2, 0.2, 0.9], size=(n, 3))
    return postures, rotations, translations


def keypoints_from_bvh(joints: list[Joint], frame: np.ndarray) -> np.ndarray:
    """The 21 keypoints in the camera frame, metres, from one motion line."""
    positions, ends = evaluate(joints, frame)
    keypoints = np.zeros((21, 3))
    keypoints[0] = positions[0]
    for finger in range(5):
        for segment in range(3):
            keypoints[1 + 4 * finger + segment] = positions[1 + 3 * finger + segment]
        keypoints[4 + 4 * finger] = ends[3 + 3 * finger]
    return keypoints @ CAMERA_TO_WORLD / 100.0


def test_file_parses_with_the_declared_channels_and_frames(tmp_path):
    postures, rotations, translations = random_poses(np.random.default_rng(0), 7)
    path = write_bvh(tmp_path / "hand.bvh", postures, rotations, translations, fps=25)
    joints, motion, frame_time = parse_bvh(path.read_text())
    assert [j.name for j in joints] == list(BONE_NAMES)
    assert joints[0].channels == ["Xposition", "Yposition", "Zposition"] + [
        "Zrotation",
        "Yrotation",
        "Xrotation",
    ]
    assert all(len(j.channels) == 3 for j in joints[1:])
    assert motion.shape == (7, 6 + 3 * (N_BONES - 1))
    assert frame_time == pytest.approx(1 / 25)
    assert sum(j.end_site is not None for j in joints) == 5


@pytest.mark.parametrize("hand_length_m", [0.16, 0.21])
def test_motion_reproduces_forward_kinematics(hand_length_m):
    rng = np.random.default_rng(1)
    skeleton = make_skeleton(hand_length_m)
    postures, rotations, translations = random_poses(rng, 20)
    joints, motion, _ = parse_bvh(
        bvh_text(bvh_motion(postures, rotations, translations, skeleton=skeleton), 30)
    )
    expected = forward_kinematics(postures, skeleton).keypoints_m
    expected = expected @ np.swapaxes(rotations, 1, 2) + translations[:, None]
    for frame, truth in zip(motion, expected, strict=True):
        np.testing.assert_allclose(keypoints_from_bvh(joints, frame), truth, atol=1e-4)


def test_rest_pose_is_all_zero_rotations():
    motion = bvh_motion(np.zeros((1, 20)), np.diag([1.0, -1.0, -1.0])[None], np.zeros((1, 3)))
    np.testing.assert_allclose(motion.rotations_deg, 0.0, atol=1e-9)
    skeleton = make_skeleton()
    tip = motion.offsets_cm[[0, 7, 8, 9]].sum(axis=0) + motion.end_sites_cm[9]
    np.testing.assert_allclose(tip, [0.0, skeleton.hand_length_m * 100, 0.0], atol=1e-9)


def test_missing_frames_repeat_the_last_pose():
    postures, rotations, translations = random_poses(np.random.default_rng(2), 5)
    found = np.array([False, True, False, True, False])
    postures[~found] = np.nan
    motion = bvh_motion(postures, rotations, translations, found=found)
    for frame, source in enumerate([1, 1, 1, 3, 3]):
        np.testing.assert_array_equal(motion.rotations_deg[frame], motion.rotations_deg[source])
        np.testing.assert_array_equal(
            motion.root_position_cm[frame], motion.root_position_cm[source]
        )
    np.testing.assert_allclose(motion.root_position_cm[3], translations[3] * [100, -100, -100])


def test_no_hand_at_all_gives_the_rest_pose():
    nan = np.full((3, 20), np.nan)
    motion = bvh_motion(nan, np.full((3, 3, 3), np.nan), np.full((3, 3), np.nan))
    assert motion.n_frames == 3
    np.testing.assert_allclose(motion.root_position_cm, 0.0)


def test_pose_arrays_from_records():
    records = [
        {"frame": 0, "hand_found": False},
        {
            "frame": 1,
            "hand_found": True,
            "posture_rad": [0.1] * 20,
            "rotation": np.eye(3).tolist(),
            "translation_m": [0, 0, 0.5],
        },
    ]
    arrays = pose_arrays(records)
    assert arrays.found.tolist() == [False, True]
    assert np.isnan(arrays.postures_rad[0]).all()
    motion = bvh_motion(arrays.postures_rad, arrays.rotations, arrays.translations_m)
    np.testing.assert_array_equal(motion.rotations_deg[0], motion.rotations_deg[1])


def test_euler_round_trip_including_gimbal_lock():
    rng = np.random.default_rng(3)
    angles = rng.uniform(-np.pi, np.pi, size=(50, 3))
    angles[:, 1] /= 2
    angles[0] = (0.3, np.pi / 2, 0.0)
    angles[1] = (0.3, -np.pi / 2, 0.7)

    def compose(a):
        return rotation_z(a[..., 0]) @ rotation_y(a[..., 1]) @ rotation_x(a[..., 2])

    matrices = compose(angles)
    np.testing.assert_allclose(compose(euler_from_matrix(matrices)), matrices, atol=1e-9)


def test_bad_input():
    postures, rotations, translations = random_poses(np.random.default_rng(4), 2)
    with pytest.raises(ValueError, match="rotations: expected shape"):
        bvh_motion(postures, rotations[:1], translations)
    with pytest.raises(ValueError, match="frame 1: rotation is not orthonormal"):
        bvh_motion(postures, rotations * [[[1.0]], [[2.0]]], translations)
    postures[0, 3] = np.nan
    with pytest.raises(ValueError, match="frame 0: marked found"):
        bvh_motion(postures, rotations, translations, found=[True, True])
    with pytest.raises(ValueError, match="fps"):
        bvh_text(bvh_motion(postures, rotations, translations), 0)
