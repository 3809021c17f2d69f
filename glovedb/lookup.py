"""A posture database ready for searching: resident packed images plus rows read on demand.

:class:`DatabaseIndex` is the thin stateful edge around :mod:`glovedb.search`: it keeps
the sizes that a cascade scans in full packed in memory (32 bytes per entry at 8x8),
reads the larger sizes' rows straight from the file (only the few candidates of the
later stages), and turns a query's tiny images into
the nearest entries and their interpolated posture and rotation.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from glovedb._closing import Closing
from glovedb.database import GloveDatabase
from glovedb.search import (
    CascadeStage,
    CoarseMaps,
    InterpolatedPose,
    PackedTinyImages,
    SearchResult,
    TinyImageSource,
    cascade_search,
    interpolate_pose,
    pack_tiny_images,
    parse_cascade,
)

DEFAULT_CASCADE = "8:2000,16:300,64:3"
# The thesis' cascade (Figure 4.10), kept for comparison.
THESIS_CASCADE = "16:500,64:3"


def default_cascade(sizes: tuple[int, ...]) -> str:
    """:data:`DEFAULT_CASCADE` when the database has its sizes, else the same shape on
    the sizes it has: the smallest keeps 2000, 16 (if present) 300, the largest 3."""
    if {8, 16, 64} <= set(sizes):
        return DEFAULT_CASCADE
    ordered = sorted(set(sizes))
    stages = [(ordered[0], 2000)]
    if 16 in ordered[1:-1]:
        stages.append((16, 300))
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
        Sizes packed into memory at once. By default the smallest, which cascades
        scan in full; any other size used as a cascade's first stage is packed on
        first use. The other stages read only their candidates' rows from the file.
    tile_to : int, optional
        Benchmarks only: repeat the entries until there are this many, to measure
        speed beyond the size that was built.

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
    ) -> None:
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
        self._rows: dict[int, _RowReader | NDArray[np.uint8]] = {}
        wanted = resident_sizes if resident_sizes is not None else self.resolutions[:1]
        for size in wanted:
            self.packed(size)

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
        """Resident packed images of one size (packed on first use)."""
        if size not in self._packed:
            images = self._database.images(size)
            if self.entries != self.base_entries:
                images = np.resize(images, (self.entries, size, size))
            self._packed[size] = pack_tiny_images(images)
        return self._packed[size]

    def rows(self, size: int, ids: NDArray[np.int64]) -> NDArray[np.uint8]:
        """Images of the given entries, ``(len(ids), s, s) uint8``."""
        base = self.base_ids(ids)
        if size not in self._rows:
            self._rows[size] = _row_source(self._database, size)
        return np.asarray(self._rows[size][base])

    def sources(self, stages: tuple[CascadeStage, ...]) -> dict[int, TinyImageSource]:
        """What :func:`~glovedb.search.cascade_search` needs for these stages."""
        sources: dict[int, TinyImageSource] = {}
        for index, stage in enumerate(stages):
            if index == 0 or stage.size in self._packed:
                sources[stage.size] = self.packed(stage.size)
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
            if isinstance(source, _RowReader):
                source.close()
        self._rows.clear()
        self._database.close()


class _RowReader:
    """Rows of a contiguous image dataset, read from the file one row at a time.

    Not a memory map: a mapping keeps every page it touched resident, and a kernel
    that caches files in large folios maps up to 2 MB per touched row (on this
    machine a 1,000,000-entry benchmark grew by about 1 MB per 32 x 32 row read). A
    positioned read costs a system call per row, about 3 microseconds (used for
    datasets larger than :data:`_IN_MEMORY_BYTES`).
    """

    def __init__(self, path: Path, offset: int, shape: tuple[int, ...]) -> None:
        self._fd = os.open(path, os.O_RDONLY)
        self._offset = offset
        self._shape = shape[1:]
        self._row_bytes = int(np.prod(self._shape))

    def __getitem__(self, ids: NDArray[np.integer]) -> NDArray[np.uint8]:
        rows = np.empty((len(ids), *self._shape), np.uint8)
        flat = rows.reshape(len(ids), self._row_bytes)
        for k, entry in enumerate(np.asarray(ids, dtype=np.int64).tolist()):
            data = os.pread(self._fd, self._row_bytes, self._offset + entry * self._row_bytes)
            if len(data) != self._row_bytes:
                raise ValueError(f"entry {entry}: the database file is shorter than its index")
            flat[k] = np.frombuffer(data, np.uint8)
        return rows

    def close(self) -> None:
        os.close(self._fd)


_IN_MEMORY_BYTES = 256 * 2**20
"""Image datasets up to this size are read whole on first use: indexing memory is
fastest (300 rows of 64 x 64, a tracker's last stage, take 0.2 ms against 0.9 ms of
positioned reads)."""


def _row_source(database: GloveDatabase, size: int) -> _RowReader | NDArray[np.uint8]:
    """Where the rows of one size come from: the whole dataset read into memory when it
    is small or stored compressed, else positioned reads from the file (where the
    system has ``os.pread``)."""
    dataset = database._dataset(size)
    offset = dataset.id.get_offset()
    contiguous = dataset.chunks is None and dataset.compression is None and offset is not None
    large = dataset.size > _IN_MEMORY_BYTES
    if contiguous and large and hasattr(os, "pread"):
        return _RowReader(database.path, int(offset), dataset.shape)
    return np.asarray(dataset[()])
