"""A camera noise model for color images: exposure, white balance, blur, pixel noise.

The counterpart of :mod:`builder.depth_noise` for the color stream. A clean sRGB image
goes through, in order:

1. **Exposure and white balance**: in linear light every channel is multiplied by a
   gain ``2**e * exp(w_c)``, with ``e`` (stops) and ``w_c`` (per channel) Gaussian.
   A sequence draws one gain (auto exposure and auto white balance settle on a scene)
   and every frame multiplies it by a small jitter of its own (their flicker).
2. **Blur**: a Gaussian of ``blur_sigma_px`` (optics and demosaicking).
3. **Pixel noise**: Gaussian with ``pixel_sigma`` 8-bit levels, independent per pixel
   and channel; then rounding and clipping to 0..255.

**Dim light** (:func:`dim_light`): the presets describe a room lit as the thesis'
recordings were. In a room with ``light`` times that illumination the camera's auto
exposure brings the image back up with a gain ``g = min(1 / light, MAX_AUTO_GAIN)``:
at 30 frames/s the exposure time is already at its 1/30 s limit, so the gain is
analog/digital amplification, which amplifies the sensor's noise with the signal
(read-noise-limited, the case of small webcam and depth-camera color sensors in a
dim room: noise std times ``g``; shot-noise-limited sensors would give ``sqrt(g)``,
so this is the harsher case). Beyond the gain limit the image darkens: linear
brightness ``light * g``. E.g. ``light`` 0.25: 4x gain, Kinect v1 noise 12 levels
instead of 3, brightness unchanged; ``light`` 0.1: 4x gain, 40 % brightness.

All randomness comes from the ``rng`` arguments, so a seed reproduces the output.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from builder.depth_noise import NOISE_PRESETS
from glovedb._validate import as_array, check_choice


@dataclass(frozen=True)
class ColorNoiseConfig:
    """Parameters of the color noise model (module docstring); all zero means none.

    Attributes
    ----------
    pixel_sigma : float
        Standard deviation of the per-pixel Gaussian noise, 8-bit levels.
    exposure_sigma_sequence_stops, exposure_sigma_frame_stops : float
        Standard deviation of the exposure offset ``e`` in stops (factors of 2), drawn
        once per sequence and once per frame.
    white_balance_sigma_sequence, white_balance_sigma_frame : float
        Standard deviation of the natural log of each channel's gain, per sequence and
        per frame.
    blur_sigma_px : float
        Standard deviation of the Gaussian blur, pixels.
    """

    pixel_sigma: float = 0.0
    exposure_sigma_sequence_stops: float = 0.0
    exposure_sigma_frame_stops: float = 0.0
    white_balance_sigma_sequence: float = 0.0
    white_balance_sigma_frame: float = 0.0
    blur_sigma_px: float = 0.0

    def __post_init__(self) -> None:
        for field in fields(self):
            value = getattr(self, field.name)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"{field.name}: expected a non-negative number, got {value}")

    @property
    def is_identity(self) -> bool:
        """Whether the model leaves every image unchanged."""
        return all(getattr(self, field.name) == 0 for field in fields(self))


# The Kinect v1 color camera: a small, noisy Bayer sensor with slow auto exposure.
_KINECT_V1 = ColorNoiseConfig(
    pixel_sigma=3.0,
    exposure_sigma_sequence_stops=0.25,
    exposure_sigma_frame_stops=0.03,
    white_balance_sigma_sequence=0.06,
    white_balance_sigma_frame=0.01,
    blur_sigma_px=0.8,
)
# The D435 color imager: sharper and less noisy at 848 x 480. The Azure Kinect's color
# camera (preset time_of_flight) gets the same typical values.
_REALSENSE_D435 = ColorNoiseConfig(
    pixel_sigma=2.0,
    exposure_sigma_sequence_stops=0.2,
    exposure_sigma_frame_stops=0.02,
    white_balance_sigma_sequence=0.05,
    white_balance_sigma_frame=0.008,
    blur_sigma_px=0.5,
)
_PRESETS: dict[str, ColorNoiseConfig] = {
    "none": ColorNoiseConfig(),
    "kinect_v1": _KINECT_V1,
    "realsense_d435": _REALSENSE_D435,
    "structured_light": _KINECT_V1,
    "active_stereo": _REALSENSE_D435,
    "time_of_flight": _REALSENSE_D435,
}


MAX_AUTO_GAIN = 4.0
"""Largest gain auto exposure applies (12 dB), beyond the exposure time's limit."""


def dim_light(config: ColorNoiseConfig, light: float) -> tuple[ColorNoiseConfig, float]:
    """A camera's noise model in a room with ``light`` times the presets' illumination.

    Parameters
    ----------
    config : ColorNoiseConfig
    light : float
        In (0, 1]; 1 returns ``config`` unchanged.

    Returns
    -------
    config : ColorNoiseConfig
        With ``pixel_sigma`` times the auto-exposure gain (module docstring).
    brightness : float
        Factor on the linear-light gains: ``light * gain``, 1 while the gain
        compensates the missing light.
    """
    if not (math.isfinite(light) and 0 < light <= 1):
        raise ValueError(f"light: expected a share in (0, 1] of the presets' light, got {light}")
    gain = min(1.0 / light, MAX_AUTO_GAIN)
    return replace(config, pixel_sigma=config.pixel_sigma * gain), min(light * gain, 1.0)


def color_noise_preset(name: str) -> ColorNoiseConfig:
    """The :class:`ColorNoiseConfig` of a preset in :data:`builder.depth_noise.NOISE_PRESETS`."""
    return _PRESETS[check_choice("noise", name, NOISE_PRESETS)]


def sample_gains(
    *, exposure_sigma_stops: float, white_balance_sigma: float, rng: np.random.Generator
) -> NDArray[np.float64]:
    """Random per-channel gains in linear light: ``2**e * exp(w_c)``.

    Returns
    -------
    (3,) float64
        Gains of R, G, B; all 1 when both sigmas are 0.
    """
    exposure = rng.normal(0.0, exposure_sigma_stops) if exposure_sigma_stops > 0 else 0.0
    balance = rng.normal(0.0, white_balance_sigma, 3) if white_balance_sigma > 0 else np.zeros(3)
    return np.exp2(exposure) * np.exp(balance)


def sequence_gains(config: ColorNoiseConfig, *, rng: np.random.Generator) -> NDArray[np.float64]:
    """The ``(3,)`` float64 gains a sequence keeps (auto exposure and white balance)."""
    return sample_gains(
        exposure_sigma_stops=config.exposure_sigma_sequence_stops,
        white_balance_sigma=config.white_balance_sigma_sequence,
        rng=rng,
    )


def apply_gains(color: ArrayLike, gains: ArrayLike) -> NDArray[np.uint8]:
    """Multiply an sRGB image by per-channel gains in linear light.

    Parameters
    ----------
    color : (H, W, 3) uint8
        sRGB image.
    gains : (3,) float
        Linear-light gains of R, G, B.

    Returns
    -------
    (H, W, 3) uint8
        Saturated at 255, as a sensor clips.
    """
    image = as_array("color", color, (None, None, 3), kind="u")
    gain = as_array("gains", gains, (3,), np.float64, finite=True)
    table = np.arange(256) / 255.0
    linear = np.where(table <= 0.04045, table / 12.92, ((table + 0.055) / 1.055) ** 2.4)
    scaled = np.clip(linear[:, None] * gain[None, :], 0.0, 1.0)
    srgb = np.where(scaled <= 0.0031308, 12.92 * scaled, 1.055 * scaled ** (1 / 2.4) - 0.055)
    lookup = np.rint(255.0 * srgb).astype(np.uint8)  # (256, 3): one table per channel
    indices = image.astype(np.intp)
    return np.stack([lookup[indices[..., c], c] for c in range(3)], axis=-1)


def add_pixel_noise(
    color: ArrayLike, *, sigma: float, rng: np.random.Generator
) -> NDArray[np.uint8]:
    """Add Gaussian noise of ``sigma`` 8-bit levels to every pixel and channel.

    Parameters
    ----------
    color : (H, W, 3) uint8

    Returns
    -------
    (H, W, 3) uint8
        Rounded and clipped to 0..255.
    """
    image = as_array("color", color, (None, None, 3), kind="u")
    if sigma < 0:
        raise ValueError(f"sigma: expected >= 0, got {sigma}")
    noise = rng.standard_normal(image.shape, dtype=np.float32) * np.float32(sigma)
    return np.clip(np.rint(image + noise), 0, 255).astype(np.uint8)


def apply_color_noise(
    color: ArrayLike,
    config: ColorNoiseConfig,
    *,
    gains: ArrayLike,
    rng: np.random.Generator,
) -> NDArray[np.uint8]:
    """What a color camera described by ``config`` would record of ``color``.

    Parameters
    ----------
    color : (H, W, 3) uint8
        Clean sRGB image.
    config : ColorNoiseConfig
    gains : (3,) float
        The sequence's gains (:func:`sequence_gains`); the frame's jitter is drawn here.
    rng : numpy.random.Generator
        Source of the frame's randomness.

    Returns
    -------
    (H, W, 3) uint8
        An unchanged copy when ``config.is_identity``.
    """
    image = as_array("color", color, (None, None, 3), kind="u").astype(np.uint8)
    base = as_array("gains", gains, (3,), np.float64, finite=True)
    if config.is_identity:
        return image.copy()
    jitter = sample_gains(
        exposure_sigma_stops=config.exposure_sigma_frame_stops,
        white_balance_sigma=config.white_balance_sigma_frame,
        rng=rng,
    )
    image = apply_gains(image, base * jitter)
    if config.blur_sigma_px > 0:
        image = cv2.GaussianBlur(image, (0, 0), config.blur_sigma_px).astype(np.uint8)
    return add_pixel_noise(image, sigma=config.pixel_sigma, rng=rng)
