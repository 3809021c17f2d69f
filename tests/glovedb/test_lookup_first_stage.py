"""DatabaseIndex's first stage (distinct images or every entry, the same lookups) and
what a large database keeps in the cache folder between runs."""

import os

import numpy as np
import pytest
from helpers import write_format_1

from glovedb.database import GloveDatabase
from glovedb.distinct_images import DistinctTinyImages
from glovedb.lookup import DatabaseIndex
from glovedb.search import PackedTinyImages

pytestmark = pytest.mark.gl  # builds a database with the renderer


def test_every_first_stage_gives_the_same_lookups(small_database):
    with GloveDatabase(small_database) as database:
        images = {size: database.images(size) for size in database.resolutions}
    queries = [{size: stack[entry] for size, stack in images.items()} for entry in (0, 9, 50)]
    results = {}
    for first_stage in ("scan", "distinct", "auto"):
        with DatabaseIndex(small_database, tile_to=500, first_stage=first_stage) as index:
            results[first_stage] = [index.search(q, "8:40,16:10,32:3") for q in queries]
    for first_stage in ("distinct", "auto"):
        for found, reference in zip(results[first_stage], results["scan"], strict=True):
            np.testing.assert_array_equal(found.entry_ids, reference.entry_ids)
            np.testing.assert_array_equal(found.errors, reference.errors)


def test_auto_scans_distinct_images_only_when_they_repeat(small_database):
    with DatabaseIndex(small_database, tile_to=500) as tiled:
        assert isinstance(tiled.first_stage_images(8), DistinctTinyImages)
        assert tiled.first_stage_images(8).num_entries == 500
    with DatabaseIndex(small_database, first_stage="scan") as plain:
        assert isinstance(plain.first_stage_images(8), PackedTinyImages)
    with pytest.raises(ValueError, match="first_stage"):
        DatabaseIndex(small_database, first_stage="tree")  # type: ignore[arg-type]


def test_a_large_first_stage_is_kept_between_runs(small_database, tmp_path, monkeypatch):
    from glovedb.stage_cache import CACHE_AT_LEAST, stage_path

    monkeypatch.setenv("GLOVE_CACHE", str(tmp_path))
    entries = CACHE_AT_LEAST  # tiled: the smallest database that is cached
    path = stage_path(small_database, size=8, entries=entries, choice="scan")
    with DatabaseIndex(small_database, tile_to=entries, first_stage="scan") as index:
        made = index.first_stage_images(8)
        assert path.is_file()
        query = {size: index.rows(size, np.array([123]))[0] for size in index.resolutions}
        expected = index.search(query, "8:40,16:10,32:3")

    def refuse(self, size):
        raise AssertionError("made again instead of loaded")

    with monkeypatch.context() as patch:  # a second run loads it, and finds the same
        patch.setattr(DatabaseIndex, "_make_first_stage", refuse)
        with DatabaseIndex(small_database, tile_to=entries, first_stage="scan") as index:
            loaded = index.first_stage_images(8)
            found = index.search(query, "8:40,16:10,32:3")
    assert isinstance(loaded, PackedTinyImages) and isinstance(made, PackedTinyImages)
    np.testing.assert_array_equal(loaded.codes, made.codes)
    np.testing.assert_array_equal(loaded.glove_pixels, made.glove_pixels)
    np.testing.assert_array_equal(found.entry_ids, expected.entry_ids)
    np.testing.assert_array_equal(found.errors, expected.errors)

    path.write_bytes(b"not an npz")  # a damaged entry is made again and replaced
    with DatabaseIndex(small_database, tile_to=entries, first_stage="scan") as index:
        np.testing.assert_array_equal(index.first_stage_images(8).codes, made.codes)
    with DatabaseIndex(small_database, tile_to=entries, first_stage="distinct") as index:
        distinct = index.first_stage_images(8)  # another choice, another entry
    assert isinstance(distinct, DistinctTinyImages) and distinct.num_entries == entries
    assert len(list(path.parent.glob("*.npz"))) == 2


def test_a_rebuilt_database_replaces_its_cache_entry(small_database, tmp_path, monkeypatch):
    import glovedb.lookup
    from glovedb.stage_cache import stage_path

    monkeypatch.setenv("GLOVE_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(glovedb.lookup, "CACHE_AT_LEAST", 1)  # the small file counts as large
    copy = tmp_path / "copy.h5"
    copy.write_bytes(small_database.read_bytes())
    with DatabaseIndex(copy) as index:
        entries = index.entries
    before = stage_path(copy, size=8, entries=entries, choice="auto")
    assert before.is_file()
    stat = copy.stat()  # "rebuilt": a newer modification time
    os.utime(copy, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1_000_000_000))
    after = stage_path(copy, size=8, entries=entries, choice="auto")
    assert after != before
    with DatabaseIndex(copy) as index:
        index.first_stage_images(8)
    assert after.is_file() and not before.exists()  # one copy per database, not per build
    assert stage_path(copy, size=16, entries=entries, choice="auto") != after


def test_decoded_rows_of_a_large_database_are_kept_in_the_cache(
    small_database, tmp_path, monkeypatch
):
    """Rows that cannot be mapped (format 1's compressed sizes, 8 and 16) are decoded
    whole and kept; those stored in one piece (32) are mapped from the file."""
    import glovedb.lookup
    from glovedb.stage_cache import stage_path

    monkeypatch.setenv("GLOVE_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(glovedb.lookup, "CACHE_AT_LEAST", 1)  # the small file counts as large
    old = tmp_path / "format1.h5"
    write_format_1(small_database, old)
    ids = np.array([5, 77, 3, 5])
    with DatabaseIndex(old) as index:
        entries = index.entries
        first = {size: index.rows(size, ids) for size in index.resolutions}
    with DatabaseIndex(small_database) as index:
        for size, rows in first.items():
            np.testing.assert_array_equal(rows, index.rows(size, ids))
    for size in (8, 16, 32):
        kept = stage_path(old, size=size, entries=entries, choice="rows").is_file()
        assert kept == (size != 32)

    damaged = stage_path(old, size=16, entries=entries, choice="rows")
    damaged.write_bytes(b"\x93NUMPY not rows")  # decoded again, and kept again
    with DatabaseIndex(old) as index:
        np.testing.assert_array_equal(index.rows(16, ids), first[16])
    kept = damaged.read_bytes()
    damaged.write_bytes(kept[:-100])  # cut short: decoded again too
    with DatabaseIndex(old) as index:
        np.testing.assert_array_equal(index.rows(16, ids), first[16])
    assert damaged.read_bytes() == kept

    def refuse(self, size):
        raise AssertionError("decoded again instead of read back")

    monkeypatch.setattr(GloveDatabase, "images", refuse)
    with DatabaseIndex(old, resident_sizes=()) as index:
        for size, rows in first.items():
            np.testing.assert_array_equal(index.rows(size, ids), rows)


def test_rows_kept_by_older_versions_are_deleted_once_rows_are_mapped(
    small_database, tmp_path, monkeypatch
):
    """Format 2's rows are mapped, no longer decoded and kept: what older versions kept
    for them (256 MB at 16 x 16 for a million entries) is deleted, every version."""
    import glovedb.lookup
    from glovedb.stage_cache import stage_path

    monkeypatch.setenv("GLOVE_CACHE", str(tmp_path))
    monkeypatch.setattr(glovedb.lookup, "CACHE_AT_LEAST", 1)  # the small file counts as large
    with DatabaseIndex(small_database) as index:
        kept = stage_path(small_database, size=16, entries=index.entries, choice="rows")
        older = kept.with_name(kept.name.split("-")[0] + "-0123456789abcdef.npy")
        other = stage_path(small_database, size=32, entries=index.entries, choice="rows")
        for path in (kept, older, other):
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(b"decoded rows of an older version")
        index.rows(16, np.array([3, 5]))
    assert not kept.exists() and not older.exists()
    assert other.exists()  # 32 x 32 was not read


def test_many_images_are_grouped_into_lists_and_kept_between_runs(
    small_database, tmp_path, monkeypatch
):
    import glovedb.lookup
    from glovedb.inverted_lists import LIST_ARRAYS, InvertedLists

    monkeypatch.setenv("GLOVE_CACHE", str(tmp_path))
    monkeypatch.setattr(glovedb.lookup, "CACHE_AT_LEAST", 1)  # the small file counts as large
    monkeypatch.setattr(glovedb.lookup, "LISTS_AT_LEAST", 50)  # and its 72 images as many
    with DatabaseIndex(small_database) as index:
        made = index.first_stage_images(8)
        query = {size: index.rows(size, np.array([40]))[0] for size in index.resolutions}
        expected = index.search(query, "8:40,16:10,32:3")
    assert isinstance(made, InvertedLists) and made.num_entries == 72
    assert expected.entry_ids[0] == 40 and expected.errors[0] == 0

    def refuse(self, size):
        raise AssertionError("made again instead of loaded")

    monkeypatch.setattr(DatabaseIndex, "_make_first_stage", refuse)
    with DatabaseIndex(small_database) as index:
        loaded = index.first_stage_images(8)
        found = index.search(query, "8:40,16:10,32:3")
    assert isinstance(loaded, InvertedLists)
    for name in LIST_ARRAYS:
        np.testing.assert_array_equal(getattr(loaded, name), getattr(made, name))
    np.testing.assert_array_equal(loaded.images.entry_ids, made.images.entry_ids)
    np.testing.assert_array_equal(loaded.images.images.codes, made.images.images.codes)
    np.testing.assert_array_equal(found.entry_ids, expected.entry_ids)
    np.testing.assert_array_equal(found.errors, expected.errors)
