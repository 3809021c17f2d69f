"""Hand proportions: the stretched skeleton and mesh, and their file."""

import json

import numpy as np
import pytest

from glovedb.hand_model import bone_transforms_per_skeleton, forward_kinematics, make_skeleton
from glovedb.mesh import make_hand_mesh, pose_mesh
from glovedb.postures import named_posture
from glovedb.proportions import (
    HandProportions,
    load_proportions,
    proportioned_mesh,
    proportioned_skeleton,
    save_proportions,
)


@pytest.fixture(scope="module")
def mesh():
    return make_hand_mesh(make_skeleton(), spacing_m=0.004)


def test_the_model_proportions_change_nothing(mesh):
    assert proportioned_mesh(mesh, HandProportions()) is mesh


def test_a_length_scale_scales_the_whole_hand_about_the_wrist(mesh):
    bigger = proportioned_mesh(mesh, HandProportions(1.1))
    np.testing.assert_allclose(bigger.rest_vertices_m, 1.1 * mesh.rest_vertices_m, atol=1e-12)
    posture = named_posture("power")
    np.testing.assert_allclose(
        pose_mesh(bigger, posture), 1.1 * pose_mesh(mesh, posture), atol=1e-8
    )
    assert bigger.skeleton.hand_length_m == pytest.approx(1.1 * mesh.skeleton.hand_length_m)


def test_finger_factors_lengthen_their_finger_only(mesh):
    factors = (1.0, 1.12, 1.0, 1.0, 0.9)
    personal = proportioned_skeleton(mesh.skeleton, HandProportions(finger_length=factors))
    model = forward_kinematics(named_posture("open"), mesh.skeleton).keypoints_m[0]
    ours = forward_kinematics(named_posture("open"), personal).keypoints_m[0]
    for finger, factor in enumerate(factors):
        base, tip = 1 + 4 * finger, 4 + 4 * finger
        ratio = np.linalg.norm(ours[tip] - ours[base]) / np.linalg.norm(model[tip] - model[base])
        assert ratio == pytest.approx(factor, rel=1e-9)
    np.testing.assert_allclose(ours[[0, 1, 5, 9, 13, 17]], model[[0, 1, 5, 9, 13, 17]])
    # The mesh's index fingertip moves out with its bone.
    stretched = proportioned_mesh(mesh, HandProportions(finger_length=factors))
    index_tip = np.argmax(mesh.rest_vertices_m[:, 1] * (mesh.dominant_bone == 6))
    reach = stretched.rest_vertices_m[index_tip] - ours[5]
    assert np.linalg.norm(reach) == pytest.approx(
        1.12 * np.linalg.norm(mesh.rest_vertices_m[index_tip] - model[5]), rel=0.02
    )


def test_thickness_scales_across_the_palm_plane_only(mesh):
    thicker = proportioned_mesh(mesh, HandProportions(), thickness=1.3)
    np.testing.assert_array_equal(thicker.skeleton.offsets_m, mesh.skeleton.offsets_m)
    np.testing.assert_array_equal(thicker.faces, mesh.faces)
    # The open hand lies in the palm plane (z = 0 for the four fingers' bones), so
    # every vertex moves away from it by the factor, except near the tilted thumb.
    before, after = mesh.rest_vertices_m, thicker.rest_vertices_m
    span = [np.ptp(v[:, 2]) for v in (before, after)]
    assert 1.2 * span[0] < span[1] < 1.31 * span[0]
    np.testing.assert_allclose(np.ptp(after[:, 1]), np.ptp(before[:, 1]), rtol=1e-3)
    with pytest.raises(ValueError, match="thickness"):
        proportioned_mesh(mesh, HandProportions(), thickness=0.3)


def test_palm_width_moves_the_finger_bases_apart():
    skeleton = make_skeleton()
    wide = proportioned_skeleton(skeleton, HandProportions(palm_width=1.2))
    np.testing.assert_allclose(wide.offsets_m[[4, 13], 0], 1.2 * skeleton.offsets_m[[4, 13], 0])
    np.testing.assert_allclose(wide.offsets_m[[4, 13], 1], skeleton.offsets_m[[4, 13], 1])


def test_factors_out_of_range_are_refused():
    with pytest.raises(ValueError, match="length_scale"):
        HandProportions(0.3)
    with pytest.raises(ValueError, match=r"finger_length\[2\]"):
        HandProportions(finger_length=(1, 1, 3, 1, 1))
    with pytest.raises(ValueError, match="5 factors"):
        HandProportions(finger_length=(1, 1))  # type: ignore[arg-type]


def test_proportions_file_round_trip_and_bad_files(tmp_path):
    proportions = HandProportions(0.93, (1.0, 1.05, 1.1, 0.95, 1.0), 1.08)
    path = save_proportions(tmp_path / "hand.json", proportions, extra={"source": "test"})
    assert load_proportions(path) == proportions
    assert json.loads(path.read_text())["source"] == "test"
    np.testing.assert_allclose(
        HandProportions.from_vector(proportions.as_vector()).as_vector(), proportions.as_vector()
    )
    with pytest.raises(ValueError, match="no such hand proportions file"):
        load_proportions(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text('{"length_scale": 1.0}')
    with pytest.raises(ValueError, match="not a hand proportions file"):
        load_proportions(tmp_path / "bad.json")


def test_bone_transforms_per_skeleton_are_forward_kinematics_on_each():
    rng = np.random.default_rng(3)
    postures = rng.uniform(-0.5, 1.2, (3, 20))
    skeletons = [
        proportioned_skeleton(
            make_skeleton(), HandProportions(scale, (1.1, 0.9, 1.0, 1.2, 0.8), palm)
        )
        for scale, palm in ((0.8, 1.0), (1.0, 1.1), (1.3, 0.9))
    ]
    per_skeleton = bone_transforms_per_skeleton(postures, skeletons)
    assert per_skeleton.shape == (3, 3, 16, 4, 4)
    for transforms, skeleton in zip(per_skeleton, skeletons, strict=True):
        np.testing.assert_array_equal(
            transforms, forward_kinematics(postures, skeleton).bone_transforms
        )


def test_a_proportioned_mesh_keeps_what_the_weights_decide(mesh):
    stretched = proportioned_mesh(mesh, HandProportions(1.1, (1.0, 1.2, 1.0, 1.0, 0.9), 1.05))
    assert stretched.weights is mesh.weights
    assert stretched.dominant_bone is mesh.dominant_bone  # carried, not recomputed
    np.testing.assert_array_equal(stretched.dominant_bone, np.argmax(mesh.weights, axis=1))
