"""Active stereo (Intel RealSense D4xx): correlated disparity noise, flying pixels, holes.

Two IR cameras ``baseline_m`` apart (the second along +x of the first, whose view the
depth image is) match a scene lit by a projected random dot pattern; depth is
``z = f b / d``. In order:

1. **Flying pixels**: a pixel next to a depth jump is, with
   ``flying_pixel_probability``, a mix of the two surfaces (the matching window
   straddles both; :func:`builder.sensors.edges.mix_flying_pixels`).
2. **Correlated disparity noise**: the subpixel error of the match, Gaussian with an RMS
   of ``subpixel_rms_px`` pixels per pixel but spatially correlated, because
   neighbouring pixels share most of their matching window: white noise low-pass
   filtered by a Gaussian of ``noise_correlation_px`` pixels and rescaled to unit
   variance. The depth RMS error is therefore ``z² subpixel / (f b)``.
3. **Holes**: the occlusion shadow of the second camera, a band of
   ``f b (1/z_fg - 1/z_bg)`` pixels on the -u side of foreground edges
   (:func:`builder.sensors.edges.occlusion_shadow`, with the ``fx`` of the image), and
   random round blobs (surfaces without a match).

``f`` in step 2 is the sensor's own focal length (``focal_length_px``), not the
rendered image's.

Sources
-------
- L. Keselman, J. I. Woodfill, A. Grunnet-Jepsen and A. Bhowmik, "Intel RealSense
  stereoscopic depth cameras", CVPR Workshops 2017: ``z = f B / d`` and the depth error
  ``dz = z² dd / (f B)`` for a constant disparity error; matching with windows
  aggregated over neighbouring pixels.
- Intel RealSense D400 series datasheet and depth tuning white paper: D435 baseline
  50 mm, depth field of view 87 degrees wide; depth RMS error
  ``= z² subpixel / (f baseline)`` with ``f = (width / 2) / tan(HFOV / 2)``, and a
  subpixel RMS of about 0.08 pixels as the typical value.

``focal_length_px`` (447) is Intel's formula for 848 x 480 at 87 degrees.
``noise_correlation_px``, ``flying_pixel_probability`` and the blob settings are
typical values.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from builder.depth_noise import check_non_negative_fields, dropout_blobs
from builder.sensors.edges import mix_flying_pixels, occlusion_shadow
from glovedb._validate import as_array


@dataclass(frozen=True)
class ActiveStereoConfig:
    """Parameters of the active stereo model (module docstring); defaults: D435.

    Attributes
    ----------
    baseline_m : float
        Distance between the two IR cameras, the second along +x, metres (50 mm).
    focal_length_px : float
        Focal length of the sensor's IR cameras at the resolution they match, pixels.
    subpixel_rms_px : float
        RMS of the disparity error of one pixel, pixels.
    noise_correlation_px : float
        Standard deviation of the Gaussian that correlates the disparity noise, pixels
        (0: independent per pixel).
    edge_jump_m : float
        Smallest depth difference between neighbours that is a discontinuity, metres.
    flying_pixel_probability : float
        Share of the pixels at discontinuities that become mixed pixels.
    dropout_blobs_per_mpx : float
        Mean number of missing round blobs per million pixels.
    dropout_blob_radius_px : tuple of float
        Range (min, max) of blob radii in pixels.
    """

    baseline_m: float = 0.050
    focal_length_px: float = 447.0
    subpixel_rms_px: float = 0.08
    noise_correlation_px: float = 1.5
    edge_jump_m: float = 0.02
    flying_pixel_probability: float = 0.5
    dropout_blobs_per_mpx: float = 4.0
    dropout_blob_radius_px: tuple[float, float] = (1.5, 5.0)

    def __post_init__(self) -> None:
        check_non_negative_fields(self)
        if not (self.baseline_m > 0 and self.focal_length_px > 0):
            raise ValueError(
                "baseline_m, focal_length_px: expected > 0, got "
                f"{self.baseline_m}, {self.focal_length_px}"
            )
        if self.flying_pixel_probability > 1:
            raise ValueError(
                f"flying_pixel_probability: expected at most 1, got {self.flying_pixel_probability}"
            )
        low, high = self.dropout_blob_radius_px
        if low > high:
            raise ValueError(f"dropout_blob_radius_px: expected (min, max), got {(low, high)}")

    def depth_rms_m(self, z_m: float) -> float:
        """The datasheet's depth RMS error at depth ``z_m``, metres."""
        return z_m**2 * self.subpixel_rms_px / (self.focal_length_px * self.baseline_m)

    def simulate(
        self, depth_m: ArrayLike, intrinsics: ArrayLike, *, rng: np.random.Generator
    ) -> NDArray[np.float32]:
        """:func:`simulate_active_stereo` with this config."""
        return simulate_active_stereo(depth_m, intrinsics, self, rng=rng)


def correlated_noise(
    shape: tuple[int, int], *, correlation_px: float, rng: np.random.Generator
) -> NDArray[np.float32]:
    """Gaussian noise of unit variance, low-pass filtered to be spatially correlated.

    Parameters
    ----------
    shape : (int, int)
        ``(H, W)``.
    correlation_px : float
        Standard deviation of the Gaussian filter, pixels; neighbouring pixels then
        correlate by about ``exp(-1 / (4 correlation_px²))``. 0: white noise.
    rng : numpy.random.Generator

    Returns
    -------
    (H, W) float32
    """
    if correlation_px < 0:
        raise ValueError(f"correlation_px: expected >= 0, got {correlation_px}")
    white = rng.standard_normal(shape, dtype=np.float32)
    if correlation_px == 0:
        return white
    size = 2 * int(np.ceil(3 * correlation_px)) + 1
    kernel = cv2.getGaussianKernel(size, correlation_px, ktype=cv2.CV_32F)
    smooth = cv2.sepFilter2D(white, -1, kernel, kernel, borderType=cv2.BORDER_REFLECT)
    # Filtered white noise has the standard deviation sqrt(sum(k2d²)) = sum(k1d²).
    return (smooth / np.sum(kernel**2)).astype(np.float32)


def simulate_active_stereo(
    depth_m: ArrayLike,
    intrinsics: ArrayLike,
    config: ActiveStereoConfig,
    *,
    rng: np.random.Generator,
) -> NDArray[np.float32]:
    """What an active stereo camera described by ``config`` measures of ``depth_m``.

    Parameters
    ----------
    depth_m : (H, W) float
        Clean depth in metres, 0 where nothing is measured.
    intrinsics : (4,) float
        ``(fx, fy, cx, cy)`` of ``depth_m`` in pixels (``fx`` places the shadows).
    config : ActiveStereoConfig
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
    mixed, _ = mix_flying_pixels(
        depth,
        edge_jump_m=config.edge_jump_m,
        probability=config.flying_pixel_probability,
        amplitude_weighted=False,
        rng=rng,
    )
    focal_baseline = config.focal_length_px * config.baseline_m
    noise = correlated_noise(depth.shape, correlation_px=config.noise_correlation_px, rng=rng)
    disparity = focal_baseline / np.where(measured, mixed, np.float32(1.0))
    disparity = disparity + np.float32(config.subpixel_rms_px) * noise
    valid = measured & (disparity > 0)
    noisy = focal_baseline / np.where(valid, disparity, np.float32(1.0))
    missing = ~valid | occlusion_shadow(depth, focal_length_px=fx, baseline_m=config.baseline_m)
    if config.dropout_blobs_per_mpx > 0:
        missing |= dropout_blobs(
            depth.shape,
            blobs_per_mpx=config.dropout_blobs_per_mpx,
            radius_px=config.dropout_blob_radius_px,
            rng=rng,
        )
    return np.where(missing, np.float32(0.0), noisy).astype(np.float32)
