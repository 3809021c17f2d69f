"""A sensor noise model for depth images: axial noise, quantisation and missing depth.

The model takes a clean depth image (metres, 0 = no measurement), the pinhole
intrinsics and a :class:`DepthNoiseConfig`, and returns what a structured-light or
stereo camera would measure. Nothing in it is hand-specific. In order:

1. **Axial noise**, Gaussian with a standard deviation that grows with depth squared
   (triangulation error) and with the local depth gradient::

       sigma(z, g) = sqrt((a + b z²)² + (s_lat * g)²)

   with ``a = sigma_base_m`` (m), ``b = sigma_quadratic_per_m`` (1/m, so ``b z²`` is
   metres), ``g`` the magnitude of the depth gradient in metres per pixel and
   ``s_lat = lateral_sigma_px`` the lateral (in-image) position uncertainty of a
   measurement in pixels: on a surface that slopes away from the camera, a lateral
   error turns into a depth error of slope times lateral error (the gradient term
   of the thesis, ch. 4.3).
2. **Disparity quantisation**: a stereo or structured-light camera measures disparity
   ``k / z`` in steps; with step 1 the depth takes the values ``k / n`` (``n`` an
   integer), so the depth step grows as ``z² / k``. The config gives the step at 1 m,
   ``quantisation_step_at_1m_m = 1 / k``.
3. **Missing depth** (set to 0): near depth discontinuities (within
   ``edge_width_px`` of a jump larger than ``edge_jump_m`` or of a missing pixel),
   each pixel with probability ``edge_dropout_probability``; on surfaces seen at a
   grazing angle (angle between the surface normal, estimated from the depth
   gradient, and the viewing ray), with a probability rising linearly from 0 at
   ``grazing_start_deg`` to 1 at 90 degrees; and in random round blobs
   (``dropout_blobs_per_mpx`` per million pixels on average).

All randomness comes from the ``rng`` argument, so a seed reproduces the output.

The presets ``kinect_v1`` and ``realsense_d435`` are this generic model. The presets
``structured_light``, ``active_stereo`` and ``time_of_flight`` are sensor models, one per
depth sensing principle, each documented with its sources in :mod:`builder.sensors`
(they build on the pieces here). :func:`noise_preset` returns either kind and
:func:`apply_depth_noise` runs either.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Literal, TypeAlias

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array, check_choice

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

    from builder.sensors import ActiveStereoConfig, StructuredLightConfig, TimeOfFlightConfig

NoisePreset = Literal[
    "none", "kinect_v1", "realsense_d435", "structured_light", "active_stereo", "time_of_flight"
]
NOISE_PRESETS: tuple[NoisePreset, ...] = (
    "none",
    "kinect_v1",
    "realsense_d435",
    "structured_light",
    "active_stereo",
    "time_of_flight",
)


def check_non_negative_fields(config: DataclassInstance) -> None:
    """Raise ``ValueError`` naming the first field of ``config`` with a value (or a tuple
    item) that is negative or not finite."""
    for field in fields(config):
        value = getattr(config, field.name)
        values = value if isinstance(value, tuple) else (value,)
        if any(not np.isfinite(v) or v < 0 for v in values):
            raise ValueError(f"{field.name}: expected non-negative values, got {value}")


@dataclass(frozen=True)
class DepthNoiseConfig:
    """Parameters of the depth noise model (module docstring); all zero means no noise.

    Attributes
    ----------
    sigma_base_m : float
        Constant part ``a`` of the axial standard deviation, metres.
    sigma_quadratic_per_m : float
        Factor ``b`` of the depth-squared part ``b z²``, 1/metre.
    lateral_sigma_px : float
        Lateral position uncertainty in pixels; times the depth gradient (m/px) it adds
        axial noise on slanted surfaces.
    quantisation_step_at_1m_m : float
        Depth step at 1 m caused by disparity quantisation, metres (0: off). The step
        at depth ``z`` is this times ``z²``.
    edge_jump_m : float
        A depth difference to a 4-neighbour larger than this (or a missing neighbour)
        makes a pixel a discontinuity, metres.
    edge_width_px : int
        Pixels within this distance of a discontinuity may be dropped.
    edge_dropout_probability : float
        Probability that such a pixel is dropped.
    grazing_start_deg : float
        Surfaces seen at more than this angle between normal and viewing ray start to
        lose depth; at 90 degrees they always do. 90 turns it off.
    dropout_blobs_per_mpx : float
        Mean number of missing round blobs per million pixels.
    dropout_blob_radius_px : tuple of float
        Range (min, max) of blob radii in pixels.
    """

    sigma_base_m: float = 0.0
    sigma_quadratic_per_m: float = 0.0
    lateral_sigma_px: float = 0.0
    quantisation_step_at_1m_m: float = 0.0
    edge_jump_m: float = 0.02
    edge_width_px: int = 1
    edge_dropout_probability: float = 0.0
    grazing_start_deg: float = 90.0
    dropout_blobs_per_mpx: float = 0.0
    dropout_blob_radius_px: tuple[float, float] = (2.0, 6.0)

    def __post_init__(self) -> None:
        check_non_negative_fields(self)
        if self.edge_dropout_probability > 1:
            raise ValueError(
                f"edge_dropout_probability: expected at most 1, got {self.edge_dropout_probability}"
            )
        if self.grazing_start_deg > 90:
            raise ValueError(
                f"grazing_start_deg: expected at most 90, got {self.grazing_start_deg}"
            )
        low, high = self.dropout_blob_radius_px
        if low > high:
            raise ValueError(f"dropout_blob_radius_px: expected (min, max), got {(low, high)}")

    @property
    def is_identity(self) -> bool:
        """Whether the model leaves every depth image unchanged."""
        return (
            self.sigma_base_m == 0
            and self.sigma_quadratic_per_m == 0
            and self.lateral_sigma_px == 0
            and self.quantisation_step_at_1m_m == 0
            and self.edge_dropout_probability == 0
            and self.grazing_start_deg == 90
            and self.dropout_blobs_per_mpx == 0
        )


_PRESETS: dict[str, DepthNoiseConfig] = {
    "none": DepthNoiseConfig(),
    # Structured light, 7.5 cm baseline, 1/8-pixel disparity steps: 1.5 mm noise and
    # 0.7 mm steps at 0.5 m, 4.5 mm and 2.9 mm at 1 m; ragged 2-pixel shadows at edges.
    "kinect_v1": DepthNoiseConfig(
        sigma_base_m=0.0005,
        sigma_quadratic_per_m=0.004,
        lateral_sigma_px=0.5,
        quantisation_step_at_1m_m=0.0029,
        edge_jump_m=0.02,
        edge_width_px=2,
        edge_dropout_probability=0.5,
        grazing_start_deg=70.0,
        dropout_blobs_per_mpx=2.0,
        dropout_blob_radius_px=(2.0, 6.0),
    ),
    # Active stereo, 5 cm baseline at 640 x 480: 1 mm noise at 0.5 m, 4 mm steps at 1 m.
    "realsense_d435": DepthNoiseConfig(
        sigma_base_m=0.0003,
        sigma_quadratic_per_m=0.0028,
        lateral_sigma_px=0.4,
        quantisation_step_at_1m_m=0.004,
        edge_jump_m=0.015,
        edge_width_px=1,
        edge_dropout_probability=0.6,
        grazing_start_deg=65.0,
        dropout_blobs_per_mpx=4.0,
        dropout_blob_radius_px=(1.5, 5.0),
    ),
}


DepthSensorModel: TypeAlias = (
    "DepthNoiseConfig | StructuredLightConfig | ActiveStereoConfig | TimeOfFlightConfig"
)


def noise_preset(name: str) -> DepthSensorModel:
    """The model of a preset in :data:`NOISE_PRESETS`: a :class:`DepthNoiseConfig` or a
    sensor model's config from :mod:`builder.sensors`."""
    check_choice("noise", name, NOISE_PRESETS)
    if name in _PRESETS:
        return _PRESETS[name]
    # Imported here: the sensor models build on this module's pieces.
    from builder.sensors import SENSOR_PRESETS

    return SENSOR_PRESETS[name]


def depth_gradient(depth_m: ArrayLike, *, edge_jump_m: float) -> NDArray[np.float32]:
    """Depth gradient ``(dz/du, dz/dv)`` in metres per pixel, 0 across discontinuities.

    Central differences where both neighbours are measured and within ``edge_jump_m``
    of the pixel, one-sided differences where only one is, 0 where neither is.

    Parameters
    ----------
    depth_m : (H, W) float
        Depth in metres, 0 where missing.
    edge_jump_m : float
        Largest depth difference between neighbours on one surface, metres.

    Returns
    -------
    gradient : (H, W, 2) float32
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
    padded = np.pad(depth, 1)
    centre = padded[1:-1, 1:-1]
    result = np.zeros(depth.shape + (2,), np.float32)
    neighbours = (
        (padded[1:-1, :-2], padded[1:-1, 2:]),  # left, right
        (padded[:-2, 1:-1], padded[2:, 1:-1]),  # up, down
    )
    for axis, (before, after) in enumerate(neighbours):
        ok_before = (before > 0) & (np.abs(centre - before) <= edge_jump_m)
        ok_after = (after > 0) & (np.abs(after - centre) <= edge_jump_m)
        span = ok_before.astype(np.float32) + ok_after.astype(np.float32)
        rise = np.where(ok_after, after, centre) - np.where(ok_before, before, centre)
        result[..., axis] = np.divide(rise, span, out=np.zeros_like(rise), where=span > 0)
    result[depth <= 0] = 0.0
    return result


def discontinuities(depth_m: ArrayLike, *, edge_jump_m: float) -> NDArray[np.bool_]:
    """Measured pixels next to a missing 4-neighbour or a jump larger than ``edge_jump_m``.

    Parameters
    ----------
    depth_m : (H, W) float
        Depth in metres, 0 where missing.
    edge_jump_m : float

    Returns
    -------
    (H, W) bool
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
    padded = np.pad(depth, 1, mode="edge")
    centre = padded[1:-1, 1:-1]
    edge = np.zeros(depth.shape, bool)
    for neighbour in (padded[1:-1, :-2], padded[1:-1, 2:], padded[:-2, 1:-1], padded[2:, 1:-1]):
        edge |= (neighbour <= 0) | (np.abs(neighbour - centre) > edge_jump_m)
    return edge & (depth > 0)


def viewing_angle(
    depth_m: ArrayLike, intrinsics: ArrayLike, *, edge_jump_m: float
) -> NDArray[np.float32]:
    """Angle between the surface normal (from the depth gradient) and the viewing ray.

    Parameters
    ----------
    depth_m : (H, W) float
        Depth in metres, 0 where missing.
    intrinsics : (4,) float
        ``(fx, fy, cx, cy)`` in pixels.
    edge_jump_m : float
        Depth steps larger than this are not differentiated across, metres.

    Returns
    -------
    (H, W) float32
        Radians in ``[0, pi/2]``; 0 where depth is missing.
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
    fx, fy, cx, cy = as_array("intrinsics", intrinsics, (4,), np.float64, finite=True)
    gradient = depth_gradient(depth, edge_jump_m=edge_jump_m)
    safe_depth = np.where(depth > 0, depth, np.float32(1.0))
    # A pixel step spans z / f metres laterally, so dz/dx = (dz/du) * f / z.
    slope_x = gradient[..., 0] * np.float32(fx) / safe_depth
    slope_y = gradient[..., 1] * np.float32(fy) / safe_depth
    v, u = np.indices(depth.shape, dtype=np.float32)
    ray_x, ray_y = (u - np.float32(cx)) / np.float32(fx), (v - np.float32(cy)) / np.float32(fy)
    # Normal (-dz/dx, -dz/dy, 1) against the ray (x/z, y/z, 1).
    dot = -slope_x * ray_x - slope_y * ray_y + 1.0
    norms = np.sqrt((slope_x**2 + slope_y**2 + 1.0) * (ray_x**2 + ray_y**2 + 1.0))
    angle = np.arccos(np.clip(np.abs(dot) / norms, 0.0, 1.0)).astype(np.float32)
    angle[depth <= 0] = 0.0
    return angle


def axial_sigma(
    depth_m: ArrayLike, gradient_px: ArrayLike, config: DepthNoiseConfig
) -> NDArray[np.float32]:
    """Standard deviation (metres) of the axial noise; 0 where depth is missing.

    Parameters
    ----------
    depth_m : (H, W) float
        Depth in metres, 0 where missing.
    gradient_px : (H, W) float
        Magnitude of the depth gradient, metres per pixel.
    config : DepthNoiseConfig

    Returns
    -------
    (H, W) float32
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
    gradient = as_array("gradient_px", gradient_px, depth.shape, np.float32, kind="fiu")
    axial = np.float32(config.sigma_base_m) + np.float32(config.sigma_quadratic_per_m) * depth**2
    lateral = np.float32(config.lateral_sigma_px) * gradient
    return np.where(depth > 0, np.sqrt(axial**2 + lateral**2), np.float32(0.0)).astype(np.float32)


def quantise_depth(depth_m: ArrayLike, *, step_at_1m_m: float) -> NDArray[np.float32]:
    """Round depth to the values a disparity camera can report (module docstring).

    Parameters
    ----------
    depth_m : (H, W) float
        Depth in metres, 0 where missing.
    step_at_1m_m : float
        Depth step at 1 m, metres; 0 returns the input unchanged.

    Returns
    -------
    (H, W) float32
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
    if step_at_1m_m < 0:
        raise ValueError(f"step_at_1m_m: expected >= 0, got {step_at_1m_m}")
    if step_at_1m_m == 0:
        return depth.copy()
    k = 1.0 / step_at_1m_m
    safe = np.where(depth > 0, depth, 1.0).astype(np.float64)
    levels = np.maximum(np.rint(k / safe), 1.0)
    return np.where(depth > 0, k / levels, 0.0).astype(np.float32)


def dropout_blobs(
    shape: tuple[int, int],
    *,
    blobs_per_mpx: float,
    radius_px: tuple[float, float],
    rng: np.random.Generator,
) -> NDArray[np.bool_]:
    """Mask of random round blobs, a Poisson number of them, uniform in the image.

    Returns
    -------
    (H, W) bool
        True inside a blob.
    """
    height, width = shape
    mask = np.zeros(shape, np.uint8)
    count = rng.poisson(blobs_per_mpx * height * width / 1e6)
    for _ in range(count):
        centre = (int(rng.integers(0, width)), int(rng.integers(0, height)))
        radius = round(rng.uniform(*radius_px))
        cv2.circle(mask, centre, radius, 1, thickness=-1)
    return mask.astype(bool)


def apply_depth_noise(
    depth_m: ArrayLike,
    intrinsics: ArrayLike,
    config: DepthSensorModel,
    *,
    rng: np.random.Generator,
) -> NDArray[np.float32]:
    """What a depth camera described by ``config`` would measure of ``depth_m``.

    Parameters
    ----------
    depth_m : (H, W) float
        Clean depth in metres, 0 where nothing is measured.
    intrinsics : (4,) float
        ``(fx, fy, cx, cy)`` of ``depth_m`` in pixels (viewing angles; the sensor models
        also place their shadows with ``fx``).
    config : DepthNoiseConfig or a sensor model's config
        The generic model (module docstring) or one of :mod:`builder.sensors`.
    rng : numpy.random.Generator
        Source of all randomness.

    Returns
    -------
    (H, W) float32
        Noisy depth in metres, 0 where missing; an unchanged copy when ``config`` is a
        :class:`DepthNoiseConfig` with ``is_identity``.
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu", finite=True)
    camera = as_array("intrinsics", intrinsics, (4,), np.float64, kind="fiu", finite=True)
    if not isinstance(config, DepthNoiseConfig):
        return config.simulate(depth, camera, rng=rng)
    if config.is_identity:
        return depth.copy()
    measured = depth > 0
    gradient = depth_gradient(depth, edge_jump_m=config.edge_jump_m)
    sigma = axial_sigma(depth, np.hypot(gradient[..., 0], gradient[..., 1]), config)
    noisy = depth + sigma * rng.standard_normal(depth.shape, dtype=np.float32)
    noisy = quantise_depth(noisy, step_at_1m_m=config.quantisation_step_at_1m_m)
    missing = ~measured | (noisy <= 0)
    if config.edge_dropout_probability > 0:
        edges = discontinuities(depth, edge_jump_m=config.edge_jump_m).astype(np.uint8)
        size = 2 * config.edge_width_px + 1
        near_edge = cv2.dilate(edges, np.ones((size, size), np.uint8)).astype(bool)
        missing |= near_edge & (rng.uniform(size=depth.shape) < config.edge_dropout_probability)
    if config.grazing_start_deg < 90:
        angle = np.degrees(viewing_angle(depth, camera, edge_jump_m=config.edge_jump_m))
        start = config.grazing_start_deg
        probability = np.clip((angle - start) / max(90.0 - start, 1e-6), 0.0, 1.0)
        missing |= rng.uniform(size=depth.shape) < probability
    if config.dropout_blobs_per_mpx > 0:
        missing |= dropout_blobs(
            depth.shape,
            blobs_per_mpx=config.dropout_blobs_per_mpx,
            radius_px=config.dropout_blob_radius_px,
            rng=rng,
        )
    return np.where(missing, np.float32(0.0), noisy).astype(np.float32)
