"""Training and test data for the fingertip detector: rendered, noisy depth of hands.

Every example is one depth image of the hand model in a random scene:

- **posture**: a named posture, an interpolation between two named postures (with a
  few degrees of jitter), or a uniform sample within the joint limits; the "named"
  pool can be joined by the postures of the database configs ``posture_sets``
  (``configs/db/NAME.toml``: their named and natural random postures); optionally a
  share of scenes with curled fingers (claw / half fist, :func:`curl_fingers`), most
  of them seen from the palm side;
- **view**: the camera looks at the middle of the hand from a direction mostly within
  a cone around the palm or the back normal and otherwise anywhere on the sphere, at
  0.3-1.2 m (``distance_range_m``), rolled about its axis, with the hand moved off the
  image centre; optionally (``border_fraction``) the middle of the hand is put on an
  image edge or beyond it, so that the border cuts the hand;
- **hand size**: hand length 0.16-0.21 m (``hand_length_range_m``). Scaling a scene
  about the camera centre leaves the image unchanged and scales depth, so one mesh of
  the default length serves every size (render at ``t / s``, multiply depth by ``s``);
- **hand shape**: optionally per scene five finger length factors, a palm width and a
  thickness factor (``finger_length_range``, ``palm_width_range``, ``thickness_range``)
  that re-rest the default mesh (:func:`glovedb.proportions.proportioned_mesh`, about
  20 ms a scene); ``hand_length_m`` then scales that hand as a whole;
- **forearm**: optionally an elliptic cylinder continuing the wrist, bent by a random
  wrist flexion and deviation, added analytically to the depth (real frames show the
  arm; the mesh ends in a short wrist cuff), and on some forearms a sleeve: a wider
  cylinder over the forearm's far part;
- **background**: sometimes a plane behind the hand (a wall or a table, possibly only
  on one side of a line in the image), added analytically to the depth;
- **nearby object**: optionally a ball or a box (a held object, a body part, a table
  corner) a few centimetres from a random keypoint, often on the camera's side of it,
  ray-cast into the depth where it is nearer than the hand;
- **sensor**: optionally half resolution (every second pixel) and the noise model of
  :mod:`builder.depth_noise`;
- **hand side**: optionally mirrored left-right, which turns the right hand model into
  a left hand (the image is flipped, ``cx -> W - 1 - cx``, ``x -> -x``).

Fingertips are the 3D keypoints 4, 8, 12, 16, 20 in the camera frame; a tip is NaN
when its projection falls outside the image or when the clean depth there (the nearby
object included) is more than ``occlusion_tolerance_m`` in front of it. With
``surface_tip_depth_m`` set, a tip hidden by at most that much surface is instead moved
onto the surface in front of it: the end of a curled finger as the camera sees it, where
annotators (and fitted hand models) place the tip of a finger curled toward the palm; a
tip behind the nearby object stays hidden (the object is not the finger's end).

Every option above that is off by default draws no random number when off, so older
configs render the same scenes for the same seed.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

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
    N_KEYPOINTS,
    forward_kinematics,
    joint_limits_rad,
    make_skeleton,
)
from glovedb.mesh import HandMesh
from glovedb.proportions import FACTOR_RANGE, HandProportions, proportioned_mesh
from glovedb.resources import config_path
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
        Wrist crease to middle fingertip, metres (of the model's shape: a scene's
        finger length factors then lengthen or shorten its fingers).
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
    posture_sets : tuple of str
        Database configs (``configs/db/NAME.toml``, e.g. ``grasp20``, ``natural1000``)
        whose postures join the named postures as the pool of named and interpolated
        postures. Empty (default): the named postures only.
    finger_length_range : tuple of float
        Each finger's length factor (thumb to little, drawn independently per scene)
        is uniform in this range, against the model's. (1, 1) (default) with the two
        ranges below: the model's shape, no draw.
    palm_width_range : tuple of float
        Palm width factor, uniform per scene.
    thickness_range : tuple of float
        Thickness factor of palm and fingers (across the palm plane), uniform per scene.
    border_fraction : float
        Share of scenes whose middle of the hand lies on an image edge or beyond it
        (instead of within ``offcentre_fraction``), so that the border cuts the hand.
    border_overhang_range : tuple of float
        How far beyond the edge the middle of the hand lies in those scenes, in hand
        lengths as seen in the image (negative: inside), uniform.
    sleeve_probability : float
        Share of forearms with a sleeve over their far part.
    sleeve_start_range : tuple of float
        Where the sleeve starts, hand lengths from the wrist (it ends with the forearm,
        :data:`FOREARM_LENGTH`), uniform.
    sleeve_width_range : tuple of float
        The sleeve's half axes against the forearm's, uniform.
    object_probability : float
        Share of scenes with a nearby object (:class:`NearbyObject`).
    object_box_fraction : float
        Share of those objects that are boxes (the others are balls).
    object_size_range_m : tuple of float
        Ball radius, or each half extent of a box, metres, uniform.
    object_gap_range_m : tuple of float
        Gap between the object's surface and the keypoint it is placed next to, metres.
    object_front_fraction : float
        Share of objects placed on the camera's side of their keypoint (within 60
        degrees of the direction to the camera), where they may hide fingertips; the
        others lie in a uniform direction.
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
    posture_sets: tuple[str, ...] = ()
    finger_length_range: tuple[float, float] = (1.0, 1.0)
    palm_width_range: tuple[float, float] = (1.0, 1.0)
    thickness_range: tuple[float, float] = (1.0, 1.0)
    border_fraction: float = 0.0
    border_overhang_range: tuple[float, float] = (-0.2, 0.3)
    sleeve_probability: float = 0.0
    sleeve_start_range: tuple[float, float] = (0.3, 1.0)
    sleeve_width_range: tuple[float, float] = (1.15, 1.5)
    object_probability: float = 0.0
    object_box_fraction: float = 0.5
    object_size_range_m: tuple[float, float] = (0.02, 0.06)
    object_gap_range_m: tuple[float, float] = (0.0, 0.03)
    object_front_fraction: float = 0.5
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
            "curl_palm_fraction", "border_fraction", "sleeve_probability",
            "object_probability", "object_box_fraction", "object_front_fraction",
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
        bounded = (
            ("finger_length_range", FACTOR_RANGE), ("palm_width_range", FACTOR_RANGE),
            ("thickness_range", FACTOR_RANGE), ("border_overhang_range", (-1.0, 1.0)),
            ("sleeve_start_range", (0.0, FOREARM_LENGTH)), ("sleeve_width_range", (1.0, 3.0)),
            ("object_size_range_m", (0.005, 0.5)), ("object_gap_range_m", (0.0, 0.5)),
        )  # fmt: skip
        for name, (least, most) in bounded:
            low, high = getattr(self, name)
            if not least <= low <= high <= most:
                raise ValueError(
                    f"{name}: expected {least} <= min <= max <= {most}, got {(low, high)}"
                )
        for name in self.posture_sets:
            try:
                config_path(f"db/{name}.toml")
            except FileNotFoundError as error:
                raise ValueError(f"posture_sets: no configs/db/{name}.toml") from error

    @property
    def varies_shape(self) -> bool:
        """Whether scenes draw a hand shape (any shape range other than (1, 1))."""
        ranges = (self.finger_length_range, self.palm_width_range, self.thickness_range)
        return any(tuple(r) != (1.0, 1.0) for r in ranges)

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
    proportions : HandProportions or None
        Finger lengths and palm width (``length_scale`` 1: ``hand_length_m`` scales);
        None: the model's.
    thickness : float
        Thickness factor of the mesh (:func:`glovedb.proportions.proportioned_mesh`).
    sleeve : (2,) tuple of float or None
        ``(start, width)``: the sleeve's start in hand lengths from the wrist and its
        half axes against the forearm's; None without a sleeve.
    nearby_object : NearbyObject or None
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
    proportions: HandProportions | None = None
    thickness: float = 1.0
    sleeve: tuple[float, float] | None = None
    nearby_object: NearbyObject | None = None


@dataclass(frozen=True)
class NearbyObject:
    """A ball or a box beside the hand: a held object, a body part, a table corner.

    Attributes
    ----------
    kind : {"ball", "box"}
    anchor : int
        Keypoint (0-20) it is placed next to.
    offset_m : (3,) float64
        From that keypoint to the object's centre, camera frame, metres.
    half_extents_m : (3,) float64
        A box's half extents along its axes; a ball's radius, three times. Metres.
    rotation : (3, 3) float64
        ``cam_R_object`` (the identity for a ball).
    """

    kind: Literal["ball", "box"]
    anchor: int
    offset_m: NDArray[np.float64]
    half_extents_m: NDArray[np.float64]
    rotation: NDArray[np.float64]


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
    if config.border_fraction > 0 and rng.uniform() < config.border_fraction:
        u, v = _border_pixel(config, config.fx * length / distance, rng)
    else:
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
    half_resolution = bool(rng.uniform() < config.half_resolution_fraction)
    noise = str(config.noise[rng.integers(len(config.noise))])
    mirrored = bool(rng.uniform() < config.mirror_probability)
    forearm = _sample_forearm(config, rng)
    proportions, thickness = _sample_shape(config, rng)
    return Scene(
        posture_rad=posture,
        rotation=rotation,
        translation_m=translation,
        hand_length_m=float(length),
        plane=plane,
        half_plane=half_plane,
        half_resolution=half_resolution,
        noise=noise,
        mirrored=mirrored,
        forearm_rotation=forearm,
        proportions=proportions,
        thickness=thickness,
        sleeve=None if forearm is None else _sample_sleeve(config, rng),
        nearby_object=_sample_object(config, rng),
    )


def _border_pixel(
    config: FingertipDataConfig, hand_px: float, rng: np.random.Generator
) -> NDArray[np.float64]:
    """A pixel on a random image edge, moved outward by ``border_overhang_range`` hands."""
    edge = int(rng.integers(4))
    along = rng.uniform()
    overhang = rng.uniform(*config.border_overhang_range) * hand_px
    width, height = config.width, config.height
    if edge == 0:
        return np.array([-0.5 - overhang, -0.5 + along * height])
    if edge == 1:
        return np.array([width - 0.5 + overhang, -0.5 + along * height])
    if edge == 2:
        return np.array([-0.5 + along * width, -0.5 - overhang])
    return np.array([-0.5 + along * width, height - 0.5 + overhang])


def _sample_shape(
    config: FingertipDataConfig, rng: np.random.Generator
) -> tuple[HandProportions | None, float]:
    """Finger lengths, palm width and thickness of one scene; the model's when fixed."""
    if not config.varies_shape:
        return None, 1.0
    fingers = tuple(float(f) for f in rng.uniform(*config.finger_length_range, size=5))
    palm = float(rng.uniform(*config.palm_width_range))
    thickness = float(rng.uniform(*config.thickness_range))
    return HandProportions(1.0, fingers, palm), thickness  # type: ignore[arg-type]


def _sample_sleeve(
    config: FingertipDataConfig, rng: np.random.Generator
) -> tuple[float, float] | None:
    """``(start, width)`` of a sleeve over the forearm, or None."""
    if config.sleeve_probability <= 0 or not rng.uniform() < config.sleeve_probability:
        return None
    return float(rng.uniform(*config.sleeve_start_range)), float(
        rng.uniform(*config.sleeve_width_range)
    )


def _sample_object(config: FingertipDataConfig, rng: np.random.Generator) -> NearbyObject | None:
    """A ball or box next to a random keypoint (:class:`NearbyObject`), or None."""
    if config.object_probability <= 0 or not rng.uniform() < config.object_probability:
        return None
    box = bool(rng.uniform() < config.object_box_fraction)
    if box:
        half = rng.uniform(*config.object_size_range_m, size=3)
        rotation = _random_rotation(rng)
    else:
        half = np.repeat(rng.uniform(*config.object_size_range_m), 3)
        rotation = np.eye(3)
    anchor = int(rng.integers(N_KEYPOINTS))
    if rng.uniform() < config.object_front_fraction:
        # Within 60 degrees of -z: the camera's side of the keypoint.
        cos_theta = rng.uniform(0.5, 1.0)
        sin_theta = np.sqrt(1.0 - cos_theta**2)
        phi = rng.uniform(0.0, 2 * np.pi)
        direction = np.array([sin_theta * np.cos(phi), sin_theta * np.sin(phi), -cos_theta])
    else:
        direction = sample_direction(0.0, 0.0, rng)
    # Centre to surface along the direction: the first box face the ray leaves by.
    local = np.abs(rotation.T @ direction)
    with np.errstate(divide="ignore"):
        reach = float(np.min(np.where(local > 0, half / local, np.inf)))
    gap = rng.uniform(*config.object_gap_range_m)
    return NearbyObject(
        kind="box" if box else "ball",
        anchor=anchor,
        offset_m=direction * (reach + gap),
        half_extents_m=half,
        rotation=rotation,
    )


def _random_rotation(rng: np.random.Generator) -> NDArray[np.float64]:
    """A uniformly random rotation matrix (QR of a Gaussian matrix, signs fixed)."""
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


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


def pixel_rays(shape: tuple[int, int], intrinsics: ArrayLike) -> NDArray[np.float64]:
    """``(H, W, 3)`` rays ``(x / z, y / z, 1)`` through every pixel of an image of
    ``shape`` with pinhole ``intrinsics`` ``(fx, fy, cx, cy)``: a point at depth ``z``
    on a pixel's ray is ``z`` times its ray."""
    fx, fy, cx, cy = (float(value) for value in np.asarray(intrinsics, dtype=np.float64))
    v, u = np.indices(shape, dtype=np.float64)
    return np.stack([(u - cx) / fx, (v - cy) / fy, np.ones(shape)], axis=-1)


def forearm_depth(
    shape: tuple[int, int],
    intrinsics: NDArray[np.float64],
    cam_R_forearm: NDArray[np.float64],
    wrist_m: NDArray[np.float64],
    hand_length_m: float,
    *,
    half_axes: tuple[float, float] = FOREARM_HALF_AXES,
    span: tuple[float, float] = (0.0, FOREARM_LENGTH),
) -> NDArray[np.float32]:
    """Depth of a forearm: the front surface of an elliptic cylinder from the wrist.

    The cylinder runs along the forearm frame's -y axis from ``span[0]`` to ``span[1]``
    hand lengths from the wrist (default: from the wrist for :data:`FOREARM_LENGTH`),
    with the half axes ``half_axes`` in hand lengths (x, z of that frame; default
    :data:`FOREARM_HALF_AXES`); it is open at both ends (the wrist end lies inside the
    hand's wrist cuff). A sleeve is such a cylinder, wider, over the far part.

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
    half_axes : (2,) tuple of float
        Hand lengths.
    span : (2,) tuple of float
        Hand lengths from the wrist.

    Returns
    -------
    (H, W) float32
        Depth in metres, 0 where the ray misses the forearm.
    """
    # Rays z * (x, y, 1) in the forearm frame, scaled so the cross-section is a unit disc.
    rays = pixel_rays(shape, intrinsics) @ cam_R_forearm
    origin = -cam_R_forearm.T @ wrist_m
    half_x, half_z = (hand_length_m * a for a in half_axes)
    dx, dz = rays[..., 0] / half_x, rays[..., 2] / half_z
    ox, oz = origin[0] / half_x, origin[2] / half_z
    a = dx**2 + dz**2
    b = 2.0 * (dx * ox + dz * oz)
    c = ox**2 + oz**2 - 1.0
    discriminant = b**2 - 4.0 * a * c
    with np.errstate(divide="ignore", invalid="ignore"):
        z = (-b - np.sqrt(np.maximum(discriminant, 0.0))) / (2.0 * a)
    along = origin[1] + z * rays[..., 1]
    near, far = (-extent * hand_length_m for extent in span)
    hit = (discriminant > 0) & (z > 0) & (along <= near) & (along >= far)
    return np.where(hit, z, 0.0).astype(np.float32)


def object_depth(
    shape: tuple[int, int],
    intrinsics: NDArray[np.float64],
    centre_m: NDArray[np.float64],
    nearby: NearbyObject,
) -> NDArray[np.float32]:
    """Depth of the front surface of a ball or a box (:class:`NearbyObject`).

    Parameters
    ----------
    shape : tuple of int
        Image ``(H, W)``.
    intrinsics : (4,) float64
        ``(fx, fy, cx, cy)`` in pixels.
    centre_m : (3,) float64
        The object's centre in the camera frame, metres.
    nearby : NearbyObject

    Returns
    -------
    (H, W) float32
        Depth in metres, 0 where the ray misses the object.
    """
    rays = pixel_rays(shape, intrinsics)  # the ray parameter is the depth
    if nearby.kind == "ball":
        radius = float(nearby.half_extents_m[0])
        a = np.einsum("hwk,hwk->hw", rays, rays)
        b = -2.0 * rays @ centre_m
        c = float(centre_m @ centre_m) - radius**2
        discriminant = b**2 - 4.0 * a * c
        z = (-b - np.sqrt(np.maximum(discriminant, 0.0))) / (2.0 * a)
        hit = (discriminant > 0) & (z > 0)
    else:
        # Slabs in the box frame: the ray is inside between the largest entry and the
        # smallest exit parameter over the three axes.
        local = rays @ nearby.rotation
        origin = -nearby.rotation.T @ centre_m
        with np.errstate(divide="ignore", invalid="ignore"):
            low = (-nearby.half_extents_m - origin) / local
            high = (nearby.half_extents_m - origin) / local
        z = np.minimum(low, high).max(axis=-1)
        hit = (z <= np.maximum(low, high).min(axis=-1)) & (z > 0)
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
    mesh = scene_mesh(renderer.mesh, scene)
    rendering = renderer.render_labels(
        scene.posture_rad,
        scene.rotation,
        scene.translation_m / scale,
        mesh=None if mesh is renderer.mesh else mesh,
    )
    hand_depth = rendering.depth_m * np.float32(scale)
    keypoints_hand = forward_kinematics(scene.posture_rad, mesh.skeleton).keypoints_m[0]
    keypoints = scale * keypoints_hand @ scene.rotation.T + scene.translation_m
    intrinsics = np.array([config.fx, config.fy, config.cx, config.cy])
    depth = _add_forearm(hand_depth, scene, intrinsics)
    thing = None
    if scene.nearby_object is not None:
        centre = keypoints[scene.nearby_object.anchor] + scene.nearby_object.offset_m
        thing = object_depth(depth.shape, intrinsics, centre, scene.nearby_object)
        depth = _nearer(thing, depth)
    depth = _add_plane(depth, hand_depth, keypoints, scene, intrinsics)
    if scene.half_resolution:
        depth = np.ascontiguousarray(depth[::2, ::2])
        thing = None if thing is None else thing[::2, ::2]
        intrinsics = intrinsics / 2
    tips = visible_tips(
        depth,
        keypoints[list(FINGERTIP_KEYPOINTS)],
        intrinsics,
        tolerance_m=config.occlusion_tolerance_m,
        surface_m=config.surface_tip_depth_m,
    )
    if thing is not None:
        # A tip behind the object is hidden, never moved onto it.
        behind = visible_tips(
            thing, keypoints[list(FINGERTIP_KEYPOINTS)], intrinsics,
            tolerance_m=config.occlusion_tolerance_m,
        )  # fmt: skip
        tips[np.isnan(behind[:, 0])] = np.nan
    depth = apply_depth_noise(depth, intrinsics, noise_preset(scene.noise), rng=rng)
    if scene.mirrored:
        depth, mirrored_camera, keypoints = mirror_example(depth, intrinsics, keypoints)
        tips = tips * np.array([-1.0, 1.0, 1.0])
        intrinsics = mirrored_camera
    return FingertipExample(depth, intrinsics, tips, keypoints, scene)


def scene_mesh(mesh: HandMesh, scene: Scene) -> HandMesh:
    """``mesh`` (the model's) with the scene's finger lengths, palm width and thickness."""
    if scene.proportions is None and scene.thickness == 1.0:
        return mesh
    proportions = scene.proportions if scene.proportions is not None else HandProportions()
    return proportioned_mesh(mesh, proportions, thickness=scene.thickness)


def _nearer(surface: NDArray[np.float32], depth_m: NDArray[np.float32]) -> NDArray[np.float32]:
    """``depth_m`` with ``surface`` wherever that is seen and nearer (0: nothing seen)."""
    in_front = (surface > 0) & ((depth_m == 0) | (surface < depth_m))
    return np.where(in_front, surface, depth_m).astype(np.float32)


def _add_forearm(
    hand_depth: NDArray[np.float32], scene: Scene, intrinsics: NDArray[np.float64]
) -> NDArray[np.float32]:
    if scene.forearm_rotation is None:
        return hand_depth
    cam_R_forearm = scene.rotation @ scene.forearm_rotation
    arm = forearm_depth(
        hand_depth.shape, intrinsics, cam_R_forearm, scene.translation_m, scene.hand_length_m
    )
    depth = _nearer(arm, hand_depth)
    if scene.sleeve is None:
        return depth
    start, width = scene.sleeve
    sleeve = forearm_depth(
        hand_depth.shape, intrinsics, cam_R_forearm, scene.translation_m, scene.hand_length_m,
        half_axes=(FOREARM_HALF_AXES[0] * width, FOREARM_HALF_AXES[1] * width),
        span=(start, FOREARM_LENGTH),
    )  # fmt: skip
    return _nearer(sleeve, depth)


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


def posture_pool(config: FingertipDataConfig) -> list[NDArray[np.float64]]:
    """The named postures, then those of each of ``config.posture_sets`` in order."""
    from builder.build import collect_postures
    from builder.config import load_config

    pool = named_posture_list()
    for name in config.posture_sets:
        pool.extend(collect_postures(load_config(config_path(f"db/{name}.toml")))[0])
    return pool


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
    named = posture_pool(config)
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
    if scene.proportions is not None or scene.thickness != 1.0:
        truth["hand_proportions"] = (scene.proportions or HandProportions()).as_dict()
        truth["hand_thickness"] = scene.thickness
    if scene.nearby_object is not None:
        truth["nearby_object"] = scene.nearby_object.kind
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
    or 1 (all 320 x 240), and a centred ``cx`` when some frames are mirrored.
    Checked before rendering, not after the first mismatch.
    """
    if config.half_resolution_fraction not in (0.0, 1.0):
        raise ValueError(
            "half_resolution_fraction: a folder has one camera, so it must be 0 (all 640x480) "
            f"or 1 (all 320x240) to write frames, got {config.half_resolution_fraction}"
        )
    if 0 < config.mirror_probability < 1 and config.cx != (config.width - 1) / 2:
        raise ValueError(
            "cx: mirroring moves the principal point to W - 1 - cx, so a folder with mirrored "
            f"and unmirrored frames needs cx = {(config.width - 1) / 2}, got {config.cx}"
        )


CONFIG_TABLES = ("data", "training", "detector", "verifier", "heatmap", "calibration")
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
