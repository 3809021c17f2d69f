"""Time of flight (Kinect v2, Azure Kinect): multipath, mixed pixels, amplitude noise.

An amplitude-modulated continuous-wave camera measures, per pixel, the phase of the
returned light; the emitter sits next to the lens, so there are no projector shadows
and no disparity steps. In order:

1. **Multipath**: light that reaches a surface after bouncing off a nearby surface
   travelled farther, so concave corners (a finger on a table, the inside of a palm)
   read too far. A phenomenological stand-in for light transport: each pixel moves away
   by ``multipath_strength`` times how far it lies behind the mean of its neighbours
   (in opposite pairs) within ``multipath_radius_px`` pixels and ``multipath_range_m``
   in depth, ``max(0, z - mean)``; planes and convex shapes are unchanged.
2. **Flying pixels**: every pixel next to a depth jump sums the light of both surfaces,
   weighted by its coverage and by the ``1/z²`` fall-off of the returned light
   (:func:`builder.sensors.edges.mix_flying_pixels`), so it reads a depth strictly
   between the two; the depth engine's confidence filter then invalidates a share
   ``flying_pixel_invalid_probability`` of them.
3. **Axial noise**: Gaussian, with a standard deviation that depends on the returned
   amplitude, not on depth as such: ``sigma = sigma_m * a**(-amplitude_exponent)`` with
   the relative amplitude ``a = cos(theta) / (z / 1 m)²`` (``theta`` the angle between
   surface normal and viewing ray), so ``sigma_m`` is the noise of a surface facing the
   camera at 1 m.
4. **Low signal**: pixels with ``a < min_relative_amplitude`` (far, or seen at a grazing
   angle) are invalid.

Sources
-------
- Microsoft, "Azure Kinect DK depth camera" (learn.microsoft.com): AMCW time of flight;
  invalidated pixels include low signal, and multi-path interference, which is common
  in corners and at object edges where pixels mix foreground and background.
- M. Tölgyessy, M. Dekan, L. Chovanec and P. Hubinský, "Evaluation of the Azure Kinect
  and its comparison to Kinect V1 and Kinect V2", Sensors 21(2):413, 2021: confirm the
  specified standard deviation of at most 17 mm and distance error below 11 mm up to
  3.5 m; study multipath and flying pixels.
- H. Sarbolandi, D. Lefloch and A. Kolb, "Kinect range sensing: structured-light versus
  time-of-flight Kinect", Computer Vision and Image Understanding 139, 2015 (arXiv
  1505.05459): mixed pixels and multipath of the time-of-flight Kinect against the
  structured-light one.

All values are typical values: ``sigma_m`` (1.5 mm at 1 m, well inside the 17 mm
bound), ``amplitude_exponent`` (0.2: the noise grows by 1.7 from 0.5 to 2 m, where
structured light grows by 16), the multipath and flying-pixel settings and
``min_relative_amplitude``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from builder.depth_noise import check_non_negative_fields, viewing_angle
from builder.sensors.edges import mix_flying_pixels
from glovedb._validate import as_array


@dataclass(frozen=True)
class TimeOfFlightConfig:
    """Parameters of the time-of-flight model (module docstring); defaults: Azure Kinect.

    Attributes
    ----------
    sigma_m : float
        Axial standard deviation on a surface facing the camera at 1 m, metres.
    amplitude_exponent : float
        The standard deviation grows as the relative amplitude to this power, inverted.
    min_relative_amplitude : float
        Pixels whose relative amplitude ``cos(theta) / z²`` (z in metres) is below this
        are invalid.
    edge_jump_m : float
        Smallest depth difference between neighbours that is a discontinuity, metres;
        also the largest one across which surfaces are smoothed for the viewing angle.
    flying_pixel_invalid_probability : float
        Share of the mixed pixels that the confidence filter invalidates.
    multipath_radius_px : int
        Neighbourhood radius of the multipath term, pixels (0: off).
    multipath_range_m : float
        Only neighbours within this depth of a pixel count for its multipath, metres.
    multipath_strength : float
        Share of the concavity ``max(0, z - mean)`` added to the depth.
    """

    sigma_m: float = 0.0015
    amplitude_exponent: float = 0.2
    min_relative_amplitude: float = 0.02
    edge_jump_m: float = 0.02
    flying_pixel_invalid_probability: float = 0.5
    multipath_radius_px: int = 2
    multipath_range_m: float = 0.05
    multipath_strength: float = 0.5

    def __post_init__(self) -> None:
        check_non_negative_fields(self)
        if self.flying_pixel_invalid_probability > 1:
            raise ValueError(
                "flying_pixel_invalid_probability: expected at most 1, got "
                f"{self.flying_pixel_invalid_probability}"
            )

    def sigma_at(self, z_m: float, theta_rad: float = 0.0) -> float:
        """Axial standard deviation at depth ``z_m`` and viewing angle ``theta_rad``, metres."""
        amplitude = np.cos(theta_rad) / z_m**2
        return float(self.sigma_m * amplitude ** (-self.amplitude_exponent))

    def simulate(
        self, depth_m: ArrayLike, intrinsics: ArrayLike, *, rng: np.random.Generator
    ) -> NDArray[np.float32]:
        """:func:`simulate_time_of_flight` with this config."""
        return simulate_time_of_flight(depth_m, intrinsics, self, rng=rng)


def multipath_bias(
    depth_m: ArrayLike, *, radius_px: int, range_m: float, strength: float
) -> NDArray[np.float32]:
    """How much farther multipath makes each pixel read (module docstring, step 1).

    Opposite pairs of neighbours count only together, both measured and within
    ``range_m`` of the pixel, so the mean of a plane's neighbours is the pixel's depth
    (up to perspective) also beside an edge or at the image border.

    Parameters
    ----------
    depth_m : (H, W) float
        Depth in metres, 0 where missing.
    radius_px : int
        The neighbourhood is the ``(2 r + 1)²`` square around a pixel.
    range_m : float
        Neighbours more than this nearer or farther than the pixel do not count, metres.
    strength : float
        Factor on the concavity.

    Returns
    -------
    (H, W) float32
        Non-negative bias in metres; 0 where depth is missing.
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
    if radius_px < 0:
        raise ValueError(f"radius_px: expected >= 0, got {radius_px}")
    height, width = depth.shape
    padded = np.pad(depth, radius_px)

    def shifted(dv: int, du: int) -> NDArray[np.float32]:
        rows = slice(radius_px + dv, radius_px + dv + height)
        return padded[rows, radius_px + du : radius_px + du + width]

    total = np.zeros(depth.shape, np.float32)
    count = np.zeros(depth.shape, np.float32)
    offsets = [(dv, du) for dv in range(radius_px + 1) for du in range(-radius_px, radius_px + 1)]
    for dv, du in offsets:
        if dv == 0 and du <= 0:
            continue
        ahead, behind = shifted(dv, du), shifted(-dv, -du)
        near = (ahead > 0) & (behind > 0)
        near &= (np.abs(ahead - depth) <= range_m) & (np.abs(behind - depth) <= range_m)
        total += np.where(near, ahead + behind, np.float32(0.0))
        count += 2 * near
    mean = np.divide(total, count, out=depth.copy(), where=count > 0)
    return np.where(depth > 0, strength * np.maximum(depth - mean, 0.0), 0.0).astype(np.float32)


def simulate_time_of_flight(
    depth_m: ArrayLike,
    intrinsics: ArrayLike,
    config: TimeOfFlightConfig,
    *,
    rng: np.random.Generator,
) -> NDArray[np.float32]:
    """What a time-of-flight camera described by ``config`` measures of ``depth_m``.

    Parameters
    ----------
    depth_m : (H, W) float
        Clean depth in metres, 0 where nothing is measured.
    intrinsics : (4,) float
        ``(fx, fy, cx, cy)`` of ``depth_m`` in pixels (for the viewing angle).
    config : TimeOfFlightConfig
    rng : numpy.random.Generator
        Source of all randomness.

    Returns
    -------
    (H, W) float32
        Measured depth in metres, 0 where missing.
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu", finite=True)
    camera = as_array("intrinsics", intrinsics, (4,), np.float64, kind="fiu", finite=True)
    measured = depth > 0
    biased = depth
    if config.multipath_radius_px > 0 and config.multipath_strength > 0:
        biased = depth + multipath_bias(
            depth,
            radius_px=config.multipath_radius_px,
            range_m=config.multipath_range_m,
            strength=config.multipath_strength,
        )
    mixed, flying = mix_flying_pixels(
        biased, edge_jump_m=config.edge_jump_m, probability=1.0, amplitude_weighted=True, rng=rng
    )
    angle = viewing_angle(depth, camera, edge_jump_m=config.edge_jump_m)
    amplitude = np.cos(angle) / np.where(measured, depth, np.float32(1.0)) ** 2
    sigma = config.sigma_m * np.maximum(amplitude, 1e-6) ** -config.amplitude_exponent
    noisy = mixed + sigma.astype(np.float32) * rng.standard_normal(depth.shape, dtype=np.float32)
    invalidated = flying & (rng.uniform(size=depth.shape) < config.flying_pixel_invalid_probability)
    missing = ~measured | (noisy <= 0) | (amplitude < config.min_relative_amplitude) | invalidated
    return np.where(missing, np.float32(0.0), noisy).astype(np.float32)
