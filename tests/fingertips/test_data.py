"""Rendered fingertip data: visibility of tips, mirroring, planes, the folder writer."""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fingertips.data import (
    FingertipDataConfig,
    FingertipExample,
    Scene,
    curl_fingers,
    forearm_depth,
    generate_examples,
    load_data_config,
    mirror_example,
    require_one_camera,
    sample_scene,
    visible_tips,
    write_annotated_folder,
)
from fingertips.evaluation import read_annotated_depth
from fingertips.features import project
from glovedb.hand_model import FINGERTIP_KEYPOINTS, JOINT_NAMES, joint_limits_rad

INTRINSICS = np.array([100.0, 100.0, 15.5, 11.5])
CLEAN = FingertipDataConfig(n_images=4, noise=("none",), seed=3)


def test_visible_tips_known_cases() -> None:
    depth = np.zeros((24, 32), np.float32)
    depth[10:14, :] = 0.5
    tips = np.array(
        [
            [0.0, 0.0, 0.51],  # pixel (15.5, 11.5) reads 0.5: 1 cm in front, visible
            [0.0, 0.0, 0.53],  # 3 cm behind the surface: hidden
            [0.0, -0.04, 0.5],  # row 3.5, nothing rendered there: visible
            [1.0, 0.0, 0.5],  # outside the image
            [0.0, 0.0, -0.2],  # behind the camera
        ]
    )
    out = visible_tips(depth, tips, INTRINSICS, tolerance_m=0.015)
    assert out.dtype == np.float64
    np.testing.assert_array_equal(np.isnan(out[:, 0]), [False, True, False, True, True])
    np.testing.assert_array_equal(out[0], tips[0])


def test_surface_tips_move_onto_the_surface_that_hides_them() -> None:
    depth = np.zeros((24, 32), np.float32)
    depth[10:14, :] = 0.5
    tips = np.array(
        [
            [0.0, 0.0, 0.51],  # 1 cm behind: visible, kept as it is
            [0.0, 0.0, 0.53],  # 3 cm behind: moved onto the surface
            [0.001, 0.0, 0.56],  # 6 cm behind: still hidden
        ]
    )
    out = visible_tips(depth, tips, INTRINSICS, tolerance_m=0.015, surface_m=0.04)
    np.testing.assert_array_equal(out[0], tips[0])
    # It projects to (15.5, 11.5), which rounds half to even to column 16, row 12, a
    # pixel that sees 0.5 m.
    np.testing.assert_allclose(out[1], [(16 - 15.5) * 0.5 / 100, (12 - 11.5) * 0.5 / 100, 0.5])
    assert np.isnan(out[2]).all()
    # Off by default; surface_m at most the tolerance changes nothing.
    hidden = visible_tips(depth, tips, INTRINSICS, tolerance_m=0.015)
    assert np.isnan(hidden[1:]).all()
    with pytest.raises(ValueError, match="surface_tip_depth_m"):
        FingertipDataConfig(surface_tip_depth_m=0.01)


def test_curl_fingers_within_ranges() -> None:
    config = replace(
        CLEAN, posture_jitter_deg=0.0, curl_mcp_range_deg=(20.0, 60.0),
        curl_pip_range_deg=(90.0, 110.0), curl_dip_range_deg=(50.0, 80.0),
    )  # fmt: skip
    rng = np.random.default_rng(0)
    base = np.radians(np.arange(20.0))  # small angles, all within the limits
    for _ in range(20):
        posture = np.degrees(curl_fingers(base, config, rng))
        for finger in ("index", "middle", "ring", "little"):
            mcp, pip, dip = (
                posture[JOINT_NAMES.index(f"{finger}_{joint}_flex")]
                for joint in ("mcp", "pip", "dip")
            )
            assert 20 <= mcp <= 60 and 90 <= pip <= 110 and 50 <= dip <= 80
            abduction = JOINT_NAMES.index(f"{finger}_mcp_abd")
            assert posture[abduction] == pytest.approx(abduction)
        np.testing.assert_allclose(posture[:4], np.arange(4.0))  # the thumb is kept
    untouched = curl_fingers(base, replace(config, curl_finger_probability=0.0), rng)
    np.testing.assert_array_equal(untouched, base)


def test_curl_fingers_beyond_the_limits_only_when_asked() -> None:
    config = replace(
        CLEAN, posture_jitter_deg=0.0, curl_mcp_range_deg=(100.0, 100.0),
        curl_pip_range_deg=(120.0, 120.0), curl_dip_range_deg=(115.0, 115.0),
    )  # fmt: skip
    limits = np.degrees(joint_limits_rad())
    for beyond in (False, True):
        case = replace(config, curl_beyond_limits=beyond)
        posture = np.degrees(curl_fingers(np.zeros(20), case, np.random.default_rng(0)))
        for joint, wanted in (("mcp", 100.0), ("pip", 120.0), ("dip", 115.0)):
            index = JOINT_NAMES.index(f"index_{joint}_flex")
            # MCP stays clipped either way; PIP and DIP pass their limits when asked.
            expected = wanted if beyond and joint != "mcp" else min(wanted, limits[index, 1])
            assert posture[index] == pytest.approx(expected)


def test_curled_scenes_face_the_palm_and_are_deterministic() -> None:
    named = [np.zeros(20)]
    config = replace(CLEAN, curl_fraction=1.0, curl_palm_fraction=1.0, posture_jitter_deg=0.0)
    cos_cone = np.cos(np.radians(config.facing_cone_deg))
    first = [sample_scene(config, named, np.random.default_rng(k)) for k in range(10)]
    again = [sample_scene(config, named, np.random.default_rng(k)) for k in range(10)]
    for scene, same in zip(first, again, strict=True):
        np.testing.assert_array_equal(scene.posture_rad, same.posture_rad)
        np.testing.assert_array_equal(scene.rotation, same.rotation)
        # The camera looks along its +z; the palm normal (hand -z) points back at it.
        assert scene.rotation[2, 2] >= cos_cone - 1e-9
        pip = np.degrees(scene.posture_rad[JOINT_NAMES.index("index_pip_flex")])
        low, high = config.curl_pip_range_deg
        assert low <= pip <= high
    # At curl_fraction 0 the curl settings draw nothing: the scenes are the old ones.
    plain = replace(CLEAN, curl_pip_range_deg=(0.0, 1.0), curl_palm_fraction=0.0)
    a = sample_scene(CLEAN, named, np.random.default_rng(5))
    b = sample_scene(plain, named, np.random.default_rng(5))
    np.testing.assert_array_equal(a.rotation, b.rotation)


def test_mirroring_maps_points_to_mirrored_pixels() -> None:
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.3, 0.6, (24, 32)).astype(np.float32)
    points = np.array([[0.01, 0.02, 0.4], [-0.03, 0.0, 0.5]])
    flipped, camera, mirrored = mirror_example(depth, INTRINSICS, points)
    np.testing.assert_array_equal(flipped, depth[:, ::-1])
    np.testing.assert_allclose(camera, [100.0, 100.0, 31 - 15.5, 11.5])
    uv, uv_mirrored = project(points, INTRINSICS), project(mirrored, camera)
    np.testing.assert_allclose(uv_mirrored[:, 0], 31 - uv[:, 0])
    np.testing.assert_allclose(uv_mirrored[:, 1], uv[:, 1])


def test_forearm_depth_known_values() -> None:
    # Forearm axis along the camera's -y from a wrist 0.5 m in front of the camera,
    # hand length 0.19 m: half width 0.0323 m (x), half thickness 0.0228 m (z).
    camera = np.array([100.0, 100.0, 50.0, 40.0])
    depth = forearm_depth((80, 100), camera, np.eye(3), np.array([0.0, 0.0, 0.5]), 0.19)
    assert depth.dtype == np.float32 and depth.shape == (80, 100)
    # Rays with x = 0 meet the front of the elliptic section at z = 0.5 - 0.0228.
    np.testing.assert_allclose(depth[:40, 50], 0.5 - 0.12 * 0.19, atol=1e-6)
    assert np.all(depth[41:, :] == 0)  # below the wrist: no forearm
    assert depth[20, 50 - 5] > depth[20, 50] and depth[20, 50 + 5] > depth[20, 50]
    assert depth[20, 50 - 8] == 0 and depth[20, 50 + 8] == 0  # 8 px = 0.04 m > half width


def test_forearm_is_drawn_as_configured() -> None:
    named = [np.zeros(20)]
    rng = np.random.default_rng(4)
    without = [sample_scene(CLEAN, named, rng) for _ in range(5)]
    assert all(scene.forearm_rotation is None for scene in without)
    config = replace(CLEAN, forearm_probability=1.0, wrist_flex_max_deg=30.0)
    for _ in range(5):
        rotation = sample_scene(config, named, rng).forearm_rotation
        assert rotation is not None
        np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
        # The forearm direction -y stays within the flexion and deviation bounds.
        angle = np.degrees(np.arccos(rotation[1, 1]))
        assert angle <= np.hypot(30.0, config.wrist_deviation_max_deg) + 1e-9


def test_config_checks_and_toml(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="noise"):
        FingertipDataConfig(noise=("kinect_v7",))
    with pytest.raises(ValueError, match="distance_range_m"):
        FingertipDataConfig(distance_range_m=(1.0, 0.5))
    with pytest.raises(ValueError, match="curl_fraction"):
        FingertipDataConfig(curl_fraction=1.5)
    with pytest.raises(ValueError, match="curl_pip_range_deg"):
        FingertipDataConfig(curl_pip_range_deg=(100.0, 90.0))
    bad_values = {
        "mirror_probability": 5.0,  # every share is in [0, 1]
        "plane_probability": -1.0,
        "half_resolution_fraction": 2.0,
        "seed": -1,
        "width": 0,
        "fx": -525.0,
        "distance_range_m": (0.0, 0.0),
        "hand_length_range_m": (5.0, 6.0),  # metres, not a hand
    }
    for name, value in bad_values.items():
        with pytest.raises(ValueError, match=name.split("_range")[0]):
            FingertipDataConfig(**{name: value})
    path = tmp_path / "data.toml"
    path.write_text('[data]\nn_images = 7\nnoise = ["none"]\n')
    assert load_data_config(path) == FingertipDataConfig(n_images=7, noise=("none",))
    path.write_text("[data]\nn_imgs = 7\n")
    with pytest.raises(ValueError, match="n_imgs"):
        load_data_config(path)
    refused = [
        ('[data]\nn_images = "7"', "data: n_images: expected a whole number, got '7'"),
        ("[data]\ndistance_range_m = [0.3]", "data: distance_range_m: expected a list of 2"),
        ("[data]\nmirror_probability = true", "data: mirror_probability: expected a number"),
        ("[dat]\nn_images = 7", "unknown tables dat"),  # a misspelt table is not ignored
        ("[training]\nseed = 1", r"no \[data\] table"),
        ("[data", r"data\.toml: cannot read config"),
    ]
    for text, message in refused:
        path.write_text(text + "\n")
        with pytest.raises(ValueError, match=message):
            load_data_config(path)


def _toy_example(frame: int) -> FingertipExample:
    depth = np.zeros((24, 32), np.float32)
    depth[5:20, 5:25] = 0.4 + 0.001 * frame
    keypoints = np.tile([0.0, 0.0, 0.4], (21, 1))
    tips = keypoints[list(FINGERTIP_KEYPOINTS)].copy()
    tips[2:] = np.nan
    scene = Scene(
        np.zeros(20), np.eye(3), np.array([0, 0, 0.4]), 0.19, None, None, False, "none", False
    )
    assert scene.forearm_rotation is None
    return FingertipExample(depth, INTRINSICS, tips, keypoints, scene)


def test_a_folder_needs_one_camera_and_that_is_checked_before_rendering() -> None:
    require_one_camera(replace(CLEAN, half_resolution_fraction=0.0))
    require_one_camera(replace(CLEAN, half_resolution_fraction=1.0))
    with pytest.raises(ValueError, match="half_resolution_fraction: a folder has one camera"):
        require_one_camera(replace(CLEAN, half_resolution_fraction=0.5))


def test_folder_writer_round_trip(tmp_path: Path) -> None:
    count = write_annotated_folder([_toy_example(k) for k in range(3)], tmp_path)
    assert count == 3
    data = read_annotated_depth(tmp_path)
    np.testing.assert_allclose(data.depth_m[2, 10, 10], 0.402, atol=1e-6)
    np.testing.assert_allclose(data.intrinsics, INTRINSICS)
    assert np.isfinite(data.tips_m[:, :2]).all() and np.isnan(data.tips_m[:, 2:]).all()
    truth = [json.loads(line) for line in (tmp_path / "groundtruth.jsonl").read_text().splitlines()]
    assert len(truth) == 3 and len(truth[0]["keypoints_3d_m"]) == 21
    other = _toy_example(0)
    other = replace(other, intrinsics=INTRINSICS + 1)
    with pytest.raises(ValueError, match="same camera"):
        write_annotated_folder([_toy_example(0), other], tmp_path / "mixed")
    assert not any("mixed" in p.name for p in tmp_path.iterdir())  # nothing half-written
    # A second run into the same folder would mix old frames with new ones.
    before = sorted(p.name for p in (tmp_path / "depth").iterdir())
    with pytest.raises(ValueError, match="exists and is not an empty folder"):
        write_annotated_folder([_toy_example(0)], tmp_path)
    assert sorted(p.name for p in (tmp_path / "depth").iterdir()) == before
    assert len((tmp_path / "groundtruth.jsonl").read_text().splitlines()) == 3


@pytest.mark.gl
def test_rendered_tips_are_nan_exactly_when_hidden(renderer) -> None:
    examples = list(generate_examples(CLEAN, renderer))
    assert len(examples) == CLEAN.n_images
    n_visible = n_hidden = 0
    for example in examples:
        assert example.depth_m.dtype == np.float32 and example.tips_m.shape == (5, 3)
        height, width = example.depth_m.shape
        truth = example.keypoints_m[list(FINGERTIP_KEYPOINTS)]
        uv = np.rint(project(truth, example.intrinsics)).astype(int)
        for tip, (u, v), point in zip(example.tips_m, uv, truth, strict=True):
            inside = 0 <= u < width and 0 <= v < height and point[2] > 0
            seen = inside and not 0 < example.depth_m[v, u] < point[2] - 0.015
            assert np.isfinite(tip).all() == seen
            n_visible += seen
            n_hidden += not seen
    assert n_visible > 0


@pytest.mark.gl
def test_forearm_adds_depth_behind_the_hand_only(renderer) -> None:
    config = replace(CLEAN, n_images=1, plane_probability=0.0, half_resolution_fraction=0.0)
    bare = list(generate_examples(config, renderer))
    armed = list(generate_examples(replace(config, forearm_probability=1.0), renderer))
    for a, b in zip(bare, armed, strict=True):
        assert a.scene.forearm_rotation is None and b.scene.forearm_rotation is not None
        np.testing.assert_array_equal(a.scene.rotation, b.scene.rotation)
        seen = a.depth_m > 0
        assert np.all(b.depth_m[seen] <= a.depth_m[seen])  # the arm may hide, never remove
        assert np.count_nonzero(b.depth_m) > np.count_nonzero(a.depth_m)


@pytest.mark.gl
def test_mirrored_examples_are_flipped_copies(renderer) -> None:
    config = replace(CLEAN, n_images=2, half_resolution_fraction=0.0, plane_probability=1.0)
    right = list(generate_examples(replace(config, mirror_probability=0.0), renderer))
    left = list(generate_examples(replace(config, mirror_probability=1.0), renderer))
    for a, b in zip(right, left, strict=True):
        assert not a.scene.mirrored and b.scene.mirrored
        np.testing.assert_array_equal(b.depth_m, a.depth_m[:, ::-1])
        np.testing.assert_allclose(b.tips_m, a.tips_m * [-1.0, 1.0, 1.0])
        width = a.depth_m.shape[1]
        np.testing.assert_allclose(b.intrinsics[2], width - 1 - a.intrinsics[2])
