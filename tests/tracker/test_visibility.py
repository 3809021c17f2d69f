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


def _visibility_reference(hand, depth, pinhole, *, radius_m=0.012, margin_m=0.012, cell_px=4):
    """The straightforward test of the module docstring, keypoint by keypoint."""
    fx, fy, cx, cy = pinhole
    points = hand.points_m[hand.facing & (hand.points_m[:, 2] > 1e-3)]
    buffer = np.full((-(-depth.shape[0] // cell_px), -(-depth.shape[1] // cell_px)), np.inf)
    u = np.rint(fx * points[:, 0] / points[:, 2] + cx).astype(int)
    v = np.rint(fy * points[:, 1] / points[:, 2] + cy).astype(int)
    inside = (u >= 0) & (u < depth.shape[1]) & (v >= 0) & (v < depth.shape[0])
    np.minimum.at(buffer, (v[inside] // cell_px, u[inside] // cell_px), points[inside, 2])
    flags = []
    for x, y, z in hand.keypoints_m:
        ku, kv = round(fx * x / z + cx), round(fy * y / z + cy)
        if z <= 0 or not (0 <= ku < depth.shape[1] and 0 <= kv < depth.shape[0]):
            flags.append("out_of_view")
            continue
        surface = buffer[kv // cell_px, ku // cell_px]
        if surface < z - radius_m - margin_m:
            flags.append("self_occluded")
            continue
        window = depth[max(kv - 1, 0) : kv + 2, max(ku - 1, 0) : ku + 2]
        seen = window[window > 0]
        front = min(surface, z - radius_m)
        hidden = len(seen) == 0 or float(np.median(seen)) < front - margin_m
        flags.append("occluded" if hidden else "seen")
    return tuple(flags)


def test_the_compiled_pass_gives_the_straightforward_flags(samples):
    # Hands moved about the image (to its borders and out of it), depth with holes and
    # an even number of measured pixels around many keypoints, in float32 and float64.
    rng = np.random.default_rng(11)
    kinds = set()
    for trial in range(40):
        posture = named_posture(("open", "fist", "pinch")[trial % 3])
        rotation = (BACK_TO_CAMERA, PALM_TO_CAMERA)[trial % 2]
        position = [rng.uniform(-0.3, 0.3), rng.uniform(-0.25, 0.25), rng.uniform(0.3, 0.9)]
        hand = PosedHand(samples, HandPose.of(posture, rotation, position))
        depth = _seen_depth(hand)
        depth[rng.random(depth.shape) < 0.3] = 0.0
        depth[rng.random(depth.shape) < 0.05] = 0.2  # something in front here and there
        for image in (depth, depth.astype(np.float64)):
            flags = keypoint_visibility(hand, image, KINECT_V1.pinhole)
            assert flags == _visibility_reference(hand, image, KINECT_V1.pinhole)
            kinds.update(flags)
    assert kinds == {"seen", "self_occluded", "occluded", "out_of_view"}
