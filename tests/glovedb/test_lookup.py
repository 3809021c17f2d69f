"""Searching a built database: entries find themselves, results carry poses."""

import numpy as np
import pytest

from glovedb.database import GloveDatabase
from glovedb.lookup import DatabaseIndex

pytestmark = pytest.mark.gl  # builds a database with the renderer


def test_every_entry_queried_against_its_own_database_returns_itself(small_database):
    with GloveDatabase(small_database) as database:
        images = {size: database.images(size) for size in database.resolutions}
        postures = database.postures
        rotations = database.entry_rotations
    with DatabaseIndex(small_database) as index:
        for entry in range(0, 72, 5):
            query = {size: stack[entry] for size, stack in images.items()}
            found = index.lookup(query, "8:30,16:10,32:3")
            assert found.search.errors[0] == 0.0
            # Identical images (symmetric views) may tie; the entry is among the ties.
            ties = found.search.entry_ids[found.search.errors == 0.0]
            assert entry in ties or np.array_equal(images[32][ties[0]], images[32][entry])
            assert found.pose.valid
            best = found.search.entry_ids[0]
            np.testing.assert_allclose(found.posture_ids[0], best // 36)
            np.testing.assert_allclose(
                index.entry_postures(found.search.entry_ids[:1])[0], postures[best // 36]
            )
            np.testing.assert_allclose(
                index.entry_rotations(found.search.entry_ids[:1])[0], rotations[best]
            )


def test_tiling_repeats_entries_and_maps_rows_back(small_database):
    with DatabaseIndex(small_database, tile_to=200) as index:
        assert index.entries == 200 and index.base_entries == 72
        np.testing.assert_array_equal(index.base_ids(np.array([0, 72, 199])), [0, 0, 55])
        np.testing.assert_array_equal(index.rows(32, np.array([73])), index.rows(32, np.array([1])))
        assert index.packed(8).num_entries == 200


def _refuse_mapping(*args: object, **kwargs: object) -> None:
    raise OSError("this file system cannot map files")


@pytest.mark.parametrize("how", ["populated", "plain", "read"])  # mapped / read whole
def test_rows_read_from_the_file_equal_the_stored_images(small_database, monkeypatch, how):
    if how == "plain":  # as for row data too large to enter at once
        monkeypatch.setattr("glovedb.lookup._POPULATE_AT_MOST", 0)
    if how == "read":
        monkeypatch.setattr("glovedb.lookup.mmap.mmap", _refuse_mapping)
    with GloveDatabase(small_database) as database:
        stored = database.images(32)
    ids = np.array([71, 3, 3, 40, 0])  # any order, repeats allowed
    with DatabaseIndex(small_database) as index:
        np.testing.assert_array_equal(index.rows(32, ids), stored[ids])
        assert index.rows(32, np.array([], np.int64)).shape == (0, 32, 32)


def test_bad_cascades_are_rejected(small_database):
    with DatabaseIndex(small_database) as index:
        query = {size: np.ones((size, size), np.uint8) for size in (8, 16, 32)}
        with pytest.raises(ValueError):
            index.search(query, "64:3")
        with pytest.raises(ValueError):
            index.search(query, "16:10,8:3")


def test_default_cascade_fits_the_database_sizes():
    from glovedb.lookup import DEFAULT_CASCADE, default_cascade

    assert default_cascade((8, 16, 32, 64)) == DEFAULT_CASCADE
    assert default_cascade((8, 16, 32)) == "8:1500,16:100,32:3"
    assert default_cascade((16, 64)) == "16:1500,64:3"
    assert default_cascade((8,)) == "8:3"
