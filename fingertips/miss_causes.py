"""Why an annotated fingertip was missed: one cause per tip, by a fixed rule.

The rule looks only at what an annotated frame gives (the depth, the camera, the
annotated tips, and the 21 keypoints where the frame has them) and at the hand pixels
the detector kept. The first test that holds names the cause:

1. ``border``: the tip's pixel lies within ``border_px`` of the image border, or
   outside the image;
2. ``segmentation``: the detector had (nearly) no depth of the tip: less than
   ``min_window_share`` of the square of half side ``window_m`` around the tip's
   pixel has a depth within ``depth_tolerance_m`` of the tip's depth (missing depth,
   e.g. the sensor's holes at a thin finger's edges, or something in front), or most
   of the pixels that have are not among the hand pixels the detector kept
   (``hand_depth_m``). The square is metric (its side in pixels shrinks with depth)
   since the tip is; a share, not the median, since a tip annotated on its finger's
   end has half its square off the finger. A tip outside the detector's working
   depth range is left to the next test: the detector drops such depth by design;
3. ``distance``: the tip lies farther than ``far_m`` from the camera, or outside the
   detector's working depth range;
4. ``merged``: another annotated tip of the frame lies within ``merged_m`` (3D):
   adjacent fingers touching;
5. ``curled``: with the frame's 21 keypoints (rendered frames), the finger's joints
   bend by more than ``curled_flexion_deg`` in all (MCP, PIP and DIP; the thumb's MCP
   and IP), or its tip is nearer to the palm centre (halfway between the wrist and the
   mean of the four finger MCPs) than ``curled_palm_fraction`` of the finger's length.
   Without keypoints (real frames) a proxy: the tip lies within
   ``proxy_centre_fraction * proxy_hand_length_m`` (3D) of the hand centre the
   heatmap stage uses (:func:`fingertips.heatmap.hand_centre` of the kept hand
   pixels), the centre of the nearest object's densest 12 cm: a curled tip lies on
   the palm, an open one a finger's length from it;
6. ``other``: none of these (the detector saw the tip and still missed it).

The causes explain misses; they do not decide them: whether a tip was missed is the
matching's business (:mod:`fingertips.evaluation`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array

MissCause = Literal["border", "segmentation", "distance", "merged", "curled", "other"]
MISS_CAUSES: tuple[MissCause, ...] = (
    "border",
    "segmentation",
    "distance",
    "merged",
    "curled",
    "other",
)
"""The causes, in the order the rule tests them."""

CAUSE_LETTERS: dict[MissCause, str] = {
    "border": "B",
    "segmentation": "S",
    "distance": "D",
    "merged": "M",
    "curled": "C",
    "other": "?",
}
"""One letter per cause, as the contact sheets mark misses."""

# MediaPipe order: the wrist, then per finger (thumb first) four keypoints from its base.
_WRIST = 0
_FINGER_BASES = (1, 5, 9, 13, 17)
_FINGER_MCPS = (5, 9, 13, 17)


@dataclass(frozen=True)
class MissCauseParams:
    """Thresholds of the miss-cause rule (module docstring), chosen before looking at
    any scored frame.

    Attributes
    ----------
    border_px : float
        A tip this close to the image border (pixels) is a ``border`` miss.
    window_m : float
        Half side (metres, at the tip's depth; at least one pixel) of the square around
        the tip's pixel that ``segmentation`` looks at: about a fingertip's radius.
    min_window_share : float
        Share of that square that must have depth within ``depth_tolerance_m`` of the
        tip's depth; less is a ``segmentation`` miss. A tip at the end of a finger
        seen from the front has about half its square on the finger, less where the
        sensor drops the finger's edges: the share asks for nearly nothing.
    depth_tolerance_m : float
        Metres between a measured depth and the tip's depth that still count as the tip.
    far_m : float
        A tip farther from the camera (metres, its z) is a ``distance`` miss.
    merged_m : float
        Another annotated tip nearer than this (metres, 3D) makes a ``merged`` miss.
    curled_flexion_deg : float
        Sum of a finger's joint bends (degrees) above which it is ``curled``.
    curled_palm_fraction : float
        A tip nearer to the palm centre than this fraction of its finger's length is
        ``curled``.
    proxy_hand_length_m : float
        Hand length (metres, wrist to middle tip) assumed by the proxy for frames
        without keypoints: an adult's.
    proxy_centre_fraction : float
        Without keypoints, a tip nearer to the hand centre than this fraction of
        ``proxy_hand_length_m`` is ``curled``.
    """

    border_px: float = 10.0
    window_m: float = 0.01
    min_window_share: float = 0.1
    depth_tolerance_m: float = 0.03
    far_m: float = 1.0
    merged_m: float = 0.015
    curled_flexion_deg: float = 120.0
    curled_palm_fraction: float = 0.6
    proxy_hand_length_m: float = 0.19
    proxy_centre_fraction: float = 0.35

    def __post_init__(self) -> None:
        for name in (
            "window_m",
            "depth_tolerance_m",
            "far_m",
            "merged_m",
            "curled_flexion_deg",
            "curled_palm_fraction",
            "proxy_hand_length_m",
            "proxy_centre_fraction",
        ):
            value = getattr(self, name)
            if not 0 < value < math.inf:
                raise ValueError(f"{name}: expected a positive, finite value, got {value}")
        if not 0 <= self.border_px < math.inf:
            raise ValueError(f"border_px: expected >= 0, got {self.border_px}")
        if not 0 < self.min_window_share <= 1:
            raise ValueError(f"min_window_share: expected a share, got {self.min_window_share}")


DEFAULT_MISS_CAUSE_PARAMS = MissCauseParams()
"""The thresholds the docs' counts use."""


def tip_causes(
    depth_m: ArrayLike,
    intrinsics: ArrayLike,
    tips_m: ArrayLike,
    tips_px: ArrayLike,
    *,
    hand_depth_m: ArrayLike | None = None,
    keypoints_m: ArrayLike | None = None,
    working_range_m: tuple[float, float] | None = None,
    params: MissCauseParams = DEFAULT_MISS_CAUSE_PARAMS,
) -> tuple[MissCause | None, ...]:
    """The cause each annotated tip of one frame would be missed for.

    Parameters
    ----------
    depth_m : (H, W) float
        Depth in metres, 0 where missing.
    intrinsics : (4,) float
        ``(fx, fy, cx, cy)`` in pixels.
    tips_m : (T, 3) float
        Annotated tips in the camera frame, metres; NaN rows are not annotated.
    tips_px : (T, 2) float
        The same tips in the image, pixels.
    hand_depth_m : (H, W) float, optional
        The depth the detector kept as the hand (:func:`fingertips.detect.hand_depth`),
        0 elsewhere. Without it, ``segmentation`` tests the depth alone and the
        curled proxy finds the hand in ``depth_m`` itself.
    keypoints_m : (21, 3) float, optional
        The hand's keypoints in MediaPipe order (camera frame, metres; rendered frames
        have them); used when ``T`` is 5 (thumb to little, as the keypoints' fingers).
        None or any NaN: the curled proxy.
    working_range_m : (near, far) float, optional
        The detector's working depth range, metres (``FingertipForest.depth_range_m``).
    params : MissCauseParams

    Returns
    -------
    tuple of (str or None), length T
        One of :data:`MISS_CAUSES` per annotated tip, None where not annotated.
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
    camera = as_array("intrinsics", intrinsics, (4,), np.float64, kind="fiu", finite=True)
    tips = as_array("tips_m", tips_m, (None, 3), np.float64, kind="fiu")
    pixels = as_array("tips_px", tips_px, (tips.shape[0], 2), np.float64, kind="fiu")
    hand = None
    if hand_depth_m is not None:
        hand = as_array("hand_depth_m", hand_depth_m, depth.shape, np.float32, kind="fiu")
    keypoints = None
    if keypoints_m is not None:
        keypoints = as_array("keypoints_m", keypoints_m, (21, 3), np.float64, kind="fiu")
        if not np.all(np.isfinite(keypoints)) or tips.shape[0] != len(_FINGER_BASES):
            keypoints = None
    annotated = np.all(np.isfinite(tips), axis=1) & np.all(np.isfinite(pixels), axis=1)
    curled = _curled(tips, keypoints, depth, camera, hand, params)
    causes: list[MissCause | None] = []
    for k in range(tips.shape[0]):
        if not annotated[k]:
            causes.append(None)
            continue
        z = float(tips[k, 2])
        in_range = working_range_m is None or working_range_m[0] <= z <= working_range_m[1]
        others = tips[annotated & (np.arange(tips.shape[0]) != k)]
        if _near_border(pixels[k], depth.shape, params.border_px):
            causes.append("border")
        elif in_range and not _seen_and_kept(depth, hand, pixels[k], z, camera[0], params):
            causes.append("segmentation")
        elif not in_range or z > params.far_m:
            causes.append("distance")
        elif others.size and np.min(np.linalg.norm(others - tips[k], axis=1)) < params.merged_m:
            causes.append("merged")
        elif curled[k]:
            causes.append("curled")
        else:
            causes.append("other")
    return tuple(causes)


def _near_border(uv: NDArray[np.float64], shape: tuple[int, ...], border_px: float) -> bool:
    height, width = shape
    u, v = float(uv[0]), float(uv[1])
    return min(u, v, width - 1 - u, height - 1 - v) < border_px


def _seen_and_kept(
    depth: NDArray[np.float32],
    hand: NDArray[np.float32] | None,
    uv: NDArray[np.float64],
    z: float,
    fx: float,
    params: MissCauseParams,
) -> bool:
    """Whether the tip's square shows depth at the tip's depth, mostly kept as hand."""
    u, v = round(float(uv[0])), round(float(uv[1]))
    r = max(1, round(params.window_m * fx / z))
    rows = slice(max(v - r, 0), v + r + 1)
    cols = slice(max(u - r, 0), u + r + 1)
    window = depth[rows, cols]
    at_tip = (window > 0) & (np.abs(window - np.float32(z)) <= params.depth_tolerance_m)
    if at_tip.sum() < params.min_window_share * (2 * r + 1) ** 2:
        return False
    if hand is None:
        return True
    kept = at_tip & (hand[rows, cols] > 0)
    return bool(kept.sum() >= 0.5 * at_tip.sum())


def _curled(
    tips: NDArray[np.float64],
    keypoints: NDArray[np.float64] | None,
    depth: NDArray[np.float32],
    camera: NDArray[np.float64],
    hand: NDArray[np.float32] | None,
    params: MissCauseParams,
) -> NDArray[np.bool_]:
    """``(T,) bool``: which fingers are curled, from keypoints or by the proxy."""
    if keypoints is not None:
        return finger_curled(keypoints, params=params)
    from fingertips.heatmap import hand_centre

    centre = hand_centre(depth, camera, hand_depth_m=hand)
    if centre is None:
        return np.zeros(tips.shape[0], dtype=bool)
    reach = params.proxy_centre_fraction * params.proxy_hand_length_m
    with np.errstate(invalid="ignore"):
        return np.linalg.norm(tips - centre, axis=1) < reach


def finger_curled(
    keypoints_m: ArrayLike, *, params: MissCauseParams = DEFAULT_MISS_CAUSE_PARAMS
) -> NDArray[np.bool_]:
    """Which fingers of a hand are curled (the ``curled`` test with keypoints).

    Parameters
    ----------
    keypoints_m : (21, 3) float
        MediaPipe order, metres (any frame).
    params : MissCauseParams

    Returns
    -------
    (5,) bool
        Thumb to little.
    """
    keypoints = as_array("keypoints_m", keypoints_m, (21, 3), np.float64, kind="fiu", finite=True)
    flexion = finger_flexion_deg(keypoints)
    palm = 0.5 * (keypoints[_WRIST] + keypoints[list(_FINGER_MCPS)].mean(axis=0))
    curled = np.zeros(len(_FINGER_BASES), dtype=bool)
    for finger, base in enumerate(_FINGER_BASES):
        chain = keypoints[base : base + 4]
        length = np.linalg.norm(np.diff(chain, axis=0), axis=1).sum()
        near_palm = np.linalg.norm(chain[-1] - palm) < params.curled_palm_fraction * length
        curled[finger] = near_palm or flexion[finger] > params.curled_flexion_deg
    return curled


def finger_flexion_deg(keypoints_m: ArrayLike) -> NDArray[np.float64]:
    """Total bend of each finger's joints, degrees, from its keypoints.

    A finger's bend at a joint is the angle between the bone into it and the bone out
    of it; the sum runs over the MCP, PIP and DIP joints (the thumb: MCP and IP, since
    its CMC joint bends even in an open hand). Sideways bends (abduction) count too.

    Parameters
    ----------
    keypoints_m : (21, 3) float
        MediaPipe order.

    Returns
    -------
    (5,) float64
        Thumb to little; 0 for a straight finger.
    """
    keypoints = as_array("keypoints_m", keypoints_m, (21, 3), np.float64, kind="fiu", finite=True)
    flexion = np.zeros(len(_FINGER_BASES))
    for finger, base in enumerate(_FINGER_BASES):
        chain = keypoints[[_WRIST, base, base + 1, base + 2, base + 3]]
        bones = np.diff(chain, axis=0)
        bones /= np.maximum(np.linalg.norm(bones, axis=1, keepdims=True), 1e-12)
        cosines = np.clip(np.sum(bones[:-1] * bones[1:], axis=1), -1.0, 1.0)
        bends = np.degrees(np.arccos(cosines))  # at the base, then the next two joints
        flexion[finger] = bends[1:].sum() if base == _FINGER_BASES[0] else bends.sum()
    return flexion
