"""The compiled and overlapped paths of detection give what the plain NumPy ones gave.

Each reference below is the NumPy code the fast path replaced, kept here as the
definition the kernels are held to, bit for bit.
"""

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.ndimage import distance_transform_edt
from scipy.sparse import csr_matrix

from fingertips.detect import (
    detect_fingertips,
    detection_points,
    hand_depth,
    model_detector_config,
    verified_candidates,
)
from fingertips.features import (
    BACKGROUND_DEPTH_M,
    foreground_pixels,
    mask_depth_range,
    nearest_band,
    nearest_depth,
    probe_image,
    stride_for_budget,
)
from fingertips.forest import DEFAULT_MODEL_PATH, load_forest
from fingertips.geodesic import (
    NEIGHBOUR_OFFSETS,
    cell_grid,
    geodesic_candidates,
    median_3x3,
    palm_centre,
    surface_graph,
    symmetric_edges,
)
from fingertips.heatmap import hand_heatmaps, heatmap_peaks, start_heatmaps

CAMERA = np.array([525.0, 525.0, 319.5, 239.5])


def _awkward_depth(seed: int, shape: tuple[int, int] = (61, 83)) -> NDArray[np.float32]:
    """Depth with holes, negative, NaN and inf values, and values on the float32
    neighbours of the thresholds used below."""
    rng = np.random.default_rng(seed)
    depth = rng.uniform(0.1, 2.2, shape).astype(np.float32)
    edges = np.array([0.15, 2.0, 0.6, 0.8], np.float32)
    special = np.concatenate(
        [edges, np.nextafter(edges, np.float32(0)), np.nextafter(edges, np.float32(9))]
    )
    depth.ravel()[rng.integers(0, depth.size, 200)] = rng.choice(special, 200)
    depth[rng.uniform(size=shape) < 0.2] = 0.0
    depth.ravel()[rng.integers(0, depth.size, 5)] = [-0.5, np.nan, np.inf, -np.inf, np.nan]
    return depth


def _reference_mask_depth_range(depth: NDArray[np.float32], near: float, far: float) -> NDArray:
    inside = (depth >= near) & (depth <= far)
    return np.where(inside, depth, np.float32(0.0)).astype(np.float32)


def _reference_nearest_band(depth: NDArray[np.float32], band_m: float) -> NDArray:
    grid = depth[::2, ::2]
    measured = grid[grid > 0]
    if measured.size == 0:
        return depth.copy()
    k = min(20, measured.size - 1)
    nearest = float(np.partition(measured, k)[k])
    return np.where(depth <= nearest + band_m, depth, np.float32(0.0)).astype(np.float32)


def _reference_probe_image(depth: NDArray[np.float32]) -> NDArray:
    filled = np.where(depth > 0, depth, np.float32(BACKGROUND_DEPTH_M)).astype(np.float32)
    return np.pad(filled, 1, mode="edge")


def _reference_cell_grid_depth(depth: NDArray[np.float32], stride: int) -> NDArray:
    h, w = -(-depth.shape[0] // stride), -(-depth.shape[1] // stride)
    padded = np.zeros((h * stride, w * stride), np.float32)
    padded[: depth.shape[0], : depth.shape[1]] = depth
    samples = min(stride, 3)
    offsets = (2 * np.arange(samples) + 1) * stride // (2 * samples)
    blocks = padded.reshape(h, stride, w, stride)[:, offsets][:, :, :, offsets]
    blocks = blocks.transpose(0, 2, 1, 3).reshape(h, w, samples * samples)
    counts = np.count_nonzero(blocks, axis=-1)
    ordered = np.sort(np.where(blocks > 0, blocks, np.float32(np.inf)), axis=-1)
    middle = np.maximum(counts - 1, 0) // 2
    grid = np.take_along_axis(ordered, middle[..., None], axis=-1)[..., 0]
    return np.where(2 * counts >= samples * samples, grid, np.float32(0.0)).astype(np.float32)


def _reference_median_3x3(depth: NDArray[np.float32], max_step: float) -> NDArray:
    measured = depth > 0
    rows, cols = np.nonzero(measured)
    padded = np.pad(np.where(measured, depth, np.float32(np.inf)), 1, constant_values=np.inf)
    stack = np.stack([padded[rows + r, cols + c] for r in range(3) for c in range(3)], axis=-1)
    centre = depth[rows, cols][:, None]
    stack[np.abs(stack - centre) > max_step * centre] = np.inf
    middle = (np.count_nonzero(np.isfinite(stack), axis=-1) - 1) // 2
    median = np.take_along_axis(np.sort(stack, axis=-1), middle[:, None], axis=-1)[:, 0]
    smooth = np.zeros_like(depth, dtype=np.float32)
    smooth[rows, cols] = median
    return smooth


@pytest.mark.parametrize("seed", range(4))
def test_depth_passes_match_numpy_bit_for_bit(seed: int) -> None:
    depth = _awkward_depth(seed)
    masked = mask_depth_range(depth, near_m=0.15, far_m=2.0)
    np.testing.assert_array_equal(masked, _reference_mask_depth_range(depth, 0.15, 2.0))
    assert masked.dtype == np.float32
    for band in (0.2, 0.45, math.inf):
        np.testing.assert_array_equal(
            nearest_band(masked, band_m=band), _reference_nearest_band(masked, band)
        )
    probes = probe_image(masked)
    np.testing.assert_array_equal(probes, _reference_probe_image(masked))
    assert probes.dtype == np.float32 and probes.shape == (63, 85)
    view = masked[3:40:2, 5:70:3]  # not contiguous
    np.testing.assert_array_equal(probe_image(view), _reference_probe_image(view))
    np.testing.assert_array_equal(
        nearest_band(view, band_m=0.3), _reference_nearest_band(view, 0.3)
    )


@pytest.mark.parametrize("seed", range(3))
def test_pixel_grid_and_budget_match_numpy(seed: int) -> None:
    """The compiled pixel grid and measured-pixel count against their NumPy
    definitions, on depth with NaN, infinities and negative values, and on a view."""
    depth = _awkward_depth(seed)
    for image in (depth, depth[3:50:2, 4:80:3]):
        for stride in (1, 2, 3, 5):
            rows, cols = np.nonzero(image[::stride, ::stride] > 0)
            expected = np.stack([cols * stride, rows * stride], axis=1).astype(np.int32)
            found = foreground_pixels(image, stride=stride)
            assert found.dtype == np.int32
            np.testing.assert_array_equal(found, expected)
        for budget in (10, 100, 1000):
            count = np.count_nonzero(image)  # NaN and negative values count, as there
            assert stride_for_budget(image, budget) == max(1, math.ceil(math.sqrt(count / budget)))
    assert foreground_pixels(np.zeros((4, 5), np.float32)).shape == (0, 2)


@pytest.mark.parametrize("measured", [1, 5, 20, 21, 22, 1500])
def test_nearest_depth_is_the_partition_of_the_grid(measured: int) -> None:
    """The one-pass selection against ``np.partition`` of the grid's values, with
    fewer values than the rank, exactly as many, and ties."""
    rng = np.random.default_rng(measured)
    for _ in range(5):
        depth = np.zeros((90, 70), np.float32)
        rows, cols = np.unravel_index(rng.choice(45 * 35, measured, replace=False), (45, 35))
        values = rng.choice(np.float32([0.5, 0.6, 0.61, 0.9, 1.3, 2.0]), measured)
        values[: measured // 2] = rng.uniform(0.2, 2.0, measured // 2)
        depth[2 * rows, 2 * cols] = values  # on the 2-pixel grid, ties included
        depth[1::2, 1::2] = 0.01  # off the grid: never counted
        depth[0, 1] = np.nan
        grid = depth[::2, ::2]
        values = grid[grid > 0]
        assert values.size == measured
        k = min(20, values.size - 1)
        assert nearest_depth(depth) == float(np.partition(values, k)[k])


def test_nearest_depth_of_nothing_and_probe_image_of_nothing() -> None:
    assert nearest_depth(np.zeros((4, 5), np.float32)) == 0.0
    with pytest.raises(ValueError, match="depth_m"):
        probe_image(np.zeros((0, 5), np.float32))


@pytest.mark.parametrize("stride", [1, 2, 3, 4, 5, 7])
def test_cell_grid_matches_numpy_bit_for_bit(stride: int) -> None:
    depth = np.nan_to_num(_awkward_depth(stride), nan=0.0, posinf=0.0, neginf=0.0)
    depth = np.maximum(depth, 0.0)  # cell_grid takes finite depth, 0 where missing
    grid = cell_grid(depth, stride, origin_uv=(7, 11))
    np.testing.assert_array_equal(grid.depth_m, _reference_cell_grid_depth(depth, stride))
    assert grid.depth_m.dtype == np.float32


@pytest.mark.parametrize("max_step", [0.0, 0.01, 0.05, 10.0])
def test_median_3x3_matches_numpy_bit_for_bit(max_step: float) -> None:
    for seed in range(3):
        depth = np.maximum(np.nan_to_num(_awkward_depth(seed), nan=0.0, posinf=0.0), 0.0)
        depth = np.round(depth, 2)  # ties within the neighbourhoods
        smooth = median_3x3(depth, max_step=max_step)
        np.testing.assert_array_equal(smooth, _reference_median_3x3(depth, max_step))


def _reference_graph_pairs(
    node_of_cell: NDArray[np.intp], z: NDArray[np.float64], max_slope: float, lateral_per_m: float
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """The kept and cut neighbour pairs as :func:`surface_graph` found them in NumPy."""
    kept, cut = [], []
    h, w = node_of_cell.shape
    for dr, dc in NEIGHBOUR_OFFSETS:
        c0, c1 = max(0, -dc), w - max(0, dc)
        a = node_of_cell[: h - dr, c0:c1]
        b = node_of_cell[dr:, c0 + dc : c1 + dc]
        both = (a >= 0) & (b >= 0)
        pairs = np.stack([a[both], b[both]], axis=1)
        za, zb = z[pairs[:, 0]], z[pairs[:, 1]]
        smooth = np.abs(za - zb) <= max_slope * math.hypot(dr, dc) * lateral_per_m * (za + zb) / 2
        kept.append(pairs[smooth])
        cut.append(pairs[~smooth])
    return np.concatenate(kept), np.concatenate(cut)


def test_surface_graph_matches_numpy_and_scipy_bit_for_bit() -> None:
    for seed in range(3):
        depth = np.maximum(np.nan_to_num(_awkward_depth(seed), nan=0.0, posinf=0.0), 0.0)
        # Half of it a smooth surface with holes: edges to keep beside edges to cut.
        ramp = 0.6 + 0.0004 * np.arange(40, dtype=np.float32)
        depth[:, :40] = np.where(depth[:, :40] > 0, ramp, 0.0)
        grid = cell_grid(depth, 1)
        graph = surface_graph(grid, CAMERA, max_slope=3.0)
        z = grid.depth_m[grid.depth_m > 0].astype(np.float64)
        lateral_per_m = grid.stride / math.sqrt(CAMERA[0] * CAMERA[1])
        kept, cut = _reference_graph_pairs(graph.node_of_cell, z, 3.0, lateral_per_m)
        np.testing.assert_array_equal(graph.cut_pairs, cut)
        assert len(kept) > 100 and len(cut) > 100  # both kinds are exercised
        heads, tails = np.r_[kept[:, 0], kept[:, 1]], np.r_[kept[:, 1], kept[:, 0]]
        lengths = np.random.default_rng(seed).uniform(0.001, 0.01, len(kept))
        expected = csr_matrix((np.r_[lengths, lengths], (heads, tails)), shape=(len(z),) * 2)
        built = symmetric_edges(kept, lengths, len(z))
        for name in ("indptr", "indices", "data"):
            np.testing.assert_array_equal(getattr(built, name), getattr(expected, name))
        # The graph's own edges join exactly the kept pairs.
        np.testing.assert_array_equal(graph.edges.indptr, expected.indptr)
        np.testing.assert_array_equal(graph.edges.indices, expected.indices)


def test_palm_centre_is_the_exact_largest_inscribed_disc() -> None:
    rng = np.random.default_rng(3)
    depth = np.zeros((40, 50), np.float32)
    depth[5:33, 8:45] = 0.5 + rng.uniform(0, 0.002, (28, 37)).astype(np.float32)
    depth[rng.uniform(size=depth.shape) < 0.05] = 0.0
    graph = surface_graph(cell_grid(depth, 1), CAMERA, max_slope=3.0)
    node, radius = palm_centre(graph, np.ones(len(graph.points_m), bool))
    mask = np.zeros(depth.shape, np.uint8)
    mask[tuple(graph.cells.T)] = 1
    on_cut = np.zeros(len(graph.points_m), bool)
    on_cut[graph.cut_pairs.ravel()] = True
    mask[tuple(graph.cells[on_cut].T)] = 0
    exact = distance_transform_edt(np.pad(mask, 1))[1:-1, 1:-1]
    assert radius == pytest.approx(exact.max(), rel=1e-7)
    assert exact[tuple(graph.cells[node])] == exact.max()


def _hand_like_depth() -> NDArray[np.float32]:
    """A palm with four fingers and a thumb at 0.55 m in front of a wall."""
    depth = np.full((480, 640), 1.6, np.float32)
    depth[250:360, 270:370] = 0.55
    for k, column in enumerate((272, 297, 322, 347)):
        depth[150 + 10 * k : 250, column : column + 18] = 0.54
    depth[300:320, 370:430] = 0.545
    return depth


def test_overlapped_heatmaps_give_the_sequential_detections() -> None:
    model = load_forest(DEFAULT_MODEL_PATH)
    assert model.heatmap is not None
    config = model_detector_config(model)
    depth = _hand_like_depth()
    started = start_heatmaps(depth, CAMERA, model.heatmap).result()
    hand = hand_depth(depth, model, depth_band_m=config.depth_band_m)
    sequential = hand_heatmaps(depth, CAMERA, model.heatmap.heatmaps, hand_depth_m=hand)
    assert started.centre is not None and sequential.centre is not None
    np.testing.assert_array_equal(started.centre, sequential.centre)
    np.testing.assert_array_equal(started.maps, sequential.maps)
    candidates = np.array([[0.0, -0.05, 0.55]])
    common = (depth, CAMERA, model.heatmap, candidates, np.array([2.0]), np.array([0.8]))
    with_started = heatmap_peaks(*common, min_tip_probability=0.75, heatmaps=started)
    plain = heatmap_peaks(*common, min_tip_probability=0.75, hand_depth_m=hand)
    np.testing.assert_array_equal(with_started[0].xyz_m, plain[0].xyz_m)
    np.testing.assert_array_equal(with_started[1], plain[1])


def test_overlapped_heatmaps_centred_on_the_fingers_give_the_sequential_ones() -> None:
    """The network thread waits for the geodesic stage's worker, then crops as the
    sequential path does with the same geodesic candidates."""
    model = load_forest(DEFAULT_MODEL_PATH)
    assert model.heatmap is not None
    config = model_detector_config(model)
    depth = _hand_like_depth()
    hand = hand_depth(depth, model, depth_band_m=config.depth_band_m)
    geodesic = geodesic_candidates(hand, CAMERA)
    assert geodesic.is_finger.sum() >= 4
    with ThreadPoolExecutor(1) as worker:
        future = worker.submit(geodesic_candidates, hand, CAMERA)
        started = start_heatmaps(depth, CAMERA, model.heatmap, geodesic=future).result()
    sequential = hand_heatmaps(
        depth, CAMERA, model.heatmap.heatmaps, hand_depth_m=hand, geodesic=geodesic
    )
    density = hand_heatmaps(depth, CAMERA, model.heatmap.heatmaps, hand_depth_m=hand)
    assert started.centre is not None and sequential.centre is not None
    np.testing.assert_array_equal(started.centre, sequential.centre)
    np.testing.assert_array_equal(started.maps, sequential.maps)
    assert density.centre is not None
    assert np.linalg.norm(started.centre - density.centre) > 0.01  # another rule indeed


@pytest.mark.parametrize("candidates", ["forest", "union"])
def test_detection_with_the_fingers_rule_crops_where_the_geodesic_stage_says(
    candidates: str,
) -> None:
    """Also with the forest's candidates alone, which do not need the geodesic stage
    otherwise: the detector starts it for the crop."""
    model = load_forest(DEFAULT_MODEL_PATH)
    assert model.heatmap is not None
    config = replace(
        model_detector_config(model),
        candidates=candidates,
        heatmap_centre="fingers",
        heatmap_min_probability=0.01,
    )
    depth = _hand_like_depth()
    found = detect_fingertips(depth, CAMERA, model, config=config)
    verified = verified_candidates(depth, CAMERA, model, config=config)
    assert verified.geodesic is not None and verified.hand_depth_m is not None
    heatmaps = hand_heatmaps(depth, CAMERA, model.heatmap.heatmaps, geodesic=verified.geodesic)
    peaks, probability = heatmap_peaks(
        depth,
        CAMERA,
        model.heatmap,
        verified.candidates.positions_m,
        verified.candidates.confidences,
        verified.probability,
        min_tip_probability=config.min_tip_probability,
        heatmaps=heatmaps,
    )
    from_heat = [d for d in found if d.source == "heatmap"]
    assert from_heat
    for detection in from_heat:
        k = np.argmin(np.linalg.norm(peaks.xyz_m - detection_points([detection]), axis=1))
        np.testing.assert_allclose(peaks.xyz_m[k], detection_points([detection])[0], atol=1e-6)
        assert probability[k] >= config.heatmap_min_probability


def test_no_object_in_view_gives_no_heatmaps() -> None:
    model = load_forest(DEFAULT_MODEL_PATH)
    assert model.heatmap is not None
    empty = start_heatmaps(np.zeros((48, 64), np.float32), CAMERA, model.heatmap).result()
    assert empty.centre is None and empty.maps is None
