"""The compiled fast paths of the generative fit give the answers of the straightforward
code they replaced: pairing by a k-d tree, posing and Jacobians by NumPy, the data,
silhouette and collision terms written with array operations (the ``_reference_*``
functions below are that code)."""

from dataclasses import replace

import numpy as np
import pytest
from helpers import model_observation, model_pose
from scipy.spatial import cKDTree

from glovedb.hand_model import JOINT_NAMES, N_BONES, make_skeleton
from glovedb.mesh import make_hand_mesh, skin, skinning_matrices
from glovedb.pattern import load_pattern, split_by_label
from glovedb.posture_prior import load_posture_prior
from glovedb.postures import named_posture
from tracker.generative.energy.collision import _model_pairs, segment_closest_points
from tracker.generative.energy.data import data_residuals, nearest_of_class
from tracker.generative.energy.residuals import huber_weights, project_rows
from tracker.generative.energy.silhouette import silhouette_residuals
from tracker.generative.fit import FitSettings, frame_energy
from tracker.generative.model import MOVES, HandPose, PosedHand, hand_samples
from tracker.generative.observation import look_up


@pytest.fixture(scope="module")
def samples():
    mesh = make_hand_mesh(make_skeleton(), spacing_m=0.003)
    return hand_samples(mesh, split_by_label(mesh, load_pattern()), spacing=2)


_pose = model_pose


def _observation(samples, pose):
    """What a camera sees of the model in ``pose`` (:func:`helpers.model_observation`)."""
    return model_observation(samples, pose, max_points=1500)


def _reference_pairs(observed, observed_labels, model, model_labels, gate_m, depth_scale):
    """Nearest model point of each observed point's class by one k-d tree, the class a
    fourth coordinate 100 m apart, as the data term and the ICP paired before:
    ``(distance, nearest)``, -1 beyond the gate."""
    squash = np.array([1.0, 1.0, depth_scale])
    tree = cKDTree(np.column_stack([model * squash, model_labels * 100.0]))
    distance, nearest = tree.query(np.column_stack([observed * squash, observed_labels * 100.0]))
    return distance, np.where(distance < gate_m, nearest, -1)


def _reference_points_normals(samples, pose):
    """Samples and unit normals posed by linear blend skinning with NumPy."""
    skinning = skinning_matrices(pose.posture_rad, samples.skeleton)
    points = skin(samples.mesh, skinning)[0]
    flat = skinning[0].reshape(N_BONES, 12)
    blended = (samples.mesh.weights.astype(np.float64) @ flat).reshape(-1, 3, 4)
    normals = np.einsum("sij,sj->si", blended[..., :3], samples.rest_normals)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    R, t = pose.rotation, pose.translation_m
    return points @ R.T + t, normals @ R.T


def _reference_jacobian(hand, points, moved_hand, share):
    """``(P, 3, 26)`` assembled with NumPy (see ``PosedHand._jacobian``)."""
    R, t = hand.pose.rotation, hand.pose.translation_m
    arm = moved_hand - share[..., None] * hand._pivots_hand
    d_angles = np.cross(hand._axes_hand[None], arm) @ R.T
    d = points - t
    jacobian = np.zeros((len(points), 3, 26))
    jacobian[:, 0, 1], jacobian[:, 0, 2] = d[:, 2], -d[:, 1]
    jacobian[:, 1, 0], jacobian[:, 1, 2] = -d[:, 2], d[:, 0]
    jacobian[:, 2, 0], jacobian[:, 2, 1] = d[:, 1], -d[:, 0]
    jacobian[:, [0, 1, 2], [3, 4, 5]] = 1.0
    jacobian[:, :, 6:] = d_angles.transpose(0, 2, 1)
    return jacobian


def _reference_vertex_jacobian(hand, ids):
    weights = hand.samples.mesh.weights.astype(np.float64)[ids]
    rest = hand.samples.mesh.rest_vertices_m[ids]
    linear = hand._skinning[..., :3].reshape(N_BONES * 3, 3)
    by_bone = (rest @ linear.T).reshape(-1, N_BONES, 3) + hand._skinning[:, :, 3]
    moved = (weights[:, None, :] * MOVES[None]) @ by_bone
    return _reference_jacobian(hand, hand.points_m[ids], moved, weights @ MOVES.T)


def _reference_data(hand, observation, *, weight, huber_m, gate_m, depth_scale):
    members = np.flatnonzero(hand.facing)
    observed = observation.points_m
    _, nearest = _reference_pairs(
        observed, observation.labels, hand.points_m[members], hand.samples.labels[members],
        gate_m, depth_scale,
    )  # fmt: skip
    kept = np.flatnonzero(nearest >= 0)
    sample = members[nearest[kept]]
    normals = hand.normals[sample]
    raw = np.einsum("ij,ij->i", hand.points_m[sample] - observed[kept], normals)
    rows = weight / np.sqrt(len(observed)) * huber_weights(raw, huber_m)
    jacobian = rows[:, None] * project_rows(_reference_vertex_jacobian(hand, sample), normals)
    by_proportions = rows[:, None] * project_rows(hand.proportion_jacobian(sample), normals)
    return rows * raw, jacobian, by_proportions, len(kept) / len(observed)


def _reference_look_up(observation, points):
    z = np.maximum(points[:, 2], 1e-3)
    fx, fy, cx, cy = observation.intrinsics.pinhole
    col = np.rint(fx * points[:, 0] / z + cx).astype(np.int64) - observation.origin_uv[0]
    row = np.rint(fy * points[:, 1] / z + cy).astype(np.int64) - observation.origin_uv[1]
    height, width = observation.outside_px.shape
    inside = (col >= 0) & (col < width) & (row >= 0) & (row < height)
    col, row = np.clip(col, 0, width - 1), np.clip(row, 0, height - 1)
    outside = np.where(inside, observation.outside_px[row, col], np.float32(np.inf))
    return row, col, inside, outside, observation.depth_m[row, col]


def _reference_silhouette(hand, observation, *, weight, margin_px, depth_margin_m, max_samples):
    facing = np.flatnonzero(hand.facing)
    chosen = facing[:: max(1, len(facing) // max_samples)]
    points = hand.points_m[chosen]
    z = np.maximum(points[:, 2], 1e-3)
    fx, fy, _, _ = observation.intrinsics.pinhole
    row, col, inside, distance, seen = _reference_look_up(observation, points)
    hidden = (seen > 0) & (seen < z - depth_margin_m)
    off_mask = (distance > margin_px) & ~hidden
    off_crop = ~inside & ~hidden
    in_front = inside & (distance <= 0) & (seen > 0) & (z < seen - depth_margin_m)
    pull, push = np.flatnonzero(off_mask & inside), np.flatnonzero(in_front)
    metres_per_px = z[pull] / fx
    g = observation.gradient[row[pull], col[pull]]
    pull_direction = np.column_stack(
        [
            g[:, 0] * fx / z[pull],
            g[:, 1] * fy / z[pull],
            -(g[:, 0] * fx * points[pull, 0] + g[:, 1] * fy * points[pull, 1]) / z[pull] ** 2,
        ]
    )
    values = np.concatenate(
        [(distance[pull] - margin_px) * metres_per_px, z[push] - (seen[push] - depth_margin_m)]
    )
    direction = np.concatenate(
        [pull_direction * metres_per_px[:, None], np.tile([0.0, 0.0, 1.0], (len(push), 1))]
    )
    index = np.concatenate([pull, push])
    scale = weight / np.sqrt(len(chosen))
    jacobian = project_rows(_reference_vertex_jacobian(hand, chosen[index]), direction)
    return scale * values, scale * jacobian, float(np.mean(off_mask | off_crop)), len(pull)


def _reference_collision(hand, *, weight, tolerance_m=0.002):
    """The collision term with its capsules posed in the camera frame by NumPy, as it
    was written before its compiled pass (which poses them in the hand frame)."""
    pairs = _model_pairs()
    capsules = hand.samples.finger_capsules
    R, t = hand.pose.rotation, hand.pose.translation_m
    camera_T_bone = hand.bone_transforms.copy()
    camera_T_bone[:, :3, :3] = R @ camera_T_bone[:, :3, :3]
    camera_T_bone[:, :3, 3] = camera_T_bone[:, :3, 3] @ R.T + t
    m = camera_T_bone[capsules.bone]
    start = np.einsum("cij,cj->ci", m[:, :3, :3], capsules.start_m) + m[:, :3, 3]
    end = np.einsum("cij,cj->ci", m[:, :3, :3], capsules.end_m) + m[:, :3, 3]
    a, b = pairs[:, 0], pairs[:, 1]
    s, u = _reference_segment_parameters(start[a], end[a], start[b], end[b])
    pa = start[a] + s[:, None] * (end[a] - start[a])
    pb = start[b] + u[:, None] * (end[b] - start[b])
    radius = capsules.radius_start_m, capsules.radius_end_m
    overlap = (
        radius[0][a] + s * (radius[1][a] - radius[0][a])
        + radius[0][b] + u * (radius[1][b] - radius[0][b])
        - np.linalg.norm(pa - pb, axis=1)
    )  # fmt: skip
    hit = np.flatnonzero(overlap > tolerance_m)
    away = pa[hit] - pb[hit]
    away /= np.linalg.norm(away, axis=1, keepdims=True)
    ja = hand.bone_point_jacobian(pa[hit], capsules.bone[a[hit]])
    jb = hand.bone_point_jacobian(pb[hit], capsules.bone[b[hit]])
    jacobian = -weight * np.einsum("pi,pik->pk", away, ja - jb)
    return weight * (overlap[hit] - tolerance_m), jacobian


def _reference_segment_parameters(a0, a1, b0, b1):
    da, db, r = a1 - a0, b1 - b0, a0 - b0
    aa, bb = np.einsum("pi,pi->p", da, da), np.einsum("pi,pi->p", db, db)
    ab, ar = np.einsum("pi,pi->p", da, db), np.einsum("pi,pi->p", da, r)
    br = np.einsum("pi,pi->p", db, r)
    denominator = aa * bb - ab * ab
    parallel = denominator < 1e-12 * np.maximum(aa * bb, 1e-30)
    s = np.where(
        parallel, 0.0, np.clip((ab * br - bb * ar) / np.where(parallel, 1.0, denominator), 0, 1)
    )
    t = (ab * s + br) / np.maximum(bb, 1e-30)
    t_clipped = np.clip(t, 0.0, 1.0)
    s = np.where(t != t_clipped, np.clip((ab * t_clipped - ar) / np.maximum(aa, 1e-30), 0, 1), s)
    return s, t_clipped


def _random_cloud(rng, count, spread_m, classes):
    points = rng.uniform(-spread_m, spread_m, size=(count, 3)) + [0.0, 0.0, 0.6]
    return points, rng.choice(classes, size=count).astype(np.uint8)


@pytest.mark.parametrize("depth_scale", [1.0, 0.5])
def test_nearest_of_class_matches_a_kd_tree(depth_scale):
    rng = np.random.default_rng(7)
    # Class 7 is missing from the model, 0 and 11 come only with the observed points.
    model, model_labels = _random_cloud(rng, 700, 0.1, [1, 2, 3, 4, 5, 6, 8, 9, 10])
    observed, observed_labels = _random_cloud(rng, 900, 0.12, np.arange(12))
    candidates = rng.uniform(size=len(model)) < 0.7
    gate = 0.03
    distance, nearest = nearest_of_class(
        observed, observed_labels, model, model_labels, gate_m=gate, depth_scale=depth_scale,
        candidates=candidates,
    )  # fmt: skip
    members = np.flatnonzero(candidates)
    expected_distance, expected = _reference_pairs(
        observed, observed_labels, model[members], model_labels[members], gate, depth_scale
    )
    assert nearest.dtype == np.int64 and distance.dtype == np.float64
    paired = expected >= 0
    assert 0.1 < paired.mean() < 0.9, "the case must pair some points and gate others"
    np.testing.assert_array_equal(nearest[paired], members[expected[paired]])
    np.testing.assert_allclose(distance[paired], expected_distance[paired], rtol=1e-12)
    assert np.all(nearest[~paired] == -1) and np.all(np.isinf(distance[~paired]))


def test_nearest_of_class_on_a_wide_or_empty_model():
    rng = np.random.default_rng(8)
    # Metres wide: more than 64 grid cells of 6 mm along x; queries far outside it.
    model, model_labels = _random_cloud(rng, 400, 3.0, [1, 2])
    observed, observed_labels = _random_cloud(rng, 300, 5.0, [1, 2])
    distance, nearest = nearest_of_class(observed, observed_labels, model, model_labels, gate_m=2.0)
    expected_distance, expected = _reference_pairs(
        observed, observed_labels, model, model_labels, 2.0, 1.0
    )
    np.testing.assert_array_equal(nearest, expected)
    paired = expected >= 0
    np.testing.assert_allclose(distance[paired], expected_distance[paired], rtol=1e-12)
    distance, nearest = nearest_of_class(
        observed, observed_labels, model[:0], model_labels[:0], gate_m=1.0
    )
    assert np.all(nearest == -1) and np.all(np.isinf(distance))
    distance, nearest = nearest_of_class(
        observed[:0], observed_labels[:0], model, model_labels, gate_m=1.0
    )
    assert distance.shape == (0,) and nearest.shape == (0,)


def test_nearest_of_class_checks_its_inputs():
    points, labels = np.zeros((4, 3)), np.ones(4, np.uint8)
    with pytest.raises(ValueError, match="observed_m"):
        nearest_of_class(np.zeros((4, 2)), labels, points, labels, gate_m=0.1)
    with pytest.raises(ValueError, match="model_labels"):
        nearest_of_class(points, labels, points, labels[:3], gate_m=0.1)
    with pytest.raises(ValueError, match="candidates"):
        nearest_of_class(points, labels, points, labels, gate_m=0.1, candidates=[True])


def test_bone_lists_hold_every_non_zero_weight_in_bone_order(samples):
    bones, weights = samples._bone_lists
    dense = np.zeros((len(samples), N_BONES))
    rows = np.repeat(np.arange(len(samples)), bones.shape[1]).reshape(bones.shape)
    used = bones >= 0
    dense[rows[used], bones[used]] = weights[used]
    np.testing.assert_array_equal(dense, samples._weights)
    both = used[:, 1:] & used[:, :-1]
    assert np.all(np.diff(bones, axis=1)[both] > 0)  # ascending
    assert np.all(used[:, :-1] >= used[:, 1:])  # the padding last
    assert np.all(weights[~used] == 0) and used[:, 0].all()


def test_posed_hand_matches_plain_skinning(samples):
    pose = _pose("power")
    hand = PosedHand(samples, pose)
    points, normals = _reference_points_normals(samples, pose)
    np.testing.assert_allclose(hand.points_m, points, atol=1e-12)
    np.testing.assert_allclose(hand.normals, normals, atol=1e-12)
    np.testing.assert_array_equal(hand.facing, np.einsum("ij,ij->i", normals, points) < 0)
    assert hand.points_m.dtype == hand.normals.dtype == np.float64
    assert hand.facing.dtype == bool and 0.2 < hand.facing.mean() < 0.8


def test_compiled_jacobians_match_the_numpy_assembly(samples):
    hand = PosedHand(samples, _pose("power"))
    ids = np.arange(0, len(samples), 7)
    expected = _reference_vertex_jacobian(hand, ids)
    np.testing.assert_allclose(hand.vertex_jacobian(ids), expected, atol=1e-12)
    directions = np.random.default_rng(3).normal(size=(len(ids), 3))
    np.testing.assert_allclose(
        hand.directional_rows(ids, directions), project_rows(expected, directions), atol=1e-12
    )
    share = MOVES[:, [3, 6, 9, 12, 15]].T
    moved = share[:, :, None] * hand._hand_keypoints[[4, 8, 12, 16, 20]][:, None, :]
    expected = _reference_jacobian(hand, hand.keypoints_m[[4, 8, 12, 16, 20]], moved, share)
    np.testing.assert_allclose(hand.keypoint_jacobian([4, 8, 12, 16, 20]), expected, atol=1e-12)


def test_plane_rows_match_distances_and_projected_jacobians(samples):
    hand = PosedHand(samples, _pose("pinch"))
    rng = np.random.default_rng(4)
    ids = rng.choice(np.flatnonzero(hand.facing), size=300)  # with repeats
    targets = hand.points_m[ids] + rng.normal(scale=0.003, size=(len(ids), 3))
    distance, rows = hand.plane_rows(ids, targets)
    normals = hand.normals[ids]
    expected = np.einsum("ij,ij->i", hand.points_m[ids] - targets, normals)
    np.testing.assert_allclose(distance, expected, atol=1e-15)
    jacobian = project_rows(_reference_vertex_jacobian(hand, ids), normals)
    np.testing.assert_allclose(rows, jacobian, atol=1e-12)
    assert distance.shape == (300,) and rows.shape == (300, 26)


def test_data_term_matches_the_kd_tree_reference(samples):
    truth = _pose("pinch")
    observation = _observation(samples, truth)
    pose = truth.step(np.r_[0.02, -0.01, 0.01, 0.004, -0.003, 0.006, np.full(20, 0.03)])
    hand = PosedHand(samples, pose)
    settings = {"weight": 1000.0, "huber_m": 0.003, "gate_m": 0.004, "depth_scale": 0.5}
    residuals, matched = data_residuals(
        hand, observation.points_m, observation.labels, proportions=True, **settings
    )
    values, jacobian, by_proportions, expected_matched = _reference_data(
        hand, observation, **settings
    )
    assert 0.3 < matched < 1.0, "the case must pair some points and gate others"
    assert matched == expected_matched
    np.testing.assert_allclose(residuals.values, values, atol=1e-12)
    np.testing.assert_allclose(residuals.jacobian, jacobian, atol=1e-9)
    np.testing.assert_allclose(residuals.proportion_jacobian, by_proportions, atol=1e-9)


def test_silhouette_term_matches_the_numpy_reference(samples):
    truth = _pose("open")
    observation = _observation(samples, truth)
    # Something in front of the crop's top half hides the hand there.
    depth = observation.depth_m.copy()
    depth[: depth.shape[0] // 2] = np.where(depth[: depth.shape[0] // 2] > 0, 0.3, 0.0)
    observation = replace(observation, depth_m=depth)
    # Nearer and aside: samples in front of the observed depth and off the mask.
    pose = truth.step(np.r_[0.0, 0.05, 0.0, 0.012, 0.0, -0.02, np.zeros(20)])
    hand = PosedHand(samples, pose)
    settings = {"weight": 300.0, "margin_px": 2.0, "depth_margin_m": 0.012, "max_samples": 400}
    residuals, outside = silhouette_residuals(hand, observation, proportions=True, **settings)
    values, jacobian, expected_outside, pulled = _reference_silhouette(
        hand, observation, **settings
    )
    assert 0 < pulled < len(values), "the case must both pull and push"
    assert outside == pytest.approx(expected_outside, abs=1e-15)
    np.testing.assert_allclose(residuals.values, values, atol=1e-12)
    np.testing.assert_allclose(residuals.jacobian, jacobian, atol=1e-9)
    assert residuals.proportion_jacobian is not None
    assert residuals.proportion_jacobian.shape == (len(values), 7)
    points = hand.points_m[::5] + [0.0, 0.0, -0.3]  # some beyond the crop
    found = look_up(observation, points)
    for got, expected in zip(
        (found.row, found.col, found.inside, found.outside_px, found.seen_m),
        _reference_look_up(observation, points),
        strict=True,
    ):
        np.testing.assert_array_equal(got, expected)


def test_segment_closest_points_match_the_numpy_reference():
    rng = np.random.default_rng(5)
    a0, a1, b0, b1 = rng.normal(size=(4, 500, 3))
    a1[:50] = a0[:50] + 2.0 * (b1[:50] - b0[:50])  # parallel pairs
    b1[50:60] = b0[50:60]  # a point against a segment
    s, t = segment_closest_points(a0, a1, b0, b1)
    expected_s, expected_t = _reference_segment_parameters(a0, a1, b0, b1)
    np.testing.assert_allclose(s, expected_s, atol=1e-12)
    np.testing.assert_allclose(t, expected_t, atol=1e-12)
    with pytest.raises(ValueError, match="b1"):
        segment_closest_points(a0, a1, b0, b1[:3])


def test_frame_energy_terms_match_the_references(samples):
    crossed = named_posture("pinch")
    crossed[JOINT_NAMES.index("index_mcp_abd")] = np.radians(-20)
    crossed[JOINT_NAMES.index("middle_mcp_abd")] = np.radians(20)
    truth = _pose("pinch")
    observation = _observation(samples, truth)
    pose = HandPose(crossed, truth.rotation, truth.translation_m + [0.003, -0.002, 0.004])
    settings = FitSettings()
    terms, quality, hand = frame_energy(
        samples, pose, observation, settings=settings, prior=load_posture_prior(),
        proportions=True,
    )  # fmt: skip
    by_name = {term.name: term for term in terms}
    points, normals = _reference_points_normals(samples, pose)
    np.testing.assert_allclose(hand.points_m, points, atol=1e-12)
    np.testing.assert_allclose(hand.normals, normals, atol=1e-12)
    values, jacobian, by_proportions, matched = _reference_data(
        hand, observation, weight=settings.data_weight, huber_m=settings.data_huber_m,
        gate_m=settings.data_gate_m, depth_scale=settings.data_depth_scale,
    )  # fmt: skip
    assert quality["matched"] == matched
    np.testing.assert_allclose(by_name["data"].values, values, atol=1e-12)
    np.testing.assert_allclose(by_name["data"].jacobian, jacobian, atol=1e-9)
    np.testing.assert_allclose(by_name["data"].proportion_jacobian, by_proportions, atol=1e-9)
    values, jacobian, outside, _ = _reference_silhouette(
        hand, observation, weight=settings.silhouette_weight,
        margin_px=settings.silhouette_margin_px, depth_margin_m=settings.depth_margin_m,
        max_samples=settings.silhouette_samples,
    )  # fmt: skip
    assert quality["outside"] == pytest.approx(outside, abs=1e-15)
    np.testing.assert_allclose(by_name["silhouette"].values, values, atol=1e-12)
    np.testing.assert_allclose(by_name["silhouette"].jacobian, jacobian, atol=1e-9)
    collision = by_name["collision"]
    assert len(collision) > 0, "the crossed fingers must collide"
    values, jacobian = _reference_collision(hand, weight=settings.collision_weight)
    np.testing.assert_allclose(collision.values, values, atol=1e-12)
    np.testing.assert_allclose(collision.jacobian, jacobian, atol=1e-9)
