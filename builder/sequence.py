"""Synthetic RGB-D sequences with ground truth, rendered from a hand trajectory.

A sequence is a trajectory (:mod:`glovedb.trajectory`) sampled at its frame rate and
rendered by :class:`~builder.render.GloveRenderer` in front of a background, with the
noise of a camera added, and written in the RGB-D folder layout of docs/conventions.md::

    SEQ/intrinsic.json      Open3D intrinsics of the camera
    SEQ/color/000000.png    8-bit RGB
    SEQ/depth/000000.png    uint16, depth_scale units per metre (0 = no measurement)
    SEQ/meta.json           depth_scale, fps, frames, project version, the settings
    SEQ/groundtruth.jsonl   one object per frame (docs/conventions.md)

This is the synthetic Kinect data of the thesis (ch. 4.3): the ground truth is exact
and the tracker's estimates can be scored against it (:mod:`tracker.evaluation`).

Backgrounds (one per sequence, the camera does not move):

- ``plain``: a uniform dark gray with no depth (nothing within range);
- ``clutter``: a wall behind the hand with random shapes in front of it, each at its
  own slightly slanted depth, in colors whose chroma is far from every glove color;
- ``table``: a textured table top just below the lowest point the hand reaches,
  seen by a camera pitched down, and a wall behind it.

The hand is composited with a depth test (the nearer surface wins), so a table can
hide the part of a hand that dips below it. Depth noise is :mod:`builder.depth_noise`,
color noise :mod:`builder.color_noise`, both under the same preset name.

Conditions a real user brings, each off by default:

- a personal hand: the model stretched by :class:`~glovedb.proportions.HandProportions`
  (hand length, finger lengths, palm width); the ground truth is that hand's skeleton;
- an occluder: a ball passing in front of the hand, rendered analytically
  (:func:`sphere_depth`) and composited with the same depth test before the noise;
- misregistration: the color image shifted against depth (:func:`shift_image`) before
  the color noise; the ground truth stays in the depth camera's frame;
- a dim room: ``light`` below 1 raises the camera's gain and with it the color noise,
  and darkens the image once the gain is at its limit (:func:`builder.color_noise.dim_light`).

Randomness: the background and the sequence's exposure come from
``default_rng([seed, 0])``, the noise of frame ``k`` from ``default_rng([seed, 1, k])``;
so a seed reproduces a sequence and its first frames do not depend on ``frames``
(unless there is an occluder: its path runs from the first to the last frame).
"""

from __future__ import annotations

import json
import math
import shutil
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
import tomllib
from numpy.typing import ArrayLike, NDArray

from builder.color_noise import apply_color_noise, color_noise_preset, dim_light, sequence_gains
from builder.depth_noise import NOISE_PRESETS, NoisePreset, apply_depth_noise, noise_preset
from builder.render import GloveRenderer
from glovedb import __version__
from glovedb._validate import as_array, check_choice
from glovedb.camera import CameraIntrinsics, save_intrinsics
from glovedb.hand_model import (
    DEFAULT_HAND_LENGTH_M,
    N_KEYPOINTS,
    Skeleton,
    forward_kinematics,
    make_skeleton,
)
from glovedb.mesh import cached_hand_mesh
from glovedb.pattern import GlovePattern, chroma_uv
from glovedb.proportions import (
    FACTOR_RANGE,
    HandProportions,
    proportioned_mesh,
    proportioned_skeleton,
)
from glovedb.resources import config_files
from glovedb.trajectory import Trajectory, load_trajectory

BackgroundKind = Literal["plain", "clutter", "table"]
BACKGROUNDS: tuple[BackgroundKind, ...] = ("plain", "clutter", "table")

PLAIN_RGB = (45, 45, 45)
MAX_RANGE_M = 4.0
"""Farthest depth a background surface is measured at (a Kinect's range)."""
MIN_HAND_DEPTH_M = 0.05
"""Nearest a keypoint may come to the camera plane (its image position must exist)."""
MAX_SEQUENCE_FRAMES = 1_000_000
"""Most frames of one rendered sequence (9 hours at 30 fps): their poses and keypoints
are sampled into memory at once, about 1 kB per frame."""
WOOD_RGB = (160, 150, 138)
"""Mean color of the table top, a pale oak."""
MIN_GLOVE_CHROMA_DISTANCE = 0.4
"""Background colors keep at least this distance to every glove color in
:func:`~glovedb.pattern.chroma_uv` space (the glove colors are 0.35 or more apart,
gray is about 0.45 from the nearest)."""
MAX_BACKGROUND_CHROMA = 0.6
"""Background colors are no more saturated than this (norm of their chroma): dark,
saturated colors lie beyond the ring of glove colors, far in chroma but alike to the
eye."""
OCCLUDER_FROM_M = (-0.12, 0.0, -0.04)
"""Default offset of the occluder's centre from the hand's centre at the first frame,
camera frame, metres: 12 cm to the left of the hand and 4 cm in front of it."""
OCCLUDER_TO_M = (0.12, 0.0, -0.04)
"""Default offset at the last frame: 12 cm to the right, 4 cm in front."""
OCCLUDER_RGB = (170, 164, 156)
"""sRGB of the lit side of the occluder, a neutral gray-beige: its chroma is more than
:data:`MIN_GLOVE_CHROMA_DISTANCE` from every glove color at every shade."""
OCCLUDER_AMBIENT = 0.35
"""Share of :data:`OCCLUDER_RGB` on the occluder where the light grazes it."""


@dataclass(frozen=True)
class SequenceSettings:
    """What ``glove render-sequence`` renders.

    Attributes
    ----------
    trajectory : str
        Named trajectory (``configs/trajectories/``) or a trajectory JSON file.
    camera : str
        Camera preset (``configs/camera/``) or a camera TOML file.
    frames : int or None
        Number of frames at the trajectory's fps; None renders the whole trajectory
        (past its end the hand holds still).
    seed : int
    background : {"plain", "clutter", "table"}
    noise : {"none", "kinect_v1", "realsense_d435"}
        Depth and color noise preset.
    depth_scale : float
        Depth units per metre in the PNG files.
    min_visible_pixels : int
        A frame's hand is visible when at least this many pixels show it (after the
        depth tests with the background and the occluder) and at least half of its
        keypoints project into the image.
    hand_length_m : float or None
        Wrist crease to the tip of the middle finger, metres; None is the model's
        :data:`~glovedb.hand_model.DEFAULT_HAND_LENGTH_M` (0.19 m). The whole hand
        scales by ``hand_length_m / 0.19`` about the wrist (half to twice the model).
    finger_length : (5,) tuple of float
        Each finger's length against the model's (after ``hand_length_m``), thumb
        first, 0.5-2.
    palm_width : float
        The palm's width against the model's, 0.5-2.
    occluder_radius_m : float
        Radius of a ball passing in front of the hand, metres; 0 is no ball.
    occluder_from_m, occluder_to_m : (3,) tuple of float
        The ball's centre relative to the hand's centre (the mean of the frame's 21
        keypoints) at the first and at the last frame, camera frame, metres; it moves
        linearly in between.
    misregistration_px : (2,) tuple of float
        ``(du, dv)``: the color image's content is shifted by this many pixels
        (right, down) against depth and the ground truth.
    light : float
        The room's illumination against the noise preset's, in (0, 1]; below 1 the
        color noise grows with the auto-exposure gain and, past its limit, the image
        darkens (:func:`builder.color_noise.dim_light`). Needs a noise preset.
    """

    trajectory: str
    camera: str = "kinect_v1"
    frames: int | None = None
    seed: int = 0
    background: BackgroundKind = "plain"
    noise: NoisePreset = "none"
    depth_scale: float = 1000.0
    min_visible_pixels: int = 200
    hand_length_m: float | None = None
    finger_length: tuple[float, float, float, float, float] = (1.0, 1.0, 1.0, 1.0, 1.0)
    palm_width: float = 1.0
    occluder_radius_m: float = 0.0
    occluder_from_m: tuple[float, float, float] = OCCLUDER_FROM_M
    occluder_to_m: tuple[float, float, float] = OCCLUDER_TO_M
    misregistration_px: tuple[float, float] = (0.0, 0.0)
    light: float = 1.0

    def __post_init__(self) -> None:
        check_choice("background", self.background, BACKGROUNDS)
        check_choice("noise", self.noise, NOISE_PRESETS)
        if self.frames is not None and self.frames < 1:
            raise ValueError(f"frames: expected at least 1, got {self.frames}")
        if not self.depth_scale > 0:
            raise ValueError(f"depth_scale: expected > 0, got {self.depth_scale}")
        if self.hand_length_m is not None:
            low, high = (DEFAULT_HAND_LENGTH_M * factor for factor in FACTOR_RANGE)
            if not low <= self.hand_length_m <= high:
                raise ValueError(
                    f"hand_length_m: expected {low:.3f}-{high:.2f} m (half to twice the "
                    f"model's {DEFAULT_HAND_LENGTH_M} m), got {self.hand_length_m}"
                )
        # HandProportions checks the factors and names the one out of range.
        object.__setattr__(self, "finger_length", self.proportions.finger_length)
        if not (math.isfinite(self.occluder_radius_m) and self.occluder_radius_m >= 0):
            raise ValueError(
                f"occluder_radius_m: expected a radius >= 0 m (0: no occluder), "
                f"got {self.occluder_radius_m}"
            )
        dim_light(color_noise_preset(self.noise), self.light)  # checks the range
        if self.light < 1 and self.noise == "none":
            raise ValueError("light: a dim room needs a camera's noise model (noise is 'none')")
        for name, size in (("occluder_from_m", 3), ("occluder_to_m", 3), ("misregistration_px", 2)):
            vector = as_array(name, getattr(self, name), (size,), np.float64, finite=True)
            object.__setattr__(self, name, tuple(float(value) for value in vector))

    @property
    def proportions(self) -> HandProportions:
        """The hand against the model: ``hand_length_m / 0.19``, fingers and palm."""
        length = DEFAULT_HAND_LENGTH_M if self.hand_length_m is None else self.hand_length_m
        return HandProportions(length / DEFAULT_HAND_LENGTH_M, self.finger_length, self.palm_width)

    def as_dict(self) -> dict[str, Any]:
        """Every setting, JSON-ready."""
        return asdict(self)


@dataclass(frozen=True)
class Background:
    """A static scene behind the hand.

    Attributes
    ----------
    color : (H, W, 3) uint8
        sRGB.
    depth_m : (H, W) float32
        Metres, 0 where nothing is within range.
    """

    color: NDArray[np.uint8]
    depth_m: NDArray[np.float32]


@dataclass(frozen=True)
class FrameTruth:
    """Ground truth of one frame (a ``groundtruth.jsonl`` object).

    Attributes
    ----------
    frame : int
    hand_visible : bool
    posture_rad : (20,) float64
    rotation : (3, 3) float64
        ``cam_R_hand``.
    translation_m : (3,) float64
        Wrist in the camera frame.
    keypoints_3d_m : (21, 3) float64
        Camera frame.
    keypoints_2d_px : (21, 2) float64
        Projections (OpenCV pixel convention).
    occluded_fraction : float or None
        Share of the hand's pixels (after the depth test with the background) that the
        occluder hides, 0-1 (0 when no pixel shows the hand); None without an occluder.
    """

    frame: int
    hand_visible: bool
    posture_rad: NDArray[np.float64]
    rotation: NDArray[np.float64]
    translation_m: NDArray[np.float64]
    keypoints_3d_m: NDArray[np.float64]
    keypoints_2d_px: NDArray[np.float64]
    occluded_fraction: float | None = None

    def as_record(self) -> dict[str, Any]:
        """The JSON object of ``groundtruth.jsonl``; fields that are None are left out."""
        return {
            field.name: value.tolist() if isinstance(value, np.ndarray) else value
            for field in fields(self)
            for value in (getattr(self, field.name),)
            if value is not None
        }


@dataclass(frozen=True)
class SyntheticFrame:
    """One rendered frame as a camera would deliver it, with its ground truth.

    Attributes
    ----------
    color : (H, W, 3) uint8
        Noisy sRGB (shifted by the misregistration).
    depth_m : (H, W) float32
        Noisy depth, metres, 0 where missing.
    hand_mask : (H, W) bool
        Pixels where the hand is the nearest surface (before noise; in the depth
        camera's frame, like the ground truth).
    truth : FrameTruth
    """

    color: NDArray[np.uint8]
    depth_m: NDArray[np.float32]
    hand_mask: NDArray[np.bool_]
    truth: FrameTruth


@dataclass(frozen=True)
class SequenceReport:
    """What :func:`render_sequence` wrote.

    Attributes
    ----------
    path : str
        The sequence folder.
    frames, visible_frames : int
        Frames written, and of those the frames with the hand visible.
    seconds : float
        Wall-clock time.
    """

    path: str
    frames: int
    visible_frames: int
    seconds: float


def _config_files(folder: str, suffix: str) -> dict[str, Path]:
    """Files ``configs/folder/*suffix`` by stem (packaged copy first, then checkout)."""
    return {path.stem: path for path in config_files(folder, suffix)}


def camera_names() -> tuple[str, ...]:
    """Names of the camera presets in ``configs/camera/``."""
    return tuple(_config_files("camera", ".toml"))


def load_camera(name_or_path: str | Path) -> CameraIntrinsics:
    """Intrinsics of a camera preset name or of a camera TOML file.

    The file holds ``width``, ``height``, ``fx``, ``fy``, ``cx``, ``cy`` (pixels,
    OpenCV convention). Raises a one-line ``ValueError`` for an unknown name or a
    malformed file.
    """
    presets = _config_files("camera", ".toml")
    path = presets.get(str(name_or_path), Path(name_or_path))
    if not path.is_file():
        raise ValueError(f"unknown camera {str(name_or_path)!r}; known: {', '.join(presets)}")
    try:
        with open(path, "rb") as stream:
            table = tomllib.load(stream)
    except tomllib.TOMLDecodeError as error:
        raise ValueError(f"{path}: not valid TOML ({error})") from error
    names = [field.name for field in fields(CameraIntrinsics)]
    if sorted(table) != sorted(names):
        raise ValueError(f"{path}: expected exactly the keys {', '.join(names)}")
    try:
        return CameraIntrinsics(
            int(table["width"]), int(table["height"]),
            *(float(table[key]) for key in ("fx", "fy", "cx", "cy")),
        )  # fmt: skip
    except (TypeError, ValueError) as error:
        raise ValueError(f"{path}: {error}") from error


def trajectory_names() -> tuple[str, ...]:
    """Names of the trajectories in ``configs/trajectories/`` (file stems)."""
    return tuple(_config_files("trajectories", ".json"))


def resolve_trajectory(name_or_path: str | Path) -> Path:
    """The file of a named trajectory, or ``name_or_path`` itself if it is a file.

    A name is a file stem (``tr1_pinch``) or its part before the first underscore
    (``tr1``). Something that looks like a file name (``.json``, a folder) is taken
    as one. Raises a one-line ``ValueError`` for an unknown name.
    """
    text = str(name_or_path)
    if text.endswith(".json") or "/" in text or Path(text).is_file():
        return Path(text)
    named = _config_files("trajectories", ".json")
    if text in named:
        return named[text]
    matches = [path for stem, path in named.items() if stem.split("_")[0] == text]
    if len(matches) == 1:
        return matches[0]
    raise ValueError(f"unknown trajectory {text!r}; known: {', '.join(named)}")


def sequence_times(trajectory: Trajectory, frames: int | None) -> NDArray[np.float64]:
    """Times ``(T,)`` in seconds of the frames: all of the trajectory, or ``frames``."""
    if frames is None:
        return trajectory.frame_times()
    return np.arange(frames) / trajectory.fps


def camera_keypoints(
    postures_rad: ArrayLike, rotations: ArrayLike, translations_m: ArrayLike, skeleton: Skeleton
) -> NDArray[np.float64]:
    """Keypoints in the camera frame of a batch of hand states.

    Parameters
    ----------
    postures_rad : (T, 20) float
    rotations : (T, 3, 3) float
        ``cam_R_hand``.
    translations_m : (T, 3) float
    skeleton : Skeleton

    Returns
    -------
    (T, 21, 3) float64
        Metres.
    """
    postures = as_array("postures_rad", postures_rad, (None, 20), np.float64, finite=True)
    count = len(postures)
    R = as_array("rotations", rotations, (count, 3, 3), np.float64, finite=True)
    t = as_array("translations_m", translations_m, (count, 3), np.float64, finite=True)
    hand = forward_kinematics(postures, skeleton).keypoints_m
    return np.einsum("tij,tkj->tki", R, hand) + t[:, None, :]


def background_colors(
    count: int, pattern: GlovePattern, *, rng: np.random.Generator
) -> NDArray[np.uint8]:
    """Random sRGB colors none of which a color classifier could take for the glove.

    Parameters
    ----------
    count : int
    pattern : GlovePattern
        Its colors are the ones to keep away from.
    rng : numpy.random.Generator

    Returns
    -------
    (count, 3) uint8
        Each at least :data:`MIN_GLOVE_CHROMA_DISTANCE` from every glove color in
        :func:`~glovedb.pattern.chroma_uv` space and with a chroma of at most
        :data:`MAX_BACKGROUND_CHROMA`.
    """
    glove = chroma_uv(pattern.colors_rgb)
    accepted: list[NDArray[np.uint8]] = []
    while sum(len(batch) for batch in accepted) < count:
        candidates = rng.integers(20, 236, size=(4 * count + 8, 3)).astype(np.uint8)
        chroma = chroma_uv(candidates)
        distance = np.linalg.norm(chroma[:, None] - glove[None], axis=-1)
        keep = (distance.min(axis=1) >= MIN_GLOVE_CHROMA_DISTANCE) & (
            np.linalg.norm(chroma, axis=1) <= MAX_BACKGROUND_CHROMA
        )
        accepted.append(candidates[keep])
    return np.concatenate(accepted)[:count]


def plain_background(camera: CameraIntrinsics) -> Background:
    """Uniform dark gray, no depth."""
    color = np.empty((camera.height, camera.width, 3), np.uint8)
    color[:] = PLAIN_RGB
    return Background(color, np.zeros((camera.height, camera.width), np.float32))


def clutter_background(
    camera: CameraIntrinsics,
    keypoints_m: ArrayLike,
    pattern: GlovePattern,
    *,
    rng: np.random.Generator,
    shapes: int = 40,
) -> Background:
    """A wall with random shapes between it and the hand, all behind the hand.

    Parameters
    ----------
    camera : CameraIntrinsics
    keypoints_m : (..., 3) float
        Every keypoint of the sequence, camera frame: the shapes stay at least 10 cm
        behind the farthest of them, the wall 30-60 cm.
    pattern : GlovePattern
    rng : numpy.random.Generator
    shapes : int
        Number of rectangles, ellipses and triangles.

    Returns
    -------
    Background
    """
    far = float(as_array("keypoints_m", keypoints_m, (..., 3), np.float64)[..., 2].max())
    height, width = camera.height, camera.width
    colors = background_colors(shapes + 1, pattern, rng=rng)
    wall_depth = min(far + rng.uniform(0.3, 0.6), MAX_RANGE_M)
    color = np.empty((height, width, 3), np.uint8)
    color[:] = colors[0]
    depth = np.full((height, width), wall_depth, np.float32)
    v, u = np.indices((height, width), dtype=np.float32)
    for shape_color in colors[1:]:
        mask = np.zeros((height, width), np.uint8)
        _draw_random_shape(mask, rng)
        inside = mask.astype(bool)
        # A slanted board: depth changes by up to 5 cm across 100 pixels.
        slope = rng.uniform(-5e-4, 5e-4, 2).astype(np.float32)
        centre = np.array([rng.uniform(0, width), rng.uniform(0, height)], np.float32)
        board = np.float32(rng.uniform(far + 0.1, wall_depth - 0.02))
        board = board + slope[0] * (u - centre[0]) + slope[1] * (v - centre[1])
        nearer = inside & (board < depth) & (board > far + 0.05)
        shade = np.clip(1.0 + 0.15 * (v - centre[1]) / height, 0.8, 1.15)[..., None]
        shaded = np.clip(shape_color[None, None, :] * shade, 0, 255).astype(np.uint8)
        color[nearer] = shaded[nearer]
        depth[nearer] = board[nearer]
    return Background(color, depth)


def _draw_random_shape(mask: NDArray[np.uint8], rng: np.random.Generator) -> None:
    height, width = mask.shape
    centre = (int(rng.integers(0, width)), int(rng.integers(0, height)))
    size = int(rng.integers(height // 20, height // 4))
    kind = int(rng.integers(3))
    if kind == 0:
        corner = (centre[0] + int(rng.integers(size // 2, 2 * size)), centre[1] + size)
        cv2.rectangle(mask, centre, corner, 1, thickness=-1)
    elif kind == 1:
        axes = (size, int(rng.integers(size // 3, size + 1)))
        cv2.ellipse(mask, centre, axes, float(rng.uniform(0, 180)), 0, 360, 1, thickness=-1)
    else:
        corners = np.array(centre) + rng.integers(-size, size + 1, size=(3, 2))
        cv2.fillPoly(mask, [corners.astype(np.int32)], 1)


def table_background(
    camera: CameraIntrinsics,
    keypoints_m: ArrayLike,
    pattern: GlovePattern,
    *,
    rng: np.random.Generator,
) -> Background:
    """A wood-grained table top below the hand and a wall behind it.

    The camera is pitched down by 10-25 degrees; the table is level, 3-12 cm below
    the lowest keypoint of the sequence, the wall 30-60 cm behind the farthest one.

    Parameters
    ----------
    camera : CameraIntrinsics
    keypoints_m : (..., 3) float
        Every keypoint of the sequence, camera frame.
    pattern : GlovePattern
        The wall color keeps away from its colors.
    rng : numpy.random.Generator

    Returns
    -------
    Background
    """
    points = as_array("keypoints_m", keypoints_m, (..., 3), np.float64).reshape(-1, 3)
    pitch = np.radians(rng.uniform(10.0, 25.0))
    up = np.array([0.0, -np.cos(pitch), -np.sin(pitch)])  # world up, camera frame
    forward = np.array([0.0, -np.sin(pitch), np.cos(pitch)])  # level, away from camera
    table_height = float((points @ up).min()) - rng.uniform(0.03, 0.12)
    wall_distance = float((points @ forward).max()) + rng.uniform(0.3, 0.6)
    table = camera.plane_depth(up, table_height * up, max_depth_m=MAX_RANGE_M)
    wall = camera.plane_depth(forward, wall_distance * forward, max_depth_m=MAX_RANGE_M)
    on_table = (table > 0) & ((wall == 0) | (table < wall))
    depth = np.where(on_table, table, wall).astype(np.float32)

    v, u = np.indices((camera.height, camera.width), dtype=np.float64)
    points_table = camera.back_project(np.stack([u, v], -1), table)
    across = points_table[..., 0]
    along = points_table @ forward
    phase = rng.uniform(0, 2 * np.pi)
    grain = 0.5 + 0.5 * np.sin(2 * np.pi * across / 0.035 + 3.0 * np.sin(along / 0.09) + phase)
    wood = np.array(WOOD_RGB, np.float64) * (0.82 + 0.18 * grain)[..., None]
    wall_color = background_colors(1, pattern, rng=rng)[0]
    color = np.where(on_table[..., None], wood, wall_color.astype(np.float64))
    color[depth == 0] = PLAIN_RGB
    return Background(np.clip(np.rint(color), 0, 255).astype(np.uint8), depth)


def make_background(
    kind: str,
    camera: CameraIntrinsics,
    keypoints_m: ArrayLike,
    pattern: GlovePattern,
    *,
    rng: np.random.Generator,
) -> Background:
    """The background ``kind`` (one of :data:`BACKGROUNDS`) for a sequence's keypoints."""
    check_choice("background", kind, BACKGROUNDS)
    if kind == "clutter":
        return clutter_background(camera, keypoints_m, pattern, rng=rng)
    if kind == "table":
        return table_background(camera, keypoints_m, pattern, rng=rng)
    return plain_background(camera)


def composite(
    hand_color: ArrayLike, hand_depth_m: ArrayLike, background: Background
) -> tuple[NDArray[np.uint8], NDArray[np.float32], NDArray[np.bool_]]:
    """Put the hand in front of a background with a depth test.

    Parameters
    ----------
    hand_color : (H, W, 3) uint8
    hand_depth_m : (H, W) float
        0 where the hand is not.
    background : Background

    Returns
    -------
    color : (H, W, 3) uint8
    depth_m : (H, W) float32
    hand_mask : (H, W) bool
        Where the hand is nearer than the background (or the background has no depth).
    """
    color = as_array("hand_color", hand_color, background.color.shape, kind="u")
    depth = as_array("hand_depth_m", hand_depth_m, background.depth_m.shape, np.float32)
    behind = background.depth_m
    hand = (depth > 0) & ((behind == 0) | (depth < behind))
    return (
        np.where(hand[..., None], color, background.color).astype(np.uint8),
        np.where(hand, depth, behind).astype(np.float32),
        hand,
    )


def hand_visible(
    hand_mask: NDArray[np.bool_],
    keypoints_2d_px: NDArray[np.float64],
    keypoints_z_m: NDArray[np.float64],
    *,
    min_pixels: int,
) -> bool:
    """Whether at least ``min_pixels`` show the hand and half its keypoints are in view."""
    height, width = hand_mask.shape
    u, v = keypoints_2d_px[:, 0], keypoints_2d_px[:, 1]
    inside = (keypoints_z_m > 0) & (u > -0.5) & (u < width - 0.5) & (v > -0.5) & (v < height - 0.5)
    return bool(hand_mask.sum() >= min_pixels and inside.mean() >= 0.5)


def check_renderer_hand(renderer: GloveRenderer, proportions: HandProportions) -> None:
    """Raise ``ValueError`` unless the renderer's mesh is rigged to the hand of
    ``proportions`` (the ground truth comes from that mesh's skeleton)."""
    expected = proportioned_skeleton(make_skeleton(), proportions)
    actual = renderer.mesh.skeleton
    same = (
        math.isclose(actual.hand_length_m, expected.hand_length_m, abs_tol=1e-9)
        and np.allclose(actual.offsets_m, expected.offsets_m, rtol=0, atol=1e-9)
        and np.allclose(actual.lengths_m, expected.lengths_m, rtol=0, atol=1e-9)
    )
    if not same:
        raise ValueError(
            f"renderer: its hand ({actual.hand_length_m:.3f} m) is not the settings' hand "
            f"{proportions.as_dict()}; give it mesh=proportioned_mesh(make_hand_mesh(), "
            "settings.proportions)"
        )


def occluder_centres(
    keypoints_m: ArrayLike, from_m: ArrayLike, to_m: ArrayLike
) -> NDArray[np.float64]:
    """Centres of a ball that moves past the hand, one per frame.

    Parameters
    ----------
    keypoints_m : (T, 21, 3) float
        The hand's keypoints in every frame, camera frame; their mean is the hand's
        centre.
    from_m, to_m : (3,) float
        The ball's centre relative to the hand's centre at the first and at the last
        frame, camera frame, metres; it moves linearly in between.

    Returns
    -------
    (T, 3) float64
        Metres, camera frame.
    """
    points = as_array("keypoints_m", keypoints_m, (None, N_KEYPOINTS, 3), np.float64, finite=True)
    start = as_array("from_m", from_m, (3,), np.float64, finite=True)
    end = as_array("to_m", to_m, (3,), np.float64, finite=True)
    fraction = np.linspace(0.0, 1.0, len(points))[:, None]
    return points.mean(axis=1) + (1 - fraction) * start + fraction * end


def _ball_arguments(centre_m: ArrayLike, radius_m: float) -> NDArray[np.float64]:
    """The checked centre ``(3,)`` of a ball wholly in front of the camera."""
    centre = as_array("centre_m", centre_m, (3,), np.float64, finite=True)
    if not (math.isfinite(radius_m) and radius_m > 0):
        raise ValueError(f"radius_m: expected a radius > 0 m, got {radius_m}")
    if not centre[2] - radius_m > 0:
        raise ValueError(
            f"centre_m: the ball (z = {centre[2]:.3f} m, radius {radius_m} m) must lie "
            "wholly in front of the camera"
        )
    return centre


def sphere_depth(
    camera: CameraIntrinsics, centre_m: ArrayLike, radius_m: float
) -> NDArray[np.float32]:
    """Exact depth image of a ball: where each pixel's ray first meets it.

    The ray through pixel ``(u, v)`` is ``z * d`` with ``d = ((u - cx) / fx,
    (v - cy) / fy, 1)``; it meets the sphere ``|p - c| = r`` where
    ``|d|² z² - 2 (d · c) z + |c|² - r² = 0``, first at the smaller root.

    Parameters
    ----------
    camera : CameraIntrinsics
    centre_m : (3,) float
        The ball's centre, camera frame, metres.
    radius_m : float
        Metres; the ball must lie wholly in front of the camera (``z - r > 0``).

    Returns
    -------
    (H, W) float32
        Distance along the optical axis (z), metres; 0 where the ray misses the ball.
    """
    c = _ball_arguments(centre_m, radius_m)
    v, u = np.indices((camera.height, camera.width), dtype=np.float64)
    x = (u - camera.cx) / camera.fx
    y = (v - camera.cy) / camera.fy
    a = x * x + y * y + 1.0
    b = x * c[0] + y * c[1] + c[2]
    k = float(c @ c) - radius_m**2  # > 0: the camera is outside the ball
    discriminant = b * b - a * k
    hit = discriminant > 0
    depth = np.zeros_like(a)
    # The smaller root (b - sqrt(disc)) / a, written without cancellation.
    depth[hit] = k / (b[hit] + np.sqrt(discriminant[hit]))
    return depth.astype(np.float32)


def sphere_image(
    camera: CameraIntrinsics, centre_m: ArrayLike, radius_m: float
) -> tuple[NDArray[np.uint8], NDArray[np.float32]]:
    """A Lambert-shaded ball lit from the camera, and its depth.

    Parameters
    ----------
    camera : CameraIntrinsics
    centre_m : (3,) float
        Camera frame, metres.
    radius_m : float
        Metres; the ball must lie wholly in front of the camera.

    Returns
    -------
    color : (H, W, 3) uint8
        :data:`OCCLUDER_RGB` times ``ambient + (1 - ambient) * cos`` of the angle
        between the surface normal and the direction to the camera (0 off the ball).
    depth_m : (H, W) float32
        :func:`sphere_depth`.
    """
    centre = _ball_arguments(centre_m, radius_m)
    depth = sphere_depth(camera, centre, radius_m)
    v, u = np.nonzero(depth > 0)
    points = camera.back_project(np.stack([u, v], -1), depth[v, u])
    normals = (points - centre) / radius_m
    towards_camera = -points / np.linalg.norm(points, axis=1, keepdims=True)
    lambert = np.clip(np.sum(normals * towards_camera, axis=1), 0.0, 1.0)
    shade = OCCLUDER_AMBIENT + (1 - OCCLUDER_AMBIENT) * lambert
    color = np.zeros((camera.height, camera.width, 3), np.uint8)
    color[v, u] = np.rint(np.array(OCCLUDER_RGB) * shade[:, None]).astype(np.uint8)
    return color, depth


def shift_image(image: ArrayLike, shift_px: ArrayLike) -> NDArray[np.uint8]:
    """An image's content moved by ``(du, dv)`` pixels: a color camera misregistered.

    ``out[v, u] = image[v - dv, u - du]``, bilinear between pixels for a sub-pixel
    shift (whole-pixel shifts copy pixels exactly); the edge pixels are repeated where
    the shifted image has no content.

    Parameters
    ----------
    image : (H, W, 3) uint8
    shift_px : (2,) float
        ``(du, dv)``, pixels, right and down.

    Returns
    -------
    (H, W, 3) uint8
    """
    picture = as_array("image", image, (None, None, 3), np.uint8, kind="u")
    du, dv = as_array("shift_px", shift_px, (2,), np.float64, finite=True)
    height, width = picture.shape[:2]
    matrix = np.array([[1.0, 0.0, du], [0.0, 1.0, dv]])
    shifted = cv2.warpAffine(
        picture, matrix, (width, height), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
    )
    return shifted.astype(np.uint8, copy=False)


def render_frames(
    trajectory: Trajectory, settings: SequenceSettings, renderer: GloveRenderer
) -> Iterator[SyntheticFrame]:
    """Render the frames of a sequence one by one (module docstring).

    Parameters
    ----------
    trajectory : Trajectory
    settings : SequenceSettings
        Everything but ``trajectory``, ``camera`` and ``depth_scale`` is used here; the
        camera is the renderer's.
    renderer : GloveRenderer
        Its mesh's skeleton gives the keypoints; it must be the settings' hand
        (:func:`check_renderer_hand`).

    Yields
    ------
    SyntheticFrame
    """
    check_renderer_hand(renderer, settings.proportions)
    camera = renderer.camera
    postures, rotations, translations = trajectory.sample(
        sequence_times(trajectory, settings.frames)
    )
    keypoints = camera_keypoints(postures, rotations, translations, renderer.mesh.skeleton)
    nearest = keypoints[..., 2].min(axis=1)
    if np.any(nearest < MIN_HAND_DEPTH_M):
        frame = int(np.argmax(nearest < MIN_HAND_DEPTH_M))
        raise ValueError(
            f"frame {frame}: the hand comes to z = {nearest[frame]:.3f} m; a trajectory must "
            f"keep it at least {MIN_HAND_DEPTH_M} m in front of the camera"
        )
    radius = settings.occluder_radius_m
    balls = occluder_centres(keypoints, settings.occluder_from_m, settings.occluder_to_m)
    if radius > 0 and np.any(balls[:, 2] - radius < MIN_HAND_DEPTH_M):
        frame = int(np.argmax(balls[:, 2] - radius < MIN_HAND_DEPTH_M))
        raise ValueError(
            f"frame {frame}: the occluder comes to z = {balls[frame, 2] - radius:.3f} m; "
            f"occluder_from_m and occluder_to_m must keep it at least {MIN_HAND_DEPTH_M} m "
            "in front of the camera"
        )
    scene_rng = np.random.default_rng([settings.seed, 0])
    background = make_background(
        settings.background, camera, keypoints, renderer.pattern, rng=scene_rng
    )
    depth_noise = noise_preset(settings.noise)
    color_noise, brightness = dim_light(color_noise_preset(settings.noise), settings.light)
    gains = sequence_gains(color_noise, rng=scene_rng) * brightness
    intrinsics = camera.pinhole
    for frame in range(len(postures)):
        rendering = renderer.render(postures[frame], rotations[frame], translations[frame])
        color, depth, mask = composite(rendering.color, rendering.depth_m, background)
        occluded_fraction = None
        if radius > 0:
            ball_color, ball_depth = sphere_image(camera, balls[frame], radius)
            color, depth, ball = composite(ball_color, ball_depth, Background(color, depth))
            occluded_fraction = float((mask & ball).sum() / max(int(mask.sum()), 1))
            mask = mask & ~ball
        keypoints_2d = camera.project(keypoints[frame])
        truth = FrameTruth(
            frame=frame,
            hand_visible=hand_visible(
                mask, keypoints_2d, keypoints[frame, :, 2], min_pixels=settings.min_visible_pixels
            ),
            posture_rad=postures[frame],
            rotation=rotations[frame],
            translation_m=translations[frame],
            keypoints_3d_m=keypoints[frame],
            keypoints_2d_px=keypoints_2d,
            occluded_fraction=occluded_fraction,
        )
        if any(settings.misregistration_px):
            color = shift_image(color, settings.misregistration_px)
        rng = np.random.default_rng([settings.seed, 1, frame])
        noisy_depth = apply_depth_noise(depth, intrinsics, depth_noise, rng=rng)
        noisy_color = apply_color_noise(color, color_noise, gains=gains, rng=rng)
        yield SyntheticFrame(noisy_color, noisy_depth, mask, truth)


def require_empty_folder(folder: str | Path) -> Path:
    """``folder`` as a path; ``ValueError`` if it exists and is not an empty folder.

    Writers of new datasets call it first: writing into an old dataset would mix its
    frames with the new ones (a shorter run leaves the old frames beyond its end).
    """
    root = Path(folder)
    if root.exists() and (not root.is_dir() or any(root.iterdir())):
        raise ValueError(f"{root}: exists and is not an empty folder")
    return root


@contextmanager
def staged_folder(folder: str | Path) -> Iterator[Path]:
    """Write a new dataset folder under a temporary name, in place only once complete.

    Yields a hidden sibling folder (``.NAME.partial-XXXX``) to write into. When the
    block ends normally it is renamed to ``folder``; when it raises (a bad frame, an
    interrupt) it is removed, so a failed run leaves neither a half-written dataset
    nor a folder that the next run would refuse.

    Raises
    ------
    ValueError
        If ``folder`` exists and is not an empty folder (before anything is written).
    """
    root = require_empty_folder(folder)
    root.parent.mkdir(parents=True, exist_ok=True)
    partial = Path(tempfile.mkdtemp(prefix=f".{root.name}.partial-", dir=root.parent))
    try:
        yield partial
        if root.exists():
            root.rmdir()  # empty, checked above
        partial.rename(root)
    finally:
        if partial.exists():
            shutil.rmtree(partial, ignore_errors=True)


def depth_to_png_units(depth_m: ArrayLike, depth_scale: float) -> NDArray[np.uint16]:
    """Metres ``(H, W)`` to ``(H, W) uint16`` in ``depth_scale`` units per metre (rounded,
    saturated at 65535; 0 stays 0)."""
    depth = as_array("depth_m", depth_m, (None, None), np.float64, finite=True)
    units = np.rint(depth * depth_scale)
    return np.clip(units, 0, np.iinfo(np.uint16).max).astype(np.uint16)


def write_frames(
    frames: Iterable[SyntheticFrame], root: Path, *, depth_scale: float
) -> tuple[int, int]:
    """Write color, depth and ground truth of every frame into a prepared folder.

    Returns
    -------
    written, visible : int
        Number of frames, and of frames whose hand is visible.
    """
    written = visible = 0
    with open(root / "groundtruth.jsonl", "w") as truth_file:
        for item in frames:
            name = f"{item.truth.frame:06d}.png"
            color_ok = cv2.imwrite(str(root / "color" / name), item.color[..., ::-1])
            depth = depth_to_png_units(item.depth_m, depth_scale)
            if not (color_ok and cv2.imwrite(str(root / "depth" / name), depth)):
                raise ValueError(f"{root}: could not write frame {item.truth.frame}")
            truth_file.write(json.dumps(item.truth.as_record()) + "\n")
            written += 1
            visible += item.truth.hand_visible
    return written, visible


def render_sequence(
    settings: SequenceSettings,
    folder: str | Path,
    *,
    renderer: GloveRenderer | None = None,
    progress: Callable[[Iterator[SyntheticFrame], int], Iterable[SyntheticFrame]] | None = None,
) -> SequenceReport:
    """Render a sequence and write it as an RGB-D folder (module docstring).

    Parameters
    ----------
    settings : SequenceSettings
    folder : str or Path
        Created; must not hold files yet. Written under a temporary name and renamed
        when complete (:func:`staged_folder`): a failed run leaves nothing behind.
    renderer : GloveRenderer, optional
        For the settings' camera and hand; one with the settings' hand
        (``proportioned_mesh(cached_hand_mesh(), settings.proportions)``) is made (and
        closed) if not given.
    progress : callable, optional
        Wraps the frame iterator, given the number of frames (e.g. a progress bar).

    Returns
    -------
    SequenceReport
    """
    start = time.perf_counter()
    trajectory_path = resolve_trajectory(settings.trajectory)
    trajectory = load_trajectory(trajectory_path)
    camera = load_camera(settings.camera)
    if renderer is not None:
        if renderer.camera != camera:
            raise ValueError(f"renderer: expected camera {camera}, got {renderer.camera}")
        check_renderer_hand(renderer, settings.proportions)
    count = len(sequence_times(trajectory, settings.frames))
    if count > MAX_SEQUENCE_FRAMES:
        raise ValueError(
            f"{count} frames: a sequence holds at most {MAX_SEQUENCE_FRAMES} "
            "(its poses are sampled into memory at once); use --frames or a shorter trajectory"
        )
    with staged_folder(folder) as root:
        (root / "color").mkdir()
        (root / "depth").mkdir()
        own = renderer is None
        active = (
            renderer
            if renderer is not None
            else GloveRenderer(
                camera, mesh=proportioned_mesh(cached_hand_mesh(), settings.proportions)
            )
        )
        try:
            frames: Iterable[SyntheticFrame] = render_frames(trajectory, settings, active)
            if progress is not None:
                frames = progress(iter(frames), count)
            written, visible = write_frames(frames, root, depth_scale=settings.depth_scale)
            hand_length = active.mesh.skeleton.hand_length_m
        finally:
            if own:
                active.close()
        save_intrinsics(camera, root / "intrinsic.json")
        meta = {
            "depth_scale": settings.depth_scale,
            "fps": trajectory.fps,
            "frames": written,
            "visible_frames": visible,
            "version": __version__,
            "generator": "glove render-sequence",
            "settings": settings.as_dict(),
            "trajectory_file": str(trajectory_path),
            "camera_intrinsics": asdict(camera),
            "hand_length_m": hand_length,
            "hand_proportions": settings.proportions.as_dict(),
        }
        (root / "meta.json").write_text(json.dumps(meta, indent=1))
    return SequenceReport(str(Path(folder)), written, visible, time.perf_counter() - start)
