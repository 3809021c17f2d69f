"""The software label rasteriser: pixel convention, depth, culling, errors, and agreement
with the OpenGL renderer."""

import numpy as np
import pytest

from glovedb.camera import CameraIntrinsics
from glovedb.mesh import pose_mesh
from glovedb.pattern import face_labels
from glovedb.postures import named_posture
from glovedb.rasterize import rasterize_labels, rasterize_labels_and_depth
from glovedb.views import named_view

CAMERA = CameraIntrinsics(64, 48, 50.0, 60.0, 31.5, 23.5)


def square(u_edges, v_edges, depth_m, camera=CAMERA, facing=True):
    """Vertices (camera frame) and two faces of a flat rectangle whose edges project to
    the given fractional pixel positions; counter-clockwise seen from the camera."""
    x = (np.asarray(u_edges) - camera.cx) * depth_m / camera.fx
    y = (np.asarray(v_edges) - camera.cy) * depth_m / camera.fy
    corners = np.array(
        [[x[0], y[0], depth_m], [x[1], y[0], depth_m], [x[1], y[1], depth_m], [x[0], y[1], depth_m]]
    )
    faces = np.array([[0, 2, 1], [0, 3, 2]]) if facing else np.array([[0, 1, 2], [0, 2, 3]])
    return corners, faces


def render(vertices, faces, labels, camera=CAMERA):
    return rasterize_labels(vertices, faces, labels, np.eye(3)[None], np.zeros((1, 3)), camera)[0]


def test_depth_is_the_nearest_surface_and_zero_elsewhere():
    near, near_faces = square([10.3, 40.7], [5.6, 30.2], 0.5)
    far, far_faces = square([20.0, 50.0], [10.0, 40.0], 0.8)
    vertices, faces = np.vstack([near, far]), np.vstack([near_faces, far_faces + 4])
    labels, depth = rasterize_labels_and_depth(
        vertices, faces, [5, 5, 9, 9], np.eye(3)[None], np.zeros((1, 3)), CAMERA
    )
    assert depth.shape == labels.shape == (1, 48, 64) and depth.dtype == np.float32
    np.testing.assert_array_equal(labels[0], render(vertices, faces, [5, 5, 9, 9]))
    np.testing.assert_allclose(depth[0][labels[0] == 5], 0.5, rtol=1e-6)
    np.testing.assert_allclose(depth[0][labels[0] == 9], 0.8, rtol=1e-6)
    assert not depth[0][labels[0] == 0].any()


def test_covers_exactly_the_pixel_centres_inside():
    vertices, faces = square([10.3, 40.7], [5.6, 30.2], 0.5)
    image = render(vertices, faces, [4, 4])
    assert image.shape == (48, 64) and image.dtype == np.uint8
    expected = np.zeros((48, 64), np.uint8)
    expected[6:31, 11:41] = 4
    np.testing.assert_array_equal(image, expected)


def test_a_centre_on_a_shared_edge_is_drawn_once_and_edges_on_centres_are_closed():
    """Edges through pixel centres: the diagonal is shared, nothing is lost or doubled."""
    vertices, faces = square([10.0, 20.0], [5.0, 15.0], 0.5)
    image = render(vertices, faces, [2, 3])
    covered = image > 0
    # The tie rule keeps one of each pair of opposite edges.
    assert covered.sum() == 10 * 10
    assert set(np.unique(image[covered])) == {2, 3}


def test_the_nearest_surface_wins_and_back_faces_are_culled():
    near, near_faces = square([10.3, 30.7], [5.6, 20.2], 0.4)
    far, far_faces = square([20.3, 50.7], [10.6, 40.2], 0.6)
    vertices = np.vstack([far, near])
    faces = np.vstack([far_faces, near_faces + 4])
    image = render(vertices, faces, [5, 5, 9, 9])
    assert image[15, 25] == 9 and image[30, 45] == 5
    # Drawn in the other order, the same image.
    swapped = render(np.vstack([near, far]), np.vstack([near_faces, far_faces + 4]), [9, 9, 5, 5])
    np.testing.assert_array_equal(image, swapped)
    back, back_faces = square([10.3, 40.7], [5.6, 30.2], 0.5, facing=False)
    assert not render(back, back_faces, [1, 1]).any()


def test_many_views_and_bad_input():
    vertices, faces = square([10.3, 40.7], [5.6, 30.2], 0.5)
    turned = np.array([np.eye(3), np.diag([-1.0, -1.0, 1.0])])  # second: rolled 180 degrees
    images = rasterize_labels(vertices, faces, [1, 1], turned, np.zeros((2, 3)), CAMERA)
    assert images.shape == (2, 48, 64)
    assert images[0].sum() > 0 and images[1].sum() == images[0].sum()
    with pytest.raises(ValueError, match="nearer to a camera"):
        rasterize_labels(vertices, faces, [1, 1], np.eye(3)[None], [[0, 0, -0.6]], CAMERA)
    with pytest.raises(ValueError, match="faces"):
        rasterize_labels(vertices, faces + 2, [1, 1], np.eye(3)[None], np.zeros((1, 3)), CAMERA)
    with pytest.raises(ValueError, match="face_labels"):
        rasterize_labels(vertices, faces, [1], np.eye(3)[None], np.zeros((1, 3)), CAMERA)


@pytest.mark.gl
@pytest.mark.parametrize("posture", ["open", "fist", "pinch", "ok"])
def test_labels_equal_the_opengl_renderer(renderer, posture):
    """Same pixel rules as OpenGL: only centres within 1/256 pixel of an edge may differ."""
    labels = face_labels(renderer.mesh, renderer.pattern)
    vertices = pose_mesh(renderer.mesh, named_posture(posture))
    views = [named_view(name, 0.4, 0.19) for name in ("back", "palm", "thumb", "tips")]
    rotations = np.array([rotation for rotation, _ in views])
    translations = np.array([translation for _, translation in views])
    ours = rasterize_labels(
        vertices, renderer.mesh.faces, labels, rotations, translations, renderer.camera
    )
    for image, rotation, translation in zip(ours, rotations, translations, strict=True):
        opengl = renderer.render_labels(named_posture(posture), rotation, translation).labels
        glove = np.count_nonzero(opengl)
        assert glove > 5000
        assert np.count_nonzero(image != opengl) <= max(3, glove // 2000)
