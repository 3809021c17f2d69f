"""What depth sensors do at depth discontinuities: occlusion shadows and mixed pixels.

Both work on clean depth in metres (0 = no measurement) and are shared by the sensor
models of this package.

- **Occlusion shadow**: a sensor that triangulates (structured light, stereo) needs a
  second viewpoint, the projector or the second camera, at ``baseline_m`` along the
  camera's x axis. A surface point seen by the camera but hidden from that viewpoint by
  a nearer surface gets no depth. The ray from a point at depth ``z_bg`` to the second
  viewpoint passes, at depth ``z``, in front of the camera pixel
  ``u + f b (1/z - 1/z_bg)`` (pinhole camera, ``f`` in pixels), so with disparity
  ``d(u) = f b / z(u)`` pixel ``u`` is shadowed exactly when some pixel ``u'`` on the
  side of the second viewpoint has ``d(u') - d(u) > |u' - u|``: a band of width
  ``f b (1/z_fg - 1/z_bg)`` beside a foreground edge, on the side away from the second
  viewpoint (and surfaces so steep that they face away from it).
- **Mixed ("flying") pixels**: a pixel whose footprint straddles a depth edge receives
  light from both surfaces and reports a depth in between. A pixel next to a jump
  takes a share ``c`` of the surface across the jump, uniform in ``(0, 1/2]`` (the
  edge lies anywhere between the two pixel centres, and half a pixel is the most of a
  pixel footprint that can lie beyond it).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array


def occlusion_shadow(
    depth_m: ArrayLike, *, focal_length_px: float, baseline_m: float
) -> NDArray[np.bool_]:
    """Measured pixels that the second viewpoint (projector or camera) cannot see.

    Parameters
    ----------
    depth_m : (H, W) float
        Depth in metres, 0 where missing (missing pixels hide nothing).
    focal_length_px : float
        Horizontal focal length of ``depth_m`` in pixels.
    baseline_m : float
        Position of the second viewpoint along the camera's x axis (+u in the image),
        metres; negative: along -x. 0: no shadow.

    Returns
    -------
    (H, W) bool
        True where a nearer surface hides the pixel from the second viewpoint.
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float64, kind="fiu")
    if not focal_length_px > 0:
        raise ValueError(f"focal_length_px: expected > 0, got {focal_length_px}")
    if baseline_m == 0:
        return np.zeros(depth.shape, bool)
    if baseline_m < 0:  # mirror the image so that the second viewpoint lies along +u
        depth = depth[:, ::-1]
    measured = depth > 0
    disparity = focal_length_px * abs(baseline_m) / np.where(measured, depth, 1.0)
    # Pixel u is hidden when d(u') - u' > d(u) - u for some u' > u.
    reach = np.where(measured, disparity - np.arange(depth.shape[1]), -np.inf)
    ahead = np.full(depth.shape, -np.inf)
    ahead[:, :-1] = np.maximum.accumulate(reach[:, :0:-1], axis=1)[:, ::-1]
    shadow = measured & (ahead > reach)
    return shadow[:, ::-1] if baseline_m < 0 else shadow


def mix_flying_pixels(
    depth_m: ArrayLike,
    *,
    edge_jump_m: float,
    probability: float,
    amplitude_weighted: bool,
    rng: np.random.Generator,
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Mix pixels next to a depth jump with the surface across it (module docstring).

    Each measured pixel with a measured 4-neighbour more than ``edge_jump_m`` away in
    depth is, with ``probability``, replaced by the mix of its own depth ``z`` and that
    of the neighbour with the largest jump ``z'``, with share ``c`` of the neighbour:
    ``(1 - c) z + c z'`` (a correlation window averaging the two surfaces), or, with
    ``amplitude_weighted``, weighted by the light each surface returns, which falls off
    as ``1/z²`` (a time-of-flight pixel summing the two returns). The result lies
    strictly between ``z`` and ``z'``.

    Parameters
    ----------
    depth_m : (H, W) float
        Depth in metres, 0 where missing (missing pixels are never mixed in).
    edge_jump_m : float
        Smallest depth difference between neighbours that is a discontinuity, metres.
    probability : float
        Share of the pixels at discontinuities that are mixed, in ``[0, 1]``.
    amplitude_weighted : bool
        Weight the two depths by ``1/z²`` as well as by coverage.
    rng : numpy.random.Generator

    Returns
    -------
    depth : (H, W) float32
        Depth with the mixed pixels, metres.
    mixed : (H, W) bool
        The pixels that were mixed.
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
    if not 0 <= probability <= 1:
        raise ValueError(f"probability: expected within [0, 1], got {probability}")
    padded = np.pad(depth, 1)
    jump = np.zeros(depth.shape, np.float32)
    across = np.zeros(depth.shape, np.float32)
    for neighbour in (padded[1:-1, :-2], padded[1:-1, 2:], padded[:-2, 1:-1], padded[2:, 1:-1]):
        step = np.abs(neighbour - depth)
        larger = (neighbour > 0) & (depth > 0) & (step > edge_jump_m) & (step > jump)
        jump = np.where(larger, step, jump)
        across = np.where(larger, neighbour, across)
    mixed = (jump > 0) & (rng.uniform(size=depth.shape) < probability)
    share = 0.5 * (1.0 - rng.uniform(size=depth.shape))  # in (0, 1/2]
    own_weight, across_weight = 1.0 - share, share
    if amplitude_weighted:
        own_weight = own_weight / np.where(mixed, depth, 1.0) ** 2
        across_weight = across_weight / np.where(mixed, across, 1.0) ** 2
    blend = (own_weight * depth + across_weight * across) / (own_weight + across_weight)
    return np.where(mixed, blend, depth).astype(np.float32), mixed
