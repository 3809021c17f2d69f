"""The headless renderer: shapes, exact labels, depth against keypoints, pixel convention."""

import numpy as np
import pytest

from glovedb.camera import CameraIntrinsics
from glovedb.capsules import finger_capsules
from glovedb.hand_model import forward_kinematics, make_skeleton
from glovedb.mesh import HandMesh
from glovedb.postures import named_posture
from glovedb.views import named_view

pytestmark = pytest.mark.gl


def view(name: str, distance_m: float = 0.4) -> tuple[np.ndarray, np.ndarray]:
    return named_view(name, distance_m, 0.19)


def test_output_shapes_dtypes_and_determinism(renderer):
    rotation, translation = view("back")
    first = renderer.render(named_posture("pinch"), rotation, translation)
    assert first.color.shape == (480, 640, 3) and first.color.dtype == np.uint8
    assert first.labels.shape == (480, 640) and first.labels.dtype == np.uint8
    assert first.depth_m.shape == (480, 640) and first.depth_m.dtype == np.float32
    second = renderer.render(named_posture("pinch"), rotation, translation)
    np.testing.assert_array_equal(first.color, second.color)
    np.testing.assert_array_equal(first.labels, second.labels)
    np.testing.assert_array_equal(first.depth_m, second.depth_m)
    labels_only = renderer.render_labels(named_posture("pinch"), rotation, translation)
    np.testing.assert_array_equal(labels_only.labels, first.labels)


def test_labels_are_exact_and_cover_exactly_the_depth(renderer):
    rendering = renderer.render(named_posture("power"), *view("thumb"))
    assert set(np.unique(rendering.labels)) <= set(range(11))
    np.testing.assert_array_equal(rendering.labels > 0, rendering.depth_m > 0)
    # The color image shows the nominal color of each class, shaded but recognisable.
    palette = renderer.pattern.palette().astype(float)
    glove = rendering.labels > 0
    color = rendering.color[glove].astype(float)
    chroma = color / np.maximum(color.sum(axis=1, keepdims=True), 1)
    nominal = palette / np.maximum(palette.sum(axis=1, keepdims=True), 1)
    nearest = np.argmin(np.linalg.norm(chroma[:, None] - nominal[None, 1:], axis=-1), axis=1) + 1
    assert np.mean(nearest == rendering.labels[glove]) > 0.97


def test_all_ten_classes_visible_from_palm_and_back(renderer):
    seen = set()
    for name in ("back", "palm"):
        seen |= set(np.unique(renderer.render_labels(np.zeros(20), *view(name)).labels))
    assert seen == set(range(11))


@pytest.mark.parametrize("posture", ["open", "fist", "pinch", "peace"])
@pytest.mark.parametrize("side", ["back", "palm", "thumb"])
def test_projected_keypoints_land_on_the_hand(renderer, posture, side):
    rotation, translation = view(side)
    rendering = renderer.render_labels(named_posture(posture), rotation, translation)
    keypoints = forward_kinematics(named_posture(posture)).keypoints_m[0]
    pixels = renderer.camera.project(keypoints @ rotation.T + translation)
    u, v = np.round(pixels).astype(int).T
    # Fingertip keypoints lie on the surface's edge: allow one pixel around them.
    near = np.zeros_like(rendering.labels, dtype=bool)
    near[v, u] = True
    grown = np.zeros_like(near)
    for dv in (-1, 0, 1):
        for du in (-1, 0, 1):
            grown |= np.roll(np.roll(rendering.labels > 0, dv, 0), du, 1)
    assert np.all(grown[v, u]), f"keypoints off the hand: {np.flatnonzero(~grown[v, u])}"


def test_depth_agrees_with_keypoints(renderer):
    """From the back, the surface above each PIP and DIP joint is one joint radius nearer."""
    skeleton = renderer.mesh.skeleton
    rotation, translation = view("back", 0.35)
    rendering = renderer.render_labels(np.zeros(20), rotation, translation)
    keypoints = forward_kinematics(np.zeros(20), skeleton).keypoints_m[0] @ rotation.T + translation
    capsules = finger_capsules(skeleton)
    for finger in range(1, 5):
        for segment in (1, 2):  # PIP and DIP: the proximal end of the middle/distal bones
            keypoint = 1 + 4 * finger + segment
            bone = 1 + 3 * finger + segment
            radius = capsules.radius_start_m[np.flatnonzero(capsules.bone == bone)[0]]
            u, v = np.round(renderer.camera.project(keypoints[keypoint])).astype(int)
            measured = rendering.depth_m[v, u]
            np.testing.assert_allclose(measured, keypoints[keypoint, 2] - radius, atol=0.0015)


def test_pixel_centres_follow_the_opencv_convention():
    """A flat square whose edges fall at known fractional pixel positions covers
    exactly the pixels whose centres lie inside its projection."""
    from builder.render import GloveRenderer

    camera = CameraIntrinsics(64, 48, 50.0, 60.0, 31.5, 23.5)
    depth = 0.5
    u_edges, v_edges = np.array([10.3, 40.7]), np.array([5.6, 30.2])
    x = (u_edges - camera.cx) * depth / camera.fx
    y = (v_edges - camera.cy) * depth / camera.fy
    corners = np.array([[x[0], y[0], 0.0], [x[1], y[0], 0.0], [x[1], y[1], 0.0], [x[0], y[1], 0.0]])
    # Hand frame = camera frame here; the square faces the camera (-z).
    faces = np.array([[0, 2, 1], [0, 3, 2]])
    weights = np.zeros((4, 16), np.float32)
    weights[:, 0] = 1.0
    square = HandMesh(make_skeleton(), corners, faces, weights)
    with GloveRenderer(camera, mesh=square) as flat:
        rendering = flat.render_labels(np.zeros(20), np.eye(3), [0.0, 0.0, depth])
    rows, cols = np.nonzero(rendering.labels)
    assert (cols.min(), cols.max()) == (11, 40)
    assert (rows.min(), rows.max()) == (6, 30)
    np.testing.assert_allclose(rendering.depth_m[rows, cols], depth, atol=1e-5)


def test_bad_pose_arguments_raise(renderer):
    with pytest.raises(ValueError, match="rotation"):
        renderer.render(np.zeros(20), np.eye(4), [0, 0, 0.5])
    with pytest.raises(ValueError, match="posture_rad"):
        renderer.render(np.zeros(19), np.eye(3), [0, 0, 0.5])


def test_another_mesh_of_the_same_topology_renders_in_its_place(renderer):
    from glovedb.proportions import HandProportions, proportioned_mesh

    view = named_view("back", 0.5, renderer.mesh.skeleton.hand_length_m)
    own = renderer.render_labels(named_posture("open"), *view)
    longer = proportioned_mesh(renderer.mesh, HandProportions(finger_length=(1.2,) * 5))
    other = renderer.render_labels(named_posture("open"), *view, mesh=longer)
    assert np.count_nonzero(other.depth_m) > np.count_nonzero(own.depth_m)
    again = renderer.render_labels(named_posture("open"), *view)  # the renderer's own again
    np.testing.assert_array_equal(again.depth_m, own.depth_m)
    wrong = HandMesh(longer.skeleton, longer.rest_vertices_m, longer.faces[::-1], longer.weights)
    with pytest.raises(ValueError, match="mesh: expected the renderer's mesh topology"):
        renderer.render_labels(named_posture("open"), *view, mesh=wrong)
