"""Geodesic fingertip candidates: a toy hand with known ends, rendered hands, the kernel."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from fingertip_toys import render_named_hand
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from fingertips._geodesic_kernels import lower_distances
from fingertips.geodesic import (
    DEFAULT_GEODESIC,
    GeodesicConfig,
    cell_grid,
    geodesic_candidates,
    median_3x3,
)
from fingertips.geodesic_evaluation import DISTANCE_BANDS_M, score_candidates

VGA = (525.0, 525.0, 319.5, 239.5)
QVGA = (262.5, 262.5, 159.5, 119.5)
SHAPES = {VGA: (480, 640), QVGA: (240, 320)}

PALM_RADIUS_M = 0.04
FINGER_RADIUS_M = 0.008
FINGER_ANGLES_DEG = (-70.0, -26.0, -9.0, 8.0, 25.0)
"""Directions of the thumb to little finger from straight up (toward -y), degrees."""
FINGER_ENDS_M = (0.08, 0.1, 0.105, 0.1, 0.09)
"""Distance of each finger's end from the palm centre, metres."""


def _capsule(x, y, start, end, radius):
    """Points within ``radius`` of the segment ``start``-``end`` (plane coordinates)."""
    direction = np.subtract(end, start)
    length = np.hypot(*direction)
    along = np.clip(
        ((x - start[0]) * direction[0] + (y - start[1]) * direction[1]) / length, 0, length
    )
    nearest_x = start[0] + along * direction[0] / length
    nearest_y = start[1] + along * direction[1] / length
    return np.hypot(x - nearest_x, y - nearest_y) <= radius


def toy_hand(
    distance_m: float,
    intrinsics: tuple[float, ...] = VGA,
    *,
    hidden_finger: int | None = None,
    wall_gap_m: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Depth of a flat toy hand facing the camera at ``distance_m``, centred in the image.

    A palm disc, five capsule fingers fanned upward and a 6 cm x 9 cm wrist downward.
    ``hidden_finger`` lies 2 cm behind the palm plane, its base hidden by the palm and
    the neighbouring fingers; ``wall_gap_m`` adds a wall that far behind the hand.

    Returns
    -------
    depth : (H, W) float32
    ends_m : (5, 3) float64
        Finger ends (on the surface) in the camera frame.
    palm_m : (3,) float64
    """
    fx, fy, cx, cy = intrinsics
    shape = SHAPES[intrinsics]
    v, u = np.indices(shape, dtype=np.float64)
    x, y = (u - cx) * distance_m / fx, (v - cy) * distance_m / fy
    depth = np.zeros(shape)
    ends = []
    for k, (angle, reach) in enumerate(zip(FINGER_ANGLES_DEG, FINGER_ENDS_M, strict=True)):
        unit = np.array([math.sin(math.radians(angle)), -math.cos(math.radians(angle))])
        inner = 0.02 * unit
        outer = (reach - FINGER_RADIUS_M) * unit
        finger = _capsule(x, y, inner, outer, FINGER_RADIUS_M)
        z = distance_m + (0.02 if k == hidden_finger else 0.0)
        depth[finger & ((depth == 0) | (depth > z))] = z
        ends.append([*(reach * unit), z])
    front = (np.hypot(x, y) <= PALM_RADIUS_M) | ((np.abs(x) <= 0.03) & (y >= 0) & (y <= 0.09))
    depth[front] = distance_m
    if wall_gap_m is not None:
        depth[depth == 0] = distance_m + wall_gap_m
    ends_m = np.array(ends)
    ends_m[:, :2] *= ends_m[:, 2:] / distance_m
    return depth.astype(np.float32), ends_m, np.array([0.0, 0.0, distance_m])


def _as_tips(ends_m: np.ndarray, config: GeodesicConfig = DEFAULT_GEODESIC) -> np.ndarray:
    """Where a candidate at a surface point ends up: ``tip_depth_m`` along the ray."""
    return ends_m * (1.0 + config.tip_depth_m / ends_m[:, 2:])


def _nearest(points: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Distance ``(T,)`` from each target to its nearest point (inf without points)."""
    if len(points) == 0:
        return np.full(len(targets), np.inf)
    return np.linalg.norm(points[:, None] - targets[None], axis=2).min(axis=0)


@pytest.mark.parametrize("intrinsics", [VGA, QVGA], ids=["vga", "qvga"])
@pytest.mark.parametrize("distance_m", [0.3, 0.6, 1.0])
def test_toy_hand_gives_its_five_finger_ends_and_palm(distance_m, intrinsics) -> None:
    depth, ends, palm = toy_hand(distance_m, intrinsics)
    found = geodesic_candidates(depth, intrinsics)
    fingers = found.fingers()
    assert len(fingers) == 5
    assert _nearest(fingers.points_m, _as_tips(ends)).max() < 0.008
    np.testing.assert_allclose(found.palm_m, palm, atol=0.01)
    assert 0.035 < found.palm_radius_m < 0.05
    # The wrist's corners are ends too, far from the palm but wide: flagged, not fingers.
    wrist = found.select(~found.is_finger)
    assert len(wrist) >= 1 and np.all(wrist.width_m > DEFAULT_GEODESIC.max_finger_width_m)
    assert np.all(wrist.points_m[:, 1] > 0.05)
    np.testing.assert_allclose(
        np.sort(fingers.reach_m), np.sort(FINGER_ENDS_M), atol=0.15 * max(FINGER_ENDS_M)
    )


def test_output_types_and_shapes() -> None:
    depth, _, _ = toy_hand(0.5)
    found = geodesic_candidates(depth, VGA)
    k = len(found)
    assert found.points_m.shape == (k, 3) and found.points_m.dtype == np.float32
    assert found.pixels_uv.shape == (k, 2) and found.pixels_uv.dtype == np.float32
    for name in ("reach_m", "separation_m", "width_m"):
        assert getattr(found, name).shape == (k,) and getattr(found, name).dtype == np.float32
    assert found.is_finger.dtype == bool
    assert found.palm_m.shape == (3,) and found.palm_uv.shape == (2,)
    # Pixels are the projections of the points.
    fx, fy, cx, cy = VGA
    x, y, z = found.points_m.T
    np.testing.assert_allclose(
        found.pixels_uv, np.stack([fx * x / z + cx, fy * y / z + cy], 1), atol=1e-3
    )
    assert np.all(found.separation_m >= DEFAULT_GEODESIC.min_separation_m)
    assert np.all(found.reach_m >= DEFAULT_GEODESIC.min_reach_m)


def test_a_wall_behind_the_hand_changes_no_finger() -> None:
    bare, _, _ = toy_hand(0.6)
    walled, _, _ = toy_hand(0.6, wall_gap_m=0.05)
    a, b = geodesic_candidates(bare, VGA), geodesic_candidates(walled, VGA)
    # The wall fills the frame, so the hand is found on a coarser grid first and its
    # window gridded at most max_cells: the cells may be larger, the ends the same.
    assert len(a.fingers()) == len(b.fingers()) == 5
    assert _nearest(b.fingers().points_m, a.fingers().points_m).max() < 0.008
    np.testing.assert_allclose(a.palm_m, b.palm_m, atol=0.01)


def test_a_finger_seen_behind_the_palm_is_joined_to_it() -> None:
    depth, ends, _ = toy_hand(0.6, hidden_finger=2)
    joined = geodesic_candidates(depth, VGA).fingers()
    assert _nearest(joined.points_m, _as_tips(ends)).max() < 0.008
    apart = geodesic_candidates(depth, VGA, config=GeodesicConfig(max_part_area_m2=0.0))
    assert _nearest(apart.points_m, _as_tips(ends[2:3]))[0] > 0.03


@pytest.mark.parametrize("fill", [0.0, np.nan])
def test_no_depth_gives_no_candidates(fill) -> None:
    found = geodesic_candidates(np.full((48, 64), fill, np.float32), VGA)
    assert len(found) == 0 and found.points_m.shape == (0, 3) and found.fingers().reach_m.size == 0
    assert np.isnan(found.palm_m).all() and np.isnan(found.palm_uv).all()
    assert found.palm_radius_m == 0.0 and found.cell_m == 0.0


def test_a_speck_is_no_hand() -> None:
    depth = np.zeros((480, 640), np.float32)
    depth[200:205, 300:305] = 0.5  # 0.6 cm², far below a hand
    found = geodesic_candidates(depth, VGA)
    assert len(found) == 0 and np.isnan(found.palm_m).all() and found.cell_m > 0


def test_bad_inputs_are_named() -> None:
    depth, _, _ = toy_hand(0.6)
    with pytest.raises(ValueError, match="depth_m"):
        geodesic_candidates(depth[None], VGA)
    with pytest.raises(ValueError, match="intrinsics"):
        geodesic_candidates(depth, VGA[:3])
    with pytest.raises(ValueError, match="intrinsics"):
        geodesic_candidates(depth, (-525.0, 525.0, 319.5, 239.5))
    with pytest.raises(TypeError, match="depth_m"):
        geodesic_candidates(depth.astype(str), VGA)


@pytest.mark.parametrize(
    "settings",
    [{"cell_m": 0.0}, {"max_extrema": 0}, {"min_reach_m": -0.01}, {"max_hand_area_m2": 0.001},
     {"width_band_m": 0.06}],
)  # fmt: skip
def test_bad_settings_are_named(settings) -> None:
    with pytest.raises(ValueError, match=next(iter(settings))):
        GeodesicConfig(**settings)


def test_cell_grid_takes_the_lower_median_of_half_measured_blocks() -> None:
    depth = np.zeros((6, 9), np.float32)
    depth[0:3, 0:3] = [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]]
    depth[0:3, 3:6] = 0.5
    depth[0:3, 6] = 0.7  # 3 of 9 measured: missing
    grid = cell_grid(depth, 3, origin_uv=(10, 20))
    np.testing.assert_array_equal(grid.depth_m, [[5.0, 0.5, 0.0], [0.0, 0.0, 0.0]])
    np.testing.assert_array_equal(grid.pixels_uv[1, 2], [10 + 1 + 6, 20 + 1 + 3])
    assert grid.depth_m.dtype == np.float32


def test_median_3x3_smooths_within_a_surface_only() -> None:
    depth = np.full((5, 6), 0.5, np.float32)
    depth[:, 3:] = 0.6  # a step of 0.1 m: two surfaces
    depth[2, 1] = 0.505  # noise on the first
    depth[0, 0] = 0.0
    smooth = median_3x3(depth, max_step=0.05)
    assert smooth[2, 1] == pytest.approx(0.5)
    np.testing.assert_array_equal(smooth[:, 2:4], depth[:, 2:4])
    assert smooth[0, 0] == 0.0 and smooth.dtype == np.float32
    # A spike steeper than max_step is a surface of its own; within it, it is noise.
    spike = np.full((3, 3), 0.5, np.float32)
    spike[1, 1] = 0.9
    assert median_3x3(spike, max_step=0.05)[1, 1] == pytest.approx(0.9)
    assert median_3x3(spike, max_step=1.0)[1, 1] == pytest.approx(0.5)


def test_lower_distances_is_dijkstra() -> None:
    rng = np.random.default_rng(3)
    heads, tails = rng.integers(0, 300, (2, 1500))
    lengths = rng.uniform(0.01, 0.2, 1500)
    graph = csr_matrix((lengths, (heads, tails)), shape=(300, 300))
    graph = graph.maximum(graph.T).tocsr()
    for limit in (math.inf, 0.5):
        distance = np.full(300, np.inf)
        lower_distances(graph.indptr, graph.indices, graph.data, distance, 7, limit)
        np.testing.assert_allclose(distance, dijkstra(graph, indices=7, limit=limit))
    # From distances to one source, adding another gives the distances to the nearer one.
    distance = dijkstra(graph, indices=7)
    lower_distances(graph.indptr, graph.indices, graph.data, distance, 42, math.inf)
    np.testing.assert_allclose(distance, dijkstra(graph, indices=[7, 42], min_only=True))


def test_score_candidates_counts_found_tips_per_band() -> None:
    examples = []
    for distance in (0.4, 0.7, 1.0):
        depth, ends, _ = toy_hand(distance)
        tips = _as_tips(ends)
        tips[4] = np.nan  # the little finger hidden: not counted
        examples.append(
            SimpleNamespace(
                depth_m=depth,
                intrinsics=np.array(VGA),
                tips_m=tips,
                keypoints_m=np.tile(ends, (4, 1)),
            )
        )
    scores = score_candidates(examples)
    np.testing.assert_array_equal(scores.n_tips, [4, 4, 4])
    np.testing.assert_array_equal(scores.n_found, [4, 4, 4])
    np.testing.assert_array_equal(scores.n_fingers, [5, 5, 5])
    rows = scores.by_band()
    assert [row["frames"] for row in rows] == [1, 1, 1] and len(rows) == len(DISTANCE_BANDS_M) - 1
    assert all(row["recall"] == 1.0 and row["extra_per_frame"] == 1.0 for row in rows)


@pytest.mark.gl
@pytest.mark.parametrize("side", ["palm", "back"])
@pytest.mark.parametrize("distance_m", [0.3, 0.6, 1.0])
def test_rendered_open_hand_gives_its_five_tips(renderer, side, distance_m) -> None:
    example = render_named_hand(renderer, "open", side, distance_m)
    assert np.isfinite(example.tips_m).all()
    fingers = geodesic_candidates(example.depth_m, example.intrinsics).fingers()
    assert _nearest(fingers.points_m, example.tips_m).max() < 0.015
    assert len(fingers) <= 5 + 1


@pytest.mark.gl
@pytest.mark.parametrize("distance_m", [0.3, 0.6, 1.0])
def test_rendered_open_hand_with_sensor_noise(renderer, distance_m) -> None:
    example = render_named_hand(renderer, "open", "palm", distance_m, noise="kinect_v1")
    fingers = geodesic_candidates(example.depth_m, example.intrinsics).fingers()
    assert _nearest(fingers.points_m, example.tips_m).max() < 0.015
    assert len(fingers) <= 5 + 4


@pytest.mark.gl
@pytest.mark.parametrize("distance_m", [0.3, 0.6, 1.0])
def test_rendered_fist_from_the_back_proposes_no_fingers(renderer, distance_m) -> None:
    example = render_named_hand(renderer, "fist", "back", distance_m)
    found = geodesic_candidates(example.depth_m, example.intrinsics)
    assert len(found) >= 1  # the knuckles and the wrist are ends, but wide ones
    assert len(found.fingers()) <= 1  # at most the thumb's end
