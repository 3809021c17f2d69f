"""Inverted lists: every image in one list, each list's exact mean distance, probing,
and a search that scans every list equal to the exhaustive one."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from glovedb import _list_kernels
from glovedb.chamfer import chamfer_maps
from glovedb.database import GloveDatabase
from glovedb.distinct_images import distinct_tiny_images
from glovedb.inverted_lists import (
    InvertedLists,
    inverted_lists,
    list_distances,
    probed_lists,
)
from glovedb.search import cascade_search, pack_tiny_images, tiny_image_distances

pytestmark = pytest.mark.gl  # builds a database with the renderer


@pytest.fixture(scope="module")
def images(open_pinch_power_database) -> dict[int, np.ndarray]:
    """DB_open+pinch+power's tiny images: 2,268 entries of rendered hands."""
    with GloveDatabase(open_pinch_power_database) as database:
        return {size: database.images(size) for size in database.resolutions}


@pytest.fixture(scope="module")
def lists(images) -> InvertedLists:
    return inverted_lists(pack_tiny_images(images[8]))


def query_of(images: dict[int, np.ndarray], entry: int) -> dict[int, np.ndarray]:
    """An entry's images with every fourth glove pixel dropped: near it, not equal."""
    query = {}
    for size, stack in images.items():
        image = stack[entry].copy()
        glove = np.flatnonzero(image)
        image.flat[glove[::4]] = 0
        query[size] = image
    return query


def test_every_image_is_in_one_list_with_its_entries(images, lists):
    assert lists.num_entries == len(images[8]) and lists.num_lists > 1
    np.testing.assert_array_equal(np.sort(lists.images.entry_ids), np.arange(len(images[8])))
    # Image i of the lists is the image of the entry it holds.
    shown = images[8][lists.images.entry_ids]
    np.testing.assert_array_equal(pack_tiny_images(shown).codes, lists.images.images.codes)
    assert np.all(np.diff(lists.list_offsets) >= 1) and lists.nbytes > 0


def test_a_lists_mean_is_its_images_mean_distance(images, lists):
    maps = chamfer_maps(images[8][100])
    errors = tiny_image_distances(maps, lists.images.images)
    mean, spread = list_distances(lists, maps)
    offsets = lists.list_offsets
    for index in (0, 1, lists.num_lists // 2, lists.num_lists - 1):
        members = errors[offsets[index] : offsets[index + 1]]
        assert mean[index] == pytest.approx(members.mean(), rel=1e-4)
        # The spread: the components' variances, as if they varied independently.
        labels = images[8][lists.images.entry_ids[offsets[index] : offsets[index + 1]]]
        u = np.stack([labels == c for c in range(1, 11)], axis=1).reshape(len(labels), -1)
        u = u / np.count_nonzero(labels.reshape(len(labels), -1), axis=1)[:, None]
        expected = np.sqrt(u.var(axis=0) @ maps.reshape(-1) ** 2)
        assert spread[index] == pytest.approx(expected, rel=1e-3, abs=1e-6)


def test_probing_covers_the_share_and_the_stage_k(images, lists):
    maps = chamfer_maps(images[8][7])
    for share, k in ((0.05, 10), (0.05, 1500), (0.3, 10)):
        probed = probed_lists(dataclasses.replace(lists, probe_share=share), maps, k)
        assert np.all(np.diff(probed) > 0)
        held = np.sum(lists.list_offsets[probed + 1] - lists.list_offsets[probed])
        assert held >= share * len(images[8]) and held >= k
        assert held < len(images[8])  # not everything
    everything = probed_lists(lists, maps, 10**6)
    np.testing.assert_array_equal(everything, np.arange(lists.num_lists))


@pytest.mark.parametrize("share", [0.01, 0.05, 0.3, 0.6])
def test_probing_takes_the_shortest_prefix_of_the_ranking(images, lists, share):
    """Straight from the definition: all lists ranked by mean less twice the spread
    (ties: lower list first), the fewest of the best that hold the share and k."""
    lists = dataclasses.replace(lists, probe_share=share)
    for entry, k in ((7, 10), (900, 300), (2000, 10)):
        maps = chamfer_maps(images[8][entry])
        mean, spread = list_distances(lists, maps)
        ranked = np.argsort(mean - 2.0 * spread, kind="stable")
        sizes = np.diff(lists.list_offsets)[ranked]
        taken = next(
            n
            for n in range(1, len(ranked) + 1)
            if sizes[:n].sum() >= max(k, share * len(images[8]))
        )
        expected = np.sort(ranked[:taken])
        np.testing.assert_array_equal(probed_lists(lists, maps, k), expected)


def test_the_compiled_prefix_is_the_sorted_one_with_ties():
    """``probe_prefix`` bins the scores instead of sorting them: the same lists as
    sorting by (score, list) and cutting, with many tied scores and a bin holding
    the cut, and every list when no prefix holds enough."""
    rng = np.random.default_rng(5)
    for trial in range(200):
        count = int(rng.integers(1, 300))
        levels = rng.choice([3, 50, 10_000])  # few levels: many ties
        score = (rng.integers(0, levels, count) / levels - 0.3).astype(np.float32)
        images = rng.integers(1, 40, count).astype(np.int64)
        entries = images * rng.integers(1, 3, count)
        wanted = float(rng.uniform(0, 1.1) * images.sum())
        k = int(rng.integers(1, int(1.1 * entries.sum()) + 2))
        ranked = np.argsort(score, kind="stable")
        enough = (np.cumsum(images[ranked]) >= wanted) & (np.cumsum(entries[ranked]) >= k)
        expected = np.zeros(count, bool)
        expected[ranked[: int(np.argmax(enough)) + 1] if enough.any() else ranked] = True
        chosen = np.empty(count, bool)
        _list_kernels.probe_prefix(score, images, entries, wanted, k, chosen)
        np.testing.assert_array_equal(chosen, expected, err_msg=f"trial {trial}")


@pytest.mark.parametrize("repeats", [False, True])
def test_scanning_every_list_is_the_exhaustive_scan(images, repeats):
    entries = np.arange(len(images[8]))
    if repeats:  # as a tiled benchmark: lists of distinct images, several entries each
        entries = np.arange(3 * len(images[8])) % len(images[8])
    stage = distinct_tiny_images(images[8], image_of_entry=entries)
    every = dataclasses.replace(inverted_lists(stage), probe_share=1.0)
    packed = pack_tiny_images(images[8][entries])
    for entry in (0, 500, 2000):
        query = query_of(images, entry)
        full = cascade_search(query, {8: packed}, "8:50")
        listed = cascade_search(query, {8: every}, "8:50")
        np.testing.assert_array_equal(listed.entry_ids, full.entry_ids)
        np.testing.assert_array_equal(listed.errors, full.errors)


def damaged(images: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Images with a tenth of their glove pixels dropped and 3 % given another colour."""
    out = images.copy()
    glove = out > 0
    out[glove & (rng.random(out.shape) < 0.1)] = 0
    recolour = glove & (rng.random(out.shape) < 0.03)
    out[recolour] = rng.integers(1, 11, int(recolour.sum()))
    return out


def test_the_default_share_finds_the_exhaustive_nearest_in_a_dense_database(images):
    # Lists serve large databases, where every image has close neighbours: 8 damaged
    # copies of each of DB_open+pinch+power's images stand in for one.
    rng = np.random.default_rng(5)
    dense = damaged(np.repeat(images[8], 8, axis=0), rng)
    packed = pack_tiny_images(dense)
    lists = inverted_lists(packed)
    queries = damaged(images[8][::50], rng)
    same = 0
    for query in queries:
        full = cascade_search({8: query}, {8: packed}, "8:20")
        found = cascade_search({8: query}, {8: lists}, "8:20")
        same += found.entry_ids[0] == full.entry_ids[0]
        assert found.errors[0] >= full.errors[0]  # never better than the exhaustive scan
    assert same >= 0.95 * len(queries)


def test_lists_serve_the_first_stage_only_and_check_their_arrays(images, lists):
    query = query_of(images, 3)
    with pytest.raises(ValueError, match="first stage only"):
        cascade_search(query, {8: pack_tiny_images(images[8]), 16: lists}, "8:20,16:3")
    with pytest.raises(ValueError, match="probe_share"):
        dataclasses.replace(lists, probe_share=0.0)
    beyond = lists.list_offsets.copy()
    beyond[-1] += 1
    with pytest.raises(ValueError, match="list_offsets"):
        dataclasses.replace(lists, list_offsets=beyond)
