"""A whole-hand fingertip heatmap: the second detection stage after the Hough forest.

The forest and its peak verifier see a few centimetres around each pixel; they cannot
tell the tip of a finger curled toward the palm from a knuckle of a fist, and keep
their precision by dropping both. This stage looks at the whole hand:

1. **Crop** (:func:`crop_centre`, :func:`hand_crop`): the centre of a 30 cm cube
   around the hand, by one of two rules (:data:`CROP_CENTRES`): ``"density"``
   (:func:`hand_centre`), the nearest object's points, their mean moved three times to
   the mean of the points within 12 cm; or ``"fingers"`` (:func:`finger_centre`), the
   mean of the geodesic stage's finger candidates (:mod:`fingertips.geodesic`), or its
   palm centre without any, moved once to the mean of the points within 8 cm. The
   first is pulled onto a forearm or a table in the depth band, which leaves a third
   of the tips outside the cube; the second follows the hand (docs/fingertips.md,
   "The crop centre"). The crop is a 64 x 64 image of the depth relative to that
   centre over 15 cm, clipped to [-1, 1] (1 where depth is missing).
2. **Network**: a small U-Net, stored as ONNX inside the model file and run by
   onnxruntime, maps the crop to the 32 x 32 logits that a visible fingertip lies in
   each 9.4 mm cell. It runs on the crop turned by quarter turns and mirrored
   (:func:`crop_views`); the probabilities, turned back (:func:`unturn_maps`), are
   averaged.
3. **Peaks** (:func:`heat_peaks`): local 3 x 3 maxima of the mean map, moved by the
   centroid of their 3 x 3 neighbourhood, lifted to 3D at the 10th percentile of the
   depth within 6 mm (and within 15 cm of the crop centre) plus 8 mm, the distance from
   the front surface of a fingertip to the tip sphere's centre line seen by the camera.
4. **Verifier** (:func:`heat_peak_features`, :func:`boosted_probability`): gradient
   boosted trees over 22 features per peak (the heat value and its spread over the
   passes, the depth around it, the forest's nearest candidate peak and its verifier
   probability) give the probability that the peak lies within 15 mm of a visible
   fingertip.

Accepted peaks farther than the voting's ``min_separation_m`` from every detection of
the forest and every more probable accepted peak are added to them
(:func:`fingertips.detect.detect_fingertips`). The network and the verifier
are trained by :mod:`fingertips.heatmap_training` (docs/fingertips.md).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fingertips import trees
from fingertips.features import intrinsics_array, mask_depth_range, nearest_band
from fingertips.geodesic import GeodesicCandidates, geodesic_candidates
from fingertips.judge import CandidateJudge
from fingertips.pose_guess import hand_points_from_depth, masked_points
from fingertips.trees import PackedNodes, check_tree_table
from glovedb._validate import as_array, check_choice

if TYPE_CHECKING:
    from onnxruntime import InferenceSession as _Session

CROP_PX = 64
"""Side of the hand crop, pixels."""
CROP_HALF_M = 0.15
"""Half the side of the cube around the hand centre, metres."""
GRID = 32
"""Side of the heatmap, cells."""
PASSES = (1, 2, 4, 8)
"""Supported numbers of averaged passes: the crop; and its mirror; and those turned by a
quarter; and by all four quarter turns (:func:`crop_views`)."""
HAND_DEPTH_RANGE_M = (0.15, 2.0)
"""Working depth range (metres) of the crop centre's hand points, as in training."""
HAND_BAND_M = 0.2
"""Depth band (metres) behind the nearest surface of the crop centre's hand points."""
_CENTRE_RADIUS_M = 0.12
_FINGER_CENTRE_RADIUS_M = 0.08
_MIN_POINTS = 20
_LIFT_RADIUS_M = 0.006
_LIFT_PERCENTILE = 10
_LIFT_BEHIND_M = 0.008

CropCentre = Literal["density", "fingers"]
CROP_CENTRES: tuple[CropCentre, ...] = ("density", "fingers")
"""Rules for the crop centre (module docstring, step 1)."""

HEAT_PEAK_FEATURES: tuple[str, ...] = (
    "value",
    "pass_std",
    "mean_3x3",
    "mean_5x5",
    "n_peaks_above_half",
    "rank",
    "cells_from_centre",
    "depth_from_centre_m",
    "centre_depth_m",
    "window_valid",
    "window_spread_m",
    "front_minus_median_m",
    "depth_m",
    "n_candidates",
    "n_forest_detections",
    "candidate_distance_m",
    "candidate_confidence",
    "candidate_probability",
    "best_probability_2cm",
    "confidence_2cm",
    "pass_min",
    "pass_share_above_half",
)
"""Names of the columns of :func:`heat_peak_features`, in order (recorded in the model)."""


# --- crop ---------------------------------------------------------------------------


def _hand_points(
    depth_m: ArrayLike, intrinsics: ArrayLike, hand_depth_m: NDArray[np.float32] | None
) -> NDArray[np.float64]:
    """Up to 1,500 points of the nearest object (see :func:`hand_centre`), metres."""
    if hand_depth_m is None:
        return hand_points_from_depth(
            depth_m,
            intrinsics,
            depth_range_m=HAND_DEPTH_RANGE_M,
            band_m=HAND_BAND_M,
            max_points=1500,
        )
    return masked_points(hand_depth_m, intrinsics, max_points=1500)


def _mean_shift(
    points_m: NDArray[np.float64], centre: NDArray[np.float64], radius_m: float, steps: int
) -> NDArray[np.float64]:
    """Move ``centre`` up to ``steps`` times to the mean of the points within ``radius_m``;
    it stays where fewer than 20 points are that near."""
    for _ in range(steps):
        near = points_m[np.linalg.norm(points_m - centre, axis=1) < radius_m]
        if len(near) < _MIN_POINTS:
            break
        centre = near.mean(axis=0)
    return centre


def hand_centre(
    depth_m: ArrayLike,
    intrinsics: ArrayLike,
    *,
    hand_depth_m: NDArray[np.float32] | None = None,
) -> NDArray[np.float64] | None:
    """Centre of the nearest object's densest 12 cm (the ``"density"`` rule).

    Parameters
    ----------
    depth_m : (H, W) float
        Depth in metres, 0 where missing.
    intrinsics : (4,) float
        ``(fx, fy, cx, cy)`` in pixels.
    hand_depth_m : (H, W) float32, optional
        ``depth_m`` already restricted to :data:`HAND_DEPTH_RANGE_M` and to
        :data:`HAND_BAND_M` behind the nearest surface (0 elsewhere), when the caller
        has it (the forest's hand depth, with these settings): saves computing it again.

    Returns
    -------
    (3,) float64 or None
        Camera frame, metres; None when fewer than 20 points are in view.
    """
    points = _hand_points(depth_m, intrinsics, hand_depth_m)
    if len(points) < _MIN_POINTS:
        return None
    return _mean_shift(points, points.mean(axis=0), _CENTRE_RADIUS_M, 3)


def finger_centre(
    palm_m: ArrayLike, fingers_m: ArrayLike, points_m: ArrayLike
) -> NDArray[np.float64]:
    """The ``"fingers"`` rule: the fingers' mean, moved once to the mean of its 8 cm.

    Parameters
    ----------
    palm_m : (3,) float
        The geodesic stage's palm centre, metres.
    fingers_m : (K, 3) float
        Its finger candidates, metres; without any the palm centre is the start.
    points_m : (N, 3) float
        The nearest object's points (:func:`hand_centre`), metres.

    Returns
    -------
    (3,) float64
        Camera frame, metres.

    The mean of the fingertips lies about where the mean of a hand's 21 keypoints lies
    (median 2.8 cm from it on the 200 frames of ``validation.toml`` against 8.8 cm for
    :func:`hand_centre`), and the step towards the points brings it onto the hand's
    depth, which the crop's values are relative to.
    """
    palm = as_array("palm_m", palm_m, (3,), np.float64)
    fingers = as_array("fingers_m", fingers_m, (None, 3), np.float64)
    points = as_array("points_m", points_m, (None, 3), np.float64)
    start = fingers.mean(axis=0) if len(fingers) else palm
    return _mean_shift(points, start, _FINGER_CENTRE_RADIUS_M, 1)


def crop_centre(
    depth_m: ArrayLike,
    intrinsics: ArrayLike,
    *,
    hand_depth_m: NDArray[np.float32] | None = None,
    geodesic: GeodesicCandidates | None = None,
) -> NDArray[np.float64] | None:
    """The crop's centre: :func:`finger_centre` of ``geodesic`` when it found a palm,
    else :func:`hand_centre`.

    Parameters are those of :func:`hand_centre`; ``geodesic`` is the frame's
    :func:`fingertips.geodesic.geodesic_candidates` (``"fingers"`` rule) or None
    (``"density"``).

    Returns
    -------
    (3,) float64 or None
        Camera frame, metres; None when fewer than 20 points are in view.
    """
    if geodesic is None or not np.isfinite(geodesic.palm_m).all():
        return hand_centre(depth_m, intrinsics, hand_depth_m=hand_depth_m)
    points = _hand_points(depth_m, intrinsics, hand_depth_m)
    if len(points) < _MIN_POINTS:
        return None
    fingers = geodesic.points_m[geodesic.is_finger]
    return finger_centre(geodesic.palm_m, fingers, points)


def frame_crop_centre(
    depth_m: ArrayLike, intrinsics: ArrayLike, rule: CropCentre
) -> NDArray[np.float64] | None:
    """The crop centre of a whole frame by ``rule`` (:data:`CROP_CENTRES`), for callers
    without the detector's hand depth (training crops, the network alone).

    For ``"fingers"`` the geodesic stage runs on the depth cut like :func:`hand_centre`'s
    (:data:`HAND_DEPTH_RANGE_M`, :data:`HAND_BAND_M`), the detector's cut with the
    shipped model.

    Returns
    -------
    (3,) float64 or None
        Camera frame, metres; None when fewer than 20 points are in view.
    """
    if check_choice("rule", rule, CROP_CENTRES) == "density":
        return hand_centre(depth_m, intrinsics)
    camera = intrinsics_array(intrinsics)
    near, far = HAND_DEPTH_RANGE_M
    hand = nearest_band(mask_depth_range(depth_m, near_m=near, far_m=far), band_m=HAND_BAND_M)
    return crop_centre(
        depth_m, camera, hand_depth_m=hand, geodesic=geodesic_candidates(hand, camera)
    )


def hand_crop(
    depth_m: NDArray[np.float32], intrinsics: NDArray[np.float64], centre: NDArray[np.float64]
) -> NDArray[np.float32]:
    """The ``(CROP_PX, CROP_PX)`` crop of the depth relative to ``centre``, in [-1, 1].

    Pixel ``(i, j)`` samples (nearest pixel, clamped to the image) the ray through the
    point ``centre + (x_j, y_i, 0)``, ``x_j`` and ``y_i`` spanning ``CROP_HALF_M`` either
    side; its value is ``(depth - centre_z) / CROP_HALF_M``, 1 where depth is missing.
    The values are rounded to float16, as in training.
    """
    fx, fy, cx, cy = (float(a) for a in intrinsics)
    h, w = depth_m.shape
    offset = ((np.arange(CROP_PX) + 0.5) / CROP_PX - 0.5) * 2 * CROP_HALF_M
    z = centre[2]
    # Written as the network's training crops were, so that they round alike.
    u = np.clip(np.rint(fx * centre[0] / z + cx + fx * offset / z), 0, w - 1).astype(np.intp)
    v = np.clip(np.rint(fy * centre[1] / z + cy + fy * offset / z), 0, h - 1).astype(np.intp)
    d = depth_m[v[:, None], u[None, :]]
    relative = np.where(d > 0, (d - z) / CROP_HALF_M, 1.0)
    return np.clip(relative, -1.0, 1.0).astype(np.float16).astype(np.float32)


def crop_units(points_m: NDArray[np.float64], centre: NDArray[np.float64]) -> NDArray[np.float64]:
    """Positions ``(..., K, 2)`` of 3D points ``(..., K, 3)`` in the [-1, 1] frame of the
    crops around ``centre`` ``(..., 3)``, through their pinhole."""
    rays = points_m[..., :2] / points_m[..., 2:3] - centre[..., None, :2] / centre[..., None, 2:3]
    return rays * centre[..., None, 2:3] / CROP_HALF_M


def crop_views(crop: NDArray[np.float32], passes: int) -> NDArray[np.float32]:
    """The network's inputs ``(passes, 1, CROP_PX, CROP_PX)``: turned and mirrored crops.

    ``passes`` 1: the crop; 2: the crop and its left-right mirror; 4: each of those
    also turned by a quarter (``np.rot90``); 8: all four quarter turns of each.
    """
    if passes not in PASSES:
        raise ValueError(f"passes: expected one of {PASSES}, got {passes}")
    mirrors = (crop,) if passes == 1 else (crop, crop[:, ::-1])
    turns = max(passes // 2, 1)
    views = [np.rot90(m, k) for m in mirrors for k in range(turns)]
    return np.ascontiguousarray(np.stack(views)[:, None], dtype=np.float32)


def unturn_maps(maps: NDArray[np.float32], passes: int) -> NDArray[np.float32]:
    """Heatmaps ``(passes, GRID, GRID)`` of :func:`crop_views` turned back onto the crop."""
    turns = max(passes // 2, 1)
    back = [np.rot90(maps[i], -(i % turns)) for i in range(len(maps))]
    return np.stack([m if i < turns else m[:, ::-1] for i, m in enumerate(back)])


def crop_cell_pixels(
    cells: NDArray[np.float64], centre: NDArray[np.float64], intrinsics: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Image pixels ``(K, 2)`` of (sub-)cell positions ``(K, 2)`` (column, row) of the map."""
    fx, fy, cx, cy = intrinsics
    offset = ((cells + 0.5) / GRID * 2 - 1) * CROP_HALF_M
    return np.stack(
        [
            fx * (centre[0] + offset[:, 0]) / centre[2] + cx,
            fy * (centre[1] + offset[:, 1]) / centre[2] + cy,
        ],
        axis=1,
    )


# --- peaks --------------------------------------------------------------------------


@dataclass(frozen=True)
class HeatPeaks:
    """Local maxima of a heatmap.

    Attributes
    ----------
    cells : (K, 2) int64
        Column and row of each maximum in the map.
    uv_px : (K, 2) float64
        Their sub-cell position projected into the image, pixels.
    xyz_m : (K, 3) float64
        Their 3D position, camera frame, metres.
    values : (K,) float64
        The map's value there.
    """

    cells: NDArray[np.int64]
    uv_px: NDArray[np.float64]
    xyz_m: NDArray[np.float64]
    values: NDArray[np.float64]


def _window(depth_m: NDArray[np.float32], uv: NDArray[np.float64], radius: int) -> NDArray:
    """The square of depth pixels within ``radius`` of pixel ``uv`` (clamped)."""
    h, w = depth_m.shape
    i = int(np.clip(round(uv[1]), 0, h - 1))
    j = int(np.clip(round(uv[0]), 0, w - 1))
    return depth_m[max(i - radius, 0) : i + radius + 1, max(j - radius, 0) : j + radius + 1]


def _lift_radius_px(intrinsics: NDArray[np.float64], centre: NDArray[np.float64]) -> int:
    return max(2, round(_LIFT_RADIUS_M * intrinsics[0] / centre[2]))


def heat_peaks(
    heat: NDArray[np.float32],
    centre: NDArray[np.float64],
    depth_m: NDArray[np.float32],
    intrinsics: NDArray[np.float64],
    *,
    min_value: float,
) -> HeatPeaks:
    """Local 3 x 3 maxima of ``heat`` above ``min_value``, placed in the image and in 3D.

    Parameters
    ----------
    heat : (GRID, GRID) float32
        Fingertip probability per cell of the crop around ``centre``.
    centre : (3,) float64
        The crop's centre (:func:`hand_centre`), metres.
    depth_m : (H, W) float32
        The frame's depth, metres, 0 where missing.
    intrinsics : (4,) float64
    min_value : float
        Smallest value of a peak.

    Returns
    -------
    HeatPeaks
        In row-major order of their cells.
    """
    padded = np.pad(heat, 1, constant_values=-np.inf)
    neighbourhood = np.lib.stride_tricks.sliding_window_view(padded, (3, 3))
    is_max = (heat >= neighbourhood.max(axis=(2, 3))) & (heat > min_value)
    cells = np.argwhere(is_max)  # (row, column), row-major
    # Neighbouring maxima are equal (a saturated plateau): keep the first in row-major order.
    maxima = {(int(r), int(c)) for r, c in cells}
    earlier = ((-1, -1), (-1, 0), (-1, 1), (0, -1))
    first = [all((r + dy, c + dx) not in maxima for dy, dx in earlier) for r, c in cells]
    cells = cells[np.asarray(first, dtype=bool)][:, ::-1].reshape(-1, 2).astype(np.int64)
    values = heat[cells[:, 1], cells[:, 0]].astype(np.float64)
    zero_padded = np.pad(heat, 1).astype(np.float64)
    refined = cells.astype(np.float64)
    grid_y, grid_x = np.mgrid[-1:2, -1:2]
    for n, (a, b) in enumerate(cells):
        weight = zero_padded[b : b + 3, a : a + 3]
        weight = np.maximum(weight - weight.min(), 0.0)
        total = weight.sum()
        if total > 0:  # a flat neighbourhood keeps the cell centre
            refined[n] += [(weight * grid_x).sum() / total, (weight * grid_y).sum() / total]
    uv = crop_cell_pixels(refined, centre, intrinsics)
    fx, fy, cx, cy = intrinsics
    radius = _lift_radius_px(intrinsics, centre)
    xyz = np.empty((len(uv), 3))
    for n, point in enumerate(uv):
        window = _window(depth_m, point, radius)
        window = window[(window > 0) & (np.abs(window - centre[2]) < CROP_HALF_M)]
        z = np.percentile(window, _LIFT_PERCENTILE) + _LIFT_BEHIND_M if window.size else centre[2]
        xyz[n] = [(point[0] - cx) * z / fx, (point[1] - cy) * z / fy, z]
    return HeatPeaks(cells, uv, xyz, values)


def heat_peak_features(
    peaks: HeatPeaks,
    maps: NDArray[np.float32],
    centre: NDArray[np.float64],
    depth_m: NDArray[np.float32],
    intrinsics: NDArray[np.float64],
    candidates_m: ArrayLike,
    candidate_confidences: ArrayLike,
    candidate_probabilities: ArrayLike,
    *,
    min_tip_probability: float,
) -> NDArray[np.float32]:
    """The verifier's features ``(K, len(HEAT_PEAK_FEATURES))`` of the heatmap's peaks.

    Parameters
    ----------
    peaks : HeatPeaks
        Of the mean of ``maps``.
    maps : (P, GRID, GRID) float32
        The turned-back heatmap of every pass.
    centre : (3,) float64
        The crop's centre, metres.
    depth_m : (H, W) float32
    intrinsics : (4,) float64
    candidates_m : (C, 3) float
        The forest's candidate vote peaks (every peak above ``c_thr``), metres.
    candidate_confidences, candidate_probabilities : (C,) float
        Their vote weights and the peak verifier's probabilities.
    min_tip_probability : float
        The forest verifier's threshold: candidates reaching it are the forest's
        detections.
    """
    candidates_m = np.asarray(candidates_m, dtype=np.float64).reshape(-1, 3)
    candidate_confidences = np.asarray(candidate_confidences, dtype=np.float64)
    candidate_probabilities = np.asarray(candidate_probabilities, dtype=np.float64)
    heat = maps.mean(axis=0)
    spread = maps.std(axis=0)
    values = peaks.values
    rank = np.empty(len(values))
    rank[np.argsort(-values, kind="stable")] = np.arange(len(values))
    radius = _lift_radius_px(intrinsics, centre)
    n_forest = float((candidate_probabilities >= min_tip_probability).sum())
    rows = np.zeros((len(values), len(HEAT_PEAK_FEATURES)))
    for k, (a, b) in enumerate(peaks.cells):
        window = _window(depth_m, peaks.uv_px[k], radius)
        valid = (window > 0) & (np.abs(window - centre[2]) < CROP_HALF_M)
        seen = window[valid].astype(np.float64)
        if seen.size:
            low, front, median, high = np.percentile(seen, [10, 25, 50, 90])
            extent, front_gap = high - low, front - median
        else:
            extent, front_gap = 0.0, 0.0
        forest_part = [1.0, 0.0, 0.0, 0.0, 0.0]
        if len(candidates_m):
            distance = np.linalg.norm(candidates_m - peaks.xyz_m[k], axis=1)
            nearest = int(distance.argmin())
            near = distance < 0.02
            forest_part = [
                distance[nearest],
                candidate_confidences[nearest],
                candidate_probabilities[nearest],
                candidate_probabilities[near].max() if near.any() else 0.0,
                candidate_confidences[near].sum(),
            ]
        at_peak = maps[:, b, a]
        rows[k] = [
            values[k],
            spread[b, a],
            heat[max(b - 1, 0) : b + 2, max(a - 1, 0) : a + 2].mean(),
            heat[max(b - 2, 0) : b + 3, max(a - 2, 0) : a + 3].mean(),
            (values > 0.5).sum(),
            rank[k],
            np.hypot(a - (GRID - 1) / 2, b - (GRID - 1) / 2),
            peaks.xyz_m[k, 2] - centre[2],
            centre[2],
            valid.mean() if valid.size else 0.0,
            extent,
            front_gap,
            peaks.xyz_m[k, 2],
            len(candidates_m),
            n_forest,
            *forest_part,
            at_peak.min(),
            (at_peak > 0.5).mean(),
        ]
    return rows.astype(np.float32)


# --- the stage ----------------------------------------------------------------------


def onnx_bytes(network_onnx: bytes | NDArray[np.uint8]) -> bytes:
    """An ONNX network as bytes, from bytes or the ``(B,) uint8`` array a model file
    stores."""
    return network_onnx if isinstance(network_onnx, bytes) else network_onnx.tobytes()


QUANTIZED_OP = b"QuantizeLinear"
"""An operator that only a quantized (QDQ) network holds: its name appears in the
ONNX bytes."""
KERNEL_TOLERANCE = 0.05
"""Largest difference of a fingertip probability between a network's fused kernels and
its reference graph on :func:`check_crop` (rounding gives about 0.02)."""


def is_quantized(network_onnx: bytes | NDArray[np.uint8]) -> bool:
    """Whether an ONNX heatmap network is quantized (holds QDQ operators)."""
    return QUANTIZED_OP in onnx_bytes(network_onnx)


def check_crop() -> NDArray[np.float32]:
    """A crop ``(CROP_PX, CROP_PX)`` like the detector's: a palm, four fingers and a thumb
    15-30 mm in front of the crop centre, the background missing (1)."""
    rows, cols = np.mgrid[0:CROP_PX, 0:CROP_PX]
    crop = np.ones((CROP_PX, CROP_PX), np.float32)
    crop[(rows - 36) ** 2 + (cols - 32) ** 2 < 14**2] = -0.2
    for top, left, width in ((8, 20, 4), (6, 28, 4), (8, 36, 4), (12, 44, 3)):
        crop[top:36, left : left + width] = -0.1
    crop[30:44, 10:20] = -0.2
    return crop


def kernels_agree(fused: _Session, reference: _Session) -> bool:
    """Whether a network's optimised session gives its reference graph's fingertip
    probabilities on :func:`check_crop`, within :data:`KERNEL_TOLERANCE`.

    onnxruntime runs a quantized network with fused integer kernels. On x86 CPUs without
    VNNI (AVX2 only: AMD Zen 1-3, Intel before Ice Lake) its kernels for unsigned 8-bit
    activations times signed 8-bit weights add pairs of products in 16 bits, which
    saturate: the shipped network's heatmaps came out as noise on such a CPU (the
    probabilities of 100 crops differed by a median 0.89 from its reference graph),
    and the detector found 1 % of the tips.
    :func:`~fingertips.heatmap_quantization.unsigned_weights` stores the weights
    unsigned, which those kernels add without saturating; this check catches a network
    that was not so stored, or any other kernel that disagrees.
    """
    views = crop_views(check_crop(), 1)
    difference = _probabilities(fused, views) - _probabilities(reference, views)
    return bool(np.abs(difference).max() <= KERNEL_TOLERANCE)


def _probabilities(session: _Session, views: NDArray[np.float32]) -> NDArray[np.float64]:
    """Fingertip probabilities ``(N, GRID, GRID)`` of a network session on crop views
    ``(N, 1, CROP_PX, CROP_PX)``: the sigmoid of its logits."""
    (logits,) = session.run(None, {"crops": views})
    return 1.0 / (1.0 + np.exp(-np.asarray(logits, dtype=np.float64)))


def _network_session(content: bytes, *, fused: bool) -> _Session:
    """An onnxruntime session of the network on one thread (:class:`HeatmapNetwork`):
    with all graph optimisations (fused kernels), or only those that keep every
    operator's arithmetic (the reference graph: a quantized network's convolutions then
    run in float between its quantize and dequantize operators)."""
    import onnxruntime

    options = onnxruntime.SessionOptions()
    options.inter_op_num_threads = 1
    options.intra_op_num_threads = 1  # one thread beside the forest: see HeatmapNetwork
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    options.log_severity_level = 3
    if not fused:
        options.graph_optimization_level = onnxruntime.GraphOptimizationLevel.ORT_ENABLE_BASIC
    try:
        return onnxruntime.InferenceSession(content, options, providers=["CPUExecutionProvider"])
    except Exception as error:  # onnxruntime raises its own unexported exception types
        raise ValueError(f"heatmap network: not a loadable ONNX model ({error})") from error


class HeatmapNetwork:
    """An ONNX heatmap network run by onnxruntime on the turned and mirrored crops.

    Parameters
    ----------
    network_onnx : bytes or (B,) uint8
        The ONNX model: input ``crops`` ``(N, 1, CROP_PX, CROP_PX)`` float32, output
        ``logits`` ``(N, GRID, GRID)`` float32.
    passes : int
        Averaged passes (:func:`crop_views`).

    Attributes
    ----------
    reference_graph : bool
        Whether the network runs as its reference graph, its fused kernels having
        disagreed with it (:func:`kernels_agree`).

    The network runs on one thread that does not spin while it waits for work: the
    detector runs it beside the forest (:func:`start_heatmaps`), and more or spinning
    threads would take the cores the forest, the geodesic stage and the frame decoding
    need (`glove bench fingertips` on 200 validation frames with the 8-bit network, two
    interleaved pairs: 69-73 frames/s with one thread, 66-67 with two).

    A quantized network is checked once against its reference graph
    (:func:`kernels_agree`); where the fused kernels disagree, it runs as the reference
    graph, with a ``RuntimeWarning``.
    """

    def __init__(self, network_onnx: bytes | NDArray[np.uint8], passes: int) -> None:
        if passes not in PASSES:
            raise ValueError(f"passes: expected one of {PASSES}, got {passes}")
        self.passes = passes
        self._worker: ThreadPoolExecutor | None = None
        content = onnx_bytes(network_onnx)
        self._session = _network_session(content, fused=True)
        self.reference_graph = False
        if is_quantized(content):
            reference = _network_session(content, fused=False)
            if not kernels_agree(self._session, reference):
                warnings.warn(
                    "heatmap network: onnxruntime's fused 8-bit kernels give other "
                    "heatmaps than the network's reference graph on this CPU (a network "
                    "with signed 8-bit weights on a CPU without VNNI); running the "
                    "reference graph, which is right but about 3 times slower",
                    RuntimeWarning,
                    stacklevel=2,
                )
                self._session, self.reference_graph = reference, True

    def __call__(self, crop: NDArray[np.float32]) -> NDArray[np.float32]:
        """Fingertip probabilities ``(passes, GRID, GRID)`` of every pass, turned back."""
        probability = _probabilities(self._session, crop_views(crop, self.passes))
        return unturn_maps(probability.astype(np.float32), self.passes)

    def submit(self, task: Callable[[], HandHeatmaps]) -> Future[HandHeatmaps]:
        """Run ``task`` in this network's own thread (one, made on first use).

        onnxruntime releases the GIL while it runs, so the caller can go on meanwhile.
        """
        if self._worker is None:
            self._worker = ThreadPoolExecutor(1, thread_name_prefix="glove-heatmap")
        return self._worker.submit(task)


@dataclass(frozen=True, eq=False)
class HeatmapStage(PackedNodes):
    """The trained heatmap network and its peak verifier, as stored in the model file.

    Attributes
    ----------
    network_onnx : (B,) uint8
        The network as an ONNX model: input ``crops`` ``(N, 1, CROP_PX, CROP_PX)``
        float32, output ``logits`` ``(N, GRID, GRID)`` float32.
    tree_roots, node_feature, node_threshold, node_left, node_right
        The verifier's boosted trees as a node table (:mod:`fingertips.trees`)
        over :data:`HEAT_PEAK_FEATURES`.
    node_value : (n,) float32
        Each leaf's contribution to the verifier's log-odds (0 at splits).
    baseline : float
        The log-odds before any tree.
    passes : int
        Averaged passes the verifier was trained with (:func:`crop_views`).
    min_value : float
        Smallest mean heat of a peak the verifier looks at.
    fusion : (3,) float64 or None
        The candidates' fused log-odds (:func:`fingertips.heat_fusion.fused_probability`):
        intercept, weight of
        the peak verifier's log-odds, weight of the heat's log-odds at the candidate;
        None (models trained before it): the peak verifier's probability stands.
        Models trained now have a judge instead.
    judge : CandidateJudge or None
        The boosted trees that keep the candidates (:mod:`fingertips.judge`); when
        given, the fusion is not used.
    """

    network_onnx: NDArray[np.uint8]
    tree_roots: NDArray[np.int32]
    node_feature: NDArray[np.int32]
    node_threshold: NDArray[np.float32]
    node_left: NDArray[np.int32]
    node_right: NDArray[np.int32]
    node_value: NDArray[np.float32]
    baseline: float
    passes: int = 8
    min_value: float = 0.3
    fusion: NDArray[np.float64] | None = None
    judge: CandidateJudge | None = None

    def __post_init__(self) -> None:
        check_tree_table(self, len(HEAT_PEAK_FEATURES))
        if self.fusion is not None:
            as_array("fusion", self.fusion, (3,), np.float64, finite=True)
        as_array("node_value", self.node_value, (self.node_feature.shape[0],), finite=True)
        as_array("network_onnx", self.network_onnx, (None,), np.uint8)
        if self.passes not in PASSES:
            raise ValueError(f"passes: expected one of {PASSES}, got {self.passes}")
        if not 0 <= self.min_value < 1:
            raise ValueError(f"min_value: expected a probability, got {self.min_value}")

    @property
    def judges_candidates(self) -> bool:
        """Whether the candidates are kept by the judge or the fusion, which need the heat."""
        return self.judge is not None or self.fusion is not None

    @cached_property
    def network(self) -> HeatmapNetwork:
        """The network, loaded into onnxruntime on first use."""
        return HeatmapNetwork(self.network_onnx, self.passes)

    def heatmaps(self, crop: NDArray[np.float32]) -> NDArray[np.float32]:
        """Fingertip probabilities ``(passes, GRID, GRID)`` of every pass, turned back."""
        return self.network(crop)


def boosted_probability(stage: HeatmapStage, features: ArrayLike) -> NDArray[np.float32]:
    """Verifier probability ``(K,)`` of heat peaks: the sigmoid of the summed leaf values.

    Parameters
    ----------
    stage : HeatmapStage
    features : (K, len(HEAT_PEAK_FEATURES)) float32
        From :func:`heat_peak_features`.
    """
    values = as_array("features", features, (None, len(HEAT_PEAK_FEATURES)), np.float32)
    return trees.boosted_probability(stage, values)


@dataclass(frozen=True)
class HandHeatmaps:
    """The crop centre of a frame and the network's maps of its crop.

    Attributes
    ----------
    centre : (3,) float64 or None
        :func:`hand_centre`; None when no object is in view.
    maps : (P, GRID, GRID) float32 or None
        The turned-back maps of every pass; None without a centre.
    """

    centre: NDArray[np.float64] | None
    maps: NDArray[np.float32] | None


def hand_heatmaps(
    depth_m: NDArray[np.float32],
    intrinsics: ArrayLike,
    network: Callable[[NDArray[np.float32]], NDArray[np.float32]],
    *,
    hand_depth_m: NDArray[np.float32] | None = None,
    geodesic: GeodesicCandidates | None = None,
) -> HandHeatmaps:
    """The crop centre and the maps of the crop (steps 1 and 2 of the module docstring).

    Parameters are those of :func:`frame_heat_peaks`.
    """
    camera = intrinsics_array(intrinsics)
    centre = crop_centre(depth_m, camera, hand_depth_m=hand_depth_m, geodesic=geodesic)
    if centre is None:
        return HandHeatmaps(None, None)
    return HandHeatmaps(centre, network(hand_crop(depth_m, camera, centre)))


def start_heatmaps(
    depth_m: NDArray[np.float32],
    intrinsics: ArrayLike,
    stage: HeatmapStage,
    *,
    geodesic: Future[GeodesicCandidates] | None = None,
) -> Future[HandHeatmaps]:
    """:func:`hand_heatmaps` of a frame with the stage's network, in the network's thread.

    The detector starts it before the forest and collects it for
    :func:`heatmap_peaks` (``heatmaps``): the network's passes, the longest part of a
    frame, run while the forest votes. With ``geodesic`` (the ``"fingers"`` rule) the
    thread first waits for the geodesic stage (the detector runs that first, on its own
    thread, and passes it finished).
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
    camera = intrinsics_array(intrinsics)
    network = stage.network

    def task() -> HandHeatmaps:
        found = None if geodesic is None else geodesic.result()
        return hand_heatmaps(depth, camera, network, geodesic=found)

    return network.submit(task)


def frame_heat_peaks(
    depth_m: NDArray[np.float32],
    intrinsics: ArrayLike,
    network: Callable[[NDArray[np.float32]], NDArray[np.float32]],
    candidates_m: ArrayLike,
    candidate_confidences: ArrayLike,
    candidate_probabilities: ArrayLike,
    *,
    min_value: float,
    min_tip_probability: float,
    hand_depth_m: NDArray[np.float32] | None = None,
    geodesic: GeodesicCandidates | None = None,
    heatmaps: HandHeatmaps | None = None,
) -> tuple[HeatPeaks, NDArray[np.float32]]:
    """The heatmap's peaks in one frame and their verifier features.

    Parameters
    ----------
    depth_m : (H, W) float32
        The whole frame, metres, 0 where missing.
    intrinsics : (4,) float
    network : callable
        Crop ``(CROP_PX, CROP_PX)`` to the maps ``(P, GRID, GRID)`` of every pass
        (:class:`HeatmapNetwork`).
    candidates_m, candidate_confidences, candidate_probabilities, min_tip_probability
        See :func:`heat_peak_features`.
    min_value : float
        See :func:`heat_peaks`.
    hand_depth_m : (H, W) float32, optional
        See :func:`hand_centre`.
    geodesic : GeodesicCandidates, optional
        The frame's geodesic candidates for the ``"fingers"`` rule (:func:`crop_centre`);
        None for the ``"density"`` rule.
    heatmaps : HandHeatmaps, optional
        The frame's :func:`hand_heatmaps`, when already made (:func:`start_heatmaps`);
        then ``network``, ``hand_depth_m`` and ``geodesic`` are not used.

    Returns
    -------
    peaks : HeatPeaks
        Empty when no object is in view.
    features : (K, len(HEAT_PEAK_FEATURES)) float32
    """
    camera = intrinsics_array(intrinsics)
    if heatmaps is None:
        heatmaps = hand_heatmaps(
            depth_m, camera, network, hand_depth_m=hand_depth_m, geodesic=geodesic
        )
    centre, maps = heatmaps.centre, heatmaps.maps
    if centre is None or maps is None:
        none = HeatPeaks(
            np.zeros((0, 2), np.int64), np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0)
        )
        return none, np.zeros((0, len(HEAT_PEAK_FEATURES)), np.float32)
    peaks = heat_peaks(maps.mean(axis=0), centre, depth_m, camera, min_value=min_value)
    features = heat_peak_features(
        peaks,
        maps,
        centre,
        depth_m,
        camera,
        candidates_m,
        candidate_confidences,
        candidate_probabilities,
        min_tip_probability=min_tip_probability,
    )
    return peaks, features


def heatmap_peaks(
    depth_m: NDArray[np.float32],
    intrinsics: ArrayLike,
    stage: HeatmapStage,
    candidates_m: ArrayLike,
    candidate_confidences: ArrayLike,
    candidate_probabilities: ArrayLike,
    *,
    min_tip_probability: float,
    hand_depth_m: NDArray[np.float32] | None = None,
    geodesic: GeodesicCandidates | None = None,
    heatmaps: HandHeatmaps | None = None,
) -> tuple[HeatPeaks, NDArray[np.float32]]:
    """The heatmap's peaks in one frame and their verifier probabilities ``(K,)``.

    Parameters are those of :func:`frame_heat_peaks`, the network and ``min_value``
    being the stage's.
    """
    peaks, features = frame_heat_peaks(
        depth_m,
        intrinsics,
        stage.heatmaps,
        candidates_m,
        candidate_confidences,
        candidate_probabilities,
        min_value=stage.min_value,
        min_tip_probability=min_tip_probability,
        hand_depth_m=hand_depth_m,
        geodesic=geodesic,
        heatmaps=heatmaps,
    )
    return peaks, boosted_probability(stage, features)
