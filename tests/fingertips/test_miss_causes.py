"""Miss causes: constructed frames where each cause is known."""

import numpy as np
import pytest

from fingertips import Detection
from fingertips.evaluation import MissCauseCounts, fingertip_metrics
from fingertips.miss_causes import (
    MISS_CAUSES,
    MissCauseParams,
    finger_curled,
    finger_flexion_deg,
    tip_causes,
)
from glovedb.hand_model import forward_kinematics
from glovedb.postures import named_posture

INTRINSICS = np.array([200.0, 200.0, 59.5, 39.5])
SHAPE = (80, 120)
Z_M = 0.5


def _posed_keypoints(posture: str) -> np.ndarray:
    """A named posture's 21 keypoints, its middle MCP 0.4 m in front of the camera."""
    keypoints = forward_kinematics(named_posture(posture)).keypoints_m[0]
    return keypoints - keypoints[9] + np.array([0.0, 0.0, 0.4])


OPEN = _posed_keypoints("open")
"""Keypoints whose fingers are all straight: no tip is curled."""


def _tip(u: float, v: float, z: float = Z_M) -> tuple[list[float], list[float]]:
    fx, fy, cx, cy = INTRINSICS
    return [(u - cx) * z / fx, (v - cy) * z / fy, z], [u, v]


def _frame(*tips: tuple[list[float], list[float]]) -> tuple[np.ndarray, np.ndarray]:
    """``(5, 3)`` and ``(5, 2)`` tips, the given ones first, the rest not annotated."""
    tips_m, tips_px = np.full((5, 3), np.nan), np.full((5, 2), np.nan)
    for k, (xyz, uv) in enumerate(tips):
        tips_m[k], tips_px[k] = xyz, uv
    return tips_m, tips_px


def test_each_cause_is_found_on_a_constructed_frame() -> None:
    depth = np.full(SHAPE, Z_M, np.float32)
    depth[30:40, 30:40] = 0.0  # a hole in the depth
    depth[:, 95:] = 1.5  # a far surface
    tips_m, tips_px = _frame(
        _tip(4.0, 40.0),  # 4 px from the left border
        _tip(35.0, 35.0),  # over the hole
        _tip(105.0, 40.0, z=1.5),  # beyond far_m, its depth measured
        _tip(60.0, 20.0),  # 5 mm from the next one
        _tip(62.0, 20.0),
    )
    causes = tip_causes(depth, INTRINSICS, tips_m, tips_px, working_range_m=(0.15, 2.0))
    assert causes == ("border", "segmentation", "distance", "merged", "merged")
    assert np.linalg.norm(tips_m[3] - tips_m[4]) == pytest.approx(0.005)


def test_the_hand_the_detector_kept_decides_segmentation() -> None:
    depth = np.full(SHAPE, Z_M, np.float32)
    tips_m, tips_px = _frame(_tip(30.0, 40.0), _tip(90.0, 40.0))
    hand = depth.copy()
    hand[:, 60:] = 0.0  # the detector dropped the right half
    causes = tip_causes(depth, INTRINSICS, tips_m, tips_px, hand_depth_m=hand, keypoints_m=OPEN)
    assert causes[:2] == ("other", "segmentation")
    assert causes[2:] == (None, None, None)  # not annotated
    # Something 5 cm in front of the tip (its depth hidden) is a segmentation miss too.
    depth[35:46, 25:36] = Z_M - 0.05
    assert tip_causes(depth, INTRINSICS, tips_m, tips_px, keypoints_m=OPEN)[0] == "segmentation"


def test_a_tip_beyond_the_working_range_is_a_distance_miss() -> None:
    depth = np.full(SHAPE, 2.5, np.float32)
    hand = np.zeros(SHAPE, np.float32)  # the detector keeps nothing beyond 2 m
    tips_m, tips_px = _frame(_tip(60.0, 40.0, z=2.5))
    causes = tip_causes(
        depth, INTRINSICS, tips_m, tips_px, hand_depth_m=hand, working_range_m=(0.15, 2.0)
    )
    assert causes[0] == "distance"
    params = MissCauseParams(far_m=3.0)
    causes = tip_causes(depth, INTRINSICS, tips_m, tips_px, keypoints_m=OPEN, params=params)
    assert causes[0] == "other"


def test_curled_fingers_from_keypoints() -> None:
    assert not finger_curled(_posed_keypoints("open")).any()
    assert finger_curled(_posed_keypoints("fist")).tolist() == [False, True, True, True, True]
    assert finger_curled(_posed_keypoints("point")).tolist() == [False, False, True, True, True]
    # A straight finger bends 0 degrees; one bent by 90 degrees at its PIP, 90.
    keypoints = np.zeros((21, 3))
    keypoints[5:9] = [[0, 0.09, 0], [0, 0.14, 0], [0, 0.14, 0.03], [0, 0.14, 0.05]]
    keypoints[1:5] = [[0, 0.01 * k, 0] for k in range(1, 5)]
    flexion = finger_flexion_deg(keypoints)
    assert flexion[0] == pytest.approx(0.0, abs=1e-9)
    assert flexion[1] == pytest.approx(90.0)


def test_a_curled_tip_that_the_depth_shows_is_a_curled_miss() -> None:
    keypoints = _posed_keypoints("fist")
    fx, fy, cx, cy = INTRINSICS
    tip = keypoints[8]  # the index tip, alone annotated so that no other tip is near
    tips_m, tips_px = np.full((5, 3), np.nan), np.full((5, 2), np.nan)
    tips_m[1], tips_px[1] = tip, [fx * tip[0] / tip[2] + cx, fy * tip[1] / tip[2] + cy]
    depth = np.full(SHAPE, tip[2], np.float32)
    causes = tip_causes(depth, INTRINSICS, tips_m, tips_px, keypoints_m=keypoints)
    assert causes == (None, "curled", None, None, None)
    open_hand = _posed_keypoints("open")
    assert tip_causes(depth, INTRINSICS, tips_m, tips_px, keypoints_m=open_hand)[1] == "other"


def test_without_keypoints_a_tip_near_the_hand_centre_is_curled() -> None:
    """The proxy of real frames: within 0.35 x 0.19 m of the hand centre."""
    depth = np.zeros(SHAPE, np.float32)
    depth[20:60, 30:90] = Z_M  # the hand: 10 cm x 15 cm at 0.5 m, centre (59.5, 39.5)
    tips_m, tips_px = _frame(_tip(62.0, 42.0), _tip(88.0, 40.0))
    causes = tip_causes(depth, INTRINSICS, tips_m, tips_px, hand_depth_m=depth)
    assert causes[:2] == ("curled", "other")  # 1 cm and 7 cm from the centre


def test_misses_by_cause_add_up_to_the_misses() -> None:
    depth = np.full(SHAPE, Z_M, np.float32)
    depth[30:40, 30:40] = 0.0
    tips_m, tips_px = _frame(_tip(4.0, 40.0), _tip(35.0, 35.0), _tip(60.0, 40.0))
    causes = [tip_causes(depth, INTRINSICS, tips_m, tips_px, keypoints_m=OPEN)]
    found = tips_m[2]  # a detection on the third tip
    detections = [[Detection(60.0, 40.0, *found.tolist(), confidence=5.0)]]
    metrics = fingertip_metrics(detections, tips_m[None], tips_px[None], causes=causes)
    assert metrics.missed_15mm == MissCauseCounts(border=1, segmentation=1)
    assert metrics.missed_10px == metrics.missed_15mm
    assert metrics.missed_15mm.total == metrics.annotated_tips - 1
    expected = {cause: int(cause in ("border", "segmentation")) for cause in MISS_CAUSES}
    assert metrics.as_dict()["missed_15mm"] == expected
    missed_all = fingertip_metrics([[]], tips_m[None], tips_px[None], causes=causes)
    assert missed_all.missed_15mm == MissCauseCounts(border=1, segmentation=1, other=1)
    assert fingertip_metrics([[]], tips_m[None], tips_px[None]).missed_15mm is None
    with pytest.raises(ValueError, match="causes: expected one cause"):
        fingertip_metrics([[]], tips_m[None], tips_px[None], causes=[causes[0][:3]])


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"far_m": 0.0}, "far_m: expected a positive"),
        ({"merged_m": float("inf")}, "merged_m: expected a positive, finite"),
        ({"border_px": -1.0}, "border_px: expected >= 0"),
        ({"min_window_share": 0.0}, "min_window_share: expected a share"),
    ],
)
def test_bad_parameters_are_refused(change: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        MissCauseParams(**change)


def test_bad_shapes_are_refused() -> None:
    depth = np.full(SHAPE, Z_M, np.float32)
    tips_m, tips_px = _frame(_tip(60.0, 40.0))
    with pytest.raises(ValueError, match="tips_px"):
        tip_causes(depth, INTRINSICS, tips_m, tips_px[:3])
    with pytest.raises(ValueError, match="hand_depth_m"):
        tip_causes(depth, INTRINSICS, tips_m, tips_px, hand_depth_m=depth[:10])
    with pytest.raises(ValueError, match="keypoints_m"):
        tip_causes(depth, INTRINSICS, tips_m, tips_px, keypoints_m=np.zeros((20, 3)))
