"""Bare-hand segmentation from depth: support planes, nearest surface, forearm cut."""

from dataclasses import replace

import numpy as np
import pytest
from fingertip_toys import INTRINSICS, STRIDE_1, bar_scene, toy_forest

from fingertips import DetectorConfig, detect_fingertips
from fingertips.detect import detector_config_from_dict, hand_depth
from fingertips.segmentation import (
    DEFAULT_SEGMENTATION,
    SurfaceSegmentationConfig,
    cut_forearm,
    find_support_planes,
    segment_hand,
    surface_components,
)

VGA = (480, 640)
CAMERA = np.array([525.0, 525.0, 319.5, 239.5])
TILT = np.radians(50.0)
TABLE_UP = np.array([0.0, -np.sin(TILT), -np.cos(TILT)])
"""Normal of a table seen 50 degrees from above, toward the camera."""
TABLE_AWAY = np.array([0.0, -np.cos(TILT), np.sin(TILT)])
"""Along the table, away from the camera."""


# --- pure numpy scenes: boxes on planes, ray-cast ----------------------------------


def _rays(shape: tuple[int, int], camera: np.ndarray) -> np.ndarray:
    fx, fy, cx, cy = camera
    v, u = np.indices(shape, dtype=np.float64)
    return np.stack([(u - cx) / fx, (v - cy) / fy, np.ones(shape)], axis=-1)


def _box_depth(centre: np.ndarray, axes: np.ndarray, half_m: tuple) -> np.ndarray:
    """Depth of a box (``axes`` columns: its frame in the camera's), 0 where missed."""
    rays = _rays(VGA, CAMERA) @ axes
    origin = -axes.T @ centre
    with np.errstate(divide="ignore", invalid="ignore"):
        first = (-np.asarray(half_m) - origin) / rays
        second = (np.asarray(half_m) - origin) / rays
    near = np.nanmax(np.minimum(first, second), axis=-1)
    far = np.nanmin(np.maximum(first, second), axis=-1)
    return np.where((near <= far) & (near > 0), near, 0.0)


def _plane_depth(normal: np.ndarray, point: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        depth = (normal @ point) / (_rays(VGA, CAMERA) @ normal)
    return np.where((depth > 0) & (depth < 5.0), depth, 0.0)


def _nearest(*depths: np.ndarray) -> np.ndarray:
    stack = np.stack([np.where(d > 0, d, np.inf) for d in depths])
    nearest = stack.min(axis=0)
    return np.where(np.isfinite(nearest), nearest, 0.0).astype(np.float32)


def _table_axes() -> np.ndarray:
    return np.stack([np.array([1.0, 0.0, 0.0]), TABLE_AWAY, TABLE_UP], axis=1)


def _box_hand_scene(*, table: bool = True, gap_m: float = 0.0):
    """A 18 x 9 x 2.5 cm box "hand" on (or ``gap_m`` above) a table seen obliquely, with
    a 30 cm box "forearm" behind it; depths of the whole scene and of each part."""
    on_table = np.array([0.0, 0.02, 0.6])
    hand = _box_depth(on_table + TABLE_UP * (0.0125 + gap_m), _table_axes(), (0.045, 0.09, 0.0125))
    arm_centre = on_table + TABLE_UP * (0.02 + gap_m) + TABLE_AWAY * (0.09 + 0.15)
    arm = _box_depth(arm_centre, _table_axes(), (0.03, 0.15, 0.02))
    plane = _plane_depth(TABLE_UP, on_table) if table else np.zeros(VGA)
    depth = _nearest(hand, arm, plane)
    return depth, hand, arm, plane


def _shares(mask: np.ndarray, depth: np.ndarray, part: np.ndarray) -> tuple[float, float]:
    """Share of a part's visible pixels in the mask, share of the mask on the part."""
    visible = (part > 0) & (depth == part.astype(np.float32))
    return (mask & visible).sum() / visible.sum(), (mask & visible).sum() / max(mask.sum(), 1)


def test_box_hand_on_a_table_is_separated_from_it() -> None:
    depth, hand, _, table = _box_hand_scene()
    result = segment_hand(depth, CAMERA)
    assert result.mask.dtype == np.bool_ and result.mask.shape == VGA
    hand_covered, _ = _shares(result.mask, depth, hand)
    _, on_table = _shares(result.mask, depth, table)
    assert hand_covered >= 0.9
    assert on_table <= 0.05
    # The table is found: one plane, its normal and offset within a degree and 2 mm.
    assert result.planes.shape == (1, 4)
    assert np.degrees(np.arccos(result.planes[0, :3] @ TABLE_UP)) < 1.0
    np.testing.assert_allclose(result.planes[0, 3], TABLE_UP @ [0.0, 0.02, 0.6], atol=0.002)
    assert result.plane_areas_m2[0] > 0.5


def test_forearm_beyond_a_hand_length_is_cut() -> None:
    depth, _, arm, _ = _box_hand_scene()
    result = segment_hand(depth, CAMERA)
    assert result.cut
    np.testing.assert_allclose(result.cut_axis @ -TABLE_AWAY, 1.0, atol=0.02)  # toward the hand
    # Distance along the table from the hand's near end (the box's fingertip end).
    fx, fy, cx, cy = CAMERA
    v, u = np.nonzero(result.mask & (depth == arm.astype(np.float32)))
    z = depth[v, u]
    points = np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z], axis=1)
    tip_end = np.array([0.0, 0.02, 0.6]) - TABLE_AWAY * 0.09
    along = (points - tip_end) @ TABLE_AWAY
    assert along.size > 0  # the wrist end of the arm stays, as part of the hand length
    assert along.max() <= DEFAULT_SEGMENTATION.hand_length_m + 0.01
    arm_kept, _ = _shares(result.mask, depth, arm)
    assert arm_kept < 0.3


def test_hand_just_above_a_table() -> None:
    depth, hand, _, table = _box_hand_scene(gap_m=0.02)
    result = segment_hand(depth, CAMERA)
    hand_covered, _ = _shares(result.mask, depth, hand)
    _, on_table = _shares(result.mask, depth, table)
    assert hand_covered >= 0.98 and on_table <= 0.01


def test_hand_in_free_space_without_a_plane() -> None:
    depth, hand, _, _ = _box_hand_scene(table=False)
    result = segment_hand(depth, CAMERA)
    assert result.planes.shape == (0, 4) and result.plane_areas_m2.shape == (0,)
    assert _shares(result.mask, depth, hand)[0] == 1.0 and result.cut
    alone = segment_hand(np.where(depth == hand.astype(np.float32), depth, 0.0), CAMERA)
    assert not alone.cut
    np.testing.assert_array_equal(alone.mask, (hand > 0) & (depth == hand.astype(np.float32)))
    # The area facing the camera: mostly the box's top, tilted by 50 degrees.
    assert alone.component_area_m2 == pytest.approx(0.09 * 0.18 * np.cos(TILT), rel=0.2)


def test_empty_depth_gives_an_empty_mask() -> None:
    for depth in (np.zeros(VGA, np.float32), np.full((4, 5), np.nan, np.float32)):
        result = segment_hand(depth, CAMERA)
        assert not result.mask.any() and result.mask.shape == depth.shape
        assert result.planes.shape == (0, 4) and not result.cut
        assert result.component_area_m2 == 0.0 and result.nearest_m == 0.0


def test_stray_near_pixels_do_not_win() -> None:
    depth, hand, _, _ = _box_hand_scene(table=False)
    depth[10:13, 10:13] = 0.3  # a few flying pixels, nearer than the hand
    result = segment_hand(depth, CAMERA)
    assert not result.mask[10:13, 10:13].any()
    assert _shares(result.mask, depth, hand)[0] == 1.0
    assert result.nearest_m > 0.4


def test_arm_entering_from_the_border_is_the_end_that_is_cut() -> None:
    # Seen from behind the shoulder: a 40 cm arm comes in from beyond the bottom border,
    # nearer to the camera than the hand at its far end.
    arm_centre = np.array([0.0, 0.10, 0.6])
    arm = _box_depth(arm_centre, _table_axes(), (0.03, 0.2, 0.0125))
    hand_centre = arm_centre + TABLE_AWAY * (0.2 + 0.09)
    hand = _box_depth(hand_centre, _table_axes(), (0.045, 0.09, 0.0125))
    depth = _nearest(arm, hand)
    assert (depth[-1] > 0).any()
    result = segment_hand(depth, CAMERA)
    assert result.cut
    assert _shares(result.mask, depth, hand)[0] == 1.0
    assert not result.mask[-20:].any()


def test_parts_split_by_a_depth_jump_join_the_hand() -> None:
    depth = np.zeros(VGA, np.float32)
    depth[200:300, 280:360] = 0.6  # palm
    depth[230:250, 300:400] = 0.57  # a finger 3 cm in front, crossing the palm's edge
    assert surface_components(depth, np.full(VGA, 0.01, np.float32))[1] == 2
    result = segment_hand(depth, CAMERA)
    np.testing.assert_array_equal(result.mask, depth > 0)
    apart = replace(DEFAULT_SEGMENTATION, join_jump_m=0.02)
    assert not segment_hand(depth, CAMERA, config=apart).mask[200:230].any()


def test_surface_components_known_values() -> None:
    depth = np.array(
        [
            [0.50, 0.50, 0.00, 0.70],
            [0.50, 0.51, 0.00, 0.70],
            [0.60, 0.60, 0.60, 0.70],
        ],
        np.float32,
    )
    labels, n = surface_components(depth, np.full(depth.shape, 0.015, np.float32))
    assert labels.dtype == np.int32 and n == 3
    expected_groups = [[(0, 0), (0, 1), (1, 0), (1, 1)], [(2, 0), (2, 1), (2, 2)], [(0, 3)]]
    for group in expected_groups:
        assert len({labels[p] for p in group}) == 1
    assert labels[0, 2] == labels[1, 2] == 0
    assert labels[0, 3] == labels[2, 3]  # 0.70 column: one surface
    with pytest.raises(ValueError, match="max_jump_m"):
        surface_components(depth, np.zeros((2, 2), np.float32))


def test_support_planes_ignore_a_narrow_planar_strip() -> None:
    height, width = 60, 80
    v, u = np.indices((height, width), dtype=np.float64)
    # A wall at 1 m facing the camera, and in front of it a flat strip 7 cm wide and
    # 70 cm long (0.049 m², a forearm and hand seen from the side), at 0.7 m.
    z = np.full((height, width), 1.0)
    strip = (v >= 26) & (v < 34)
    z[strip] = 0.7
    points = np.stack([(u - 40) * 0.0125 * z, (v - 30) * 0.0125 * z, z], axis=-1)
    area = np.square(0.0125 * z)
    planes, areas, on_plane = find_support_planes(points, area)
    assert planes.shape == (1, 4) and on_plane.shape == (height, width)
    np.testing.assert_allclose(planes[0], [0.0, 0.0, -1.0, -1.0], atol=1e-6)
    np.testing.assert_allclose(areas[0], area[~strip].sum(), rtol=0.05)
    assert not on_plane[strip].any() and on_plane[~strip].mean() > 0.95
    again = find_support_planes(points, area)
    np.testing.assert_array_equal(again[2], on_plane)  # seeded: deterministic


def test_cut_forearm_keeps_a_hand_length_from_the_ragged_end() -> None:
    rng = np.random.default_rng(0)
    along = rng.uniform(0.0, 0.45, 4000)
    points = np.stack([along, rng.uniform(-0.03, 0.03, 4000), np.full(4000, 0.6)], axis=1)
    ragged = along > 0.35  # the fingers: more outline per area
    outline = rng.uniform(size=4000) < np.where(ragged, 0.5, 0.1)
    point, axis = cut_forearm(points, np.zeros(4000, bool), outline)
    np.testing.assert_allclose(axis, [1.0, 0.0, 0.0], atol=1e-2)
    np.testing.assert_allclose(point @ axis, 0.45 - 0.22, atol=0.01)
    # An end on the image border is the arm, whatever its outline.
    point, axis = cut_forearm(points, along > 0.44, outline)
    np.testing.assert_allclose(axis, [-1.0, 0.0, 0.0], atol=1e-2)
    short = points[along < 0.2]
    assert np.isnan(cut_forearm(short, np.zeros(len(short), bool), outline[along < 0.2])[0]).all()


def test_settings_are_checked() -> None:
    with pytest.raises(ValueError, match="hand_length_m"):
        SurfaceSegmentationConfig(hand_length_m=0.0)
    with pytest.raises(ValueError, match="max_planes"):
        SurfaceSegmentationConfig(max_planes=-1)
    with pytest.raises(ValueError, match="intrinsics"):
        segment_hand(np.zeros((4, 4), np.float32), (0.0, 1.0, 2.0, 2.0))


def test_detector_setting_selects_the_segmentation() -> None:
    with pytest.raises(ValueError, match="segmentation"):
        DetectorConfig(segmentation="glove")  # type: ignore[arg-type]
    config = detector_config_from_dict({"segmentation": "surface", "c_thr": 2.0})
    assert config.segmentation == "surface"
    assert detector_config_from_dict(config.as_dict()) == config
    assert DetectorConfig().segmentation == "band"
    depth, tip = bar_scene()
    forest = toy_forest()
    with pytest.raises(ValueError, match="intrinsics"):
        hand_depth(depth, forest, segmentation="surface")
    surface = replace(STRIDE_1, segmentation="surface")
    masked = hand_depth(depth, forest, segmentation="surface", intrinsics=INTRINSICS)
    assert masked.dtype == np.float32
    np.testing.assert_array_equal(masked, depth)  # the bar alone: all of it is the hand
    band = detect_fingertips(depth, INTRINSICS, forest, config=STRIDE_1)
    found = detect_fingertips(depth, INTRINSICS, forest, config=surface)
    assert found == band and len(found) == 1
    assert np.linalg.norm(np.array([found[0].x_m, found[0].y_m, found[0].z_m]) - tip) < 0.005


# --- the rendered hand model on a table ----------------------------------------------


def _rendered_hand_on_table(renderer, *, gap_m: float):
    """The open hand model palm down on (or ``gap_m`` above) a table, seen obliquely
    from beyond the fingertips at 0.6 m, with its forearm lying on the table."""
    from fingertips.data import forearm_depth
    from glovedb.camera import KINECT_V1
    from glovedb.mesh import pose_mesh
    from glovedb.postures import named_posture
    from glovedb.views import HAND_CENTRE, pose_for_view, view_direction

    posture = named_posture("open")
    length = renderer.mesh.skeleton.hand_length_m
    rotation, translation = pose_for_view(
        view_direction(0.0, np.radians(40.0)), 0.6, target_m=np.array(HAND_CENTRE) * length
    )
    hand = renderer.render_labels(posture, rotation, translation).depth_m
    lowest = pose_mesh(renderer.mesh, posture)[:, 2].min() - gap_m  # the table, hand frame
    up = rotation[:, 2]
    table = KINECT_V1.plane_depth(up, translation + lowest * up, max_depth_m=2.0)
    arm = forearm_depth(VGA, KINECT_V1.pinhole, rotation, translation, length)
    clean = _nearest(hand, arm, table)
    rng = np.random.default_rng(7)
    noisy = clean + rng.normal(size=VGA).astype(np.float32) * (0.0005 + 0.004 * clean**2)
    depth = np.where(clean > 0, noisy, 0.0).astype(np.float32)
    fingertip_y = pose_mesh(renderer.mesh, posture)[:, 1].max()
    return depth, clean, hand, arm, table, rotation, translation, fingertip_y


@pytest.mark.gl
@pytest.mark.parametrize("gap_m", [0.0, 0.015])
def test_rendered_hand_on_a_table_is_separated_from_it(renderer, gap_m: float) -> None:
    depth, clean, hand, arm, table, rotation, translation, tip_y = _rendered_hand_on_table(
        renderer, gap_m=gap_m
    )
    result = segment_hand(depth, CAMERA)
    seen_hand = (hand > 0) & (clean == hand)
    seen_table = (table > 0) & (clean == table) & ~seen_hand
    seen_arm = (arm > 0) & (clean == arm) & ~seen_hand
    assert seen_hand.sum() > 5000 and seen_table.sum() > 100000 and seen_arm.sum() > 2000
    assert (result.mask & seen_hand).sum() >= 0.9 * seen_hand.sum()
    assert (result.mask & seen_table).sum() <= 0.05 * result.mask.sum()
    assert result.planes.shape[0] == 1 and result.cut
    # The arm's pixels kept lie within about a hand length of the fingertips.
    fx, fy, cx, cy = CAMERA
    v, u = np.nonzero(result.mask & seen_arm)
    z = clean[v, u]
    in_hand_frame = (
        np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z], 1) - translation
    ) @ rotation
    assert (tip_y - in_hand_frame[:, 1]).max() <= DEFAULT_SEGMENTATION.hand_length_m + 0.02
    assert (result.mask & seen_arm).sum() < 0.5 * seen_arm.sum()
