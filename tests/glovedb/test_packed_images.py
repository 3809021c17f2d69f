"""The packed layout: codes of pixel groups and the per-query table of their distances."""

from __future__ import annotations

import numpy as np
import pytest

from glovedb.packed_images import code_table, pack_tiny_images


@pytest.mark.parametrize(("size", "group"), [(4, 1), (4, 2), (4, 4), (8, 4), (16, 2)])
def test_code_table_sums_the_distances_of_the_codes_labels(size: int, group: int) -> None:
    rng = np.random.default_rng(size * group)
    maps = rng.uniform(0, 5, (10, size, size)).astype(np.float32)
    table = code_table(maps, group)
    assert table.shape == (size * size // group, 11**group) and table.dtype == np.float32
    per_label = np.concatenate([np.zeros((1, size * size), np.float32), maps.reshape(10, -1)])
    positions = rng.integers(0, len(table), 50)
    codes = rng.integers(0, 11**group, 50)
    for position, code in zip(positions, codes, strict=True):
        labels = [(code // 11 ** (group - 1 - i)) % 11 for i in range(group)]
        pixels = position * group + np.arange(group)
        expected = per_label[labels, pixels].sum()
        np.testing.assert_allclose(table[position, code], expected, rtol=1e-6)


def test_packed_codes_index_the_table() -> None:
    rng = np.random.default_rng(1)
    images = rng.integers(0, 11, (20, 8, 8)).astype(np.uint8)
    maps = rng.uniform(0, 5, (10, 8, 8)).astype(np.float32)
    packed = pack_tiny_images(images)
    per_label = np.concatenate([np.zeros((1, 64), np.float32), maps.reshape(10, -1)])
    expected = per_label[images.reshape(20, 64), np.arange(64)].sum(axis=1)
    table = code_table(maps, packed.group)
    found = table[np.arange(16), packed.codes].sum(axis=1)
    np.testing.assert_allclose(found, expected, rtol=1e-5)
    assert packed.nbytes == 20 * 16 * 2 + 20 * 2


@pytest.mark.parametrize(("size", "group"), [(4, 1), (8, 2), (8, 4), (16, 2)])
def test_unpacking_gives_back_the_packed_labels(size: int, group: int) -> None:
    from glovedb.packed_images import unpack_tiny_images

    images = np.random.default_rng(size + group).integers(0, 11, (30, size, size), np.uint8)
    unpacked = unpack_tiny_images(pack_tiny_images(images, group=group))
    assert unpacked.dtype == np.uint8
    np.testing.assert_array_equal(unpacked, images)
