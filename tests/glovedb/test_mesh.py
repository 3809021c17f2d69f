"""The generated glove mesh: closed, hand-sized, and skinned so vertices follow bones."""

import numpy as np
import pytest

from glovedb.capsules import (
    concatenate,
    finger_capsules,
    palm_capsules,
    pose_capsules,
    round_cone_distance,
)
from glovedb.hand_model import N_BONES, forward_kinematics, joint_limits_rad, make_skeleton
from glovedb.mesh import make_hand_mesh, pose_mesh, skin, skinning_matrices, vertex_normals
from glovedb.postures import named_posture
from glovedb.shape import hand_distance, make_hand_shape
from glovedb.surface_nets import surface_nets


def edge_use_counts(faces: np.ndarray) -> np.ndarray:
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return np.unique(edges, axis=0, return_counts=True)[1]


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def test_surface_nets_meshes_a_sphere_closed_and_outward():
    axis = np.linspace(-1, 1, 41)
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1)
    vertices, faces = surface_nets(np.linalg.norm(grid, axis=-1) - 0.7, [-1, -1, -1], 0.05)
    assert np.all(edge_use_counts(faces) == 2)
    np.testing.assert_allclose(np.linalg.norm(vertices, axis=1), 0.7, atol=0.01)
    np.testing.assert_allclose(signed_volume(vertices, faces), 4 / 3 * np.pi * 0.7**3, rtol=0.02)


def test_surface_nets_rejects_a_surface_touching_the_grid_boundary():
    with pytest.raises(ValueError, match="boundary"):
        surface_nets(np.full((4, 4, 4), -1.0), [0, 0, 0], 1.0)


def test_mesh_is_a_closed_hand_sized_solid(hand_mesh):
    assert hand_mesh.faces.dtype == np.int64 and hand_mesh.weights.dtype == np.float32
    assert np.all(edge_use_counts(hand_mesh.faces) == 2), "mesh must be closed and manifold"
    volume_cm3 = signed_volume(hand_mesh.rest_vertices_m, hand_mesh.faces) * 1e6
    assert 250 < volume_cm3 < 500  # adult hands with a short cuff: 300-450 cm3
    low, high = hand_mesh.rest_vertices_m.min(0), hand_mesh.rest_vertices_m.max(0)
    # From the cuff to the middle fingertip; about a palm's thickness deep.
    np.testing.assert_allclose(high[1], 0.19, atol=0.002)
    assert 0.12 < high[0] - low[0] < 0.2 and 0.03 < high[2] - low[2] < 0.06


def test_normals_point_outward(hand_mesh):
    normals = vertex_normals(hand_mesh.rest_vertices_m, hand_mesh.faces)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-9)
    shape = make_hand_shape(hand_mesh.skeleton)
    outside = hand_distance(hand_mesh.rest_vertices_m + 0.0005 * normals, shape)
    inside = hand_distance(hand_mesh.rest_vertices_m - 0.0005 * normals, shape)
    assert np.mean(outside > inside) > 0.999


def test_vertices_lie_on_the_signed_distance_surface(hand_mesh):
    shape = make_hand_shape(hand_mesh.skeleton)
    distance = hand_distance(hand_mesh.rest_vertices_m, shape)
    assert np.percentile(np.abs(distance), 99) < 1e-4


def test_weights_are_convex_and_every_bone_owns_vertices(hand_mesh):
    np.testing.assert_allclose(hand_mesh.weights.sum(axis=1), 1.0, atol=1e-5)
    assert hand_mesh.weights.min() >= 0
    assert set(hand_mesh.dominant_bone) == set(range(N_BONES))


def test_rest_posture_reproduces_the_rest_mesh(hand_mesh):
    np.testing.assert_allclose(
        pose_mesh(hand_mesh, np.zeros(20)), hand_mesh.rest_vertices_m, atol=1e-12
    )


def test_vertices_follow_their_bones(hand_mesh):
    posture = named_posture("fist")
    posed = pose_mesh(hand_mesh, posture)
    matrices = skinning_matrices(posture[None], hand_mesh.skeleton)[0]
    rest = hand_mesh.rest_vertices_m
    rigid_bones = 0
    for bone in range(N_BONES):
        rigid = hand_mesh.weights[:, bone] == 1.0
        if rigid.sum() < 20:  # short segments (the little finger's middle) always blend
            continue
        rigid_bones += 1
        expected = rest[rigid] @ matrices[bone, :, :3].T + matrices[bone, :, 3]
        np.testing.assert_allclose(posed[rigid], expected, atol=1e-6)
    assert rigid_bones >= 15


def test_batch_posing_matches_single(hand_mesh):
    limits = joint_limits_rad()
    postures = np.random.default_rng(3).uniform(limits[:, 0], limits[:, 1], (3, 20))
    batch = pose_mesh(hand_mesh, postures)
    assert batch.shape == (3,) + hand_mesh.rest_vertices_m.shape
    np.testing.assert_allclose(batch[2], pose_mesh(hand_mesh, postures[2]), atol=1e-12)


def test_skinning_is_the_weighted_sum_of_every_bone_matrix(hand_mesh):
    # The compiled loop skips zero weights; the straightforward sum over all 16 bones.
    matrices = np.random.default_rng(4).normal(size=(2, N_BONES, 3, 4))
    weights = hand_mesh.weights.astype(np.float64)
    blended = np.einsum("vb,nbij->nvij", weights, matrices)
    dense = np.einsum("nvij,vj->nvi", blended[..., :3], hand_mesh.rest_vertices_m)
    expected = dense + blended[..., 3]
    np.testing.assert_allclose(skin(hand_mesh, matrices), expected, rtol=0, atol=1e-12)


def test_capsules_approximate_the_posed_fingers(hand_mesh):
    skeleton = hand_mesh.skeleton
    capsules = concatenate(finger_capsules(skeleton), palm_capsules(skeleton, 0.0137))
    posture = named_posture("power")
    start, end = pose_capsules(capsules, forward_kinematics(posture, skeleton).bone_transforms[0])
    vertices = pose_mesh(hand_mesh, posture)
    distance = round_cone_distance(
        vertices, start, end, capsules.radius_start_m, capsules.radius_end_m
    ).min(axis=1)
    on_fingers = hand_mesh.weights[:, 0] < 0.01
    # Finger surface vertices lie on the capsule surfaces up to skinning and blending.
    assert np.median(np.abs(distance[on_fingers])) < 0.001
    assert np.percentile(np.abs(distance[on_fingers]), 95) < 0.004


def test_smaller_spacing_gives_a_finer_mesh():
    coarse = make_hand_mesh(make_skeleton(), spacing_m=0.004)
    assert 2000 < len(coarse.rest_vertices_m) < 6000
    with pytest.raises(ValueError, match="spacing_m"):
        make_hand_mesh(spacing_m=0.1)


def test_the_cached_mesh_is_the_generated_one_and_survives_a_corrupt_file(tmp_path, monkeypatch):
    import glovedb.mesh as mesh_module
    from glovedb.mesh import cached_hand_mesh

    skeleton = make_skeleton(0.18)
    made = cached_hand_mesh(skeleton, spacing_m=0.004, folder=tmp_path)
    fresh = make_hand_mesh(skeleton, spacing_m=0.004)
    (stored,) = tmp_path.glob("hand-*.npz")
    monkeypatch.setattr(mesh_module, "make_hand_mesh", None)  # a second call must load
    loaded = cached_hand_mesh(skeleton, spacing_m=0.004, folder=tmp_path)
    for mesh in (made, loaded):
        for name in ("rest_vertices_m", "faces", "weights"):
            assert getattr(mesh, name).dtype == getattr(fresh, name).dtype
            np.testing.assert_array_equal(getattr(mesh, name), getattr(fresh, name))
        assert mesh.skeleton is skeleton
    monkeypatch.undo()
    stored.write_bytes(b"half a file")  # an interrupted copy, a full disk
    again = cached_hand_mesh(skeleton, spacing_m=0.004, folder=tmp_path)
    np.testing.assert_array_equal(again.faces, fresh.faces)
    # Another hand or spacing is another entry, not the same one reused.
    cached_hand_mesh(make_skeleton(0.2), spacing_m=0.004, folder=tmp_path)
    cached_hand_mesh(skeleton, spacing_m=0.005, folder=tmp_path)
    assert len(list(tmp_path.glob("hand-*.npz"))) == 3
    assert not list(tmp_path.glob("*.partial*"))
