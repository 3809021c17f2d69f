"""Cascade parsing, the packed scan, the cascaded k-NN search and pose interpolation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from glovedb.chamfer import cell_mean_maps, chamfer_maps, directed_distance
from glovedb.rotations import (
    axis_angle_to_matrix,
    geodesic_angle,
    matrix_to_quaternion,
    quaternion_to_matrix,
    slerp,
    weighted_rotation_average,
)
from glovedb.search import (
    CascadeStage,
    InterpolatedPose,
    SearchResult,
    TinyImageSource,
    cascade_search,
    interpolate_pose,
    pack_tiny_images,
    parse_cascade,
    tiny_image_distances,
)


def hand_like_labels(rng: np.random.Generator, count: int, size: int) -> np.ndarray:
    """Ellipses filled with a 4x4 grid of random colour patches: tiny-image-like blobs."""
    yy, xx = np.mgrid[0:size, 0:size] / (size - 1) * 2 - 1
    centre_y, centre_x = rng.uniform(-0.2, 0.2, (2, count, 1, 1))
    radius_y, radius_x = rng.uniform(0.6, 1.0, (2, count, 1, 1))
    inside = ((yy - centre_y) / radius_y) ** 2 + ((xx - centre_x) / radius_x) ** 2 <= 1
    patches = rng.integers(1, 11, (count, 4, 4), dtype=np.uint8)
    colours = np.repeat(np.repeat(patches, size // 4, 1), size // 4, 2)
    return np.where(inside, colours, 0).astype(np.uint8)


def multi_size_database(rng: np.random.Generator, count: int) -> dict[int, np.ndarray]:
    """The same entries at 8, 16 and 32 pixels (smaller sizes subsampled from 32)."""
    images = hand_like_labels(rng, count, 32)
    return {8: images[:, ::4, ::4].copy(), 16: images[:, ::2, ::2].copy(), 32: images}


def assert_brute_force_top_k(
    result: SearchResult, query: np.ndarray, images: np.ndarray, k: int
) -> None:
    """The result is the k nearest entries by the reference NumPy lookup of m(D, Q).

    The scan sums in another order, so mathematically tied errors may differ by float32
    rounding and swap places: compare errors (rtol 1e-5), not the order of ties.
    """
    reference = directed_distance(images, chamfer_maps(query))
    assert len(np.unique(result.entry_ids)) == k
    np.testing.assert_allclose(result.errors, np.sort(reference)[:k], rtol=1e-5)
    np.testing.assert_allclose(reference[result.entry_ids], result.errors, rtol=1e-5)


# --- parse_cascade -------------------------------------------------------------------


def test_parse_cascade() -> None:
    assert parse_cascade("8:2000, 16:300,64:3", sizes=(8, 16, 32, 64)) == (
        CascadeStage(8, 2000),
        CascadeStage(16, 300),
        CascadeStage(64, 3),
    )
    assert parse_cascade("16:3,64:3") == (CascadeStage(16, 3), CascadeStage(64, 3))


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("", "size:k"),
        ("8", "size:k"),
        ("8:", "size:k"),
        ("a:3", "size:k"),
        ("8:-3", "size:k"),
        ("8:3:1", "size:k"),
        ("8:10,,16:3", "size:k"),
        ("8:0", "positive"),
        ("16:500,8:3", "sizes must increase"),
        ("8:500,8:3", "sizes must increase"),
        ("8:3,16:500", "k must not increase"),
        ("8:500,24:3", "not in the database"),
    ],
)
def test_parse_cascade_rejects_bad_specs(spec: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        parse_cascade(spec, sizes=(8, 16, 32, 64))


def test_parse_cascade_rejects_non_strings() -> None:
    with pytest.raises(TypeError, match="cascade"):
        parse_cascade(8)  # type: ignore[arg-type]


# --- packed scan ---------------------------------------------------------------------


@pytest.mark.parametrize(("size", "group"), [(8, 1), (8, 2), (8, 4), (16, 2), (16, 4), (32, 2)])
def test_packed_scan_equals_numpy_lookup(size: int, group: int) -> None:
    rng = np.random.default_rng(size + group)
    images = hand_like_labels(rng, 300, size)
    images[7] = 0  # an empty entry
    maps = chamfer_maps(hand_like_labels(rng, 1, size)[0])
    packed = pack_tiny_images(images, group=group)
    assert packed.codes.shape == (300, size * size // group)
    errors = tiny_image_distances(maps, packed, workers=1)
    assert errors.dtype == np.float32
    assert errors[7] == np.inf
    # Same sums in a different order: float32 rounding only.
    np.testing.assert_allclose(errors, directed_distance(images, maps), rtol=1e-5)


def test_packed_scan_is_independent_of_threads() -> None:
    rng = np.random.default_rng(3)
    images = hand_like_labels(rng, 70_000, 8)
    maps = chamfer_maps(images[0])
    packed = pack_tiny_images(images)
    np.testing.assert_array_equal(
        tiny_image_distances(maps, packed, workers=1), tiny_image_distances(maps, packed, workers=2)
    )


def test_default_groups_and_bad_groups() -> None:
    assert pack_tiny_images(np.zeros((1, 8, 8), np.uint8)).group == 4
    assert pack_tiny_images(np.zeros((1, 64, 64), np.uint8)).group == 2
    with pytest.raises(ValueError, match="group"):
        pack_tiny_images(np.zeros((1, 8, 8), np.uint8), group=3)
    with pytest.raises(ValueError, match="images"):
        pack_tiny_images(np.zeros((8, 8), np.uint8))


# --- cascade_search ------------------------------------------------------------------


def test_cascade_with_large_k_equals_brute_force() -> None:
    rng = np.random.default_rng(4)
    images = multi_size_database(rng, 1500)
    query = multi_size_database(rng, 1)
    database: dict[int, TinyImageSource] = {
        8: pack_tiny_images(images[8]),
        16: images[16],  # an in-memory array, packed per query
        32: lambda ids: images[32][ids],  # a loader, as the HDF5 reader will give
    }
    result = cascade_search(
        {size: image[0] for size, image in query.items()}, database, "8:1500,16:1500,32:10"
    )
    assert isinstance(result, SearchResult)
    assert result.entry_ids.dtype == np.int64
    assert result.errors.dtype == np.float32
    assert_brute_force_top_k(result, query[32][0], images[32], 10)
    assert len(result.stage_ms) == 3
    assert result.cascade == parse_cascade("8:1500,16:1500,32:10")


@pytest.mark.parametrize("coarse_maps", ["cell_mean", "exact"])
def test_early_stages_rank_by_the_chosen_query_maps(coarse_maps: str) -> None:
    rng = np.random.default_rng(9)
    images = multi_size_database(rng, 400)
    query = {size: stack[0] for size, stack in multi_size_database(rng, 1).items()}
    database = {size: pack_tiny_images(stack) for size, stack in images.items()}
    result = cascade_search(query, database, "8:40,32:40", coarse_maps=coarse_maps)  # type: ignore[arg-type]
    # The last stage is exact Eq. 4.2 over the first stage's 40 survivors, which are
    # the 40 nearest under the early maps: cell means of the 32x32 maps, or the
    # exact maps of the 8x8 query.
    if coarse_maps == "cell_mean":
        early_maps = cell_mean_maps(chamfer_maps(query[32]), 8)
    else:
        early_maps = chamfer_maps(query[8])
    early = directed_distance(images[8], early_maps)
    survivors = np.lexsort((np.arange(len(early)), early))[:40]
    np.testing.assert_array_equal(np.sort(result.entry_ids), np.sort(survivors))
    final = directed_distance(images[32], chamfer_maps(query[32]))
    np.testing.assert_allclose(result.errors, np.sort(final[survivors]), rtol=1e-5)


def test_first_stage_selection_on_a_large_scan_equals_brute_force() -> None:
    rng = np.random.default_rng(5)
    images = hand_like_labels(rng, 100_000, 8)
    query = hand_like_labels(rng, 1, 8)[0]
    packed = pack_tiny_images(images)
    result = cascade_search({8: query}, {8: packed}, "8:300")
    assert_brute_force_top_k(result, query, images, 300)
    # Exactly the first 300 of the scan's own errors ranked by (error, id).
    errors = tiny_image_distances(chamfer_maps(query), packed)
    ranked = np.lexsort((np.arange(len(errors)), errors))
    np.testing.assert_array_equal(result.entry_ids, ranked[:300])


@pytest.mark.parametrize("entry", [0, 17, 499])
def test_entry_queried_against_its_own_database_returns_itself(entry: int) -> None:
    images = multi_size_database(np.random.default_rng(6), 500)
    database = {size: pack_tiny_images(stack) for size, stack in images.items()}
    query = {size: stack[entry] for size, stack in images.items()}
    result = cascade_search(query, database, [CascadeStage(8, 100), CascadeStage(32, 3)])
    assert result.entry_ids[0] == entry
    assert result.errors[0] == 0.0


def test_ties_are_broken_by_lower_id_and_k_is_capped_by_the_database() -> None:
    image = hand_like_labels(np.random.default_rng(7), 1, 8)
    images = np.repeat(image, 5, axis=0)
    result = cascade_search({8: image[0]}, {8: pack_tiny_images(images)}, "8:10")
    np.testing.assert_array_equal(result.entry_ids, np.arange(5))
    np.testing.assert_array_equal(result.errors, 0.0)


def test_cascade_search_rejects_bad_inputs() -> None:
    images = multi_size_database(np.random.default_rng(8), 20)
    packed = {size: pack_tiny_images(stack) for size, stack in images.items()}
    query = {size: stack[0] for size, stack in images.items()}
    with pytest.raises(ValueError, match="no tiny image of size 16"):
        cascade_search({8: query[8]}, packed, "8:5,16:2")
    with pytest.raises(ValueError, match="no glove pixels"):
        cascade_search({8: np.zeros((8, 8), np.uint8)}, packed, "8:5")
    with pytest.raises(ValueError, match=r"query_images\[8\]"):
        cascade_search({8: query[16]}, packed, "8:5")
    with pytest.raises(ValueError, match="must be in memory"):
        cascade_search(query, {8: lambda ids: images[8][ids]}, "8:5")
    with pytest.raises(ValueError, match="different numbers of entries"):
        cascade_search(query, {8: packed[8], 16: images[16][:10]}, "8:5,16:2")
    with pytest.raises(ValueError, match="not in the database"):
        cascade_search(query, packed, "8:5,64:2")
    with pytest.raises(ValueError, match="coarse_maps"):
        cascade_search(query, packed, "8:5,16:2", coarse_maps="blurred")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="loaded"):
        cascade_search(query, {8: packed[8], 16: lambda ids: images[16][:1]}, "8:5,16:2")


# --- rotation average and interpolation ------------------------------------------------


def test_weighted_rotation_average_of_identical_rotations_is_that_rotation() -> None:
    rotation = axis_angle_to_matrix(np.array([0.3, -1.0, 0.5]), 2.5)
    average = weighted_rotation_average(np.stack([rotation] * 4), [0.1, 3.0, 1.0, 0.5])
    np.testing.assert_allclose(average, rotation, atol=1e-12)


@pytest.mark.parametrize("angle", [0.4, 2.0, 3.0])
def test_weighted_rotation_average_of_two_is_the_geodesic_midpoint(angle: float) -> None:
    rotation_a = axis_angle_to_matrix(np.array([1.0, 2.0, -0.5]), 0.7)
    rotation_b = rotation_a @ axis_angle_to_matrix(np.array([0.0, 1.0, 1.0]), angle)
    average = weighted_rotation_average(np.stack([rotation_a, rotation_b]), [2.0, 2.0])
    midpoint = quaternion_to_matrix(
        slerp(matrix_to_quaternion(rotation_a), matrix_to_quaternion(rotation_b), 0.5)
    )
    np.testing.assert_allclose(average, midpoint, atol=1e-9)
    np.testing.assert_allclose(geodesic_angle(rotation_a, average), angle / 2, atol=1e-9)
    np.testing.assert_allclose(geodesic_angle(average, rotation_b), angle / 2, atol=1e-9)


def test_weighted_rotation_average_rejects_bad_weights() -> None:
    rotations = np.stack([np.eye(3)] * 2)
    with pytest.raises(ValueError, match="weights"):
        weighted_rotation_average(rotations, [1.0, -1.0])
    with pytest.raises(ValueError, match="weights"):
        weighted_rotation_average(rotations, [0.0, 0.0])
    with pytest.raises(ValueError, match="weights"):
        weighted_rotation_average(rotations, [1.0])


def test_interpolate_pose_weights_by_inverse_error() -> None:
    postures = np.stack([np.zeros(20), np.ones(20), np.full(20, 5.0)])
    rotations = np.stack([np.eye(3), np.eye(3), np.eye(3)])
    errors = np.array([1.0, 3.0, np.inf], np.float32)
    pose = interpolate_pose(errors, postures, rotations, epsilon_px=1.0, power=1.0)
    assert isinstance(pose, InterpolatedPose)
    assert pose.valid
    # weights 1/2 and 1/4, normalised: 2/3 and 1/3; the infinite error gets none
    np.testing.assert_allclose(pose.weights, [2 / 3, 1 / 3, 0.0], rtol=1e-12)
    np.testing.assert_allclose(pose.posture_rad, np.full(20, 1 / 3), rtol=1e-12)
    np.testing.assert_allclose(pose.rotation, np.eye(3), atol=1e-12)
    # By default the squares: 1/4 and 1/16, normalised 4/5 and 1/5.
    squared = interpolate_pose(errors, postures, rotations, epsilon_px=1.0)
    np.testing.assert_allclose(squared.weights, [4 / 5, 1 / 5, 0.0], rtol=1e-12)
    with pytest.raises(ValueError, match="power"):
        interpolate_pose(errors, postures, rotations, power=0.0)


def test_interpolate_pose_of_an_exact_match_is_nearly_that_pose() -> None:
    rotations = np.stack([axis_angle_to_matrix(np.array([0.0, 0.0, 1.0]), a) for a in (0.0, 1.0)])
    pose = interpolate_pose([0.0, 1.0], np.stack([np.zeros(20), np.ones(20)]), rotations)
    assert pose.weights[0] > 0.99
    assert geodesic_angle(pose.rotation, rotations[0]) < math.radians(1.0)


def test_interpolate_pose_without_finite_errors_is_invalid() -> None:
    pose = interpolate_pose([np.inf, np.inf], np.zeros((2, 20)), np.stack([np.eye(3)] * 2))
    assert not pose.valid
    assert np.all(np.isnan(pose.posture_rad))
    assert np.all(np.isnan(pose.rotation))
    with pytest.raises(ValueError, match="postures_rad"):
        interpolate_pose([1.0, 2.0], np.zeros((3, 20)), np.stack([np.eye(3)] * 2))
    with pytest.raises(ValueError, match="errors"):
        interpolate_pose([-1.0], np.zeros((1, 20)), np.eye(3)[None])


def test_an_empty_database_gives_an_empty_result() -> None:
    query = hand_like_labels(np.random.default_rng(9), 1, 8)[0]
    empty = pack_tiny_images(np.zeros((0, 8, 8), np.uint8))
    result = cascade_search({8: query}, {8: empty}, "8:5")
    assert result.entry_ids.shape == (0,)
    assert result.errors.shape == (0,)


@pytest.mark.parametrize("k", [1, 300, 2000, 50_000])
def test_selection_over_scanned_ranges_equals_selection_over_their_positions(k: int) -> None:
    from glovedb.distinct_images import DistinctTinyImages, range_positions
    from glovedb.packed_images import pack_tiny_images
    from glovedb.search import _smallest_entries, _smallest_in_ranges

    rng = np.random.default_rng(5)
    images = 40_000
    distinct = DistinctTinyImages(
        images=pack_tiny_images(np.zeros((images, 8, 8), np.uint8)),
        entry_ids=rng.permutation(images).astype(np.int64),  # one entry per image
        offsets=np.arange(images + 1, dtype=np.int64),
    )
    lengths = rng.integers(1, 40, size=800).astype(np.int64)
    starts = np.sort(rng.choice(images - 40, size=800, replace=False)).astype(np.int64)
    scanned = int(lengths.sum())
    # Few distinct values: many ties, broken by the entry id.
    errors = rng.integers(0, 50, size=scanned).astype(np.float32)
    expected = _smallest_entries(distinct, errors, k, range_positions(starts, lengths))
    got = _smallest_in_ranges(errors, distinct.entry_ids, starts, lengths, k)
    np.testing.assert_array_equal(got[0], expected[0])
    np.testing.assert_array_equal(got[1], expected[1])
    assert len(got[0]) == min(k, scanned)


def test_the_candidates_order_is_error_then_id_as_lexsort_gives():
    """One uint64 key per candidate (the float's bits, then the id) sorts exactly as
    ``np.lexsort`` on the two keys, for negative, zero, tiny and infinite values, and
    gives them back."""
    from glovedb._ordering import order_key, split_keys, value_id_order

    rng = np.random.default_rng(5)
    special = np.array([-np.inf, -2.5, -1e-30, -0.0, 0.0, 1e-45, 1.0, 3.25, np.inf], np.float32)
    for _ in range(50):
        count = int(rng.integers(1, 2000))
        values = np.where(
            rng.random(count) < 0.5,
            rng.choice(special, count),
            rng.normal(size=count).astype(np.float32),
        ).astype(np.float32)
        ids = rng.permutation(3 * count)[:count]
        expected = np.lexsort((ids, values + np.float32(0.0)))
        np.testing.assert_array_equal(value_id_order(values, ids), expected)
        # The compiled keys sort the same way and give back their ids and values.
        keys = np.array([order_key(v, i) for v, i in zip(values, ids, strict=True)], np.uint64)
        back_ids, back_values = split_keys(np.sort(keys))
        np.testing.assert_array_equal(back_ids, ids[expected])
        np.testing.assert_array_equal(back_values, values[expected] + np.float32(0.0))
