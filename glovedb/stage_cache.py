"""What a large database's search needs in memory, kept in the cache folder between runs.

Opening a database for searching makes what the cascade's first stage scans
(:meth:`glovedb.lookup.DatabaseIndex.first_stage_images`: every entry's smallest tiny
image decoded, the distinct ones counted, packed) and, for format 1 files whose sizes
are compressed, decodes the later stages' sizes whole (:meth:`glovedb.lookup.
DatabaseIndex.rows`; format 2's rows are read where they lie in the mapped file). For
a million entries that took about 1.0 s for the 8x8 first stage packed (6-9 s as
inverted lists, :mod:`glovedb.inverted_lists`) and another 1.0 s for 16x16 rows, most
of a tracker's start; reading the stage back takes 0.04-0.1 s, mapping the rows
(:func:`load_rows`) under 1 ms. Databases of at least :data:`CACHE_AT_LEAST` entries
keep them in :func:`glovedb.cache.cache_folder` ``/ "stages"``: 34 bytes per entry for
the packed 8x8 first stage (56 MB for a million entries as lists), ``s * s`` bytes per
entry for decoded rows (256 at 16x16).

The file name is two hashes: of what was asked (the database's resolved path, the
size, the tiling, the first-stage choice), and of the version (the file's size,
modification time and inode, so that a rebuilt or edited file is a new version, and
the source of the modules that make the stage), so a stale entry is never read.
Writing a version deletes the older versions of what was asked. An entry that cannot
be read or does not fit is passed over and made again; one that cannot be written is
not kept. Deleting the folder is always safe.
"""

from __future__ import annotations

import hashlib
import mmap
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from glovedb._files import write_atomically
from glovedb.cache import cache_folder, source_digest
from glovedb.distinct_images import DistinctTinyImages
from glovedb.inverted_lists import LIST_ARRAYS, InvertedLists
from glovedb.packed_images import PackedTinyImages

FirstStageImages = PackedTinyImages | DistinctTinyImages | InvertedLists
"""What a cascade's first stage scans (:class:`glovedb.lookup.DatabaseIndex`)."""

CACHE_AT_LEAST = 100_000
"""Databases with fewer searchable entries make their first stage in well under 0.1 s
and are not cached."""

# What decides the stage's arrays: these modules' source is part of the cache key.
_SOURCES = (
    "stage_cache", "lookup", "database", "_row_codec", "packed_images", "distinct_images",
    "inverted_lists", "_list_kernels",
)  # fmt: skip


def stage_path(
    database: str | os.PathLike[str],
    *,
    size: int,
    entries: int,
    choice: str,
    folder: str | os.PathLike[str] | None = None,
) -> Path:
    """Where a stage of ``database`` at ``size`` is kept.

    Parameters
    ----------
    database : path
        The database file (it must exist).
    size : int
        Tiny image side, pixels.
    entries : int
        Searchable entries (the file's, or a benchmark's tiling).
    choice : str
        For a first stage, the index's ``first_stage`` setting (``"auto"``,
        ``"distinct"`` or ``"scan"``); ``"rows"`` for decoded rows.
    folder : path, optional
        Default :func:`glovedb.cache.cache_folder` ``/ "stages"``.
    """
    source = Path(database).resolve()
    status = source.stat()
    asked = hashlib.sha256(f"{source} {size} {entries} {choice}".encode())
    version = source_digest(*_SOURCES)
    version.update(
        f"{np.__version__} {status.st_size} {status.st_mtime_ns} {status.st_ino}".encode()
    )
    suffix = "npy" if choice == "rows" else "npz"
    name = f"{asked.hexdigest()[:16]}-{version.hexdigest()[:16]}.{suffix}"
    return Path(folder or cache_folder() / "stages") / name


def _versions(path: Path) -> list[Path]:
    """What is kept for the same database, size and choice as ``path``, any version
    (files being written, whose names start with a dot, left out)."""
    asked = path.name.split("-")[0]
    return [kept for kept in path.parent.glob(f"{asked}-*") if not kept.name.startswith(".")]


def _drop_older(path: Path) -> None:
    """Delete what is kept for the same database, size and choice under another
    version (the file was rebuilt, or the code changed): the folder holds one copy
    per database, not one per build."""
    for other in _versions(path):
        if other != path:
            other.unlink(missing_ok=True)


def forget(path: str | os.PathLike[str]) -> None:
    """Delete every version kept of what ``path`` (a :func:`stage_path`) names: for what
    is no longer made, such as the decoded rows of a format 2 database, which older
    versions kept (256 MB at 16 x 16 for a million entries)."""
    try:
        for kept in _versions(Path(path)):
            kept.unlink(missing_ok=True)
    except OSError:
        pass  # a read-only cache: left as it is


def load_first_stage(path: str | os.PathLike[str], *, entries: int) -> FirstStageImages | None:
    """The stage kept at ``path``, or None when there is none, it cannot be read, or
    it does not hold ``entries`` entries."""
    try:
        with np.load(path, allow_pickle=False) as stored:
            packed = PackedTinyImages(
                np.ascontiguousarray(stored["codes"]),
                stored["glove_pixels"],
                int(stored["size"]),
                int(stored["group"]),
            )
            if "entry_ids" not in stored:
                return packed if packed.num_entries == entries else None
            stage: FirstStageImages
            stage = DistinctTinyImages(packed, stored["entry_ids"], stored["offsets"])
            if "list_offsets" in stored:
                stage = InvertedLists(stage, *(stored[name] for name in LIST_ARRAYS))
            return stage if stage.num_entries == entries else None
    except (OSError, ValueError, TypeError, KeyError, EOFError, zipfile.BadZipFile):
        return None


def save_first_stage(path: str | os.PathLike[str], stage: FirstStageImages) -> None:
    """Keep ``stage`` at ``path`` (whole or not at all; nothing is kept when the folder
    cannot be written)."""
    arrays: dict[str, Any] = {}
    if isinstance(stage, InvertedLists):
        arrays |= {name: getattr(stage, name) for name in LIST_ARRAYS}
        stage = stage.images
    packed = stage.images if isinstance(stage, DistinctTinyImages) else stage
    arrays |= {
        "codes": packed.codes,
        "glove_pixels": packed.glove_pixels,
        "size": np.array(packed.size),
        "group": np.array(packed.group),
    }
    if isinstance(stage, DistinctTinyImages):
        arrays |= {"entry_ids": stage.entry_ids, "offsets": stage.offsets}
    target = Path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        write_atomically(target, lambda file: np.savez(file, **arrays))
        _drop_older(target)
    except OSError:
        pass  # a read-only cache: the next run makes the stage again


def load_rows(
    path: str | os.PathLike[str], *, shape: tuple[int, int, int]
) -> NDArray[np.uint8] | None:
    """Decoded rows kept at ``path``, or None when there are none, they cannot be read
    or they do not have ``shape``.

    Mapped with every page entered at once (``MAP_POPULATE``, where the system has
    it), else read into memory. Reading 256 MB took 0.5 s of a tracker's start (most
    of it giving the process fresh pages), mapping them takes under 1 ms, and 2,000
    rows are gathered as fast as from memory (0.17 ms). A plain map is not used: every
    row a lookup touched first was a page fault, and the first 40 lookups took 59 ms
    median instead of 12.
    """
    try:
        with open(path, "rb") as file:
            version = np.lib.format.read_magic(file)
            header = np.lib.format.read_array_header_2_0 if version >= (2, 0) else (
                np.lib.format.read_array_header_1_0
            )  # fmt: skip
            stored_shape, fortran_order, dtype = header(file)
            if stored_shape != shape or dtype != np.uint8 or fortran_order:
                return None  # another array under that name
            offset = file.tell()
            if os.fstat(file.fileno()).st_size != offset + int(np.prod(shape)):
                return None  # cut short
            if not hasattr(mmap, "MAP_POPULATE"):
                return np.fromfile(file, np.uint8).reshape(shape)
            mapped = mmap.mmap(
                file.fileno(), 0, flags=mmap.MAP_SHARED | mmap.MAP_POPULATE, prot=mmap.PROT_READ
            )
    except (OSError, ValueError, EOFError):
        return None  # none, or not an array file (an archive under that name)
    return np.frombuffer(mapped, np.uint8, offset=offset).reshape(shape)


def save_rows(path: str | os.PathLike[str], rows: NDArray[np.uint8]) -> None:
    """Keep decoded rows at ``path`` (whole or not at all)."""
    target = Path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        write_atomically(target, lambda file: np.save(file, rows, allow_pickle=False))
        _drop_older(target)
    except OSError:
        pass  # a read-only cache: the next run decodes them again
