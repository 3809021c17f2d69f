"""Synthetic sequences: presets, trajectories, backgrounds, compositing, color noise,
and ground truth that agrees with the rendered images."""

import dataclasses

import cv2
import numpy as np
import pytest

from builder.color_noise import (
    ColorNoiseConfig,
    add_pixel_noise,
    apply_color_noise,
    apply_gains,
    color_noise_preset,
    sequence_gains,
)
from builder.sequence import (
    MAX_BACKGROUND_CHROMA,
    MIN_GLOVE_CHROMA_DISTANCE,
    WOOD_RGB,
    Background,
    SequenceSettings,
    background_colors,
    camera_keypoints,
    composite,
    hand_visible,
    load_camera,
    make_background,
    render_frames,
    resolve_trajectory,
    staged_folder,
    trajectory_names,
)
from glovedb.camera import KINECT_V1
from glovedb.hand_model import make_skeleton
from glovedb.pattern import chroma_uv, load_pattern
from glovedb.rotations import geodesic_angle, quaternion_to_matrix, slerp
from glovedb.trajectory import load_trajectory, trajectory_from_dict

NAMED = ("tr1_pinch", "tr2_pinch", "tr3_power", "tr4_power", "tr5_power")


def test_camera_presets():
    assert load_camera("kinect_v1") == KINECT_V1
    d435 = load_camera("realsense_d435")
    assert (d435.width, d435.height) == (848, 480) and 590 < d435.fx < 630
    with pytest.raises(dataclasses.FrozenInstanceError):
        d435.fx = 1.0  # type: ignore[misc]
    with pytest.raises(ValueError, match="unknown camera 'kinect2'; known: kinect_v1"):
        load_camera("kinect2")


def test_camera_file_with_wrong_keys(tmp_path):
    path = tmp_path / "cam.toml"
    path.write_text("width = 640\nheight = 480\nfx = 500.0\n")
    with pytest.raises(ValueError, match="expected exactly the keys"):
        load_camera(path)


def test_named_trajectories_resolve_and_look_like_the_thesis():
    assert set(NAMED) <= set(trajectory_names())
    assert resolve_trajectory("tr1").name == "tr1_pinch.json"
    assert resolve_trajectory("tr4_power").name == "tr4_power.json"
    with pytest.raises(ValueError, match="unknown trajectory 'tr9'; known: tr1_pinch"):
        resolve_trajectory("tr9")
    skeleton = make_skeleton()
    for name in NAMED:
        trajectory = load_trajectory(resolve_trajectory(name))
        assert trajectory.fps == 30 and 5.0 <= trajectory.duration_s <= 10.0
        postures, rotations, translations = trajectory.sample(trajectory.frame_times())
        assert np.degrees(geodesic_angle(rotations[:, None], rotations[None]).max()) > 90
        assert np.ptp(translations, axis=0).max() > 0.1
        assert 0.4 <= translations[:, 2].min() and translations[:, 2].max() <= 1.0
        pixels = KINECT_V1.project(camera_keypoints(postures, rotations, translations, skeleton))
        inside = np.all((pixels >= 0) & (pixels < [640, 480]), axis=(1, 2))
        assert inside.mean() > 0.9, name


def test_trajectory_passes_through_its_keyframes_and_slerps_between():
    trajectory = load_trajectory(resolve_trajectory("tr2"))
    postures, rotations, translations = trajectory.sample(trajectory.times_s)
    np.testing.assert_allclose(postures, trajectory.postures_rad, atol=1e-12)
    np.testing.assert_allclose(translations, trajectory.translations_m, atol=1e-12)
    np.testing.assert_allclose(
        rotations, quaternion_to_matrix(trajectory.quaternions_wxyz), atol=1e-9
    )
    middle = (trajectory.times_s[:-1] + trajectory.times_s[1:]) / 2
    _, halfway, _ = trajectory.sample(middle)
    start = quaternion_to_matrix(trajectory.quaternions_wxyz[:-1])
    end = quaternion_to_matrix(trajectory.quaternions_wxyz[1:])
    np.testing.assert_allclose(
        geodesic_angle(start, halfway), geodesic_angle(start, end) / 2, atol=1e-9
    )
    expected = quaternion_to_matrix(
        slerp(trajectory.quaternions_wxyz[:-1], trajectory.quaternions_wxyz[1:], 0.5)
    )
    np.testing.assert_allclose(halfway, expected, atol=1e-9)


def test_background_colors_stay_away_from_the_glove():
    pattern = load_pattern()
    colors = background_colors(200, pattern, rng=np.random.default_rng(0))
    assert colors.shape == (200, 3) and colors.dtype == np.uint8
    distance = np.linalg.norm(
        chroma_uv(colors)[:, None] - chroma_uv(pattern.colors_rgb)[None], axis=-1
    )
    assert distance.min() >= MIN_GLOVE_CHROMA_DISTANCE
    assert np.linalg.norm(chroma_uv(colors), axis=1).max() <= MAX_BACKGROUND_CHROMA
    wood = chroma_uv(np.array(WOOD_RGB) * np.array([[0.82], [1.0]]))
    assert np.linalg.norm(wood[:, None] - chroma_uv(pattern.colors_rgb)[None], axis=-1).min() > 0.4


@pytest.mark.parametrize("kind", ["clutter", "table"])
def test_backgrounds_are_behind_the_hand_and_reproducible(kind):
    pattern = load_pattern()
    trajectory = load_trajectory(resolve_trajectory("tr3"))
    keypoints = camera_keypoints(*trajectory.sample(trajectory.frame_times()), make_skeleton())
    first = make_background(kind, KINECT_V1, keypoints, pattern, rng=np.random.default_rng(3))
    again = make_background(kind, KINECT_V1, keypoints, pattern, rng=np.random.default_rng(3))
    np.testing.assert_array_equal(first.color, again.color)
    np.testing.assert_array_equal(first.depth_m, again.depth_m)
    assert first.color.dtype == np.uint8 and first.depth_m.dtype == np.float32
    assert first.depth_m.shape == (480, 640) and (first.depth_m > 0).mean() > 0.9
    # Wherever a keypoint of any frame projects, the background is behind it.
    pixels = np.rint(KINECT_V1.project(keypoints)).astype(int).reshape(-1, 2)
    behind = first.depth_m[pixels[:, 1], pixels[:, 0]]
    assert np.all((behind == 0) | (behind > keypoints[..., 2].ravel() + 0.02))


def test_composite_keeps_the_nearer_surface():
    background = Background(np.full((2, 3, 3), 9, np.uint8),
                            np.array([[0.5, 0.5, 0.0], [1.0, 0.0, 2.0]], np.float32))  # fmt: skip
    hand_color = np.full((2, 3, 3), 200, np.uint8)
    hand_depth = np.array([[0.4, 0.6, 0.7], [0.0, 0.0, 1.5]], np.float32)
    color, depth, mask = composite(hand_color, hand_depth, background)
    np.testing.assert_array_equal(mask, [[True, False, True], [False, False, True]])
    np.testing.assert_allclose(depth, [[0.4, 0.5, 0.7], [1.0, 0.0, 1.5]], rtol=1e-7)
    np.testing.assert_array_equal(color[..., 0], np.where(mask, 200, 9))
    assert color.dtype == np.uint8 and depth.dtype == np.float32


def test_hand_visible_needs_pixels_and_keypoints_in_view():
    mask = np.zeros((480, 640), bool)
    mask[100:200, 100:200] = True
    pixels = np.full((21, 2), 150.0)
    z = np.full(21, 0.5)
    assert hand_visible(mask, pixels, z, min_pixels=200)
    assert not hand_visible(mask, pixels + [600.0, 0.0], z, min_pixels=200)
    assert not hand_visible(mask, pixels, z, min_pixels=20000)


def test_settings_reject_unknown_choices():
    with pytest.raises(ValueError, match="background: expected one of"):
        SequenceSettings("tr1", background="forest")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="frames"):
        SequenceSettings("tr1", frames=0)


# --- color noise ----------------------------------------------------------------------


def gray(value: int = 128, size: int = 200) -> np.ndarray:
    return np.full((size, size, 3), value, np.uint8)


def test_no_color_noise_is_the_identity():
    image = np.random.default_rng(0).integers(0, 256, (20, 30, 3)).astype(np.uint8)
    config = color_noise_preset("none")
    gains = sequence_gains(config, rng=np.random.default_rng(1))
    np.testing.assert_array_equal(gains, np.ones(3))
    out = apply_color_noise(image, config, gains=gains, rng=np.random.default_rng(2))
    np.testing.assert_array_equal(out, image)
    np.testing.assert_array_equal(apply_gains(image, np.ones(3)), image)


def test_pixel_noise_has_the_configured_sigma():
    for sigma in (2.0, 5.0):
        noisy = add_pixel_noise(gray(), sigma=sigma, rng=np.random.default_rng(0))
        assert noisy.dtype == np.uint8
        residual = noisy.astype(float) - 128
        assert abs(residual.mean()) < 0.1
        # Rounding adds 1/12 level² of variance.
        np.testing.assert_allclose(residual.std(), np.sqrt(sigma**2 + 1 / 12), rtol=0.03)


def test_exposure_gains_have_the_configured_spread():
    config = ColorNoiseConfig(exposure_sigma_sequence_stops=0.25, white_balance_sigma_sequence=0.05)
    rng = np.random.default_rng(0)
    gains = np.array([sequence_gains(config, rng=rng) for _ in range(4000)])
    log_gains = np.log(gains)
    exposure = log_gains.mean(axis=1) / np.log(2)  # the shared part, in stops
    np.testing.assert_allclose(exposure.std(), np.sqrt(0.25**2 + 0.05**2 / 3 / np.log(2) ** 2),
                               rtol=0.05)  # fmt: skip
    balance = log_gains - log_gains.mean(axis=1, keepdims=True)
    np.testing.assert_allclose(balance.std(), 0.05 * np.sqrt(2 / 3), rtol=0.05)
    # A gain of 2 in linear light: 128 (0.216 linear) -> 0.432 linear -> 175.5 sRGB.
    assert apply_gains(gray(128, 4), [2.0, 2.0, 2.0])[0, 0, 0] == 176


def test_blur_softens_edges_and_keeps_the_mean():
    image = gray(0, 64)
    image[:, 32:] = 200
    out = apply_color_noise(image, ColorNoiseConfig(blur_sigma_px=1.5), gains=np.ones(3),
                            rng=np.random.default_rng(0))  # fmt: skip
    assert 0 < out[10, 31, 0] < 200 and 0 < out[10, 32, 0] < 200
    assert abs(out.astype(float).mean() - image.astype(float).mean()) < 0.5


def test_color_noise_is_reproducible():
    config = color_noise_preset("kinect_v1")
    image = gray()
    gains = sequence_gains(config, rng=np.random.default_rng(5))
    first = apply_color_noise(image, config, gains=gains, rng=np.random.default_rng(9))
    second = apply_color_noise(image, config, gains=gains, rng=np.random.default_rng(9))
    np.testing.assert_array_equal(first, second)
    assert not np.array_equal(first, image)


# --- rendered frames (OpenGL) ---------------------------------------------------------


def diverse_trajectory():
    """tr2 at 0.5 fps: frames 2 s apart show quite different poses."""
    return dataclasses.replace(load_trajectory(resolve_trajectory("tr2")), fps=0.5)


@pytest.mark.gl
def test_ground_truth_agrees_with_the_rendered_images(renderer):
    settings = SequenceSettings("tr2", frames=4, background="table")
    frames = list(render_frames(diverse_trajectory(), settings, renderer))
    assert [f.truth.frame for f in frames] == [0, 1, 2, 3]
    for item in frames:
        truth = item.truth
        assert truth.hand_visible
        assert item.color.dtype == np.uint8 and item.depth_m.dtype == np.float32
        np.testing.assert_allclose(KINECT_V1.project(truth.keypoints_3d_m), truth.keypoints_2d_px)
        np.testing.assert_allclose(truth.keypoints_3d_m[0], truth.translation_m, atol=1e-12)
        # Keypoints are joint centres inside the glove: they project onto the hand.
        near_hand = cv2.dilate(item.hand_mask.astype(np.uint8), np.ones((5, 5), np.uint8))
        u, v = np.rint(truth.keypoints_2d_px).astype(int).T
        assert near_hand[v, u].mean() >= 19 / 21
        # The glove's surface over the wrist is 2 cm in front of the wrist joint centre
        # seen square on, up to 3 cm seen at a slant.
        wrist_u, wrist_v = u[0], v[0]
        patch = item.depth_m[wrist_v - 2 : wrist_v + 3, wrist_u - 2 : wrist_u + 3]
        patch = patch[item.hand_mask[wrist_v - 2 : wrist_v + 3, wrist_u - 2 : wrist_u + 3]]
        z = truth.translation_m[2]
        assert len(patch) and np.all(patch > z - 0.035) and np.all(patch < z - 0.015)


@pytest.mark.gl
def test_noise_is_seeded_and_frames_do_not_depend_on_the_count(renderer):
    trajectory = diverse_trajectory()
    noisy = SequenceSettings("tr2", frames=2, noise="kinect_v1", background="clutter", seed=4)
    short = list(render_frames(trajectory, noisy, renderer))
    longer = list(render_frames(trajectory, dataclasses.replace(noisy, frames=3), renderer))
    for a, b in zip(short, longer[:2], strict=True):
        np.testing.assert_array_equal(a.color, b.color)
        np.testing.assert_array_equal(a.depth_m, b.depth_m)
    clean = list(render_frames(trajectory, dataclasses.replace(noisy, noise="none"), renderer))
    hand = clean[0].hand_mask & (short[0].depth_m > 0)
    difference = short[0].depth_m[hand] - clean[0].depth_m[hand]
    assert 0.0005 < np.abs(difference).mean() < 0.01
    assert (short[0].depth_m[clean[0].hand_mask] == 0).mean() > 0.005  # dropped pixels


@pytest.mark.gl
def test_a_hand_out_of_view_is_not_visible(renderer):
    trajectory = trajectory_from_dict(
        {
            "fps": 1,
            "keyframes": [
                {
                    "time_s": 0,
                    "posture": "open",
                    "rotation_quat_wxyz": [0, 1, 0, 0],
                    "translation_m": [0.0, 0.08, 0.6],
                },
                {
                    "time_s": 1,
                    "posture": "open",
                    "rotation_quat_wxyz": [0, 1, 0, 0],
                    "translation_m": [2.0, 0.08, 0.6],
                },
            ],
        }
    )
    frames = list(render_frames(trajectory, SequenceSettings("custom"), renderer))
    assert [f.truth.hand_visible for f in frames] == [True, False]
    assert not frames[1].hand_mask.any()
    # A hand at the camera has no image position: refused, not written as NaN.
    at_camera = trajectory_from_dict(
        {
            "fps": 1,
            "keyframes": [
                {"time_s": 0, "posture": "open", "rotation_quat_wxyz": [1, 0, 0, 0],
                 "translation_m": [0.0, 0.0, 0.0]},
            ],
        }
    )  # fmt: skip
    with pytest.raises(ValueError, match="frame 0: the hand comes to z = "):
        next(render_frames(at_camera, SequenceSettings("custom"), renderer))


def test_staged_folder_appears_only_when_complete(tmp_path):
    with staged_folder(tmp_path / "done") as root:
        (root / "a.txt").write_text("a")
        assert not (tmp_path / "done").exists()
    assert (tmp_path / "done" / "a.txt").read_text() == "a"
    with pytest.raises(RuntimeError), staged_folder(tmp_path / "failed") as root:
        (root / "a.txt").write_text("a")
        raise RuntimeError("a frame failed")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["done"]  # no partial folder either
    (tmp_path / "empty").mkdir()
    with staged_folder(tmp_path / "empty") as root:
        (root / "b.txt").write_text("b")
    assert (tmp_path / "empty" / "b.txt").exists()
    with pytest.raises(ValueError, match="exists and is not an empty folder"):
        with staged_folder(tmp_path / "done"):
            pass
