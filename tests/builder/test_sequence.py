"""Synthetic sequences: presets, trajectories, backgrounds, compositing, color noise,
and ground truth that agrees with the rendered images."""

import dataclasses
import json

import cv2
import numpy as np
import pytest

from builder.color_noise import (
    ColorNoiseConfig,
    add_pixel_noise,
    apply_color_noise,
    apply_gains,
    color_noise_preset,
    dim_light,
    sequence_gains,
)
from builder.sequence import (
    MAX_BACKGROUND_CHROMA,
    MIN_GLOVE_CHROMA_DISTANCE,
    PLAIN_RGB,
    WOOD_RGB,
    Background,
    SequenceSettings,
    background_colors,
    camera_keypoints,
    composite,
    hand_visible,
    load_camera,
    make_background,
    occluder_centres,
    render_frames,
    render_sequence,
    resolve_trajectory,
    sphere_depth,
    sphere_image,
    staged_folder,
    trajectory_names,
)
from glove_cli.commands.render_sequence import settings_from_args
from glove_cli.main import build_parser, main
from glovedb.camera import KINECT_V1, CameraIntrinsics
from glovedb.hand_model import FINGERTIP_KEYPOINTS, make_skeleton, within_limits
from glovedb.pattern import chroma_uv, load_pattern
from glovedb.postures import load_named_postures
from glovedb.proportions import HandProportions, proportioned_mesh, proportioned_skeleton
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
    with pytest.raises(ValueError, match="'tr9'; known: free_fingers, tr1_pinch, tr2_pinch"):
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


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"hand_length_m": 0.05}, r"hand_length_m: expected 0.095-0.38 m"),
        ({"hand_length_m": float("nan")}, "hand_length_m: expected"),
        ({"finger_length": (1.0, 1.0, 3.0, 1.0, 1.0)}, r"finger_length\[2\]: expected a factor"),
        ({"finger_length": (1.0, 1.0)}, "finger_length: expected 5 factors"),
        ({"palm_width": 0.3}, "palm_width: expected a factor in 0.5-2.0"),
        ({"occluder_radius_m": -0.01}, "occluder_radius_m: expected a radius >= 0"),
        ({"occluder_radius_m": float("inf")}, "occluder_radius_m: expected a radius >= 0"),
        ({"occluder_from_m": (0.0, 0.1)}, r"occluder_from_m: expected shape \(3,\)"),
        ({"occluder_to_m": (0.0, float("nan"), 0.0)}, "occluder_to_m: contains NaN"),
        ({"misregistration_px": (1.0, 2.0, 3.0)}, r"misregistration_px: expected shape \(2,\)"),
        ({"light": 0.0, "noise": "kinect_v1"}, r"light: expected a share in \(0, 1\]"),
        ({"light": 1.5, "noise": "kinect_v1"}, r"light: expected a share in \(0, 1\]"),
        ({"light": 0.5}, "light: a dim room needs a camera's noise model"),
    ],
)
def test_settings_reject_bad_hands_occluders_and_shifts(options, message):
    with pytest.raises(ValueError, match=message):
        SequenceSettings("tr1", **options)


def test_settings_give_the_hand_proportions():
    assert SequenceSettings("tr1").proportions.is_model
    # Lists (as from JSON) become tuples of floats.
    fingers, shift = [1, 1.1, 1, 1, 0.9], [2, 0]
    settings = SequenceSettings("tr1", hand_length_m=0.17, finger_length=fingers,  # type: ignore[arg-type]
                                palm_width=1.2, misregistration_px=shift)  # type: ignore[arg-type]  # fmt: skip
    assert settings.proportions == HandProportions(0.17 / 0.19, (1.0, 1.1, 1.0, 1.0, 0.9), 1.2)
    assert settings.finger_length == (1.0, 1.1, 1.0, 1.0, 0.9)
    assert settings.misregistration_px == (2.0, 0.0)
    assert json.loads(json.dumps(settings.as_dict()))["finger_length"] == [1, 1.1, 1, 1, 0.9]


def test_sphere_depth_is_exact_and_the_ball_keeps_away_from_the_glove_colors():
    camera = CameraIntrinsics(64, 48, 50.0, 50.0, 32.0, 24.0)
    centre, radius = np.array([0.02, -0.01, 0.5]), 0.1
    depth = sphere_depth(camera, centre, radius)
    assert depth.shape == (48, 64) and depth.dtype == np.float32
    v, u = np.nonzero(depth > 0)
    points = camera.back_project(np.stack([u, v], -1), depth[v, u].astype(np.float64))
    np.testing.assert_allclose(np.linalg.norm(points - centre, axis=1), radius, atol=1e-6)
    # Seen along the optical axis, the nearest point is r in front of the centre.
    on_axis = sphere_depth(camera, [0.0, 0.0, 0.5], radius)
    assert on_axis[24, 32] == np.float32(0.4) == on_axis[on_axis > 0].min()
    # The silhouette of a ball at distance d has the angular radius asin(r / d).
    expected_area = np.pi * (50.0 * np.tan(np.arcsin(radius / 0.5))) ** 2
    assert abs((on_axis > 0).sum() - expected_area) < 0.02 * expected_area
    color, same_depth = sphere_image(camera, centre, radius)
    np.testing.assert_array_equal(same_depth, depth)
    assert not color[depth == 0].any()
    glove = chroma_uv(load_pattern().colors_rgb)
    distance = np.linalg.norm(chroma_uv(color[depth > 0])[:, None] - glove[None], axis=-1)
    assert distance.min() >= MIN_GLOVE_CHROMA_DISTANCE
    with pytest.raises(ValueError, match=r"centre_m: the ball .* wholly in front of the camera"):
        sphere_depth(camera, [0.0, 0.0, 0.05], radius)
    with pytest.raises(ValueError, match="radius_m: expected a radius > 0"):
        sphere_depth(camera, centre, 0.0)


def test_occluder_moves_linearly_past_the_hand_centre():
    keypoints = np.random.default_rng(0).normal(size=(5, 21, 3))
    centres = occluder_centres(keypoints, [-0.1, 0.0, -0.04], [0.1, 0.02, -0.04])
    offsets = centres - keypoints.mean(axis=1)
    np.testing.assert_allclose(offsets[:, 0], [-0.1, -0.05, 0.0, 0.05, 0.1], atol=1e-12)
    np.testing.assert_allclose(offsets[:, 1:], [[0.005 * k, -0.04] for k in range(5)], atol=1e-12)
    np.testing.assert_allclose(occluder_centres(keypoints[:1], [1, 2, 3], [4, 5, 6])
                               - keypoints[0].mean(axis=0), [[1, 2, 3]])  # fmt: skip


def test_free_fingers_holds_postures_no_grasp_database_has_in_view():
    assert resolve_trajectory("free").name == "free_fingers.json"
    trajectory = load_trajectory(resolve_trajectory("free_fingers"))
    assert trajectory.fps == 30 and 6.0 <= trajectory.duration_s <= 8.0
    postures, rotations, translations = trajectory.sample(trajectory.frame_times())
    assert within_limits(postures).all()
    keypoints = camera_keypoints(postures, rotations, translations, make_skeleton())
    pixels = KINECT_V1.project(keypoints)
    assert np.all((pixels >= 0) & (pixels <= [639, 479]))
    centre_depth = keypoints.mean(axis=1)[:, 2]
    assert 0.5 <= centre_depth.min() and centre_depth.max() <= 0.7
    # Back and then palm to the camera: the hand turns half around.
    assert np.degrees(geodesic_angle(rotations[0], rotations[-1])) > 150
    named = np.array(list(load_named_postures().values()))
    distance = np.abs(trajectory.postures_rad[:, None] - named[None]).max(axis=-1).min(axis=1)
    assert (distance > np.radians(30)).sum() >= 5  # five keyframes of postures no name holds


def test_cli_parses_the_new_options():
    args = build_parser().parse_args(
        ["render-sequence", "--trajectory", "tr1", "--out", "x", "--hand-length", "0.17",
         "--finger-length", "1.12", "--palm-width", "0.9", "--occluder-radius", "0.03",
         "--occluder-from=-0.1,0.01,-0.05", "--occluder-to", "0.1,0,-0.03",
         "--misregistration", "2.5", "--noise", "kinect_v1", "--light", "0.3"]
    )  # fmt: skip
    settings = settings_from_args(args)
    assert settings.light == 0.3
    assert settings.hand_length_m == 0.17 and settings.palm_width == 0.9
    assert settings.finger_length == (1.12,) * 5
    assert settings.occluder_radius_m == 0.03
    assert settings.occluder_from_m == (-0.1, 0.01, -0.05)
    assert settings.occluder_to_m == (0.1, 0.0, -0.03)
    assert settings.misregistration_px == (2.5, 0.0)
    args = build_parser().parse_args(
        ["render-sequence", "--trajectory", "tr1", "--out", "x",
         "--finger-length", "1,1.1,1.2,1.1,0.9", "--misregistration=-1,0.5"]
    )  # fmt: skip
    settings = settings_from_args(args)
    assert settings.finger_length == (1.0, 1.1, 1.2, 1.1, 0.9)
    assert settings.misregistration_px == (-1.0, 0.5)
    plain = settings_from_args(build_parser().parse_args(["render-sequence", "--trajectory",
                                                          "tr1", "--out", "x"]))  # fmt: skip
    assert plain == SequenceSettings("tr1")


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--finger-length", "1,1.1"], "--finger-length: expected 1 or 5 comma-separated"),
        (["--finger-length", "3"], "finger_length[0]: expected a factor in 0.5-2.0"),
        (["--hand-length", "0.6"], "hand_length_m: expected 0.095-0.38 m"),
        (["--palm-width", "wide"], "argument --palm-width: invalid float value"),
        (["--occluder-radius", "-0.02"], "occluder_radius_m: expected a radius >= 0"),
        (["--occluder-from", "0.1,0"], "--occluder-from: expected 3 comma-separated"),
        (["--occluder-to", "a,b,c"], "--occluder-to: expected 3 comma-separated"),
        (["--misregistration", "1,2,3"], "--misregistration: expected 1 or 2 comma-separated"),
    ],
)
def test_cli_rejects_bad_new_options_with_one_line(capsys, tmp_path, args, message):
    out = tmp_path / "seq"
    assert main(["render-sequence", "--trajectory", "tr1", "--out", str(out), *args]) == 2
    err = capsys.readouterr().err
    assert message in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not out.exists()


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


def test_dim_light_raises_the_gain_and_noise_then_darkens():
    kinect = color_noise_preset("kinect_v1")
    assert dim_light(kinect, 1.0) == (kinect, 1.0)
    # Auto exposure makes up for a quarter of the light with 4x gain, noise and all.
    config, brightness = dim_light(kinect, 0.25)
    assert config.pixel_sigma == pytest.approx(4 * kinect.pixel_sigma) and brightness == 1.0
    assert config.blur_sigma_px == kinect.blur_sigma_px
    # Past the gain's limit the image darkens: a tenth of the light, 40 % brightness.
    config, brightness = dim_light(kinect, 0.1)
    assert config.pixel_sigma == pytest.approx(4 * kinect.pixel_sigma)
    assert brightness == pytest.approx(0.4)
    dark = apply_color_noise(
        gray(), config, gains=np.full(3, brightness), rng=np.random.default_rng(0)
    )
    mid = np.mean(dark.astype(float))  # sRGB of 0.4 x the linear light of 128: about 85
    assert 80 < mid < 90
    with pytest.raises(ValueError, match="light"):
        dim_light(kinect, -0.5)


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


def still_hand(seconds: int = 0):
    """The open hand's back to the camera 0.6 m away, held for ``seconds`` at 1 fps."""
    keyframe = {"posture": "open", "rotation_quat_wxyz": [0, 1, 0, 0],
                "translation_m": [0.0, 0.08, 0.6]}  # fmt: skip
    times = sorted({0, seconds})
    return trajectory_from_dict({"fps": 1, "keyframes": [{"time_s": t, **keyframe} for t in times]})


SMALL_HAND = SequenceSettings("custom", hand_length_m=0.17)


@pytest.fixture(scope="module")
def small_hand_renderer(hand_mesh):
    """A VGA renderer of the 0.17 m hand of :data:`SMALL_HAND`."""
    from builder.render import GloveRenderer

    mesh = proportioned_mesh(hand_mesh, SMALL_HAND.proportions)
    with GloveRenderer(KINECT_V1, mesh=mesh) as instance:
        yield instance


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


@pytest.mark.gl
def test_a_smaller_hand_gives_its_own_keypoints_and_silhouette(renderer, small_hand_renderer):
    model = next(render_frames(still_hand(), SequenceSettings("custom"), renderer))
    small = next(render_frames(still_hand(), SMALL_HAND, small_hand_renderer))
    wrist = small.truth.translation_m
    scaled = (model.truth.keypoints_3d_m - wrist) * 0.17 / 0.19
    np.testing.assert_allclose(small.truth.keypoints_3d_m - wrist, scaled, atol=1e-12)
    area = small.hand_mask.sum() / model.hand_mask.sum()
    assert 0.7 < area < 0.9  # about (0.17 / 0.19)² = 0.80
    near_hand = cv2.dilate(small.hand_mask.astype(np.uint8), np.ones((5, 5), np.uint8))
    u, v = np.rint(small.truth.keypoints_2d_px).astype(int).T
    assert near_hand[v, u].all()
    with pytest.raises(ValueError, match=r"renderer: its hand .* is not the settings' hand"):
        next(render_frames(still_hand(), SMALL_HAND, renderer))


@pytest.mark.gl
def test_longer_fingers_put_the_tips_farther_from_the_mcps(hand_mesh):
    from builder.render import GloveRenderer

    settings = SequenceSettings("custom", finger_length=(1.12,) * 5)
    mesh = proportioned_mesh(hand_mesh, settings.proportions)
    with GloveRenderer(KINECT_V1, mesh=mesh) as long_fingers:
        truth = next(render_frames(diverse_trajectory(), settings, long_fingers)).truth
    postures, rotations, translations = diverse_trajectory().sample([0.0])
    model = camera_keypoints(postures, rotations, translations, make_skeleton())[0]
    mcps = [2, 5, 9, 13, 17]  # the thumb's MCP, the fingers' MCPs
    tips = list(FINGERTIP_KEYPOINTS)
    reach = np.linalg.norm(truth.keypoints_3d_m[tips] - truth.keypoints_3d_m[mcps], axis=1)
    model_reach = np.linalg.norm(model[tips] - model[mcps], axis=1)
    np.testing.assert_allclose(reach / model_reach, 1.12, rtol=1e-9)
    palm = [0, 5, 9, 13, 17]  # wrist and finger bases do not move
    np.testing.assert_allclose(truth.keypoints_3d_m[palm], model[palm], atol=1e-12)


@pytest.mark.gl
def test_the_occluder_hides_a_known_share_of_the_hand(renderer):
    occluded = SequenceSettings("custom", frames=3, occluder_radius_m=0.025)
    bare = dataclasses.replace(occluded, occluder_radius_m=0.0)
    with_ball = list(render_frames(still_hand(2), occluded, renderer))
    without = list(render_frames(still_hand(2), bare, renderer))
    assert [f.truth.occluded_fraction for f in without] == [None] * 3
    assert "occluded_fraction" not in without[0].truth.as_record()
    # 12 cm beside the hand at the first and last frame, over its centre in between.
    assert [with_ball[k].truth.occluded_fraction for k in (0, 2)] == [0.0, 0.0]
    middle, reference = with_ball[1], without[1]
    assert not (middle.hand_mask & ~reference.hand_mask).any()
    hidden = reference.hand_mask.sum() - middle.hand_mask.sum()
    assert middle.truth.occluded_fraction == hidden / reference.hand_mask.sum()
    assert 0.05 < middle.truth.occluded_fraction < 0.5 and middle.truth.hand_visible
    assert middle.truth.as_record()["occluded_fraction"] == middle.truth.occluded_fraction
    # Its depth at the pixel of its centre is where that pixel's ray meets the sphere.
    centre = middle.truth.keypoints_3d_m.mean(axis=0) + [0.0, 0.0, -0.04]
    u, v = np.rint(KINECT_V1.project(centre)).astype(int)
    ray = np.array([(u - KINECT_V1.cx) / KINECT_V1.fx, (v - KINECT_V1.cy) / KINECT_V1.fy, 1.0])
    b, a, k = ray @ centre, ray @ ray, centre @ centre - 0.025**2
    assert middle.depth_m[v, u] == np.float32((b - np.sqrt(b * b - a * k)) / a)
    assert abs(middle.depth_m[v, u] - (centre[2] - 0.025)) < 1e-4
    ball = (middle.depth_m > 0) & (middle.depth_m < reference.depth_m - 0.005)
    glove = chroma_uv(load_pattern().colors_rgb)
    assert np.linalg.norm(chroma_uv(middle.color[ball])[:, None] - glove[None], axis=-1).min() > 0.4
    # A ball that covers the whole hand hides all of it.
    big = dataclasses.replace(occluded, frames=1, occluder_radius_m=0.15,
                              occluder_from_m=(0.0, 0.0, -0.2))  # fmt: skip
    covered = next(render_frames(still_hand(2), big, renderer))
    assert covered.truth.occluded_fraction == 1.0 and not covered.truth.hand_visible
    assert not covered.hand_mask.any()
    near = dataclasses.replace(big, occluder_from_m=(0.0, 0.0, -0.45))
    with pytest.raises(ValueError, match="frame 0: the occluder comes to z = "):
        next(render_frames(still_hand(2), near, renderer))


@pytest.mark.gl
def test_misregistration_shifts_the_color_against_depth(renderer):
    clean = next(render_frames(still_hand(), SequenceSettings("custom"), renderer))

    def shifted(du, dv):
        settings = SequenceSettings("custom", misregistration_px=(du, dv))
        frame = next(render_frames(still_hand(), settings, renderer))
        np.testing.assert_array_equal(frame.depth_m, clean.depth_m)
        np.testing.assert_array_equal(frame.hand_mask, clean.hand_mask)
        np.testing.assert_array_equal(frame.truth.keypoints_2d_px, clean.truth.keypoints_2d_px)
        return frame.color

    whole = shifted(3, -2)  # out[v, u] = clean[v + 2, u - 3]
    np.testing.assert_array_equal(whole[:-2, 3:], clean.color[2:, :-3])
    assert not np.array_equal(whole, clean.color)

    def centroid(color):  # linear in the image, so it moves exactly with the content
        weight = color.astype(np.float64).sum(axis=-1) - sum(PLAIN_RGB)
        v, u = np.indices(weight.shape)
        return np.array([(weight * u).sum(), (weight * v).sum()]) / weight.sum()

    np.testing.assert_allclose(centroid(shifted(1.5, 0.25)) - centroid(clean.color), [1.5, 0.25],
                               atol=0.02)  # fmt: skip


@pytest.mark.gl
def test_a_dim_room_keeps_the_depth_and_makes_the_color_noisier(renderer):
    def frame(light):
        settings = SequenceSettings("custom", noise="kinect_v1", light=light, seed=2)
        return next(render_frames(still_hand(), settings, renderer))

    bright, dim = frame(1.0), frame(0.25)
    np.testing.assert_array_equal(dim.depth_m, bright.depth_m)
    background = ~cv2.dilate(bright.hand_mask.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(
        bool
    )
    spread = [f.color[background].astype(float).std(axis=0).mean() for f in (bright, dim)]
    assert 3.3 < spread[1] / spread[0] < 4.5  # the noise times the 4x gain
    means = [f.color[background].astype(float).mean() for f in (bright, dim)]
    assert abs(means[1] - means[0]) < 2.0  # auto exposure keeps the brightness


@pytest.mark.gl
def test_render_sequence_writes_the_hand_and_the_occluder(tmp_path, renderer, small_hand_renderer):
    settings = dataclasses.replace(SMALL_HAND, trajectory="tr1", frames=2, occluder_radius_m=0.02,
                                   misregistration_px=(1.0, 0.0))  # fmt: skip
    report = render_sequence(settings, tmp_path / "seq", renderer=small_hand_renderer)
    assert report.frames == 2
    meta = json.loads((tmp_path / "seq" / "meta.json").read_text())
    assert meta["hand_length_m"] == pytest.approx(0.17)
    assert meta["hand_proportions"] == settings.proportions.as_dict()
    assert meta["settings"]["occluder_radius_m"] == 0.02
    assert meta["settings"]["misregistration_px"] == [1.0, 0.0]
    lines = (tmp_path / "seq" / "groundtruth.jsonl").read_text().splitlines()
    assert all(0.0 <= json.loads(line)["occluded_fraction"] <= 1.0 for line in lines)
    with pytest.raises(ValueError, match="renderer: its hand"):
        render_sequence(settings, tmp_path / "other", renderer=renderer)
    assert not (tmp_path / "other").exists()
    skeleton = proportioned_skeleton(make_skeleton(), settings.proportions)
    assert small_hand_renderer.mesh.skeleton.hand_length_m == skeleton.hand_length_m
