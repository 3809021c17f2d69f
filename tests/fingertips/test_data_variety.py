"""Varied fingertip scenes (issue 23): hand shapes, distances, border cuts, sensors,
nearby objects and sleeves, against known truth; default configs render as before."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fingertips.data import (
    FingertipDataConfig,
    NearbyObject,
    Scene,
    forearm_depth,
    generate_examples,
    load_data_config,
    object_depth,
    render_scene,
    require_one_camera,
    sample_scene,
)
from fingertips.evaluation import recall_by_depth
from fingertips.features import project
from glovedb.hand_model import FINGERTIP_KEYPOINTS
from glovedb.proportions import HandProportions
from glovedb.views import HAND_CENTRE, pose_for_view

CONFIGS = Path(__file__).resolve().parents[2] / "configs" / "fingertips"
CLEAN = FingertipDataConfig(n_images=4, noise=("none",), seed=3)
INDEX_MCP, INDEX_TIP = 5, 8


def _open_hand_scene(**fields: object) -> Scene:
    """An open right hand 0.5 m away, its back to the camera, fingers up, centred."""
    rotation, translation = pose_for_view(
        np.array([0.0, 0.0, 1.0]), 0.5, target_m=np.array(HAND_CENTRE) * 0.19, roll_rad=0.0
    )
    return Scene(
        np.zeros(20), rotation, translation, 0.19, None, None, False, "none", False, **fields
    )


def _hand_centre(scene: Scene) -> np.ndarray:
    """The middle of the hand (what the camera distance counts to), camera frame."""
    return scene.rotation @ (np.array(HAND_CENTRE) * scene.hand_length_m) + scene.translation_m


@pytest.mark.gl
def test_default_config_examples_are_unchanged(renderer) -> None:
    # Recorded before the widened scenes existed: same seed, same examples.
    config = replace(load_data_config(CONFIGS / "default.toml"), n_images=4, seed=7)
    expected = [
        ((480, 640), 157252, 1.119087, "realsense_d435", [-0.161469, -0.221951, 0.712122]),
        ((240, 320), 76107, 1.666982, "kinect_v1", [-0.226234, -0.167515, 1.100313]),
        ((240, 320), 1385, 0.463748, "realsense_d435", [-0.154039, 0.174763, 0.438203]),
        ((240, 320), 15085, 1.608987, "kinect_v1", [0.212933, 0.078672, 0.931907]),
    ]
    examples = list(generate_examples(config, renderer))
    for example, (shape, seen, mean, noise, thumb) in zip(examples, expected, strict=True):
        assert example.depth_m.shape == shape and example.scene.noise == noise
        assert example.scene.proportions is None and example.scene.nearby_object is None
        assert np.count_nonzero(example.depth_m) == seen
        np.testing.assert_allclose(example.depth_m[example.depth_m > 0].mean(), mean, atol=2e-6)
        np.testing.assert_allclose(example.tips_m[0], thumb, atol=2e-6)
    assert np.isnan(examples[2].tips_m[[1, 2, 4]]).all()


@pytest.mark.gl
def test_longer_index_finger_reaches_farther_by_its_factor(renderer) -> None:
    model = render_scene(renderer, _open_hand_scene(), CLEAN, np.random.default_rng(0))
    longer = HandProportions(finger_length=(1.0, 1.2, 1.0, 1.0, 1.0))
    stretched = render_scene(
        renderer, _open_hand_scene(proportions=longer), CLEAN, np.random.default_rng(0)
    )
    before, after = model.keypoints_m, stretched.keypoints_m
    # The index chain from its MCP scales by exactly 1.2 (the palm is unchanged).
    np.testing.assert_allclose(after[INDEX_MCP], before[INDEX_MCP], atol=1e-12)
    np.testing.assert_allclose(
        after[INDEX_TIP] - after[INDEX_MCP],
        1.2 * (before[INDEX_TIP] - before[INDEX_MCP]),
        atol=1e-9,
    )
    wrist = before[0]
    reach = [np.linalg.norm(k[INDEX_TIP] - wrist) for k in (before, after)]
    expected = np.linalg.norm(
        before[INDEX_MCP] + 1.2 * (before[INDEX_TIP] - before[INDEX_MCP]) - wrist
    )
    np.testing.assert_allclose(reach[1], expected, atol=1e-9)
    assert reach[1] - reach[0] > 0.2 * 0.06  # the index finger is more than 6 cm long
    # The rendered surface follows: the new tip is visible and hand pixels reach it.
    assert np.isfinite(stretched.tips_m[1]).all()
    u, v = np.rint(project(after[INDEX_TIP][None], stretched.intrinsics)[0]).astype(int)
    near = stretched.depth_m[v - 3 : v + 4, u - 3 : u + 4]
    assert np.any(np.abs(near[near > 0] - after[INDEX_TIP, 2]) < 0.015)
    assert np.count_nonzero(model.depth_m[v - 3 : v + 4, u - 3 : u + 4]) == 0


@pytest.mark.gl
def test_an_object_in_front_of_a_tip_hides_it(renderer) -> None:
    bare = render_scene(renderer, _open_hand_scene(), CLEAN, np.random.default_rng(0))
    tip = bare.keypoints_m[INDEX_TIP]
    ray = tip / np.linalg.norm(tip)
    # A 1.5 cm ball centred 4 cm in front of the index tip on its viewing ray.
    ball = NearbyObject("ball", INDEX_TIP, -0.04 * ray, np.full(3, 0.015), np.eye(3))
    scene = _open_hand_scene(nearby_object=ball)
    hidden = render_scene(renderer, scene, CLEAN, np.random.default_rng(0))
    assert np.isfinite(bare.tips_m).all()
    assert np.isnan(hidden.tips_m[1]).all()
    np.testing.assert_array_equal(hidden.tips_m[[0, 2, 3, 4]], bare.tips_m[[0, 2, 3, 4]])
    # At the tip's pixel the ball's front is 5.5 cm nearer along the ray.
    u, v = np.rint(project(tip[None], bare.intrinsics)[0]).astype(int)
    np.testing.assert_allclose(hidden.depth_m[v, u], tip[2] - 0.055 * ray[2], atol=1e-3)
    # Moving hidden tips onto the surface in front never puts one on the object.
    surface = replace(CLEAN, surface_tip_depth_m=0.06)
    moved = render_scene(renderer, scene, surface, np.random.default_rng(0))
    assert np.isnan(moved.tips_m[1]).all()


@pytest.mark.gl
def test_border_option_cuts_the_hand(renderer) -> None:
    config = replace(
        CLEAN, n_images=6, half_resolution_fraction=0.0, plane_probability=0.0,
        border_fraction=1.0, border_overhang_range=(0.0, 0.0),
    )  # fmt: skip
    outside = inside = 0
    for example in generate_examples(config, renderer):
        truth = example.keypoints_m[list(FINGERTIP_KEYPOINTS)]
        uv = np.rint(project(truth, example.intrinsics))
        out = (uv[:, 0] < 0) | (uv[:, 0] >= 640) | (uv[:, 1] < 0) | (uv[:, 1] >= 480)
        assert np.isnan(example.tips_m[out]).all()
        outside += int(out.sum())
        inside += int(np.isfinite(example.tips_m[:, 0]).sum())
    assert outside >= 3 and inside >= 3


def test_border_scenes_put_the_middle_of_the_hand_on_an_edge() -> None:
    config = replace(CLEAN, border_fraction=1.0, border_overhang_range=(0.0, 0.0))
    rng = np.random.default_rng(5)
    for _ in range(20):
        scene = sample_scene(config, [np.zeros(20)], rng)
        centre = _hand_centre(scene)
        u, v = project(centre[None], np.array([525.0, 525.0, 319.5, 239.5]))[0]
        to_edge = min(abs(u + 0.5), abs(u - 639.5), abs(v + 0.5), abs(v - 479.5))
        assert to_edge < 1e-6


def test_distance_and_hand_length_ranges_are_respected() -> None:
    config = replace(CLEAN, distance_range_m=(0.25, 1.5), hand_length_range_m=(0.16, 0.22))
    rng = np.random.default_rng(6)
    depths, lengths = [], []
    for _ in range(300):
        scene = sample_scene(config, [np.zeros(20)], rng)
        centre = _hand_centre(scene)
        depths.append(centre[2])
        lengths.append(scene.hand_length_m)
    assert 0.25 <= min(depths) < 0.3 and 1.45 < max(depths) <= 1.5
    assert 0.16 <= min(lengths) < 0.165 and 0.215 < max(lengths) <= 0.22


def test_shapes_sleeves_and_objects_are_drawn_within_their_ranges() -> None:
    config = replace(
        CLEAN, finger_length_range=(0.8, 1.2), palm_width_range=(0.9, 1.1),
        thickness_range=(0.85, 1.15), forearm_probability=1.0, sleeve_probability=1.0,
        object_probability=1.0, object_size_range_m=(0.02, 0.05), object_gap_range_m=(0.01, 0.02),
    )  # fmt: skip
    rng = np.random.default_rng(8)
    kinds = set()
    for _ in range(40):
        scene = sample_scene(config, [np.zeros(20)], rng)
        assert scene.proportions is not None and scene.sleeve is not None
        assert all(0.8 <= f <= 1.2 for f in scene.proportions.finger_length)
        assert 0.9 <= scene.proportions.palm_width <= 1.1 and 0.85 <= scene.thickness <= 1.15
        assert 0.3 <= scene.sleeve[0] <= 1.0 and 1.15 <= scene.sleeve[1] <= 1.5
        thing = scene.nearby_object
        assert thing is not None
        kinds.add(thing.kind)
        assert np.all((thing.half_extents_m >= 0.02) & (thing.half_extents_m <= 0.05))
        np.testing.assert_allclose(thing.rotation @ thing.rotation.T, np.eye(3), atol=1e-12)
        # The object's surface lies 1-2 cm from its keypoint along the offset.
        direction = thing.offset_m / np.linalg.norm(thing.offset_m)
        local = np.abs(thing.rotation.T @ direction)
        reach = np.min(thing.half_extents_m / np.maximum(local, 1e-12))
        assert 0.01 - 1e-9 <= np.linalg.norm(thing.offset_m) - reach <= 0.02 + 1e-9
    assert kinds == {"ball", "box"}


def test_object_depth_known_values() -> None:
    camera = np.array([100.0, 100.0, 50.0, 40.0])
    centre = np.array([0.0, 0.0, 0.5])
    ball = NearbyObject("ball", 0, np.zeros(3), np.full(3, 0.1), np.eye(3))
    depth = object_depth((80, 100), camera, centre, ball)
    assert depth.dtype == np.float32 and depth.shape == (80, 100)
    np.testing.assert_allclose(depth[40, 50], 0.4, atol=1e-6)
    assert depth[40, 50 + 25] == 0  # tan = 0.25 > 0.1 / 0.5: the ray misses
    box = NearbyObject("box", 0, np.zeros(3), np.array([0.1, 0.05, 0.1]), np.eye(3))
    depth = object_depth((80, 100), camera, centre, box)
    np.testing.assert_allclose(depth[40, 50 + 15], 0.4, atol=1e-6)  # the front face
    assert depth[40 + 15, 50] == 0  # 0.15 * 0.4 m = 6 cm > 5 cm half extent in y


def test_sleeve_covers_only_the_far_part_of_the_forearm() -> None:
    camera = np.array([100.0, 100.0, 50.0, 40.0])
    args = ((80, 100), camera, np.eye(3), np.array([0.0, 0.0, 0.5]), 0.19)
    arm = forearm_depth(*args)
    sleeve = forearm_depth(*args, half_axes=(0.17 * 1.3, 0.12 * 1.3), span=(0.5, 1.4))
    # The forearm runs up from the wrist row 40; the sleeve from 0.5 hand lengths on.
    start_row = 40 - int(np.ceil(100 * 0.5 * 0.19 / (0.5 - 0.12 * 1.3 * 0.19)))
    assert np.all(sleeve[start_row + 2 : 41, 50] == 0) and np.all(sleeve[: start_row - 2, 50] > 0)
    np.testing.assert_allclose(sleeve[10, 50], 0.5 - 0.12 * 1.3 * 0.19, atol=1e-6)
    assert np.all(sleeve[: start_row - 2, 50] < arm[: start_row - 2, 50])


def test_sensor_models_at_qvga() -> None:
    # Without a renderer: the sensor presets on an analytic scene at half resolution.
    from builder.depth_noise import apply_depth_noise, noise_preset

    camera = np.array([262.5, 262.5, 159.75, 119.75])
    ball = NearbyObject("ball", 0, np.zeros(3), np.full(3, 0.05), np.eye(3))
    clean = object_depth((240, 320), camera, np.array([0.0, 0.0, 0.6]), ball)
    for name in ("structured_light", "active_stereo", "time_of_flight"):
        config = replace(CLEAN, noise=(name,), half_resolution_fraction=1.0)
        assert config.noise == (name,)
        noisy = apply_depth_noise(clean, camera, noise_preset(name), rng=np.random.default_rng(1))
        assert noisy.shape == (240, 320) and noisy.dtype == np.float32
        centre = noisy[110:130, 150:170]
        assert np.median(centre[centre > 0]) == pytest.approx(0.55, abs=0.01)


def test_new_config_keys_are_checked() -> None:
    for fields, message in [
        ({"finger_length_range": (0.4, 1.0)}, "finger_length_range"),
        ({"palm_width_range": (1.2, 1.1)}, "palm_width_range"),
        ({"object_size_range_m": (0.0, 0.1)}, "object_size_range_m"),
        ({"border_fraction": 1.5}, "border_fraction"),
        ({"posture_sets": ("no_such_set",)}, "posture_sets"),
        ({"sleeve_start_range": (0.5, 2.0)}, "sleeve_start_range"),
    ]:
        with pytest.raises(ValueError, match=message):
            FingertipDataConfig(**fields)  # type: ignore[arg-type]
    assert not CLEAN.varies_shape
    assert replace(CLEAN, thickness_range=(0.9, 1.0)).varies_shape


def test_new_configs_load_and_validation_holds_what_training_never_saw() -> None:
    from fingertips.training import load_recipe

    train = load_recipe(CONFIGS / "train_varied.toml").data
    unseen = load_data_config(CONFIGS / "validation_unseen.toml")
    require_one_camera(unseen)  # one folder
    assert train.distance_range_m == (0.25, 1.5) and train.hand_length_range_m == (0.16, 0.22)
    assert train.varies_shape and train.object_probability > 0 and train.border_fraction > 0
    assert set(unseen.noise) - set(train.noise) == {"time_of_flight"}
    assert (unseen.fx, unseen.cy) != (train.fx, train.cy)
    assert unseen.finger_length_range[0] < train.finger_length_range[0]
    assert unseen.finger_length_range[1] > train.finger_length_range[1]
    assert unseen.seed not in {train.seed, train.seed + 1000, 0, 1, 2, 3}
    default = load_data_config(CONFIGS / "default.toml")
    assert not default.varies_shape and default.object_probability == 0


def test_recall_by_depth_bands() -> None:
    bands = recall_by_depth([0.3, 0.45, 0.6, 1.1, 1.4, 1.6], [True, False, True, True, False, True])
    assert list(bands) == ["0-0.5 m", "0.5-0.75 m", "0.75-1 m", "1-1.25 m", "1.25+ m"]
    assert bands["0-0.5 m"] == {"tips": 2, "recall_15mm": 0.5}
    assert bands["1.25+ m"] == {"tips": 2, "recall_15mm": 0.5}
    assert bands["0.75-1 m"]["tips"] == 0 and np.isnan(bands["0.75-1 m"]["recall_15mm"])
