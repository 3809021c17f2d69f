"""Training and test data for the fingertip detector: rendered, noisy depth of hands.

Every example is one depth image of the hand model in a random scene:

- **posture**: a named posture, an interpolation between two named postures (with a
  few degrees of jitter), or a uniform sample within the joint limits; optionally a
  share of scenes with curled fingers (claw / half fist, :func:`curl_fingers`), most
  of them seen from the palm side;
- **view**: the camera looks at the middle of the hand from a direction mostly within
  a cone around the palm or the back normal and otherwise anywhere on the sphere, at
  0.3-1.2 m, rolled about its axis, with the hand moved off the image centre;
- **hand size**: hand length 0.16-0.21 m. Scaling a scene about the camera centre
  leaves the image unchanged and scales depth, so one mesh of the default length
  serves every size (render at ``t / s``, multiply depth by ``s``);
- **forearm**: optionally an elliptic cylinder continuing the wrist, bent by a random
  wrist flexion and deviation, added analytically to the depth (real frames show the
  arm; the mesh ends in a short wrist cuff);
- **background**: sometimes a plane behind the hand (a wall or a table, possibly only
  on one side of a line in the image), added analytically to the depth;
- **sensor**: optionally half resolution (every second pixel) and the noise model of
  :mod:`builder.depth_noise`;
- **hand side**: optionally mirrored left-right, which turns the right hand model into
  a left hand (the image is flipped, ``cx -> W - 1 - cx``, ``x -> -x``).

Fingertips are the 3D keypoints 4, 8, 12, 16, 20 in the camera frame; a tip is NaN
when its projection falls outside the image or when the clean depth there is more than
``occlusion_tolerance_m`` in front of it. With ``surface_tip_depth_m`` set, a tip hidden
by at most that much surface is instead moved onto the surface in front of it: the end
of a curled finger as the camera sees it, where annotators (and fitted hand models)
place the tip of a finger curled toward the palm.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import tomllib
from numpy.typing import ArrayLike, NDArray

from builder.depth_noise import NOISE_PRESETS, apply_depth_noise, noise_preset
from builder.render import GloveRenderer
from builder.sequence import depth_to_png_units, staged_folder
from glovedb import __version__
from glovedb._validate import as_array, check_choice, dataclass_from_table
from glovedb.camera import CameraIntrinsics
from glovedb.hand_model import (
    DEFAULT_HAND_LENGTH_M,
    FINGERS,
    FINGERTIP_KEYPOINTS,
    JOINT_NAMES,
    N_JOINTS,
    forward_kinematics,
    joint_limits_rad,
    make_skeleton,
)
from glovedb.views import HAND_CENTRE, pose_for_view

MIRROR = np.diag([-1.0, 1.0, 1.0])
"""Reflection ``x -> -x`` that turns the right hand into a left hand."""


@dataclass(frozen=True)
class FingertipDataConfig:
    """How scenes are drawn and rendered.

    Attributes
    ----------
    n_images : int
        Number of examples.
    width, height : int
        Rendered image size in pixels.
    fx, fy, cx, cy : float
        Pinhole intrinsics of the rendered image, pixels (OpenCV convention).
    half_resolution_fraction : float
        Share of examples reduced to every second pixel (e.g. 320 x 240).
    distance_range_m : tuple of float
        Camera to the middle of the hand, metres.
    hand_length_range_m : tuple of float
        Wrist crease to middle fingertip, metres.
    posture_mix : tuple of float
        Shares of named, interpolated and uniform postures (normalised).
    posture_jitter_deg : float
        Standard deviation of the jitter added to interpolated postures, degrees.
    facing_fraction : float
        Share of views within ``facing_cone_deg`` of the palm or back normal.
    facing_cone_deg : float
        Half-angle of those cones, degrees.
    roll_range_deg : float
        Camera roll is uniform in ``[-roll, roll]``, degrees (0: fingers up).
    offcentre_fraction : float
        The middle of the hand lands uniformly within this fraction of the half image
        size around the principal point.
    plane_probability : float
        Share of examples with a plane behind the hand.
    plane_gap_range_m : tuple of float
        Gap from the farthest hand point to the plane along the hand's ray, metres.
    plane_tilt_max_deg : float
        Largest angle between the plane normal and the optical axis, degrees.
    half_plane_probability : float
        Share of those planes that end at a random line in the image.
    noise : tuple of str
        Noise presets (:data:`builder.depth_noise.NOISE_PRESETS`), one drawn per image.
    mirror_probability : float
        Share of examples mirrored into a left hand.
    forearm_probability : float
        Share of examples with a forearm (:func:`forearm_depth`).
    wrist_flex_max_deg, wrist_deviation_max_deg : float
        The forearm axis is turned from the hand's -y axis by a uniform wrist flexion
        (about the hand's x axis) and deviation (about its z axis) within these bounds,
        degrees.
    occlusion_tolerance_m : float
        A tip is hidden when the depth at its pixel is more than this in front of it.
    surface_tip_depth_m : float
        A tip hidden by at most this much surface (metres; more than
        ``occlusion_tolerance_m``) is not hidden but moved onto that surface, to the
        point its pixel sees (:func:`visible_tips`). 0 (default): off.
    curl_fraction : float
        Share of scenes whose four fingers are curled toward the palm (claw, half
        fist; :func:`curl_fingers`) on top of a posture drawn as usual (which gives the
        thumb and the fingers left uncurled). 0 (default): none, and no random draw,
        so older configs render the same scenes.
    curl_finger_probability : float
        In a curled scene, each of the four fingers is curled with this probability.
    curl_mcp_range_deg, curl_pip_range_deg, curl_dip_range_deg : tuple of float
        A curled scene draws one MCP, PIP and DIP flexion uniformly in these ranges,
        degrees; every curled finger gets them plus ``posture_jitter_deg`` of Gaussian
        jitter each (clipped to the joint limits, see ``curl_beyond_limits``).
    curl_beyond_limits : bool
        Let curled PIP and DIP flexions exceed the upper joint limits (real hands
        curled against the palm reach about 115° at the DIP, the model's limit is 85°).
    curl_palm_fraction : float
        Share of the curled scenes seen from the palm side: the direction to the camera
        is uniform over the cap within ``facing_cone_deg`` of the palm normal; the
        others are drawn like every other scene.
    seed : int
        Seed of every random choice.
    """

    n_images: int = 2000
    width: int = 640
    height: int = 480
    fx: float = 525.0
    fy: float = 525.0
    cx: float = 319.5
    cy: float = 239.5
    half_resolution_fraction: float = 0.5
    distance_range_m: tuple[float, float] = (0.3, 1.2)
    hand_length_range_m: tuple[float, float] = (0.16, 0.21)
    posture_mix: tuple[float, float, float] = (0.2, 0.5, 0.3)
    posture_jitter_deg: float = 5.0
    facing_fraction: float = 0.7
    facing_cone_deg: float = 50.0
    roll_range_deg: float = 90.0
    offcentre_fraction: float = 0.6
    plane_probability: float = 0.5
    plane_gap_range_m: tuple[float, float] = (0.02, 0.5)
    plane_tilt_max_deg: float = 50.0
    half_plane_probability: float = 0.5
    noise: tuple[str, ...] = ("kinect_v1", "realsense_d435")
    mirror_probability: float = 0.5
    forearm_probability: float = 0.0
    wrist_flex_max_deg: float = 50.0
    wrist_deviation_max_deg: float = 25.0
    occlusion_tolerance_m: float = 0.015
    surface_tip_depth_m: float = 0.0
    curl_fraction: float = 0.0
    curl_finger_probability: float = 1.0
    curl_mcp_range_deg: tuple[float, float] = (0.0, 70.0)
    curl_pip_range_deg: tuple[float, float] = (75.0, 110.0)
    curl_dip_range_deg: tuple[float, float] = (30.0, 85.0)
    curl_palm_fraction: float = 0.7
    curl_beyond_limits: bool = False
    seed: int = 0

    def __post_init__(self) -> None:
        if self.n_images < 1:
            raise ValueError(f"n_images: expected at least 1, got {self.n_images}")
        for name in ("distance_range_m", "hand_length_range_m", "plane_gap_range_m"):
            low, high = getattr(self, name)
            if not 0 <= low <= high:
                raise ValueError(f"{name}: expected 0 <= min <= max, got {(low, high)}")
        if len(self.posture_mix) != 3 or min(self.posture_mix) < 0 or sum(self.posture_mix) <= 0:
            raise ValueError(f"posture_mix: expected 3 non-negative shares, got {self.posture_mix}")
        for name in ("curl_mcp_range_deg", "curl_pip_range_deg", "curl_dip_range_deg"):
            low, high = getattr(self, name)
            if not low <= high:
                raise ValueError(f"{name}: expected min <= max, got {(low, high)}")
        shares = (
            "half_resolution_fraction", "facing_fraction", "offcentre_fraction",
            "plane_probability", "half_plane_probability", "mirror_probability",
            "forearm_probability", "curl_fraction", "curl_finger_probability",
            "curl_palm_fraction",
        )  # fmt: skip
        for name in shares:
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"{name}: expected a share in [0, 1], got {getattr(self, name)}")
        if self.seed < 0:
            raise ValueError(f"seed: expected 0 or more, got {self.seed}")
        if not (2 <= self.width <= 4096 and 2 <= self.height <= 4096):
            raise ValueError(
                f"width, height: expected 2 to 4096 pixels, got {self.width}x{self.height}"
            )
        if not (self.fx > 0 and self.fy > 0):
            raise ValueError(f"fx, fy: expected positive focal lengths, got {self.fx}, {self.fy}")
        for name, (least, most) in (("distance_range_m", (0.05, 10.0)),
                                    ("hand_length_range_m", (0.05, 0.5))):  # fmt: skip
            low, high = getattr(self, name)
            if not least <= low <= high <= most:
                raise ValueError(f"{name}: expected within [{least}, {most}] m, got {(low, high)}")
        if self.surface_tip_depth_m and not (
            self.surface_tip_depth_m > self.occlusion_tolerance_m >= 0
        ):
            raise ValueError(
                "surface_tip_depth_m: expected 0 or more than occlusion_tolerance_m "
                f"({self.occlusion_tolerance_m}), got {self.surface_tip_depth_m}"
            )
        if not self.noise:
            raise ValueError("noise: expected at least one preset")
        for preset in self.noise:
            check_choice("noise", preset, NOISE_PRESETS)

    @property
    def camera(self) -> CameraIntrinsics:
        """The full-resolution rendering camera."""
        return CameraIntrinsics(self.width, self.height, self.fx, self.fy, self.cx, self.cy)


def data_config_from_dict(table: Mapping[str, Any]) -> FingertipDataConfig:
    """Build a :class:`FingertipDataConfig` from a TOML table; unknown keys are errors."""
    return dataclass_from_table(FingertipDataConfig, table, "data")


@dataclass(frozen=True)
class Scene:
    """One drawn scene before rendering (hand frame of the right hand model).

    Attributes
    ----------
    posture_rad : (20,) float64
    rotation : (3, 3) float64
        ``cam_R_hand``.
    translation_m : (3,) float64
        Wrist in the camera frame, metres.
    hand_length_m : float
    plane : (4,) float64 or None
        Plane ``n . p = n . point`` as ``(nx, ny, nz, gap_m)``: unit normal toward the
        camera and the gap behind the farthest hand point, metres.
    half_plane : (3,) float64 or None
        Line ``a u + b v + c >= 0`` (full-resolution pixels) on which the plane is kept.
    half_resolution : bool
    noise : str
        Noise preset.
    mirrored : bool
    forearm_rotation : (3, 3) float64 or None
        ``hand_R_forearm``: the forearm runs along its frame's -y axis from the wrist;
        None without a forearm.
    """

    posture_rad: NDArray[np.float64]
    rotation: NDArray[np.float64]
    translation_m: NDArray[np.float64]
    hand_length_m: float
    plane: NDArray[np.float64] | None
    half_plane: NDArray[np.float64] | None
    half_resolution: bool
    noise: str
    mirrored: bool
    forearm_rotation: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class FingertipExample:
    """One rendered training or test image.

    Attributes
    ----------
    depth_m : (H, W) float32
        Noisy depth in metres, 0 where missing.
    intrinsics : (4,) float64
        ``(fx, fy, cx, cy)`` of this image, pixels.
    tips_m : (5, 3) float64
        Fingertips (thumb to little) in the camera frame, metres; NaN if not visible.
    keypoints_m : (21, 3) float64
        All keypoints in the camera frame (visible or not), metres.
    scene : Scene
    """

    depth_m: NDArray[np.float32]
    intrinsics: NDArray[np.float64]
    tips_m: NDArray[np.float64]
    keypoints_m: NDArray[np.float64]
    scene: Scene


def sample_posture(
    named: Sequence[NDArray[np.float64]],
    mix: tuple[float, float, float],
    jitter_deg: float,
    rng: np.random.Generator,
) -> NDArray[np.float64]:
    """A named, interpolated-and-jittered or uniform posture within the joint limits.

    Returns
    -------
    (20,) float64
        Radians.
    """
    limits = joint_limits_rad()
    shares = np.asarray(mix, dtype=np.float64)
    source = rng.choice(3, p=shares / shares.sum())
    if source == 0:
        return np.array(named[int(rng.integers(len(named)))], dtype=np.float64)
    if source == 1:
        a, b = rng.choice(len(named), size=2, replace=len(named) < 2)
        fraction = rng.uniform()
        posture = (1 - fraction) * named[a] + fraction * named[b]
        posture = posture + np.radians(jitter_deg) * rng.standard_normal(N_JOINTS)
        return np.clip(posture, limits[:, 0], limits[:, 1])
    return rng.uniform(limits[:, 0], limits[:, 1])


CURLED_FINGERS = ("index", "middle", "ring", "little")
"""The fingers :func:`curl_fingers` bends (the thumb keeps its posture)."""


def curl_fingers(
    posture_rad: NDArray[np.float64],
    config: FingertipDataConfig,
    rng: np.random.Generator,
) -> NDArray[np.float64]:
    """``posture_rad`` with the four fingers curled toward the palm (claw, half fist).

    One MCP, PIP and DIP flexion is drawn uniformly in ``config.curl_*_range_deg``;
    each finger is curled with probability ``config.curl_finger_probability`` and then
    gets those angles plus ``config.posture_jitter_deg`` of Gaussian jitter, clipped to
    the joint limits (PIP and DIP only to the lower ones with
    ``config.curl_beyond_limits``). Abduction and the thumb are kept.

    Returns
    -------
    (20,) float64
        Radians.
    """
    angles = [
        rng.uniform(*config.curl_mcp_range_deg),
        rng.uniform(*config.curl_pip_range_deg),
        rng.uniform(*config.curl_dip_range_deg),
    ]
    limits = joint_limits_rad()
    posture = np.array(posture_rad, dtype=np.float64)
    for finger in CURLED_FINGERS:
        curled = rng.uniform() < config.curl_finger_probability
        jitter = config.posture_jitter_deg * rng.standard_normal(3)
        if not curled:
            continue
        for joint, angle, extra in zip(("mcp", "pip", "dip"), angles, jitter, strict=True):
            index = JOINT_NAMES.index(f"{finger}_{joint}_flex")
            low, high = limits[index]
            if config.curl_beyond_limits and joint != "mcp":
                high = np.inf
            posture[index] = np.clip(np.radians(angle + extra), low, high)
    return posture


def sample_palm_direction(cone_deg: float, rng: np.random.Generator) -> NDArray[np.float64]:
    """Unit direction ``(3,)`` from the hand to the camera, seen from the palm side.

    Uniform over the cap within ``cone_deg`` of the palm normal (hand frame -z).
    """
    cos_theta = rng.uniform(np.cos(np.radians(cone_deg)), 1.0)
    sin_theta = np.sqrt(max(0.0, 1.0 - cos_theta**2))
    phi = rng.uniform(0.0, 2 * np.pi)
    return np.array([sin_theta * np.cos(phi), sin_theta * np.sin(phi), -cos_theta])


def sample_direction(
    facing_fraction: float, facing_cone_deg: float, rng: np.random.Generator
) -> NDArray[np.float64]:
    """Unit direction from the hand to the camera, hand frame.

    With probability ``facing_fraction`` within ``facing_cone_deg`` of +z (back) or -z
    (palm), uniformly over the cap; otherwise uniform on the sphere.
    """
    if rng.uniform() < facing_fraction:
        cos_min = np.cos(np.radians(facing_cone_deg))
        cos_theta = rng.uniform(cos_min, 1.0)
        side = 1.0 if rng.uniform() < 0.5 else -1.0
    else:
        cos_theta, side = rng.uniform(-1.0, 1.0), 1.0
    sin_theta = np.sqrt(max(0.0, 1.0 - cos_theta**2))
    phi = rng.uniform(0.0, 2 * np.pi)
    return np.array([sin_theta * np.cos(phi), sin_theta * np.sin(phi), side * cos_theta])


def sample_scene(
    config: FingertipDataConfig,
    named: Sequence[NDArray[np.float64]],
    rng: np.random.Generator,
) -> Scene:
    """Draw one scene (posture, pose, size, background, sensor, side) from ``config``."""
    # No draw at curl_fraction 0, so that older configs render the same scenes.
    curled = config.curl_fraction > 0 and rng.uniform() < config.curl_fraction
    posture = sample_posture(named, config.posture_mix, config.posture_jitter_deg, rng)
    if curled:
        posture = curl_fingers(posture, config, rng)
    length = rng.uniform(*config.hand_length_range_m)
    distance = rng.uniform(*config.distance_range_m)
    if curled and rng.uniform() < config.curl_palm_fraction:
        direction = sample_palm_direction(config.facing_cone_deg, rng)
    else:
        direction = sample_direction(config.facing_fraction, config.facing_cone_deg, rng)
    roll = np.radians(rng.uniform(-config.roll_range_deg, config.roll_range_deg))
    centre_hand = np.array(HAND_CENTRE) * length
    rotation, translation = pose_for_view(direction, distance, target_m=centre_hand, roll_rad=roll)
    # Move the middle of the hand, at its depth, to a random pixel.
    half = config.offcentre_fraction * np.array([config.width, config.height]) / 2
    u, v = np.array([config.cx, config.cy]) + rng.uniform(-half, half)
    lateral = np.array([(u - config.cx) / config.fx, (v - config.cy) / config.fy]) * distance
    translation = translation + np.append(lateral, 0.0)
    plane = half_plane = None
    if rng.uniform() < config.plane_probability:
        tilt = np.radians(rng.uniform(0.0, config.plane_tilt_max_deg))
        azimuth = rng.uniform(0.0, 2 * np.pi)
        normal = [np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), -np.cos(tilt)]
        plane = np.append(normal, rng.uniform(*config.plane_gap_range_m))
        if rng.uniform() < config.half_plane_probability:
            angle = rng.uniform(0.0, 2 * np.pi)
            through = rng.uniform((0, 0), (config.width, config.height))
            a, b = np.cos(angle), np.sin(angle)
            half_plane = np.array([a, b, -(a * through[0] + b * through[1])])
    return Scene(
        posture_rad=posture,
        rotation=rotation,
        translation_m=translation,
        hand_length_m=float(length),
        plane=plane,
        half_plane=half_plane,
        half_resolution=bool(rng.uniform() < config.half_resolution_fraction),
        noise=str(config.noise[rng.integers(len(config.noise))]),
        mirrored=bool(rng.uniform() < config.mirror_probability),
        forearm_rotation=_sample_forearm(config, rng),
    )


def _sample_forearm(
    config: FingertipDataConfig, rng: np.random.Generator
) -> NDArray[np.float64] | None:
    """``hand_R_forearm`` for a random wrist flexion and deviation, or None (no forearm)."""
    # No draw at probability 0, so that older configs render the same scenes.
    if config.forearm_probability <= 0 or not rng.uniform() < config.forearm_probability:
        return None
    flex = np.radians(rng.uniform(-config.wrist_flex_max_deg, config.wrist_flex_max_deg))
    deviation = np.radians(
        rng.uniform(-config.wrist_deviation_max_deg, config.wrist_deviation_max_deg)
    )
    c, s = np.cos(flex), np.sin(flex)
    about_x = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    c, s = np.cos(deviation), np.sin(deviation)
    about_z = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return about_z @ about_x


FOREARM_HALF_AXES = (0.17, 0.12)
"""Half width (hand x) and half thickness (hand z) of the forearm, in hand lengths."""

FOREARM_LENGTH = 1.4
"""Length of the forearm from the wrist, in hand lengths."""


def forearm_depth(
    shape: tuple[int, int],
    intrinsics: NDArray[np.float64],
    cam_R_forearm: NDArray[np.float64],
    wrist_m: NDArray[np.float64],
    hand_length_m: float,
) -> NDArray[np.float32]:
    """Depth of a forearm: the front surface of an elliptic cylinder from the wrist.

    The cylinder runs from the wrist along the forearm frame's -y axis for
    :data:`FOREARM_LENGTH` hand lengths, with the half axes :data:`FOREARM_HALF_AXES`
    (x, z of that frame); it is open at both ends (the wrist end lies inside the
    hand's wrist cuff).

    Parameters
    ----------
    shape : tuple of int
        Image ``(H, W)``.
    intrinsics : (4,) float64
        ``(fx, fy, cx, cy)`` in pixels.
    cam_R_forearm : (3, 3) float64
        Forearm frame to camera frame.
    wrist_m : (3,) float64
        Wrist in the camera frame, metres.
    hand_length_m : float

    Returns
    -------
    (H, W) float32
        Depth in metres, 0 where the ray misses the forearm.
    """
    fx, fy, cx, cy = intrinsics
    v, u = np.indices(shape, dtype=np.float64)
    # Rays z * (x, y, 1) in the forearm frame, scaled so the cross-section is a unit disc.
    rays = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones(shape)], axis=-1) @ cam_R_forearm
    origin = -cam_R_forearm.T @ wrist_m
    half_x, half_z = (hand_length_m * a for a in FOREARM_HALF_AXES)
    dx, dz = rays[..., 0] / half_x, rays[..., 2] / half_z
    ox, oz = origin[0] / half_x, origin[2] / half_z
    a = dx**2 + dz**2
    b = 2.0 * (dx * ox + dz * oz)
    c = ox**2 + oz**2 - 1.0
    discriminant = b**2 - 4.0 * a * c
    with np.errstate(divide="ignore", invalid="ignore"):
        z = (-b - np.sqrt(np.maximum(discriminant, 0.0))) / (2.0 * a)
    along = origin[1] + z * rays[..., 1]
    hit = (discriminant > 0) & (z > 0) & (along <= 0) & (along >= -FOREARM_LENGTH * hand_length_m)
    return np.where(hit, z, 0.0).astype(np.float32)


def visible_tips(
    depth_m: ArrayLike,
    tips_m: ArrayLike,
    intrinsics: ArrayLike,
    *,
    tolerance_m: float = 0.015,
    surface_m: float = 0.0,
) -> NDArray[np.float64]:
    """Fingertips with the hidden ones set to NaN (or moved onto the surface hiding them).

    A tip is hidden when it is behind the camera, projects outside the image, or the
    depth at its (rounded) pixel is measured and more than ``tolerance_m`` in front of
    it. A tip hidden by at most ``surface_m`` of depth is moved instead to the 3D point
    its pixel sees (the end of a curled finger seen from the palm). Use the clean depth
    (before noise).

    Parameters
    ----------
    depth_m : (H, W) float
        Clean depth in metres, 0 where nothing is seen.
    tips_m : (T, 3) float
        Fingertips in the camera frame, metres.
    intrinsics : (4,) float
        ``(fx, fy, cx, cy)`` in pixels.
    tolerance_m : float
        Metres.
    surface_m : float
        Metres; at most ``tolerance_m`` (such as the default 0) turns moving off.

    Returns
    -------
    (T, 3) float64
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
    tips = as_array("tips_m", tips_m, (None, 3), np.float64, kind="fiu").copy()
    fx, fy, cx, cy = as_array("intrinsics", intrinsics, (4,), np.float64, finite=True)
    height, width = depth.shape
    for k, (x, y, z) in enumerate(tips):
        if not z > 0:
            tips[k] = np.nan
            continue
        u, v = round(fx * x / z + cx), round(fy * y / z + cy)
        if not (0 <= u < width and 0 <= v < height):
            tips[k] = np.nan
            continue
        seen = float(depth[v, u])
        if 0 < seen < z - tolerance_m:
            if seen >= z - surface_m:
                tips[k] = [(u - cx) * seen / fx, (v - cy) * seen / fy, seen]
            else:
                tips[k] = np.nan
    return tips


def mirror_example(
    depth_m: NDArray[np.float32], intrinsics: NDArray[np.float64], points_m: NDArray[np.float64]
) -> tuple[NDArray[np.float32], NDArray[np.float64], NDArray[np.float64]]:
    """Flip an image left-right with its camera and camera-frame points ``(..., 3)``.

    Pixel ``u`` goes to ``W - 1 - u``, so ``cx -> W - 1 - cx`` and ``x -> -x``.
    """
    fx, fy, cx, cy = intrinsics
    flipped = np.ascontiguousarray(depth_m[:, ::-1])
    camera = np.array([fx, fy, depth_m.shape[1] - 1 - cx, cy])
    return flipped, camera, points_m * np.array([-1.0, 1.0, 1.0])


def render_scene(
    renderer: GloveRenderer, scene: Scene, config: FingertipDataConfig, rng: np.random.Generator
) -> FingertipExample:
    """Render one scene with the default-length mesh of ``renderer`` (see module doc)."""
    scale = scene.hand_length_m / renderer.mesh.skeleton.hand_length_m
    rendering = renderer.render_labels(
        scene.posture_rad, scene.rotation, scene.translation_m / scale
    )
    hand_depth = rendering.depth_m * np.float32(scale)
    keypoints_hand = forward_kinematics(scene.posture_rad, renderer.mesh.skeleton).keypoints_m[0]
    keypoints = scale * keypoints_hand @ scene.rotation.T + scene.translation_m
    intrinsics = np.array([config.fx, config.fy, config.cx, config.cy])
    depth = _add_forearm(hand_depth, scene, intrinsics)
    depth = _add_plane(depth, hand_depth, keypoints, scene, intrinsics)
    if scene.half_resolution:
        depth = np.ascontiguousarray(depth[::2, ::2])
        intrinsics = intrinsics / 2
    tips = visible_tips(
        depth,
        keypoints[list(FINGERTIP_KEYPOINTS)],
        intrinsics,
        tolerance_m=config.occlusion_tolerance_m,
        surface_m=config.surface_tip_depth_m,
    )
    depth = apply_depth_noise(depth, intrinsics, noise_preset(scene.noise), rng=rng)
    if scene.mirrored:
        depth, mirrored_camera, keypoints = mirror_example(depth, intrinsics, keypoints)
        tips = tips * np.array([-1.0, 1.0, 1.0])
        intrinsics = mirrored_camera
    return FingertipExample(depth, intrinsics, tips, keypoints, scene)


def _add_forearm(
    hand_depth: NDArray[np.float32], scene: Scene, intrinsics: NDArray[np.float64]
) -> NDArray[np.float32]:
    if scene.forearm_rotation is None:
        return hand_depth
    arm = forearm_depth(
        hand_depth.shape,
        intrinsics,
        scene.rotation @ scene.forearm_rotation,
        scene.translation_m,
        scene.hand_length_m,
    )
    in_front = (arm > 0) & ((hand_depth == 0) | (arm < hand_depth))
    return np.where(in_front, arm, hand_depth).astype(np.float32)


def _add_plane(
    depth_m: NDArray[np.float32],
    hand_depth: NDArray[np.float32],
    keypoints_m: NDArray[np.float64],
    scene: Scene,
    intrinsics: NDArray[np.float64],
) -> NDArray[np.float32]:
    """``depth_m`` with the scene's plane behind it; the gap counts from the hand alone."""
    if scene.plane is None:
        return depth_m
    on_hand = hand_depth > 0
    far = float(hand_depth[on_hand].max()) if on_hand.any() else float(keypoints_m[:, 2].max())
    centre = keypoints_m.mean(axis=0)
    point = centre * (far + scene.plane[3]) / centre[2]
    height, width = hand_depth.shape
    camera = CameraIntrinsics(width, height, *(float(x) for x in intrinsics))
    plane = camera.plane_depth(scene.plane[:3], point)
    if scene.half_plane is not None:
        v, u = np.indices(hand_depth.shape)
        a, b, c = scene.half_plane
        plane[a * u + b * v + c < 0] = 0.0
    seen = depth_m > 0
    in_front = seen & ((plane == 0) | (depth_m < plane))
    return np.where(in_front, depth_m, plane).astype(np.float32)


def named_posture_list() -> list[NDArray[np.float64]]:
    """The project's named postures, in file order."""
    from glovedb.postures import load_named_postures

    return list(load_named_postures().values())


def generate_examples(
    config: FingertipDataConfig, renderer: GloveRenderer | None = None
) -> Iterator[FingertipExample]:
    """Render ``config.n_images`` examples, deterministically from ``config.seed``.

    Parameters
    ----------
    config : FingertipDataConfig
    renderer : GloveRenderer, optional
        A renderer for ``config.camera`` with the default-length mesh; one is made
        (and closed at the end) when not given.

    Yields
    ------
    FingertipExample
    """
    named = named_posture_list()
    rng = np.random.default_rng(config.seed)
    own = renderer is None
    if renderer is None:
        from glovedb.mesh import make_hand_mesh

        renderer = GloveRenderer(
            config.camera, mesh=make_hand_mesh(make_skeleton(DEFAULT_HAND_LENGTH_M))
        )
    try:
        for _ in range(config.n_images):
            scene = sample_scene(config, named, rng)
            yield render_scene(renderer, scene, config, rng)
    finally:
        if own:
            renderer.close()


def _record(frame: int, example: FingertipExample) -> tuple[dict[str, Any], dict[str, Any]]:
    """The ``groundtruth.jsonl`` and ``annotations.jsonl`` records of one example."""
    scene = example.scene
    rotation, translation = scene.rotation, scene.translation_m
    if scene.mirrored:
        # The left hand's frame is the mirror image of the right hand's: x -> -x.
        rotation, translation = MIRROR @ rotation @ MIRROR, MIRROR @ translation
    fx, fy, cx, cy = example.intrinsics
    keypoints = example.keypoints_m
    keypoints_px = np.stack(
        [fx * keypoints[:, 0] / keypoints[:, 2] + cx, fy * keypoints[:, 1] / keypoints[:, 2] + cy],
        axis=1,
    )
    truth = {
        "frame": frame,
        "hand_visible": bool(np.any(example.depth_m > 0)),
        "hand": "left" if scene.mirrored else "right",
        "hand_length_m": scene.hand_length_m,
        "posture_rad": scene.posture_rad.tolist(),
        "rotation": rotation.tolist(),
        "translation_m": translation.tolist(),
        "keypoints_3d_m": keypoints.tolist(),
        "keypoints_2d_px": keypoints_px.tolist(),
        "noise": scene.noise,
    }
    tips_px = keypoints_px[list(FINGERTIP_KEYPOINTS)]
    fingertips = {
        name: {"xyz_m": example.tips_m[k].tolist(), "uv_px": tips_px[k].tolist()}
        for k, name in enumerate(FINGERS)
        if np.all(np.isfinite(example.tips_m[k]))
    }
    return truth, {"frame": frame, "fingertips": fingertips}


def write_annotated_folder(
    examples: Iterable[FingertipExample],
    folder: str | Path,
    *,
    depth_scale: float = 1000.0,
    settings: Mapping[str, Any] | None = None,
) -> int:
    """Write examples as an RGB-D folder (docs/conventions.md layout, depth only).

    Writes ``intrinsic.json``, ``depth/NNNNNN.png`` (uint16, ``depth_scale`` units per
    metre), ``meta.json`` (with the project version and ``settings``),
    ``groundtruth.jsonl`` (all keypoints; a mirrored example is a left hand, whose
    frame is the right hand's mirrored in x) and ``annotations.jsonl`` (the visible
    fingertips, in the format of :mod:`fingertips.evaluation`).

    Returns
    -------
    int
        Number of frames written.

    Raises
    ------
    ValueError
        If ``folder`` exists and is not empty (checked before the first example is
        drawn), or if the examples do not share one camera. The folder is written under
        a temporary name and renamed when complete (:func:`builder.sequence.staged_folder`),
        so a failed or interrupted run leaves nothing behind.
    """
    camera: NDArray[np.float64] | None = None
    size: tuple[int, int] | None = None
    count = 0
    with staged_folder(folder) as root:
        (root / "depth").mkdir()
        with (
            open(root / "groundtruth.jsonl", "w") as truth_file,
            open(root / "annotations.jsonl", "w") as annotation_file,
        ):
            for frame, example in enumerate(examples):
                if camera is None:
                    camera, size = example.intrinsics, example.depth_m.shape
                elif not np.allclose(camera, example.intrinsics) or size != example.depth_m.shape:
                    raise ValueError("examples: every frame of a folder needs the same camera")
                depth = depth_to_png_units(example.depth_m, depth_scale)
                if not cv2.imwrite(str(root / "depth" / f"{frame:06d}.png"), depth):
                    raise ValueError(f"{folder}: could not write the depth of frame {frame}")
                truth, annotation = _record(frame, example)
                truth_file.write(json.dumps(truth) + "\n")
                annotation_file.write(json.dumps(annotation) + "\n")
                count += 1
        if camera is None or size is None:
            raise ValueError("examples: expected at least one example")
        fx, fy, cx, cy = camera
        intrinsic = CameraIntrinsics(size[1], size[0], fx, fy, cx, cy)
        (root / "intrinsic.json").write_text(json.dumps(intrinsic.to_open3d_json(), indent=1))
        meta = {
            "depth_scale": depth_scale,
            "version": __version__,
            "settings": dict(settings or {}),
        }
        (root / "meta.json").write_text(json.dumps(meta, indent=1))
    return count


def require_one_camera(config: FingertipDataConfig) -> None:
    """``ValueError`` unless every frame of ``config`` has the same camera.

    An RGB-D folder has one ``intrinsic.json``, so a folder of rendered frames
    (:func:`write_annotated_folder`) needs ``half_resolution_fraction`` 0 (all 640 x 480)
    or 1 (all 320 x 240). Checked before rendering, not after the first mismatch.
    """
    if config.half_resolution_fraction not in (0.0, 1.0):
        raise ValueError(
            "half_resolution_fraction: a folder has one camera, so it must be 0 (all 640x480) "
            f"or 1 (all 320x240) to write frames, got {config.half_resolution_fraction}"
        )


CONFIG_TABLES = ("data", "training", "detector", "verifier", "heatmap")
"""The tables of a fingertip config file (``configs/fingertips/*.toml``)."""


def read_config_tables(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The tables of a fingertip config file; ``ValueError`` if unreadable or unknown.

    A misspelt table (``[dat]``) would otherwise be ignored and its settings silently
    replaced by the defaults.
    """
    try:
        with open(path, "rb") as stream:
            content = tomllib.load(stream)
    except (OSError, tomllib.TOMLDecodeError) as error:
        raise ValueError(f"{os.fspath(path)}: cannot read config ({error})") from error
    unknown = set(content) - set(CONFIG_TABLES)
    if unknown:
        raise ValueError(f"{os.fspath(path)}: unknown tables {', '.join(sorted(unknown))}")
    return content


def load_data_config(path: str | os.PathLike[str]) -> FingertipDataConfig:
    """Read the ``[data]`` table of a fingertip config file, which must have one."""
    tables = read_config_tables(path)
    if "data" not in tables:
        raise ValueError(f"{os.fspath(path)}: no [data] table")
    return data_config_from_dict(tables["data"])
