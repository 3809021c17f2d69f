"""Distinct tiny images: grouping entries, and a first stage that equals the full scan."""

from __future__ import annotations

import numpy as np
import pytest

from glovedb.distinct_images import (
    DistinctTinyImages,
    _group_rows,
    distinct_image_count,
    distinct_tiny_images,
)
from glovedb.search import cascade_search, pack_tiny_images


def blob_images(rng: np.random.Generator, count: int, size: int, colours: int) -> np.ndarray:
    """Random glove pixels (about half) of ``colours`` classes: few colours, many ties."""
    glove = rng.random((count, size, size)) < 0.5
    return np.where(glove, rng.integers(1, colours + 1, (count, size, size)), 0).astype(np.uint8)


def assert_same_first_stage(
    query: np.ndarray, images: np.ndarray, distinct: DistinctTinyImages, k: int
) -> None:
    """Distinct images give the full scan's entries, errors and order (exactly)."""
    full = cascade_search({8: query}, {8: pack_tiny_images(images)}, f"8:{k}")
    grouped = cascade_search({8: query}, {8: distinct}, f"8:{k}")
    np.testing.assert_array_equal(grouped.entry_ids, full.entry_ids)
    np.testing.assert_array_equal(grouped.errors, full.errors)
    assert grouped.entry_ids.dtype == np.int64 and grouped.errors.dtype == np.float32


# --- grouping --------------------------------------------------------------------------


def test_distinct_image_count_counts_what_grouping_finds() -> None:
    rng = np.random.default_rng(4)
    images = blob_images(rng, 50, 8, 3)[rng.integers(0, 50, 400)]
    assert distinct_image_count(images) == distinct_tiny_images(images).num_images
    assert distinct_image_count(images) == len(np.unique(images.reshape(400, -1), axis=0))


def test_entries_are_grouped_by_identical_image() -> None:
    a, b, c = blob_images(np.random.default_rng(0), 3, 8, 10)
    images = np.stack([a, b, a, c, b, a])
    distinct = distinct_tiny_images(images)
    assert distinct.num_images == 3 and distinct.num_entries == 6
    groups = [
        distinct.entry_ids[start:stop].tolist()
        for start, stop in zip(distinct.offsets[:-1], distinct.offsets[1:], strict=True)
    ]
    assert sorted(groups) == [[0, 2, 5], [1, 4], [3]]  # each group ascending
    for group, codes in zip(groups, distinct.images.codes, strict=True):
        np.testing.assert_array_equal(codes, pack_tiny_images(images[group[:1]]).codes[0])
    assert distinct.offsets.dtype == np.int64 and distinct.entry_ids.dtype == np.int64
    assert distinct.nbytes > 0


def test_entries_may_share_images_and_unshown_images_are_dropped() -> None:
    images = blob_images(np.random.default_rng(1), 5, 8, 10)
    distinct = distinct_tiny_images(images, image_of_entry=[3, 1, 3, 3, 1])
    assert distinct.num_images == 2 and distinct.num_entries == 5
    assert sorted(np.diff(distinct.offsets).tolist()) == [2, 3]


def test_hash_collisions_never_merge_different_images() -> None:
    rows = blob_images(np.random.default_rng(2), 6, 4, 2).reshape(6, 16)
    rows[4] = rows[1]
    group_of_row, first_rows = _group_rows(rows, np.zeros(6, np.uint64))  # all collide
    assert len(first_rows) == 5
    assert group_of_row[4] == group_of_row[1]
    assert len(set(group_of_row[[0, 1, 2, 3, 5]].tolist())) == 5


def test_grouping_edge_cases_and_bad_input() -> None:
    empty = distinct_tiny_images(np.zeros((0, 8, 8), np.uint8))
    assert empty.num_images == 0 and empty.num_entries == 0
    assert empty.offsets.tolist() == [0]
    with pytest.raises(ValueError, match="image_of_entry"):
        distinct_tiny_images(np.zeros((2, 8, 8), np.uint8), image_of_entry=[0, 2])
    with pytest.raises(ValueError, match="images"):
        distinct_tiny_images(np.full((2, 8, 8), 11, np.uint8))
    with pytest.raises(ValueError, match="offsets"):
        DistinctTinyImages(
            images=pack_tiny_images(np.zeros((1, 8, 8), np.uint8)),
            entry_ids=np.arange(2),
            offsets=np.array([0, 1]),
        )
    with pytest.raises(ValueError, match="at least one entry"):
        DistinctTinyImages(
            images=pack_tiny_images(np.zeros((2, 8, 8), np.uint8)),
            entry_ids=np.arange(2),
            offsets=np.array([0, 2, 2]),
        )


# --- the first stage -------------------------------------------------------------------


@pytest.mark.parametrize("k", [1, 3, 40, 399, 400, 1000])
def test_tiled_entries_give_the_full_scans_result(k: int) -> None:
    rng = np.random.default_rng(k)
    base = blob_images(rng, 37, 8, 3)
    base[5] = 0  # an entry without glove pixels: error inf
    images = np.resize(base, (400, 8, 8))
    distinct = distinct_tiny_images(base, image_of_entry=np.arange(400) % 37)
    for query in blob_images(rng, 5, 8, 3):
        assert_same_first_stage(query, images, distinct, k)


@pytest.mark.parametrize("k", [1, 7, 50, 300])
def test_random_entries_with_few_repeats_give_the_full_scans_result(k: int) -> None:
    rng = np.random.default_rng(100 + k)
    images = blob_images(rng, 300, 8, 10)
    images[rng.integers(0, 300, 40)] = images[rng.integers(0, 300, 40)]
    distinct = distinct_tiny_images(images)
    assert distinct.num_images < 300
    for query in blob_images(rng, 5, 8, 10):
        assert_same_first_stage(query, images, distinct, k)


def test_one_entry_and_no_entries() -> None:
    rng = np.random.default_rng(7)
    query = blob_images(rng, 1, 8, 10)[0]
    one = blob_images(rng, 1, 8, 10)
    assert_same_first_stage(query, one, distinct_tiny_images(one), 5)
    none = np.zeros((0, 8, 8), np.uint8)
    result = cascade_search({8: query}, {8: distinct_tiny_images(none)}, "8:5")
    assert result.entry_ids.shape == (0,) and result.errors.shape == (0,)


def test_later_stages_take_the_distinct_first_stages_candidates() -> None:
    rng = np.random.default_rng(8)
    fine = np.resize(blob_images(rng, 50, 16, 4), (200, 16, 16))
    coarse = fine[:, ::2, ::2].copy()
    query = {8: blob_images(rng, 1, 8, 4)[0], 16: blob_images(rng, 1, 16, 4)[0]}
    full = cascade_search(query, {8: pack_tiny_images(coarse), 16: fine}, "8:60,16:5")
    grouped = cascade_search(query, {8: distinct_tiny_images(coarse), 16: fine}, "8:60,16:5")
    np.testing.assert_array_equal(grouped.entry_ids, full.entry_ids)
    np.testing.assert_array_equal(grouped.errors, full.errors)


def test_distinct_images_serve_only_a_first_stage_of_their_size() -> None:
    rng = np.random.default_rng(9)
    images = {8: blob_images(rng, 10, 8, 10), 16: blob_images(rng, 10, 16, 10)}
    query = {8: images[8][0], 16: images[16][0]}
    with pytest.raises(ValueError, match="first stage only"):
        cascade_search(
            query, {8: pack_tiny_images(images[8]), 16: distinct_tiny_images(images[16])},
            "8:5,16:2",
        )  # fmt: skip
    with pytest.raises(ValueError, match="holds 16x16"):
        cascade_search(query, {8: distinct_tiny_images(images[16])}, "8:5")


def test_ties_across_images_are_broken_by_entry_id() -> None:
    rng = np.random.default_rng(10)
    base = blob_images(rng, 60, 8, 3)
    base[:30] = (base[:30] > 0).astype(np.uint8)  # colour 1 only: error 0 for the query
    images = np.resize(base, (600, 8, 8))
    distinct = distinct_tiny_images(base, image_of_entry=np.arange(600) % 60)
    query = np.ones((8, 8), np.uint8)
    for k in (1, 5, 29, 31, 299, 301):
        assert_same_first_stage(query, images, distinct, k)


def test_many_entries_give_the_full_scans_result() -> None:
    rng = np.random.default_rng(11)
    base = blob_images(rng, 700, 8, 10)
    images = np.resize(base, (50_000, 8, 8))  # more than the selection's sample
    distinct = distinct_tiny_images(base, image_of_entry=np.arange(50_000) % 700)
    for query in blob_images(rng, 3, 8, 10):
        for k in (3, 2000):
            assert_same_first_stage(query, images, distinct, k)
