"""Tracker core: color table, point cloud, ICP, the whole pipeline on rendered frames."""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from glovedb.camera import KINECT_V1, CameraIntrinsics
from glovedb.hand_model import make_skeleton
from glovedb.mesh import pose_mesh, vertex_normals
from glovedb.pattern import load_pattern, split_by_label
from glovedb.postures import named_posture
from glovedb.rotations import axis_angle_to_matrix, geodesic_angle
from tracker import _icp_kernels
from tracker.classify import calibrated_table, load_table, nominal_table
from tracker.frames import Frame
from tracker.icp import color_icp, rigid_fit
from tracker.point_cloud import hand_region, labeled_point_cloud


@pytest.fixture(scope="module")
def pattern():
    return load_pattern()


def test_compiled_classification_is_the_table_lookup(pattern):
    table = nominal_table(pattern)
    rng = np.random.default_rng(8)
    image = rng.integers(0, 256, (48, 64, 3)).astype(np.uint8)
    for rgb in (image, image[::2, 1::3], np.ascontiguousarray(image[..., ::-1])):
        cells = rgb >> 3
        expected = table.table[cells[..., 0], cells[..., 1], cells[..., 2]]
        np.testing.assert_array_equal(table.classify(rgb), expected)


def test_nominal_table_classifies_glove_colors_under_lighting_changes(pattern):
    table = nominal_table(pattern)
    assert table.table.shape == (32, 32, 32) and table.table.dtype == np.uint8
    expected = np.arange(1, 11, dtype=np.uint8)[None]
    for gain, balance in [(1.0, (1, 1, 1)), (0.45, (1, 1, 1)), (1.25, (1, 1, 1)),
                          (0.8, (1.12, 1.0, 0.88)), (0.9, (0.9, 1.0, 1.1))]:  # fmt: skip
        lit = np.clip(pattern.colors_rgb[None] * gain * np.array(balance), 0, 255)
        np.testing.assert_array_equal(table.classify(lit.astype(np.uint8)), expected)
    greys = np.array([[[0, 0, 0], [60, 60, 60], [128, 128, 128], [250, 250, 250]]], np.uint8)
    np.testing.assert_array_equal(table.classify(greys), 0)


@pytest.mark.gl
def test_nominal_table_on_rendered_shading(renderer, pattern):
    rotation, translation = axis_angle_to_matrix([1.0, 0.2, 0.0], 2.6), np.array([0, 0.05, 0.5])
    rendering = renderer.render(named_posture("power"), rotation, translation)
    labels = nominal_table(pattern).classify(rendering.color)
    glove = rendering.labels > 0
    assert np.mean(labels[glove] == rendering.labels[glove]) > 0.97
    assert np.mean(labels[~glove] == 0) > 0.999


def test_calibrated_table_learns_a_shifted_glove_and_round_trips(pattern, tmp_path):
    rng = np.random.default_rng(0)
    # A real glove's dye: every color darker and warmer than nominal, sampled noisily.
    real = np.clip(pattern.colors_rgb * 0.7 * np.array([1.1, 0.95, 0.85]), 0, 255)
    glove = np.repeat(real, 50, axis=0) + rng.normal(0, 4, (500, 3))
    background = rng.integers(0, 256, (2000, 3)) * np.array([1, 1, 1])
    background = background[np.ptp(background, axis=1) < 40]  # greyish clutter
    colors = np.clip(np.concatenate([glove, background]), 0, 255).astype(np.uint8)
    labels = np.concatenate([np.repeat(np.arange(1, 11), 50), np.zeros(len(background), int)])
    table = calibrated_table(colors, labels)
    np.testing.assert_array_equal(table.classify(real[None].astype(np.uint8)), [list(range(1, 11))])
    path = tmp_path / "table.npz"
    table.save(path)
    np.testing.assert_array_equal(load_table(path).table, table.table)
    (tmp_path / "bad.npz").write_bytes(b"nope")
    with pytest.raises(ValueError, match="not a color table"):
        load_table(tmp_path / "bad.npz")


def test_point_cloud_of_a_plane_at_known_depth():
    camera = CameraIntrinsics(80, 60, 70.0, 70.0, 39.5, 29.5)
    labels = np.zeros((60, 80), np.uint8)
    labels[20:40, 30:50] = 4
    depth = np.full((60, 80), 0.8, np.float32)
    depth[25, 35] = 0.0  # a hole: no point there
    region = hand_region(labels, depth)
    assert len(region) == 400
    cloud = labeled_point_cloud(region, camera)
    assert len(cloud) == 399 and cloud.points_m.dtype == np.float32
    np.testing.assert_allclose(cloud.points_m[:, 2], 0.8, atol=1e-6)
    # The patch spans pixels 30..49: x from (30 - 39.5) to (49 - 39.5) times 0.8 / 70.
    np.testing.assert_allclose(cloud.points_m[:, 0].min(), -9.5 * 0.8 / 70, atol=1e-6)
    np.testing.assert_allclose(cloud.points_m[:, 0].max(), 9.5 * 0.8 / 70, atol=1e-6)
    assert np.all(cloud.labels == 4)


def test_hand_region_drops_far_and_small_glove_colored_things():
    labels = np.zeros((100, 100), np.uint8)
    depth = np.full((100, 100), 0.6, np.float32)
    labels[30:60, 30:60] = 2  # the hand
    labels[5:8, 90:93] = 5  # a speck far from it
    labels[80:95, 5:20] = 3  # a glove-colored poster on the wall
    depth[80:95, 5:20] = 2.5
    region = hand_region(labels, depth, z_range_m=(0.2, 1.5))
    assert len(region) == 900 and set(region.labels) == {2}
    empty = hand_region(np.zeros((10, 10), np.uint8), np.zeros((10, 10), np.float32))
    assert len(empty) == 0


def test_hand_region_ignores_glove_colored_noise_on_the_wall_behind():
    # A dim room: the camera's gain makes a third of a dark wall's pixels glove-like
    # at random. Dense enough to connect into one blob with the hand, it is noise: the
    # hand (a palm and a finger 4 px wide) keeps its pixels and nothing else.
    rng = np.random.default_rng(5)
    labels = np.where(rng.random((120, 160)) < 0.35, rng.integers(1, 11, (120, 160)), 0)
    depth = np.full((120, 160), 1.2, np.float32)  # the wall, within the working range
    hand = np.zeros((120, 160), bool)
    hand[50:90, 60:100] = True  # palm
    hand[20:50, 70:74] = True  # finger
    labels[hand] = 4
    depth[hand] = 0.6
    ring = cv2.dilate(hand.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~hand
    region = hand_region(labels.astype(np.uint8), depth)
    kept = np.zeros_like(hand)
    kept[region.pixels_uv[:, 1], region.pixels_uv[:, 0]] = True
    assert kept[hand].all()
    assert not (kept & ~hand & ~ring).any()  # at most wall noise touching the hand


def test_hand_region_is_the_same_wherever_the_scene_lies_in_the_frame():
    # hand_region works in the window of the glove pixels: a noisy scene that fills its
    # frame (the window is the frame) gives the same region as the scene placed inside
    # a larger empty frame, shifted.
    rng = np.random.default_rng(6)
    labels = np.where(rng.random((60, 80)) < 0.3, rng.integers(1, 11, (60, 80)), 0)
    depth = np.where(rng.random((60, 80)) < 0.1, 0.0, 1.2).astype(np.float32)
    labels[20:45, 25:50] = 7  # a hand in the noise
    depth[20:45, 25:50] = 0.6
    region = hand_region(labels.astype(np.uint8), depth)
    assert len(region) >= 25 * 25
    for top, left in ((0, 0), (37, 91), (140, 120)):
        big_labels = np.zeros((200, 200), np.uint8)
        big_depth = np.zeros((200, 200), np.float32)
        big_labels[top : top + 60, left : left + 80] = labels
        big_depth[top : top + 60, left : left + 80] = depth
        moved = hand_region(big_labels, big_depth)
        np.testing.assert_array_equal(moved.pixels_uv, region.pixels_uv + [left, top])
        np.testing.assert_array_equal(moved.labels, region.labels)
        np.testing.assert_array_equal(moved.depth_m, region.depth_m)


def test_rigid_fit_recovers_a_transform():
    rng = np.random.default_rng(1)
    points = rng.normal(size=(50, 3))
    rotation = axis_angle_to_matrix([0.3, -0.5, 0.8], 0.7)
    fitted_rotation, fitted_translation = rigid_fit(points, points @ rotation.T + [0.1, -0.2, 0.5])
    np.testing.assert_allclose(fitted_rotation, rotation, atol=1e-12)
    np.testing.assert_allclose(fitted_translation, [0.1, -0.2, 0.5], atol=1e-12)
    # A pair of weight zero does not count, however wrong it is.
    target = points @ rotation.T + [0.1, -0.2, 0.5]
    target[0] += 10.0
    weights = np.ones(len(points))
    weights[0] = 0.0
    fitted_rotation, fitted_translation = rigid_fit(points, target, weights)
    np.testing.assert_allclose(fitted_rotation, rotation, atol=1e-12)
    np.testing.assert_allclose(fitted_translation, [0.1, -0.2, 0.5], atol=1e-12)


def test_the_compiled_icp_steps_solve_what_their_numpy_forms_solve():
    rng = np.random.default_rng(2)
    source = rng.normal(size=(40, 3))
    rotation = axis_angle_to_matrix([0.3, -0.5, 0.8], 0.7)
    target = source @ rotation.T + [0.1, -0.2, 0.5] + rng.normal(scale=0.01, size=(40, 3))
    kabsch_rotation, kabsch_translation = np.eye(3), np.zeros(3)
    _icp_kernels._kabsch(source, target, kabsch_rotation, kabsch_translation)
    expected_rotation, expected_translation = rigid_fit(source, target)
    np.testing.assert_allclose(kabsch_rotation, expected_rotation, atol=1e-12)
    np.testing.assert_allclose(kabsch_translation, expected_translation, atol=1e-12)
    # Point-to-plane steps from a nearby pose reach the exact map of noise-free pairs.
    normals = rng.normal(size=(40, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    exact = source @ rotation.T + [0.1, -0.2, 0.5]
    step_rotation = axis_angle_to_matrix([1.0, 0.2, -0.3], np.radians(2.0)) @ rotation
    step_translation = np.array([0.103, -0.198, 0.497])
    for _ in range(4):
        _icp_kernels._point_to_plane_step(source, normals, exact, step_rotation, step_translation)
    np.testing.assert_allclose(step_rotation, rotation, atol=1e-9)
    np.testing.assert_allclose(step_translation, [0.1, -0.2, 0.5], atol=1e-9)


@pytest.mark.gl
def test_icp_recovers_a_rigid_perturbation_of_a_rendered_hand(renderer, pattern):
    skeleton = make_skeleton()
    mesh = renderer.mesh
    posture = named_posture("pinch")
    rotation = axis_angle_to_matrix([0.4, 1.0, 0.2], 2.2)
    translation = np.array([0.03, -0.02, 0.55])
    rendering = renderer.render_labels(posture, rotation, translation)
    region = hand_region(rendering.labels, rendering.depth_m)
    cloud = labeled_point_cloud(region, renderer.camera)
    split = split_by_label(mesh, pattern)
    surface = pose_mesh(mesh, posture)
    normals = vertex_normals(surface, mesh.faces)
    start_rotation = axis_angle_to_matrix([1.0, -0.4, 0.3], np.radians(6)) @ rotation
    start_translation = translation + [0.008, -0.006, 0.01]
    result = color_icp(
        cloud.points_m[::4], cloud.labels[::4],
        surface[split.source_vertex], normals[split.source_vertex], split.labels,
        start_rotation, start_translation, iterations=40,
    )  # fmt: skip
    assert np.degrees(geodesic_angle(result.rotation, rotation)) < 0.5
    assert np.linalg.norm(result.translation_m - translation) < 0.001
    assert result.cost_m < 0.001 and result.inlier_fraction > 0.9
    assert skeleton.hand_length_m == mesh.skeleton.hand_length_m


@pytest.mark.gl
def test_tracker_finds_rendered_hands_and_reports_no_hand_without_glove(small_database, renderer):
    from tracker.pipeline import Tracker, TrackerSettings

    settings = TrackerSettings(cascade="8:30,16:10,32:3", smoothing=None)
    with pytest.raises(ValueError, match="64"):
        Tracker(small_database, settings=TrackerSettings(cascade="8:30,64:3"))
    rng = np.random.default_rng(3)
    with Tracker(small_database, settings=settings) as tracker:
        errors = []
        for index, name in enumerate(["open", "pinch", "open", "pinch"]):
            rotation = axis_angle_to_matrix(rng.normal(size=3), rng.uniform(0, np.pi))
            translation = np.array([rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), 0.6])
            rendering = renderer.render(named_posture(name), rotation, translation)
            frame = Frame(index, rendering.color, rendering.depth_m, KINECT_V1)
            result = tracker.track(frame)
            assert result.hand_found
            errors.append((np.degrees(geodesic_angle(result.rotation, rotation)),
                           np.linalg.norm(result.translation_m - translation)))  # fmt: skip
            record = result.as_record()
            assert len(record["keypoints_2d_px"]) == 21 and len(record["fingertips"]) == 5
            assert 0 <= record["confidence"] <= 1 and record["timing_ms"]["total"] > 0
        # A 36-view database gives coarse starts; the fit still lands near the truth.
        assert np.median([e[0] for e in errors]) < 15 and np.median([e[1] for e in errors]) < 0.02
        bare = Frame(9, np.full((480, 640, 3), 90, np.uint8), np.full((480, 640), 0.7, np.float32),
                     KINECT_V1)  # fmt: skip
        empty_depth = Frame(10, rendering.color, np.zeros((480, 640), np.float32), KINECT_V1)
        # A red shirt and a blue sleeve: glove colors, but nothing looks up or fits.
        colors = load_pattern().colors_rgb
        clothes = np.full((480, 640, 3), 90, np.uint8)
        clothes[200:400, 100:300], clothes[220:380, 320:420] = colors[0], colors[8]
        shirt = Frame(11, clothes, np.full((480, 640), 0.7, np.float32), KINECT_V1)
        # A dark room's noise: a third of the pixels glove-colored at random, a wall at
        # 0.9 m: no hand (such pixels once reached the lookup and raised ValueError).
        glove_like = colors[rng.integers(0, 10, (480, 640))]
        speckle = np.where(rng.random((480, 640, 1)) < 0.35, glove_like, 40).astype(np.uint8)
        noise = Frame(12, speckle, np.full((480, 640), 0.9, np.float32), KINECT_V1)
        for frame in (bare, empty_depth, shirt, noise):
            result = tracker.track(frame)
            assert not result.hand_found
            assert result.as_record() == {"frame": frame.index, "timestamp_s": None,
                                          "hand_found": False,
                                          "timing_ms": result.as_record()["timing_ms"]}  # fmt: skip
    # Without the lookup's confidence gate, the generative fit's quality test says no;
    # with neither, the shirt is taken for a hand: the two gates are what say no.
    ungated = replace(settings, min_confidence=0.0)
    with Tracker(small_database, settings=ungated) as tracker:
        assert not tracker.track(shirt).hand_found
    trusting = replace(
        ungated, min_matched=0.0, max_outside=1.0, max_rms_m=1.0, min_fit_confidence=0.0,
        min_start_confidence=0.0,
    )  # fmt: skip
    with Tracker(small_database, settings=trusting) as tracker:
        found = tracker.track(shirt)
        assert found.hand_found and found.confidence < 0.3


@pytest.mark.gl
def test_the_warm_up_leaves_no_trace_in_the_poses(small_database, renderer, monkeypatch):
    # Tracker._warm_up runs the ICP and a fit on a synthetic frame; the tracker it
    # leaves behind must track exactly as one that never warmed up.
    from tracker.pipeline import Tracker, TrackerSettings

    settings = TrackerSettings(cascade="8:30,16:10,32:3")
    rotation = axis_angle_to_matrix(np.array([1.0, 0.0, 0.0]), np.pi)
    frames = [
        Frame(i, r.color, r.depth_m, KINECT_V1)
        for i, r in enumerate(
            renderer.render(named_posture(name), rotation, np.array([0.01, 0.0, 0.6]))
            for name in ("open", "pinch", "pinch")
        )
    ]

    def poses() -> list:
        with Tracker(small_database, settings=settings) as tracker:
            return [tracker.track(frame) for frame in frames]

    warmed = poses()
    monkeypatch.setattr(Tracker, "_warm_up", lambda self: None)
    cold = poses()
    for a, b in zip(warmed, cold, strict=True):
        assert a.hand_found and b.hand_found
        np.testing.assert_array_equal(a.posture_rad, b.posture_rad)
        np.testing.assert_array_equal(a.translation_m, b.translation_m)


@pytest.mark.gl
def test_icp_converges_from_the_lookup_of_a_thesis_database(open_pinch_power_database, renderer):
    from tracker.pipeline import Tracker, TrackerSettings

    rng = np.random.default_rng(11)
    rotation_errors, position_errors = [], []
    with Tracker(open_pinch_power_database, settings=TrackerSettings(smoothing=None)) as tracker:
        for index in range(12):
            name = ("open", "pinch", "power")[index % 3]
            rotation = axis_angle_to_matrix(rng.normal(size=3), rng.uniform(0, np.pi))
            translation = np.array([rng.uniform(-0.1, 0.1), rng.uniform(-0.08, 0.08),
                                    rng.uniform(0.5, 0.8)])  # fmt: skip
            rendering = renderer.render(named_posture(name), rotation, translation)
            result = tracker.track(Frame(index, rendering.color, rendering.depth_m, KINECT_V1))
            assert result.hand_found
            rotation_errors.append(np.degrees(geodesic_angle(result.rotation, rotation)))
            position_errors.append(np.linalg.norm(result.translation_m - translation))
    assert np.median(rotation_errors) < 1.0 and np.median(position_errors) < 0.002


@pytest.mark.gl
def test_fingertip_detections_are_named_and_reported(open_pinch_power_database, renderer):
    from glovedb.hand_model import FINGERS, FINGERTIP_KEYPOINTS, forward_kinematics
    from tracker.pipeline import Tracker, TrackerSettings, tip_targets_of

    rotation, translation = np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.06, 0.45])
    rendering = renderer.render(named_posture("open"), rotation, translation)
    frame = Frame(0, rendering.color, rendering.depth_m, KINECT_V1)
    settings = TrackerSettings(smoothing=None, fingertip_model="default")
    with Tracker(open_pinch_power_database, settings=settings) as tracker:
        result = tracker.track(frame)
        skeleton = tracker.skeleton
    true_tips = forward_kinematics(named_posture("open"), skeleton).keypoints_m[0]
    true_tips = true_tips[list(FINGERTIP_KEYPOINTS)] @ rotation.T + translation
    assert result.hand_found and "fingertips" in result.timing_ms
    detections = result.fingertip_detections
    # An open hand at 45 cm: the shipped model finds every tip and Eq. 11 names it.
    assert detections is not None and len(detections) == 5
    for detection in detections:
        true_tip = true_tips[FINGERS.index(str(detection.finger))]
        assert np.linalg.norm(true_tip - [detection.x_m, detection.y_m, detection.z_m]) < 0.012
    np.testing.assert_allclose(tip_targets_of(detections), true_tips, atol=0.012)
    record = result.as_record()
    assert {d["finger"] for d in record["fingertip_detections"]} == set(FINGERS)
    with Tracker(
        open_pinch_power_database, settings=replace(settings, fingertip_model=None)
    ) as plain:
        assert "fingertip_detections" not in plain.track(frame).as_record()


def test_tip_targets_of_leaves_unnamed_fingers_empty():
    from fingertips.detect import Detection
    from tracker.pipeline import tip_targets_of

    detections = [Detection(1.0, 2.0, 0.1, 0.2, 0.5, 3.0, finger="ring"),
                  Detection(5.0, 6.0, 0.3, 0.1, 0.6, 2.0)]  # fmt: skip
    targets = tip_targets_of(detections)
    np.testing.assert_array_equal(targets[3], [0.1, 0.2, 0.5])
    assert np.isnan(np.delete(targets, 3, axis=0)).all()
    assert np.isnan(tip_targets_of([])).all()


def test_temporal_scores_prefer_the_previous_posture_by_the_given_weight():
    from tracker.pipeline import temporal_scores

    errors = np.array([1.0, 1.2, np.inf])
    postures = np.stack([np.full(20, 0.5), np.zeros(20), np.zeros(20)])
    np.testing.assert_array_equal(temporal_scores(errors, postures, None, 1.0), errors)
    np.testing.assert_array_equal(temporal_scores(errors, postures, np.zeros(20), 0.0), errors)
    # 0.5 rad from the previous posture costs 0.5 px at 1 px/rad: the second
    # candidate (error 1.2, no change) now beats the first (1.0 + 0.5).
    scores = temporal_scores(errors, postures, np.zeros(20), 1.0)
    np.testing.assert_allclose(scores[:2], [1.5, 1.2])
    assert scores[2] == np.inf
    with pytest.raises(ValueError, match="prior_px_per_rad"):
        temporal_scores(errors, postures, np.zeros(20), -1.0)
    with pytest.raises(ValueError, match="postures_rad"):
        temporal_scores(errors, postures[:2], np.zeros(20), 1.0)


@pytest.mark.gl
def test_a_warm_fit_that_leaves_the_hand_asks_the_lookup_again(open_pinch_power_database, renderer):
    from tracker.pipeline import Tracker, TrackerSettings

    rotation = axis_angle_to_matrix(np.array([1.0, 0.0, 0.0]), np.pi)  # palm to the camera
    translation = np.array([0.0, 0.0, 0.6])
    frames = [
        Frame(index, rendering.color, rendering.depth_m, KINECT_V1)
        for index, rendering in enumerate(
            renderer.render(named_posture(name), rotation, translation)
            for name in ("open", "fist")  # the hand closes faster than a warm start follows
        )
    ]
    lookups, errors = {}, {}
    for relook in (0.03, 1.0):  # the default, and off
        # Within the frame (tests/tracker/test_background.py: off the frame).
        settings = TrackerSettings(smoothing=None, relook_outside=relook, lookup_delay_frames=0)
        with Tracker(open_pinch_power_database, settings=settings) as tracker:
            calls = []
            start = tracker._lookup_start
            tracker._lookup_start = lambda *a, start=start, calls=calls, **k: (  # type: ignore
                calls.append(1) or start(*a, **k)
            )
            results = [tracker.track(frame) for frame in frames]
        lookups[relook] = len(calls)
        assert all(result.hand_found for result in results)
        errors[relook] = np.degrees(np.abs(results[1].posture_rad - named_posture("fist"))).mean()
    # The first frame always looks up; the second only when the warm fit sticks out.
    assert lookups == {0.03: 2, 1.0: 1}
    # From the open hand the warm fit stays 32 deg from the fist; from the lookup's
    # start (the database's power grasp, its nearest posture), 17.
    assert errors[0.03] < 20.0 and errors[1.0] > 1.5 * errors[0.03]


def test_a_start_needs_more_confidence_than_a_tracked_frame():
    from tracker.pipeline import TrackerSettings, fit_quality, fit_trusted

    settings = TrackerSettings()
    matched, outside, rms_m = 0.625, 0.2, 0.0  # confidence 0.625 * 0.8 = 0.5
    assert fit_quality(matched, outside, rms_m) == pytest.approx(0.5)
    assert settings.min_fit_confidence < 0.5 < settings.min_start_confidence
    assert fit_trusted(matched, outside, rms_m, settings, starting=False)
    assert not fit_trusted(matched, outside, rms_m, settings, starting=True)
    with pytest.raises(ValueError, match="min_start_confidence"):
        TrackerSettings(min_start_confidence=1.5)


def test_the_databases_postures_join_the_prior_unless_they_are_many(open_pinch_power_database):
    from tracker.generative.fit import FitSettings
    from tracker.pipeline import Tracker, TrackerSettings

    def task_postures(**fit):
        settings = TrackerSettings(fit=FitSettings(**fit))
        with Tracker(open_pinch_power_database, settings=settings) as tracker:
            return tracker.prior.task_postures_rad

    held = task_postures()
    expected = np.stack([named_posture(name) for name in ("open", "pinch", "power")])
    np.testing.assert_allclose(np.sort(held, axis=0), np.sort(expected, axis=0), atol=1e-6)
    assert len(task_postures(task_prior_max_postures=2)) == 0  # more than a task holds
    assert len(task_postures(task_prior_spread=0.0)) == 0  # turned off
