"""A posture database ready for searching: resident packed images plus rows read on demand.

:class:`DatabaseIndex` is the thin stateful edge around :mod:`glovedb.search`: it keeps
the sizes that a cascade scans in full in memory, packed (32 bytes per entry at 8x8)
or, when images repeat, as distinct images (:mod:`glovedb.distinct_images`: the same
result from scanning each image once) or, when there are very many, as inverted lists
(:mod:`glovedb.inverted_lists`: only the lists like the query are scanned), reads
the larger sizes' rows straight from the file (only the few candidates of the later
stages), and turns a query's tiny images into the nearest entries and their
interpolated posture and rotation.
"""

from __future__ import annotations

import functools
import mmap
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, TypeAlias

import numpy as np
from numpy.typing import NDArray

from glovedb._closing import Closing
from glovedb._validate import check_choice
from glovedb.chamfer import directed_distance
from glovedb.database import GloveDatabase, RowLayout, read_rows, score_file_rows
from glovedb.distinct_images import (
    DistinctTinyImages,
    distinct_image_count,
    distinct_tiny_images,
)
from glovedb.inverted_lists import inverted_lists
from glovedb.search import (
    CascadeStage,
    CoarseMaps,
    InterpolatedPose,
    PackedTinyImages,
    RowScorer,
    SearchResult,
    TinyImageSource,
    cascade_search,
    interpolate_pose,
    pack_tiny_images,
    parse_cascade,
)
from glovedb.stage_cache import (
    CACHE_AT_LEAST,
    FirstStageImages,
    forget,
    load_first_stage,
    load_rows,
    save_first_stage,
    save_rows,
    stage_path,
)

DEFAULT_CASCADE = "8:1500,16:100,64:3"
"""Chosen on 300 held-out queries (``held_out_queries`` with seed 1234, not the
benchmark's) against 1,000,188 natural entries (natural1000's config with ``select =
1323``): the top entry was the exhaustive ``8:2000,16:200,64:3`` cascade's for 299 of
300 with ``8:1500,16:100,64:3``, 297 with ``8:1200,16:100``, 295 with
``8:1000,16:100`` (300 for the cascade itself; on 200 of them, ``8:1000,16:50`` kept
as many as ``8:1000,16:100``, ``8:1000,16:10`` 0.93 of them). With the benchmark's
queries alternating between the two (``glove bench lookup --against``), a lookup took
0.56-0.79 ms less than with the old cascade (5.2-6.4 against 5.8-7.3 ms, 2-core AMD
EPYC machine). The exhaustive 8 x 8 scan ranks the nearest entry up to about 1,600th,
which is what the first stage must keep; at 16 x 16 the three entries nearest at 64 x
64 ranked at most 96th.
Tracking Tr1-Tr5 with DB_open+pinch+power (and Tr3 with DB_20postures) gave the same
errors to the last digit as with ``8:2000,16:200,64:3``.

A database whose images repeat many times keeps fewer distinct images: grasp20 tiled
to 1,000,000 entries holds every image 66 times, so 100 places at 16 x 16 hold two
images, and the exact nearest entry came first for 0.78 of the benchmark's 100
queries with this cascade against 0.97 with ``8:2000,16:200,64:3``; pass a larger
cascade for such a database."""
# The thesis' cascade (Figure 4.10), kept for comparison.
THESIS_CASCADE = "16:500,64:3"

FirstStage: TypeAlias = Literal["auto", "distinct", "scan", "lists"]
FIRST_STAGES: tuple[FirstStage, ...] = ("auto", "distinct", "scan", "lists")
_DISTINCT_AT_MOST = 0.75
"""``first_stage="auto"`` scans the distinct images when there are at most this many
per entry. Both give the same result; with fewer repeats the grouping saves little
scan time and costs 8 bytes per entry more than the packed images alone."""
LISTS_AT_LEAST = 250_000
"""``first_stage="auto"`` groups the images it would scan into inverted lists
(:mod:`glovedb.inverted_lists`) when there are at least this many: below, a scan
takes a few milliseconds at most and grouping is not worth its seconds."""


def default_cascade(sizes: tuple[int, ...]) -> str:
    """:data:`DEFAULT_CASCADE` when the database has its sizes, else the same shape on
    the sizes it has: the smallest keeps 1500, 16 (if present) 100, the largest 3."""
    if {8, 16, 64} <= set(sizes):
        return DEFAULT_CASCADE
    ordered = sorted(set(sizes))
    stages = [(ordered[0], 1500)]
    if 16 in ordered[1:-1]:
        stages.append((16, 100))
    if ordered[-1] != ordered[0]:
        stages.append((ordered[-1], 3))
    else:
        stages = [(ordered[0], 3)]
    return ",".join(f"{size}:{k}" for size, k in stages)


@dataclass(frozen=True)
class Lookup:
    """Result of :meth:`DatabaseIndex.lookup`.

    Attributes
    ----------
    search : SearchResult
        Nearest entries and their matching errors.
    pose : InterpolatedPose
        Posture and rotation (``cam_R_hand`` of the database views) blended from them.
    posture_ids : (k,) int64
        Posture of each returned entry.
    """

    search: SearchResult
    pose: InterpolatedPose
    posture_ids: NDArray[np.int64]


class DatabaseIndex(Closing):
    """Search structures of one database file.

    Parameters
    ----------
    path : str or Path
        A complete database (see :mod:`glovedb.database`).
    resident_sizes : sequence of int, optional
        Sizes made ready for a first stage at once. By default the smallest, which
        cascades scan in full; any other size used as a cascade's first stage is made
        ready on first use. The other stages read only their candidates' rows from the
        file.
    tile_to : int, optional
        Benchmarks only: repeat the entries until there are this many, to measure
        speed beyond the size that was built.
    first_stage : {"auto", "distinct", "scan", "lists"}
        How the first stage scans: every entry's packed images (``"scan"``), each
        distinct image once (``"distinct"``, :mod:`glovedb.distinct_images`; same
        result), or only the lists of images like the query's (``"lists"``,
        :mod:`glovedb.inverted_lists`; approximate, of the distinct images when they
        are at most 3/4 of the entries, else of every entry's). ``"auto"``: distinct
        images when they are at most 3/4 of the entries (tiled benchmarks always,
        natural1000's 722,888 of 756,000 not), and lists when that leaves at least
        :data:`LISTS_AT_LEAST` images to scan.

    Attributes
    ----------
    entries : int
        Searchable entries (``tile_to`` when tiling).
    base_entries : int
        Entries in the file.
    hand_length_m : float
        Size of the hand the database was rendered with.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        resident_sizes: tuple[int, ...] | None = None,
        tile_to: int | None = None,
        first_stage: FirstStage = "auto",
    ) -> None:
        check_choice("first_stage", first_stage, FIRST_STAGES)
        self.first_stage = first_stage
        self.path = Path(path)
        self._database = GloveDatabase(self.path)
        base_entries = self._database.info().entries
        self.entries = base_entries if tile_to is None else int(tile_to)
        if self.entries < 1:
            raise ValueError(f"tile_to: expected at least 1, got {tile_to}")
        self.base_entries = base_entries
        self.postures_rad = self._database.postures.astype(np.float64)
        self._posture_ids = self._database.entry_posture_ids.astype(np.int64)
        self._rotations = self._database.entry_rotations.astype(np.float64)
        self.resolutions = self._database.resolutions
        self.hand_length_m = float(self._database.settings["config"]["hand_length_m"])
        self._packed: dict[int, PackedTinyImages] = {}
        self._first: dict[int, FirstStageImages] = {}
        self._rows: dict[int, _MappedRows | NDArray[np.uint8]] = {}
        wanted = resident_sizes if resident_sizes is not None else self.resolutions[:1]
        for size in wanted:
            self.first_stage_images(size)

    # Entries -------------------------------------------------------------------

    def base_ids(self, entry_ids: NDArray[np.integer]) -> NDArray[np.int64]:
        """Ids in the file of (possibly tiled) entry ids."""
        return np.asarray(entry_ids, dtype=np.int64) % self.base_entries

    def entry_postures(self, entry_ids: NDArray[np.integer]) -> NDArray[np.float64]:
        """``(k, 20)`` postures of the entries, radians."""
        return self.postures_rad[self._posture_ids[self.base_ids(entry_ids)]]

    def entry_rotations(self, entry_ids: NDArray[np.integer]) -> NDArray[np.float64]:
        """``(k, 3, 3)`` ``cam_R_hand`` of the entries."""
        return self._rotations[self.base_ids(entry_ids)]

    # Images --------------------------------------------------------------------

    def packed(self, size: int) -> PackedTinyImages:
        """Resident packed images of every entry at one size (packed on first use)."""
        if size not in self._packed:
            self._packed[size] = self._pack(self._database.images(size))
        return self._packed[size]

    def first_stage_images(self, size: int) -> FirstStageImages:
        """What a first stage at ``size`` scans (made on first use; see ``first_stage``;
        kept between runs for large databases, :mod:`glovedb.stage_cache`)."""
        if size in self._first:
            return self._first[size]
        path, stage = None, None
        if self.entries >= CACHE_AT_LEAST:
            path = stage_path(self.path, size=size, entries=self.entries, choice=self.first_stage)
            stage = load_first_stage(path, entries=self.entries)
        if stage is None:
            stage = self._make_first_stage(size)
            if path is not None:
                save_first_stage(path, stage)
        self._first[size] = stage
        if isinstance(stage, PackedTinyImages):
            self._packed[size] = stage
        return stage

    def _make_first_stage(self, size: int) -> FirstStageImages:
        """Decode the file's images of ``size`` and group or pack them."""
        images = self._database.images(size)
        stage: PackedTinyImages | DistinctTinyImages
        # Every image of the file is shown by an entry, tiled or not.
        if self.first_stage == "distinct" or (
            self.first_stage in ("auto", "lists")
            and distinct_image_count(images) <= _DISTINCT_AT_MOST * self.entries
        ):
            tiled = self.entries != self.base_entries
            stage = distinct_tiny_images(
                images,
                image_of_entry=np.arange(self.entries) % self.base_entries if tiled else None,
            )
        else:
            stage = self._packed[size] if size in self._packed else self._pack(images)
        scanned = stage.num_images if isinstance(stage, DistinctTinyImages) else stage.num_entries
        if self.first_stage == "lists" or (
            self.first_stage == "auto" and scanned >= LISTS_AT_LEAST
        ):
            return inverted_lists(stage)
        return stage

    def _pack(self, images: NDArray[np.uint8]) -> PackedTinyImages:
        """Pack the file's images of one size, repeated or cut to ``entries``."""
        if self.entries != self.base_entries:
            images = np.resize(images, (self.entries, *images.shape[1:]))
        return pack_tiny_images(images)

    def rows(self, size: int, ids: NDArray[np.int64]) -> NDArray[np.uint8]:
        """Images of the given entries, ``(len(ids), s, s) uint8``."""
        return np.asarray(self._rows_of(size)[self.base_ids(ids)])

    def row_errors(
        self, size: int, ids: NDArray[np.int64], maps: NDArray[np.float32]
    ) -> NDArray[np.float32]:
        """``m(D, Q)`` of the given entries' images at one size for the query's chamfer
        maps ``(10, s, s)``: scored on the file's run-length coded rows where they lie
        (:func:`glovedb.database.score_file_rows`), else on the images."""
        source = self._rows_of(size)
        if isinstance(source, _MappedRows) and source.encoded:
            return source.errors(self.base_ids(ids), maps)
        return directed_distance(self.rows(size, ids), maps)

    def _rows_of(self, size: int) -> _MappedRows | NDArray[np.uint8]:
        if size not in self._rows:
            self._rows[size] = self._row_source(size)
        return self._rows[size]

    def _row_source(self, size: int) -> _MappedRows | NDArray[np.uint8]:
        """Where the rows of one size come from: the file's row data mapped into memory
        when it is stored in one piece (format 2, format 1 uncompressed), else every
        image decoded into memory (format 1's compressed sizes), and then kept between
        runs for a large database (:mod:`glovedb.stage_cache`)."""
        layout = self._database.row_layout(size)
        path = None
        if self.base_entries >= CACHE_AT_LEAST:
            path = stage_path(self.path, size=size, entries=self.base_entries, choice="rows")
        if layout is not None and layout.file_offset is not None:
            if path is not None:
                forget(path)  # decoded rows that versions before 2026-11-27 kept
            return _MappedRows(self.path, layout)
        if path is None:
            return self._database.images(size)
        rows = load_rows(path, shape=(self.base_entries, size, size))
        if rows is None:
            rows = self._database.images(size)
            save_rows(path, rows)
        return rows

    def sources(self, stages: tuple[CascadeStage, ...]) -> dict[int, TinyImageSource]:
        """What :func:`~glovedb.search.cascade_search` needs for these stages."""
        sources: dict[int, TinyImageSource] = {}
        for index, stage in enumerate(stages):
            if index == 0:
                sources[stage.size] = self.first_stage_images(stage.size)
            elif stage.size in self._packed:
                sources[stage.size] = self.packed(stage.size)
            elif isinstance(rows := self._rows_of(stage.size), _MappedRows) and rows.encoded:
                sources[stage.size] = RowScorer(functools.partial(self.row_errors, stage.size))
            else:
                sources[stage.size] = functools.partial(self.rows, stage.size)
        return sources

    # Search --------------------------------------------------------------------

    def search(
        self,
        query_images: dict[int, NDArray[np.uint8]],
        cascade: str = DEFAULT_CASCADE,
        *,
        workers: int | None = None,
        coarse_maps: CoarseMaps = "cell_mean",
    ) -> SearchResult:
        """Cascaded nearest entries of a query (see :func:`glovedb.search.cascade_search`)."""
        stages = parse_cascade(cascade, sizes=self.resolutions)
        return cascade_search(
            query_images,
            self.sources(stages),
            stages,
            workers=workers,
            coarse_maps=coarse_maps,
        )

    def lookup(
        self,
        query_images: dict[int, NDArray[np.uint8]],
        cascade: str = DEFAULT_CASCADE,
        *,
        workers: int | None = None,
        coarse_maps: CoarseMaps = "cell_mean",
    ) -> Lookup:
        """Nearest entries and their error-weighted posture and rotation."""
        result = self.search(query_images, cascade, workers=workers, coarse_maps=coarse_maps)
        pose = interpolate_pose(
            result.errors,
            self.entry_postures(result.entry_ids),
            self.entry_rotations(result.entry_ids),
        )
        return Lookup(result, pose, self._posture_ids[self.base_ids(result.entry_ids)])

    # Lifetime ------------------------------------------------------------------

    def close(self) -> None:
        for source in self._rows.values():
            if isinstance(source, _MappedRows):
                source.close()
        self._rows.clear()
        self._database.close()


class _MappedRows:
    """The row data of one image size, mapped from the file read-only.

    The later stages of a cascade read a few thousand rows scattered over the file,
    in place: on a 1,000,188-entry database the 16 x 16 stage's 2,000 run-length rows
    (59 MB mapped) scored in 0.60 ms against 0.83 ms for the same rows decoded into
    memory (256 MB), and the 64 x 64 stage's 200 (337 MB mapped) in 0.32 ms against
    1.12 ms with a positioned read (a system call) per run of consecutive entries.
    Every page is entered at once (``MAP_POPULATE``, where the system has it) when the
    size's row data takes at most :data:`_POPULATE_AT_MOST`: a row touched first would
    otherwise cost a page fault, and the resident memory would grow with every row
    read instead of being known from the start. Larger row data (a real database of
    many millions of entries) is mapped plainly, so that opening it does not read
    gigabytes; its rows fault in as lookups touch them. Where a file cannot be mapped,
    the row data is read into memory.
    """

    def __init__(self, path: Path, layout: RowLayout) -> None:
        if layout.file_offset is None:
            raise ValueError(f"{path}: /tiny/{layout.size} is not stored in one piece")
        self._path = str(path)
        self._layout = layout
        self._map: mmap.mmap | None = None
        length = int(layout.offsets[-1])
        start = layout.file_offset - layout.file_offset % mmap.ALLOCATIONGRANULARITY
        skip = layout.file_offset - start
        with open(path, "rb") as file:
            try:
                if length == 0:
                    raise ValueError("nothing to map")  # mmap refuses empty mappings
                options = _READ_ONLY if length <= _POPULATE_AT_MOST else _READ_ONLY_PLAIN
                self._map = mmap.mmap(file.fileno(), skip + length, offset=start, **options)
                self._data = np.frombuffer(self._map, np.uint8, length, skip)
            except (OSError, ValueError):
                file.seek(layout.file_offset)
                self._data = np.frombuffer(file.read(length), np.uint8)

    @property
    def encoded(self) -> bool:
        """Rows in the run-length code, which :meth:`errors` scores without decoding."""
        return self._layout.encoded

    def __getitem__(self, ids: NDArray[np.integer]) -> NDArray[np.uint8]:
        return read_rows(self._layout, self._data, ids, self._path)

    def errors(self, ids: NDArray[np.integer], maps: NDArray[np.float32]) -> NDArray[np.float32]:
        return score_file_rows(self._layout, self._data, ids, maps, self._path)

    def close(self) -> None:
        self._data = np.zeros(0, np.uint8)
        if self._map is not None:
            try:
                self._map.close()
            except BufferError:  # a view of the rows is still alive: unmapped with it
                pass
            self._map = None


_READ_ONLY: dict[str, int] = (
    {"flags": mmap.MAP_SHARED | mmap.MAP_POPULATE, "prot": mmap.PROT_READ}
    if hasattr(mmap, "MAP_POPULATE")
    else {"access": mmap.ACCESS_READ}
)
"""A read-only mapping, with every page entered at once where the system can (Linux)."""
_READ_ONLY_PLAIN: dict[str, int] = {"access": mmap.ACCESS_READ}
_POPULATE_AT_MOST = 2**30
"""Bytes of one size's row data entered at once on opening (natural1323's 64 x 64 rows,
1,000,188 entries: 337 MB, about 30 ms from the page cache)."""
