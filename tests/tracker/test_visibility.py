"""Keypoint visibility: seen, hidden by the hand itself, by an object, out of view."""

import numpy as np
import pytest

from glovedb.camera import KINECT_V1
from glovedb.hand_model import FINGERTIP_KEYPOINTS, make_skeleton
from glovedb.mesh import make_hand_mesh
from glovedb.pattern import load_pattern, split_by_label
from glovedb.postures import named_posture
from tracker.generative.model import HandPose, PosedHand, hand_samples
from tracker.generative.visibility import keypoint_visibility

BACK_TO_CAMERA = np.diag([1.0, -1.0, -1.0])
PALM_TO_CAMERA = np.diag([-1.0, -1.0, 1.0])


@pytest.fixture(scope="module")
def samples():
    mesh = make_hand_mesh(make_skeleton(), spacing_m=0.003)
    return hand_samples(mesh, split_by_label(mesh, load_pattern()))


def _seen_depth(hand):
    """The depth a camera would measure of the model alone (nearest sample per pixel)."""
    depth = np.zeros((KINECT_V1.height, KINECT_V1.width), np.float32)
    facing = np.einsum("ij,ij->i", hand.normals, hand.points_m) < 0
    points = hand.points_m[facing]
    uv = np.rint(KINECT_V1.project(points)).astype(int)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < KINECT_V1.width) & (uv[:, 1] >= 0)
    inside &= uv[:, 1] < KINECT_V1.height
    points, uv = points[inside], uv[inside]
    order = np.argsort(-points[:, 2])
    depth[uv[order, 1], uv[order, 0]] = points[order, 2]
    # Close the sampling gaps so every hand pixel has depth.
    near = depth.copy()
    for du, dv in ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, -1), (1, -1), (-1, 1)):
        shifted = np.roll(np.roll(depth, dv, axis=0), du, axis=1)
        near = np.where((near == 0) | ((shifted > 0) & (shifted < near)), shifted, near)
    return near


def test_an_open_hand_facing_the_camera_shows_every_keypoint(samples):
    hand = PosedHand(samples, HandPose.of(named_posture("open"), PALM_TO_CAMERA, [0, 0.08, 0.5]))
    flags = keypoint_visibility(hand, _seen_depth(hand), KINECT_V1.pinhole)
    assert flags.count("seen") >= 19, flags


def test_the_fingertips_of_a_fist_seen_from_the_back_are_hidden_by_the_hand(samples):
    hand = PosedHand(samples, HandPose.of(named_posture("fist"), BACK_TO_CAMERA, [0, 0.08, 0.5]))
    flags = keypoint_visibility(hand, _seen_depth(hand), KINECT_V1.pinhole)
    tips = [flags[k] for k in FINGERTIP_KEYPOINTS[1:]]
    assert tips.count("self_occluded") >= 3, flags
    assert flags[0] == "seen"


def test_an_object_in_front_and_the_image_border(samples):
    pose = HandPose.of(named_posture("open"), PALM_TO_CAMERA, [0, 0.08, 0.5])
    hand = PosedHand(samples, pose)
    depth = _seen_depth(hand)
    tip = np.rint(KINECT_V1.project(hand.keypoints_m[8])).astype(int)  # index tip
    depth[tip[1] - 15 : tip[1] + 16, tip[0] - 15 : tip[0] + 16] = 0.3  # a card 20 cm nearer
    flags = keypoint_visibility(hand, depth, KINECT_V1.pinhole)
    assert flags[8] == "occluded" and flags[0] == "seen"
    aside = PosedHand(samples, HandPose.of(named_posture("open"), PALM_TO_CAMERA, [0.3, 0.08, 0.5]))
    flags = keypoint_visibility(aside, _seen_depth(aside), KINECT_V1.pinhole)
    assert "out_of_view" in flags and set(flags) <= {
        "seen",
        "self_occluded",
        "occluded",
        "out_of_view",
    }
