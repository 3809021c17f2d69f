"""Structured light (Kinect v1): disparity noise and steps, projector shadows.

An IR projector ``baseline_m`` beside the IR camera (along +x) casts a fixed speckle
pattern; the sensor finds each pixel's shift (disparity) against a memorised image of
the pattern with a small correlation window and triangulates ``z = f b / d``. In
order:

1. **Disparity noise**: Gaussian, ``disparity_sigma_px`` pixels, so the depth error
   grows with depth squared, ``sigma_z = z² sigma_d / (f b)``.
2. **Disparity steps**: the disparity is reported in steps of ``disparity_step_px``,
   so depth takes the values ``f b / (n step)`` and the depth step at ``z`` is
   ``z² step / (f b)`` (:func:`builder.depth_noise.quantise_depth`).
3. **Projector shadow**: background beside a foreground edge that the projector
   cannot light gets no depth, a band of ``f b (1/z_fg - 1/z_bg)`` pixels on the -u
   side of the edge (:func:`builder.sensors.edges.occlusion_shadow`, with the ``fx``
   of the image).
4. **Holes**: random round blobs (dark, shiny or hairy surfaces).

``f`` in steps 1 and 2 is the sensor's own focal length (``focal_length_px``, the IR
camera at 640 x 480, where the sensor matches), not the rendered image's: a depth
image shown at another resolution keeps the sensor's depth noise.

Sources
-------
- K. Konolige and P. Mihelich, "Technical description of Kinect calibration", ROS
  wiki ``kinect_calibration/technical``: IR camera and projector form a stereo pair
  with a baseline of about 7.5 cm; a 9x9 (or 9x7) correlation window; disparity
  interpolated to 1/8 pixel.
- K. Khoshelham and S. O. Elberink, "Accuracy and resolution of Kinect depth data for
  indoor mapping applications", Sensors 12(2):1437, 2012: the random error grows with
  the square of the distance, from a few millimetres near the sensor to about 4 cm at
  its maximum range of 5 m; the depth resolution (step) falls with the square of the
  distance too.

``focal_length_px`` (580) and ``disparity_sigma_px`` (0.06: with the 1/8 pixel steps
about 4 cm at 5 m, as Khoshelham and Elberink measured) are typical values; the blob
settings are typical values as well. Not modelled: the correlation window's blurring
and shifting of depth edges by a pixel or two.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from builder.depth_noise import check_non_negative_fields, dropout_blobs, quantise_depth
from builder.sensors.edges import occlusion_shadow
from glovedb._validate import as_array


@dataclass(frozen=True)
class StructuredLightConfig:
    """Parameters of the structured-light model (module docstring); defaults: Kinect v1.

    Attributes
    ----------
    baseline_m : float
        Distance from the IR camera to the projector along +x, metres (7.5 cm).
    focal_length_px : float
        Focal length of the sensor's IR camera at the resolution it matches, pixels.
    disparity_step_px : float
        Step in which disparity is reported, pixels (1/8).
    disparity_sigma_px : float
        Standard deviation of the disparity noise, pixels.
    dropout_blobs_per_mpx : float
        Mean number of missing round blobs per million pixels.
    dropout_blob_radius_px : tuple of float
        Range (min, max) of blob radii in pixels.
    """

    baseline_m: float = 0.075
    focal_length_px: float = 580.0
    disparity_step_px: float = 0.125
    disparity_sigma_px: float = 0.06
    dropout_blobs_per_mpx: float = 2.0
    dropout_blob_radius_px: tuple[float, float] = (2.0, 6.0)

    def __post_init__(self) -> None:
        check_non_negative_fields(self)
        if not (self.baseline_m > 0 and self.focal_length_px > 0):
            raise ValueError(
                "baseline_m, focal_length_px: expected > 0, got "
                f"{self.baseline_m}, {self.focal_length_px}"
            )
        low, high = self.dropout_blob_radius_px
        if low > high:
            raise ValueError(f"dropout_blob_radius_px: expected (min, max), got {(low, high)}")

    @property
    def depth_step_at_1m_m(self) -> float:
        """Depth step at 1 m, metres: ``disparity_step_px / (focal_length_px baseline_m)``."""
        return self.disparity_step_px / (self.focal_length_px * self.baseline_m)

    def simulate(
        self, depth_m: ArrayLike, intrinsics: ArrayLike, *, rng: np.random.Generator
    ) -> NDArray[np.float32]:
        """:func:`simulate_structured_light` with this config."""
        return simulate_structured_light(depth_m, intrinsics, self, rng=rng)


def simulate_structured_light(
    depth_m: ArrayLike,
    intrinsics: ArrayLike,
    config: StructuredLightConfig,
    *,
    rng: np.random.Generator,
) -> NDArray[np.float32]:
    """What a structured-light sensor described by ``config`` measures of ``depth_m``.

    Parameters
    ----------
    depth_m : (H, W) float
        Clean depth in metres, 0 where nothing is measured.
    intrinsics : (4,) float
        ``(fx, fy, cx, cy)`` of ``depth_m`` in pixels (``fx`` places the shadows).
    config : StructuredLightConfig
    rng : numpy.random.Generator
        Source of all randomness.

    Returns
    -------
    (H, W) float32
        Measured depth in metres, 0 where missing.
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu", finite=True)
    fx = float(as_array("intrinsics", intrinsics, (4,), np.float64, kind="fiu", finite=True)[0])
    measured = depth > 0
    focal_baseline = config.focal_length_px * config.baseline_m
    disparity = focal_baseline / np.where(measured, depth, np.float32(1.0))
    disparity = disparity + np.float32(config.disparity_sigma_px) * rng.standard_normal(
        depth.shape, dtype=np.float32
    )
    valid = measured & (disparity > 0)
    noisy = np.where(valid, focal_baseline / np.where(valid, disparity, 1.0), 0.0)
    noisy = quantise_depth(noisy, step_at_1m_m=config.depth_step_at_1m_m)
    missing = ~valid | occlusion_shadow(depth, focal_length_px=fx, baseline_m=config.baseline_m)
    if config.dropout_blobs_per_mpx > 0:
        missing |= dropout_blobs(
            depth.shape,
            blobs_per_mpx=config.dropout_blobs_per_mpx,
            radius_px=config.dropout_blob_radius_px,
            rng=rng,
        )
    return np.where(missing, np.float32(0.0), noisy).astype(np.float32)
