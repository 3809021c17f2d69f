"""Depth-invariant pixel-pair features (Shotton et al., CVPR 2011) and hand-pixel selection.

A feature compares the depth at two probes placed around a reference pixel ``x``::

    f(x) = d(x + a / d(x)) - d(x + b / d(x))

Shotton et al. give the offsets ``a`` and ``b`` in pixel·metres. Here they are lateral
offsets in metres (as if measured in the plane through the reference point parallel
to the image) and become pixels through the focal length: ``a_px = a_m * f / d(x)``.
That is Shotton's feature with ``a = a_m * f`` and keeps a trained forest valid for
any camera resolution. A probe on a missing measurement reads
:data:`BACKGROUND_DEPTH_M`, so silhouettes give large, stable feature values. A probe
outside the image reads the nearest pixel of the image border: the scene goes on
beyond the image, so an arm or a body cut by the border does not look like a small
isolated object (a fingertip) there.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fingertips._features_kernels import (
    count_measured,
    depth_within,
    filled_with_edge,
    measured_on_grid,
    measured_pixels,
)
from glovedb._validate import as_array

BACKGROUND_DEPTH_M = 10.0
"""Depth read by a probe that falls on a missing measurement."""


def intrinsics_array(intrinsics: ArrayLike) -> NDArray[np.float64]:
    """Check pinhole intrinsics ``(fx, fy, cx, cy)`` in pixels and return them as an array.

    Parameters
    ----------
    intrinsics : (4,) float
        Focal lengths and principal point in pixels, OpenCV convention.

    Returns
    -------
    (4,) float64
    """
    values = as_array("intrinsics", intrinsics, (4,), np.float64, kind="fiu", finite=True)
    if values[0] <= 0 or values[1] <= 0:
        raise ValueError(f"intrinsics: focal lengths must be positive, got {values[:2]}")
    return values


def random_offsets(
    n_features: int, *, max_offset_m: float, unary_fraction: float = 0.5, seed: int = 0
) -> NDArray[np.float32]:
    """Draw a deterministic set of probe-offset pairs.

    Each probe offset is uniform in the disc of radius ``max_offset_m``. For a fraction
    ``unary_fraction`` of the features the second probe is the reference pixel itself
    (``b = 0``), so the feature is the depth step from the pixel to one probe.

    Parameters
    ----------
    n_features : int
        Number of features ``F``.
    max_offset_m : float
        Largest lateral probe distance in metres.
    unary_fraction : float
        Fraction of features whose second probe is the reference pixel.
    seed : int
        Seed for ``np.random.default_rng``; the same seed gives the same offsets.

    Returns
    -------
    offsets_m : (F, 2, 2) float32
        ``offsets_m[k, j]`` is the lateral offset (x right, y down) of probe ``j`` of
        feature ``k`` in metres.
    """
    if n_features < 1:
        raise ValueError(f"n_features: expected at least 1, got {n_features}")
    if not max_offset_m > 0:
        raise ValueError(f"max_offset_m: expected a positive distance, got {max_offset_m}")
    if not 0.0 <= unary_fraction <= 1.0:
        raise ValueError(f"unary_fraction: expected a value in [0, 1], got {unary_fraction}")
    rng = np.random.default_rng(seed)
    radius = max_offset_m * np.sqrt(rng.uniform(size=(n_features, 2)))
    angle = rng.uniform(0.0, 2.0 * np.pi, size=(n_features, 2))
    offsets = np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=-1)
    offsets[rng.uniform(size=n_features) < unary_fraction, 1] = 0.0
    return offsets.astype(np.float32)


def mask_depth_range(depth_m: ArrayLike, *, near_m: float, far_m: float) -> NDArray[np.float32]:
    """Set depths outside the working range ``[near_m, far_m]`` to 0 (no measurement).

    Parameters
    ----------
    depth_m : (H, W) float
        Depth in metres, 0 where missing.
    near_m, far_m : float
        Working range in metres.

    Returns
    -------
    (H, W) float32
        Masked copy; the detector treats everything outside the range as background.
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
    if not 0 <= near_m < far_m:
        raise ValueError(f"near_m, far_m: expected 0 <= near < far, got {near_m}, {far_m}")
    return depth_within(depth, np.float32(near_m), np.float32(far_m))


def nearest_depth(depth_m: NDArray[np.float32], *, rank: int = 20) -> float:
    """Depth of the nearest surface: the ``rank``-th smallest measurement on a 2-pixel grid.

    A few spurious near pixels do not move it. Returns 0 when nothing is measured.
    """
    measured = measured_on_grid(depth_m, 2)
    if measured.size == 0:
        return 0.0
    k = min(rank, measured.size - 1)
    return float(np.partition(measured, k)[k])


def nearest_band(depth_m: ArrayLike, *, band_m: float) -> NDArray[np.float32]:
    """Keep only depth within ``band_m`` behind the nearest surface (a hand segmentation).

    The hand is taken to be the object nearest the camera, as in the depth thresholding
    of Tzionas et al. (2014, Sec. 3.2.1); see :func:`nearest_depth`.

    Parameters
    ----------
    depth_m : (H, W) float
        Depth in metres, 0 where missing.
    band_m : float
        Depth of the kept band, metres; ``inf`` keeps everything.

    Returns
    -------
    (H, W) float32
        Copy with depth outside the band set to 0.
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
    if not band_m > 0:
        raise ValueError(f"band_m: expected a positive depth, got {band_m}")
    nearest = nearest_depth(depth)
    if not np.isfinite(band_m) or nearest == 0:
        return depth.copy()
    return depth_within(depth, np.float32(-np.inf), np.float32(nearest + band_m))


def stride_for_spacing(depth_m: ArrayLike, focal_px: float, *, spacing_m: float) -> int:
    """Pixel stride that samples the nearest surface about every ``spacing_m`` metres.

    Parameters
    ----------
    depth_m : (H, W) float
        Depth in metres, 0 where missing.
    focal_px : float
        Focal length in pixels.
    spacing_m : float
        Wanted lateral distance between sampled points at the nearest depth, metres.

    Returns
    -------
    int
        At least 1.
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
    if not spacing_m > 0:
        raise ValueError(f"spacing_m: expected a positive distance, got {spacing_m}")
    nearest = nearest_depth(depth)
    return max(1, round(spacing_m * focal_px / nearest)) if nearest > 0 else 1


def stride_for_budget(depth_m: ArrayLike, max_pixels: int) -> int:
    """Smallest pixel stride that leaves about ``max_pixels`` (> 0) measured pixels.

    Returns
    -------
    int
        At least 1.
    """
    depth = as_array("depth_m", depth_m, (None, None), kind="fiu")
    if depth.dtype == np.float32:  # the detector's depth: compiled (no NumPy fast path)
        count = count_measured(np.ascontiguousarray(depth))
    else:
        count = int(np.count_nonzero(depth))
    return max(1, math.ceil(math.sqrt(count / max_pixels)))


def foreground_pixels(depth_m: ArrayLike, *, stride: int = 1) -> NDArray[np.int32]:
    """Pixels with a depth measurement, on a regular grid of step ``stride``.

    Parameters
    ----------
    depth_m : (H, W) float
        Depth in metres, 0 where missing (apply :func:`mask_depth_range` first to
        restrict to a working range).
    stride : int
        Keep every ``stride``-th pixel in both directions.

    Returns
    -------
    pixels_uv : (N, 2) int32
        Column ``u`` and row ``v`` of each selected pixel, in row-major order.
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
    if stride < 1:
        raise ValueError(f"stride: expected at least 1, got {stride}")
    return measured_pixels(np.ascontiguousarray(depth), stride)


def probe_image(depth_m: NDArray[np.float32]) -> NDArray[np.float32]:
    """Depth with missing values set to :data:`BACKGROUND_DEPTH_M` and a 1-pixel edge copy.

    Reading it at clipped coordinates gives every probe outside the image the value
    of the nearest border pixel without further tests.

    Parameters
    ----------
    depth_m : (H, W) float32
        Depth in metres, 0 where missing.

    Returns
    -------
    (H + 2, W + 2) float32
    """
    if depth_m.size == 0:
        raise ValueError(f"depth_m: expected a non-empty image, got shape {depth_m.shape}")
    return filled_with_edge(depth_m, np.float32(BACKGROUND_DEPTH_M))


def read_probes(padded: NDArray[np.float32], u: NDArray, v: NDArray) -> NDArray[np.float32]:
    """Values of a :func:`probe_image` at integer pixels ``(u, v)`` of the original image."""
    height, width = padded.shape
    column = np.clip(u, -1, width - 2) + 1
    row = np.clip(v, -1, height - 2) + 1
    return padded.ravel().take(row * width + column)


def paired_feature_values(
    padded: NDArray[np.float32],
    pixels_uv: NDArray[np.int32],
    pixel_depth_m: NDArray[np.float32],
    offsets_m: NDArray[np.float32],
    focal_px: tuple[float, float],
) -> NDArray[np.float32]:
    """Feature values for matched (pixel, offset pair) rows, without checks (inner kernel).

    ``padded`` is a :func:`probe_image`; ``pixels_uv`` (..., 2), ``pixel_depth_m`` (...)
    and ``offsets_m`` (..., 2, 2) must broadcast against each other; the result has the
    broadcast leading shape.
    """
    scale_u = np.float32(focal_px[0]) / pixel_depth_m
    scale_v = np.float32(focal_px[1]) / pixel_depth_m
    u, v = pixels_uv[..., 0], pixels_uv[..., 1]
    probes = []
    for j in range(2):
        du = np.rint(offsets_m[..., j, 0] * scale_u).astype(np.int32)
        dv = np.rint(offsets_m[..., j, 1] * scale_v).astype(np.int32)
        probes.append(read_probes(padded, u + du, v + dv))
    return probes[0] - probes[1]


def pixel_features(
    depth_m: ArrayLike,
    pixels_uv: ArrayLike,
    offsets_m: ArrayLike,
    intrinsics: ArrayLike,
) -> NDArray[np.float32]:
    """Evaluate every feature at every given pixel.

    Parameters
    ----------
    depth_m : (H, W) float
        Depth in metres, 0 where missing.
    pixels_uv : (N, 2) int
        Reference pixels ``(u, v)``; each must have a depth measurement.
    offsets_m : (F, 2, 2) float
        Probe offsets in metres, as from :func:`random_offsets`.
    intrinsics : (4,) float
        ``(fx, fy, cx, cy)`` in pixels.

    Returns
    -------
    features : (N, F) float32
        Depth differences in metres.
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
    pixels = as_array("pixels_uv", pixels_uv, (None, 2), np.int32, kind="iu")
    offsets = as_array("offsets_m", offsets_m, (None, 2, 2), np.float32, kind="f", finite=True)
    fx, fy, _, _ = intrinsics_array(intrinsics)
    padded = probe_image(depth)
    reference_depth = read_probes(padded, pixels[:, 0], pixels[:, 1])
    inside = np.all((pixels >= 0) & (pixels < (depth.shape[1], depth.shape[0])), axis=1)
    if not np.all(inside & (reference_depth < BACKGROUND_DEPTH_M)):
        raise ValueError("pixels_uv: every reference pixel must lie in the image with depth > 0")
    return paired_feature_values(
        padded, pixels[:, None, :], reference_depth[:, None], offsets[None], (fx, fy)
    )


def backproject(
    pixels_uv: NDArray, depth_m: NDArray, intrinsics: NDArray[np.float64]
) -> NDArray[np.float32]:
    """Camera-frame points ``(N, 3)`` in metres of pixels ``(N, 2)`` at depths ``(N,)``."""
    fx, fy, cx, cy = intrinsics
    z = depth_m.astype(np.float32)
    x = (pixels_uv[:, 0] - cx) * z / fx
    y = (pixels_uv[:, 1] - cy) * z / fy
    return np.stack([x, y, z], axis=1).astype(np.float32)


def project(points_m: NDArray, intrinsics: NDArray[np.float64]) -> NDArray[np.float64]:
    """Pixel coordinates ``(..., 2)`` of camera-frame points ``(..., 3)`` in metres."""
    fx, fy, cx, cy = intrinsics
    z = points_m[..., 2]
    return np.stack([fx * points_m[..., 0] / z + cx, fy * points_m[..., 1] / z + cy], axis=-1)
