"""Rotations, camera intrinsics and views around the hand."""

import json

import numpy as np
import pytest

from glovedb.camera import KINECT_V1, CameraIntrinsics, load_intrinsics, save_intrinsics
from glovedb.rotations import (
    axis_angle_to_matrix,
    geodesic_angle,
    look_at,
    matrix_to_quaternion,
    quaternion_to_matrix,
    rotation_vector,
    slerp,
)
from glovedb.views import (
    HAND_CENTRE,
    NAMED_VIEWS,
    database_views,
    icosphere,
    named_view,
    pose_for_view,
)


def random_rotations(count: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return axis_angle_to_matrix(rng.normal(size=(count, 3)), rng.uniform(0, np.pi, count))


def test_quaternion_round_trip_and_w_first():
    rotations = random_rotations(100)
    quaternions = matrix_to_quaternion(rotations)
    assert quaternions.shape == (100, 4) and np.all(quaternions[:, 0] >= 0)
    np.testing.assert_allclose(quaternion_to_matrix(quaternions), rotations, atol=1e-12)
    quarter_turn_z = axis_angle_to_matrix([0, 0, 1], np.pi / 2)
    expected = [np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)]
    np.testing.assert_allclose(matrix_to_quaternion(quarter_turn_z), expected, atol=1e-12)


def test_slerp_endpoints_and_midpoint():
    a, b = matrix_to_quaternion(random_rotations(2, seed=4))
    np.testing.assert_allclose(quaternion_to_matrix(slerp(a, b, 0.0)), quaternion_to_matrix(a))
    np.testing.assert_allclose(quaternion_to_matrix(slerp(a, b, 1.0)), quaternion_to_matrix(b))
    middle = quaternion_to_matrix(slerp(a, b, 0.5))
    ra, rb = quaternion_to_matrix(a), quaternion_to_matrix(b)
    np.testing.assert_allclose(geodesic_angle(ra, middle), geodesic_angle(ra, rb) / 2, atol=1e-9)


def test_geodesic_angle_of_a_known_offset():
    base = random_rotations(1, seed=2)[0]
    offset = axis_angle_to_matrix([0.3, -0.2, 0.9], 0.25)
    np.testing.assert_allclose(geodesic_angle(base, base @ offset), 0.25, atol=1e-9)


def test_look_at_points_the_optical_axis_and_keeps_up():
    rotation = look_at([0, 0, -1], [0, 0, 0], [0, -1, 0])
    np.testing.assert_allclose(rotation, np.eye(3), atol=1e-12)
    with pytest.raises(ValueError, match="parallel"):
        look_at([0, 0, -1], [0, 0, 0], [0, 0, 1])


def test_projection_round_trip_and_json_format(tmp_path):
    camera = CameraIntrinsics(320, 240, 287.26, 287.26, 159.0, 119.0)
    points = np.array([[0.01, -0.02, 0.3], [0.0, 0.0, 1.0]])
    pixels = camera.project(points)
    np.testing.assert_allclose(pixels[1], [159.0, 119.0])
    np.testing.assert_allclose(camera.back_project(pixels, points[:, 2]), points, atol=1e-12)
    path = tmp_path / "intrinsic.json"
    save_intrinsics(camera, path)
    stored = json.loads(path.read_text())
    assert stored["intrinsic_matrix"][6:8] == [159.0, 119.0]  # column-major, as Open3D
    assert load_intrinsics(path) == camera


def test_scaled_camera_keeps_pixel_centres():
    half = KINECT_V1.scaled(0.5)
    point = np.array([0.05, -0.03, 0.6])
    np.testing.assert_allclose(half.project(point), (KINECT_V1.project(point) + 0.5) * 0.5 - 0.5)


def test_malformed_intrinsics_give_one_clear_error(tmp_path):
    path = tmp_path / "intrinsic.json"
    path.write_text('{"width": 640}')
    with pytest.raises(ValueError, match="malformed camera intrinsics"):
        load_intrinsics(path)
    with pytest.raises(ValueError, match="cannot read"):
        load_intrinsics(tmp_path / "missing.json")
    with pytest.raises(ValueError, match="focal"):
        CameraIntrinsics(640, 480, 0.0, 525.0, 319.5, 239.5)


@pytest.mark.parametrize("name", sorted(NAMED_VIEWS))
def test_named_views_put_the_hand_centre_on_the_optical_axis(name):
    rotation, translation = named_view(name, 0.5, 0.19)
    centre = rotation @ np.array([0.0, 0.42 * 0.19, 0.0]) + translation
    np.testing.assert_allclose(centre, [0.0, 0.0, 0.5], atol=1e-12)
    direction = np.array(NAMED_VIEWS[name])
    # The camera sits along the view direction: the hand-frame direction maps to -z.
    np.testing.assert_allclose(rotation @ direction, [0.0, 0.0, -1.0], atol=1e-12)


def test_roll_rotates_about_the_optical_axis():
    plain, _ = pose_for_view([0, 0, 1], 0.5)
    rolled, _ = pose_for_view([0, 0, 1], 0.5, roll_rad=0.3)
    np.testing.assert_allclose(geodesic_angle(plain, rolled), 0.3, atol=1e-12)
    np.testing.assert_allclose(rolled[2], plain[2], atol=1e-12)


def test_plane_depth_known_values():
    camera = CameraIntrinsics(32, 24, 100.0, 100.0, 15.5, 11.5)
    np.testing.assert_allclose(
        camera.plane_depth([0.0, 0.0, -1.0], [0.0, 0.0, 0.8]), 0.8, rtol=1e-6
    )
    tilted = camera.plane_depth([0.0, -np.sqrt(0.5), -np.sqrt(0.5)], [0, 0, 0.8])
    # y + z = 0.8 on the plane: at row v, y = (v - cy) / fy * z.
    v = np.arange(24)[:, None]
    np.testing.assert_allclose(tilted, np.broadcast_to(0.8 / (1 + (v - 11.5) / 100), (24, 32)))
    behind = camera.plane_depth([0.0, 0.0, 1.0], [0.0, 0.0, -0.5])
    assert not behind.any()


def test_rotation_vector_inverts_axis_angle():
    for angle in (1e-9, 0.3, 3.0):
        axis = np.array([0.2, -0.5, 0.84])
        axis /= np.linalg.norm(axis)
        np.testing.assert_allclose(
            rotation_vector(axis_angle_to_matrix(axis, angle)), axis * angle, atol=1e-9
        )


def test_one_rotation_is_the_batched_formula_bit_for_bit():
    # One axis and one angle take a scalar path (the fit's solver steps); it must give
    # exactly what the broadcasting path gives for a batch of one, zero axes included.
    rng = np.random.default_rng(7)
    for k in range(2000):
        axis = rng.normal(size=3) * 10.0 ** rng.uniform(-8, 2) if k % 50 else np.zeros(3)
        angle = rng.normal() * 3.0
        one = axis_angle_to_matrix(axis, angle)
        assert one.shape == (3, 3) and one.dtype == np.float64
        np.testing.assert_array_equal(one, axis_angle_to_matrix(axis[None], [angle])[0])
    # A zero axis turns by nothing, whatever the angle (the docstring's promise).
    np.testing.assert_array_equal(axis_angle_to_matrix([0.0, 0.0, 0.0], 1.0), np.eye(3))
    np.testing.assert_array_equal(axis_angle_to_matrix(np.zeros((2, 3)), [1.0, 2.0])[1], np.eye(3))


def test_one_matrix_to_quaternion_and_rotation_vector_are_the_batched_ones_bit_for_bit():
    # One matrix takes a scalar path (the pose filter's); near 0 and near 180 degrees,
    # and the diagonal rotations whose pivots tie, included.
    rng = np.random.default_rng(3)
    for k in range(2000):
        axis = rng.normal(size=3)
        angle = (
            rng.uniform(0, np.pi),
            np.pi - 10 ** rng.uniform(-12, -1),
            10 ** rng.uniform(-14, -2),
        )
        rotation = (
            axis_angle_to_matrix(axis, angle[k % 3])
            if k % 4
            else np.diag(rng.choice([-1.0, 1.0], 3))
        )
        if np.linalg.det(rotation) < 0:
            rotation = -rotation
        np.testing.assert_array_equal(
            matrix_to_quaternion(rotation), matrix_to_quaternion(rotation[None])[0]
        )
        np.testing.assert_array_equal(rotation_vector(rotation), rotation_vector(rotation[None])[0])


def test_database_views_are_pose_for_view_of_every_position_and_roll():
    rotations, translations, rolls = database_views(1, 5, distance_m=0.45, hand_length_m=0.2)
    directions = icosphere(1)
    assert rotations.shape == (42 * 5, 3, 3) and np.allclose(rolls, np.arange(5) * 2 * np.pi / 5)
    target = np.array(HAND_CENTRE) * 0.2
    for view in range(len(rotations)):
        position, roll = divmod(view, 5)
        expected = pose_for_view(directions[position], 0.45, target_m=target, roll_rad=rolls[roll])
        np.testing.assert_array_equal(rotations[view], expected[0])  # bit for bit
        np.testing.assert_array_equal(translations[view], expected[1])
