"""DatabaseIndex's first stage: distinct images or every entry, the same lookups."""

import numpy as np
import pytest

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
