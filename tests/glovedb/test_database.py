"""The database file: the row code of format 2, reading format 1, refusing damage."""

import functools
import shutil

import h5py
import numpy as np
import pytest
from helpers import write_format_1

from glovedb._row_codec import _running_sums, decode_rows, encode_rows, score_rows
from glovedb.chamfer import chamfer_maps, directed_distance
from glovedb.database import GloveDatabase, RowLayout, read_rows, score_file_rows
from glovedb.lookup import DatabaseIndex


def _round_trip(images):
    data, lengths = encode_rows(images)
    stops = np.cumsum(lengths)
    decoded, damaged, reason = decode_rows(data, stops - lengths, stops, images.shape[1])
    assert (damaged, reason) == (-1, "")
    assert decoded.dtype == np.uint8 and decoded.shape == images.shape
    return data, lengths, decoded


def test_rows_decode_to_the_images_they_encode():
    rng = np.random.default_rng(5)
    blobs = np.zeros((3, 64, 64), np.uint8)
    blobs[0, 10:50, 20:40] = 3
    blobs[1, 5:9, :] = 10
    blobs[2, :, 31:33] = 15  # the largest label the code holds
    alternating = (np.arange(32 * 32) % 2).astype(np.uint8).reshape(1, 32, 32)
    cases = [
        blobs,
        rng.integers(0, 11, size=(5, 16, 16), dtype=np.uint8),  # a run per pixel
        alternating,
        np.zeros((2, 256, 256), np.uint8),  # one run of 65,536: three length bytes
        np.full((1, 4, 4), 7, np.uint8),
        np.zeros((0, 8, 8), np.uint8),
    ]
    for images in cases:
        decoded = _round_trip(images)[2]
        np.testing.assert_array_equal(decoded, images)
    # Worst and best cases: a byte per pixel, and a head byte plus the length's bytes.
    assert _round_trip(alternating)[1].tolist() == [4 + 32 * 32]
    assert _round_trip(np.zeros((1, 256, 256), np.uint8))[1].tolist() == [4 + 1 + 3]


def test_a_row_is_its_hash_then_its_runs():
    image = np.zeros((1, 4, 4), np.uint8)
    image[0, 2:] = 3  # 8 pixels of 0, then 8 of 3
    data, lengths = encode_rows(image)
    assert lengths.tolist() == [6] and data[4:].tolist() == [0x07, 0x37]
    fnv = 2166136261
    for byte in (0x07, 0x37):
        fnv = ((fnv ^ byte) * 16777619) % 2**32
    assert int.from_bytes(data[:4].tobytes(), "little") == fnv
    long_run = np.zeros((1, 16, 16), np.uint8)  # 256 = 16 + 240, 240 in 7-bit groups
    assert encode_rows(long_run)[0][4:].tolist() == [0x0F, 0x80 | (240 & 0x7F), 240 >> 7]


def test_damaged_rows_are_found_not_decoded():
    images = np.zeros((3, 16, 16), np.uint8)
    images[:, 4:12, 4:12] = [[[2]], [[5]], [[9]]]
    data, lengths = encode_rows(images)
    stops = np.cumsum(lengths)
    starts = stops - lengths
    flipped = data.copy()
    flipped[starts[1] + 5] ^= 0x10  # another label in row 1
    assert decode_rows(flipped, starts, stops, 16)[1:] == (1, "its hash does not match its bytes")
    cut = decode_rows(data, starts, stops - 1, 16)  # the last byte of every row lost
    assert cut[1:] == (0, "its hash does not match its bytes")
    assert decode_rows(data, starts, starts + 4, 16)[1] == 0  # a hash, no runs
    # Runs that do not make the image's pixels, behind a hash that matches.
    short = "its runs do not fill the image"
    sixty_four, length = encode_rows(np.zeros((1, 8, 8), np.uint8))
    assert decode_rows(sixty_four, np.array([0]), length, 16)[1:] == (0, short)
    two_five_six, length = encode_rows(np.zeros((1, 16, 16), np.uint8))
    assert decode_rows(two_five_six, np.array([0]), length, 8)[1:] == (0, short)
    with pytest.raises(ValueError, match=r"labels must lie in 0\.\.15"):
        encode_rows(np.full((1, 4, 4), 16, np.uint8))


def test_rows_are_scored_from_their_runs_as_their_images_are():
    """m(D, Q) from the runs, without decoding: the per-pixel lookups' value (float64
    running sums against float32 per-pixel sums: equal to float32 rounding)."""
    rng = np.random.default_rng(11)
    for size in (8, 32, 64):
        images = rng.integers(0, 11, size=(40, size, size), dtype=np.uint8)
        images[:10] = 0
        images[:10, size // 4 : size // 2, 2:-2] = rng.integers(1, 11, size=(10, 1, 1))  # runs
        images[10] = 0  # no glove pixels
        maps = chamfer_maps(rng.integers(0, 11, size=(size, size), dtype=np.uint8))
        data, lengths = encode_rows(images)
        stops = np.cumsum(lengths)
        errors, damaged, reason = score_rows(data, stops - lengths, stops, maps)
        assert (damaged, reason) == (-1, "") and errors.dtype == np.float32
        np.testing.assert_allclose(errors, directed_distance(images, maps), rtol=1e-6)
        assert errors[10] == np.inf
    # A file's rows, any order and repeats, read in runs of entries like read_rows.
    layout = RowLayout(size, np.concatenate([[0], np.cumsum(lengths)]), True, 0)
    ids = np.array([7, 2, 3, 2, 39, 4])

    def read(start, length, data=data):
        return data[start : start + length].tobytes()

    np.testing.assert_array_equal(score_file_rows(layout, read, ids, maps, "db.h5"), errors[ids])
    # Damage is refused as when decoding, and so are labels above the ten classes.
    flipped = data.copy()
    flipped[stops[1] - lengths[1] + 5] ^= 0x10
    assert score_rows(flipped, stops - lengths, stops, maps)[1:] == (
        1,
        "its hash does not match its bytes",
    )
    eleven, length = encode_rows(np.full((1, 64, 64), 11, np.uint8))
    assert score_rows(eleven, np.array([0]), length, maps)[1:] == (0, "a label is not 0..10")
    with pytest.raises(ValueError, match=r"db\.h5: damaged database, /tiny/64 entry 1: its hash"):
        score_file_rows(
            layout, functools.partial(read, data=flipped), np.array([3, 1]), maps, "db.h5"
        )


def test_compiled_running_sums_are_numpys_bit_for_bit():
    maps = np.random.default_rng(5).random((10, 64 * 64), dtype=np.float32) * 40
    sums = _running_sums(maps)
    assert sums.shape == (11, 64 * 64 + 1) and not sums[0].any() and not sums[:, 0].any()
    np.testing.assert_array_equal(sums[1:, 1:], np.cumsum(maps.astype(np.float64), axis=1))


def test_read_rows_gathers_runs_of_entries_and_refuses_short_reads():
    rng = np.random.default_rng(1)
    images = rng.integers(0, 3, size=(10, 8, 8), dtype=np.uint8)
    data, lengths = encode_rows(images)
    layout = RowLayout(8, np.concatenate([[0], np.cumsum(lengths)]), True, 0)
    calls = []

    def read(start, length):
        calls.append((start, length))
        return data[start : start + length].tobytes()

    ids = np.array([7, 2, 3, 2, 9, 4])
    np.testing.assert_array_equal(read_rows(layout, read, ids, "db.h5"), images[ids])
    assert len(calls) == 3  # 2-4, 7, 9
    assert read_rows(layout, read, np.array([], np.int64), "db.h5").shape == (0, 8, 8)
    with pytest.raises(ValueError, match=r"db\.h5: damaged database, shorter than its /tiny/8"):
        read_rows(layout, lambda start, length: b"\0" * (length - 1), ids, "db.h5")
    raw = RowLayout(8, np.arange(11) * 64, False, 0)
    flat = images.tobytes()
    rows = read_rows(raw, lambda start, length: flat[start : start + length], ids, "db.h5")
    np.testing.assert_array_equal(rows, images[ids])


# Files ---------------------------------------------------------------------------


@pytest.mark.gl  # builds a database
def test_format_2_stores_rows_and_reads_them_like_whole_images(small_database):
    with GloveDatabase(small_database) as database:
        assert database.format_version == 2 and database.info().format_version == 2
        for size in database.resolutions:
            images = database.images(size)
            layout = database.row_layout(size)
            assert layout.encoded and layout.offsets.shape == (73,)
            assert layout.offsets[-1] < images.nbytes / 2  # 38% at 8 x 8, 14% at 32 x 32
            ids = np.array([71, 0, 36, 36, 5])
            np.testing.assert_array_equal(database.image_rows(size, ids), images[ids])
    with h5py.File(small_database) as file:
        assert set(file["tiny/32"]) == {"rows", "offsets"}
        assert file["tiny/32/offsets"].dtype == np.int64


@pytest.mark.gl
def test_format_1_files_are_read_as_before(small_database, tmp_path):
    old = tmp_path / "format1.h5"
    write_format_1(small_database, old)
    ids = np.array([40, 3, 40, 71])
    with GloveDatabase(small_database) as new, GloveDatabase(old) as database:
        assert database.format_version == 1 and database.row_layout(8) is None
        for size in (8, 16, 32):
            np.testing.assert_array_equal(database.images(size), new.images(size))
            np.testing.assert_array_equal(database.image_rows(size, ids), new.images(size)[ids])
        query = {size: new.images(size)[17] for size in (8, 16, 32)}
    with DatabaseIndex(small_database) as new, DatabaseIndex(old) as index:
        np.testing.assert_array_equal(index.rows(32, ids), new.rows(32, ids))
        found, expected = (
            index.lookup(query, "8:30,16:10,32:3"),
            new.lookup(query, "8:30,16:10,32:3"),
        )
        np.testing.assert_array_equal(found.search.entry_ids, expected.search.entry_ids)
        # Format 2's rows are scored from their runs (float64 sums), format 1's images
        # pixel by pixel (float32): the same to float32 rounding.
        np.testing.assert_allclose(found.search.errors, expected.search.errors, rtol=1e-6)
        maps = chamfer_maps(query[32])
        np.testing.assert_allclose(
            new.row_errors(32, ids, maps), directed_distance(index.rows(32, ids), maps), rtol=1e-6
        )


@pytest.mark.gl
def test_damaged_rows_give_one_line_errors(small_database, tmp_path):
    damaged = tmp_path / "damaged.h5"
    shutil.copyfile(small_database, damaged)
    with h5py.File(damaged, "r+") as file:
        offsets = file["tiny/32/offsets"][()]
        rows = file["tiny/32/rows"]
        rows[offsets[5] + 6] ^= 0x10  # a run of entry 5 gets another label
    message = r"damaged\.h5: damaged database, /tiny/32 entry 5: its hash does not match"
    with GloveDatabase(damaged) as database, DatabaseIndex(damaged) as index:
        np.testing.assert_array_equal(database.image_rows(32, np.array([4, 6])).shape, (2, 32, 32))
        maps = chamfer_maps(database.image_rows(32, np.array([4]))[0])
        for read in (
            lambda: database.images(32),
            lambda: database.image_rows(32, np.array([6, 5])),
            lambda: index.rows(32, np.array([5])),
            lambda: index.row_errors(32, np.array([6, 5]), maps),
        ):
            with pytest.raises(ValueError, match=message) as error:
                read()
            assert "\n" not in str(error.value)

    # Offsets that do not split the rows are found when the file is opened: past the
    # end, an empty row, rows cut short.
    broken = tmp_path / "broken.h5"
    for name, change in [
        ("tiny/16/offsets", lambda offsets: np.r_[offsets[:-1], offsets[-1] + 1]),
        ("tiny/16/offsets", lambda offsets: np.r_[offsets[:3], offsets[2], offsets[4:]]),
        ("tiny/16/rows", lambda rows: rows[:-10]),
    ]:
        shutil.copyfile(small_database, broken)
        with h5py.File(broken, "r+") as file:
            values = change(file[name][()])
            del file[name]
            file[name] = values
        with pytest.raises(ValueError, match="/tiny/16: offsets do not split its"):
            GloveDatabase(broken)
    truncated = tmp_path / "truncated.h5"
    truncated.write_bytes(small_database.read_bytes()[:-100])
    with pytest.raises(ValueError, match="not a readable HDF5 file"):
        GloveDatabase(truncated)


@pytest.mark.gl
def test_other_format_versions_are_refused(small_database, tmp_path):
    for version, message in [(3, "format version 3 is newer"), (0, "format_version 0")]:
        copy = tmp_path / f"v{version}.h5"
        shutil.copyfile(small_database, copy)
        with h5py.File(copy, "r+") as file:
            file.attrs["format_version"] = version
        with pytest.raises(ValueError, match=message):
            GloveDatabase(copy)
