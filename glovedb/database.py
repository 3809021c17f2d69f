"""The posture database file (HDF5): format, checks and a reader.

See ``docs/database_format.md`` for the layout. In short: entry ``e`` shows posture
``e // V`` from view ``e % V`` (V views per posture); ``/entries`` holds both ids and
the rotation ``cam_R_hand`` of every entry; ``/tiny/<s>`` holds the tiny images of
size ``s``: in format 2 a group of every entry's row in a run-length code
(:mod:`glovedb._row_codec`), ``rows`` (bytes) and ``offsets`` (``(N + 1,) int64``,
row ``e`` is ``rows[offsets[e]:offsets[e + 1]]``); in format 1, which is still read,
an ``(N, s, s) uint8`` dataset. A file is a database only when its root attribute
``complete`` is true: the builder sets it last, then renames the file into place, so
an interrupted build never looks valid.

The reader opens files read-only and holds no lock, so many processes can read one
database at once.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeAlias

import h5py
import numpy as np
from numpy.typing import NDArray

from glovedb._closing import Closing
from glovedb._row_codec import HEADER_BYTES, decode_rows, score_rows
from glovedb._validate import as_array

FORMAT_NAME = "glove-posture-db"
FORMAT_VERSION = 2


@dataclass(frozen=True)
class DatabaseInfo:
    """What ``glove db info`` reports about a database file."""

    path: str
    entries: int
    postures: int
    views_per_posture: int
    camera_positions: int
    rolls: int
    resolutions: tuple[int, ...]
    size_bytes: int
    name: str
    project_version: str
    format_version: int

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary."""
        return {
            "path": self.path,
            "name": self.name,
            "entries": self.entries,
            "postures": self.postures,
            "views_per_posture": self.views_per_posture,
            "camera_positions": self.camera_positions,
            "rolls": self.rolls,
            "resolutions": list(self.resolutions),
            "size_bytes": self.size_bytes,
            "project_version": self.project_version,
            "format_version": self.format_version,
        }


@dataclass(frozen=True)
class RowLayout:
    """Where the tiny images of one size lie in a database file, row by row.

    Attributes
    ----------
    size : int
        Images are ``(size, size)``.
    offsets : (N + 1,) int64
        Entry ``e`` is bytes ``offsets[e]:offsets[e + 1]`` of the row data.
    encoded : bool
        Rows in the run-length code (format 2), else ``size * size`` raw bytes.
    file_offset : int or None
        Byte of the file where the row data begins; None when HDF5 does not store
        it in one piece (format 1's compressed sizes).
    """

    size: int
    offsets: NDArray[np.int64]
    encoded: bool
    file_offset: int | None


RowData: TypeAlias = Callable[[int, int], bytes] | NDArray[np.uint8]
"""The row data of one size: ``read(start, length)``, which returns ``length`` bytes
from byte ``start`` of it (called once per run of consecutive entries, in ascending
order), or all of it in memory (a mapped file region), read where it lies."""


def read_rows(
    layout: RowLayout,
    read: RowData,
    ids: NDArray[np.integer],
    where: str,
) -> NDArray[np.uint8]:
    """Images of the given entries, ``(len(ids), s, s) uint8`` in ``ids`` order.

    Parameters
    ----------
    layout : RowLayout
    read : RowData
        The row data, or how to read it.
    ids : (k,) int
        Entries in ``0..N-1``, any order, repeats allowed (checked by the caller).
    where : str
        The file, for error messages.

    Raises
    ------
    ValueError
        When the file is shorter than its offsets say, or a row is damaged.
    """
    size = layout.size
    unique, inverse, data, starts, stops = _row_bytes(layout, read, ids, where)
    if layout.encoded:
        images = _decoded(data, starts, stops, size, unique, where)
    else:
        images = data[starts[:, None] + np.arange(size * size)].reshape(len(unique), size, size)
    return images if inverse is None else images[inverse]


def score_file_rows(
    layout: RowLayout,
    read: RowData,
    ids: NDArray[np.integer],
    maps: NDArray[np.float32],
    where: str,
) -> NDArray[np.float32]:
    """The directed distance ``m(D, Q)`` of the given entries' run-length coded rows
    to a query, in ``ids`` order, without decoding them
    (:func:`glovedb._row_codec.score_rows`); what :func:`read_rows` and a scan of the
    images give, to float32 rounding.

    Parameters
    ----------
    layout : RowLayout
        Of an encoded size (format 2).
    read, ids, where
        As in :func:`read_rows`.
    maps : (10, s, s) float32
        The query's chamfer maps at the layout's size.

    Returns
    -------
    (k,) float32
        Pixels; ``inf`` for rows without glove pixels.

    Raises
    ------
    ValueError
        When the file is shorter than its offsets say, or a row is damaged.
    """
    if not layout.encoded:
        raise ValueError(f"{where}: /tiny/{layout.size} is not run-length coded")
    unique, inverse, data, starts, stops = _row_bytes(layout, read, ids, where)
    errors, damaged, reason = score_rows(data, starts, stops, maps)
    if damaged >= 0:
        entry = unique[damaged]
        raise ValueError(f"{where}: damaged database, /tiny/{layout.size} entry {entry}: {reason}")
    return errors if inverse is None else errors[inverse]


def _row_bytes(
    layout: RowLayout,
    read: RowData,
    ids: NDArray[np.integer],
    where: str,
) -> tuple[
    NDArray[np.int64],
    NDArray[np.int64] | None,
    NDArray[np.uint8],
    NDArray[np.int64],
    NDArray[np.int64],
]:
    """The distinct ``ids`` (ascending) and where each id is among them (None when
    ``ids`` are those), and bytes that hold their rows, with each row's start and stop
    in them (arguments of :func:`read_rows`): the data in memory itself, or the rows
    read in one call per run of consecutive entries."""
    asked: NDArray[np.int64] = np.asarray(ids, np.int64)
    unique: NDArray[np.int64] = asked
    where_in: NDArray[np.int64] | None = None
    if not np.all(asked[1:] > asked[:-1]):  # a cascade's candidates need no sort
        unique, where_in = np.unique(asked, return_inverse=True)
    if not len(unique):
        empty = np.zeros(0, np.int64)
        return unique, where_in, np.zeros(0, np.uint8), empty, empty
    if isinstance(read, np.ndarray):
        starts, stops = layout.offsets[unique], layout.offsets[unique + 1]
        if stops[-1] > len(read):
            raise ValueError(
                f"{where}: damaged database, shorter than its /tiny/{layout.size} offsets"
            )
        return unique, where_in, read, starts, stops
    gaps = np.flatnonzero(np.diff(unique) != 1) + 1
    firsts = unique[np.r_[0, gaps]]
    lasts = unique[np.r_[gaps - 1, len(unique) - 1]]
    offsets = layout.offsets
    starts, spans = offsets[firsts], offsets[lasts + 1] - offsets[firsts]
    pieces = map(read, starts.tolist(), spans.tolist())
    data = np.frombuffer(bytearray().join(pieces), np.uint8)
    if len(data) != spans.sum():
        raise ValueError(f"{where}: damaged database, shorter than its /tiny/{layout.size} offsets")
    lengths = offsets[unique + 1] - offsets[unique]
    stops = np.cumsum(lengths)
    return unique, where_in, data, stops - lengths, stops


class GloveDatabase(Closing):
    """A posture database opened for reading.

    Parameters
    ----------
    path : str or Path

    Raises
    ------
    ValueError
        With one line saying what is wrong: missing, not HDF5, not a glove database,
        unfinished (an interrupted build), a newer format, or inconsistent shapes.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file = open_database_file(self.path)
        self.format_version = int(self._file.attrs["format_version"])
        self._offsets: dict[int, NDArray[np.int64]] = {}  # format 2, checked on opening
        try:
            self._check()
        except Exception:
            self._file.close()
            raise

    def _check(self) -> None:
        file = self._file
        entries = len(file["entries/posture_id"])
        postures = len(file["postures"])
        views = len(file["views/rotation"])
        if entries != postures * views:
            raise ValueError(
                f"{self.path}: {entries} entries, expected {postures} postures x {views} views"
            )
        for size in self.resolutions:
            if self.format_version == 1:
                dataset = file[f"tiny/{size}"]
                shape = getattr(dataset, "shape", "no shape (a group)")
                if shape != (entries, size, size):
                    raise ValueError(f"{self.path}: /tiny/{size} has shape {shape}")
            else:
                self._offsets[size] = self._checked_offsets(size, entries)
        try:  # parsed now, so that a damaged file fails when opened, not mid-run
            dict(json.loads(file.attrs["settings_json"]))
        except (KeyError, ValueError, TypeError) as error:
            raise ValueError(f"{self.path}: damaged database, settings_json ({error})") from error
        ids = {}
        for name, count in (("posture_id", postures), ("view_id", views)):
            ids[name] = file[f"entries/{name}"][()]
            if len(ids[name]) and (ids[name].min() < 0 or ids[name].max() >= count):
                raise ValueError(
                    f"{self.path}: damaged database, entries/{name} outside 0..{count - 1}"
                )
        # Every entry is seen from its view: its rotation is the view's, a rotation.
        view_rotations = file["views/rotation"][()]
        gram = np.einsum("nji,njk->nik", view_rotations, view_rotations, dtype=np.float64)
        if not np.allclose(gram, np.eye(3), atol=1e-4) or not np.array_equal(
            file["entries/rotation"][()], view_rotations[ids["view_id"]]
        ):
            raise ValueError(f"{self.path}: damaged database, entry rotations are not its views'")

    # Metadata ------------------------------------------------------------------

    @property
    def resolutions(self) -> tuple[int, ...]:
        """Tiny image sizes, ascending."""
        return tuple(sorted(int(name) for name in self._file["tiny"]))

    @property
    def settings(self) -> dict[str, Any]:
        """The build settings stored in the file (parsed JSON)."""
        return dict(json.loads(self._file.attrs["settings_json"]))

    def info(self) -> DatabaseInfo:
        """Counts and sizes of the database."""
        attrs = self._file.attrs
        return DatabaseInfo(
            path=str(self.path),
            entries=len(self._file["entries/posture_id"]),
            postures=len(self._file["postures"]),
            views_per_posture=len(self._file["views/rotation"]),
            camera_positions=int(attrs["camera_positions"]),
            rolls=int(attrs["rolls"]),
            resolutions=self.resolutions,
            size_bytes=self.path.stat().st_size,
            name=str(attrs["name"]),
            project_version=str(attrs["project_version"]),
            format_version=self.format_version,
        )

    # Arrays --------------------------------------------------------------------

    @property
    def postures(self) -> NDArray[np.float32]:
        """``(P, 20) float32`` postures in radians."""
        return np.asarray(self._file["postures"][()])

    @property
    def posture_names(self) -> tuple[str, ...]:
        """A name per posture (the named posture's, or ``source:index``)."""
        return tuple(
            n.decode() if isinstance(n, bytes) else n for n in self._file["posture_names"][()]
        )

    @property
    def entry_posture_ids(self) -> NDArray[np.int32]:
        """``(N,) int32`` posture of every entry."""
        return np.asarray(self._file["entries/posture_id"][()])

    @property
    def entry_view_ids(self) -> NDArray[np.int32]:
        """``(N,) int32`` view of every entry."""
        return np.asarray(self._file["entries/view_id"][()])

    @property
    def entry_rotations(self) -> NDArray[np.float32]:
        """``(N, 3, 3) float32`` ``cam_R_hand`` of every entry."""
        return np.asarray(self._file["entries/rotation"][()])

    def images(self, size: int) -> NDArray[np.uint8]:
        """All tiny images of one size, ``(N, s, s) uint8`` (read into memory)."""
        self._check_size(size)
        if self.format_version == 1:
            return np.asarray(self._file[f"tiny/{size}"][()])
        offsets = self._offsets[size]
        data = np.asarray(self._file[f"tiny/{size}/rows"][()])
        return _decoded(data, offsets[:-1], offsets[1:], size, None, str(self.path))

    def image_rows(self, size: int, ids: NDArray[np.integer]) -> NDArray[np.uint8]:
        """Tiny images of the given entries, ``(len(ids), s, s) uint8``, in ``ids`` order."""
        ids = as_array("ids", ids, (None,), np.int64)
        self._check_size(size)
        entries = len(self._file["entries/posture_id"])
        if len(ids) and (ids.min() < 0 or ids.max() >= entries):
            raise ValueError(f"ids: entries must lie in 0..{entries - 1}")
        if self.format_version == 1:
            dataset = self._file[f"tiny/{size}"]
            order = np.argsort(ids, kind="stable")
            unique, inverse = np.unique(ids[order], return_inverse=True)
            rows = dataset[unique] if len(unique) else np.zeros((0, size, size), np.uint8)
            result = np.empty((len(ids), size, size), np.uint8)
            result[order] = rows[inverse]
            return result
        rows = self._file[f"tiny/{size}/rows"]
        return read_rows(
            self._encoded_layout(size),
            lambda start, length: rows[start : start + length].tobytes(),
            ids,
            str(self.path),
        )

    def row_layout(self, size: int) -> RowLayout | None:
        """Where the images of one size lie in the file (see :class:`RowLayout`); None
        when they cannot be read row by row (format 1's compressed sizes)."""
        self._check_size(size)
        if self.format_version == 1:
            dataset = self._file[f"tiny/{size}"]
            if dataset.chunks is not None or dataset.compression is not None:
                return None
            offsets = np.arange(dataset.shape[0] + 1, dtype=np.int64) * (size * size)
            return RowLayout(size, offsets, False, _file_offset(dataset))
        return self._encoded_layout(size)

    def _encoded_layout(self, size: int) -> RowLayout:
        rows = self._file[f"tiny/{size}/rows"]
        return RowLayout(size, self._offsets[size], True, _file_offset(rows))

    def _checked_offsets(self, size: int, entries: int) -> NDArray[np.int64]:
        """The checked ``(N + 1,)`` offsets of format 2's rows of one size."""
        group = self._file[f"tiny/{size}"]
        where = f"{self.path}: damaged database, /tiny/{size}"
        datasets = [group.get(name) for name in ("rows", "offsets")] if isinstance(
            group, h5py.Group
        ) else []  # fmt: skip
        if len(datasets) != 2 or not all(isinstance(d, h5py.Dataset) for d in datasets):
            raise ValueError(f"{where} is not a group of rows and offsets")
        rows, offsets = datasets
        if (rows.dtype, rows.ndim, offsets.dtype, offsets.shape) != (
            np.uint8, 1, np.int64, (entries + 1,)
        ):  # fmt: skip
            raise ValueError(
                f"{where} has rows {rows.shape} {rows.dtype}, offsets {offsets.shape} "
                f"{offsets.dtype}; expected offsets ({entries + 1},) int64"
            )
        bounds = np.asarray(offsets[()])
        # Every row holds its hash and at least one run.
        if bounds[0] != 0 or bounds[-1] != len(rows) or np.any(np.diff(bounds) <= HEADER_BYTES):
            raise ValueError(f"{where}: offsets do not split its {len(rows)} bytes into rows")
        return bounds

    def _check_size(self, size: int) -> None:
        if size not in self.resolutions:
            raise ValueError(
                f"size: the database has tiny images of {self.resolutions}, not {size}"
            )

    # Lifetime ------------------------------------------------------------------

    def close(self) -> None:
        """Close the file."""
        self._file.close()


def _decoded(
    data: NDArray[np.uint8],
    starts: NDArray[np.int64],
    stops: NDArray[np.int64],
    size: int,
    ids: NDArray[np.int64] | None,
    where: str,
) -> NDArray[np.uint8]:
    """Decoded rows, or a one-line ``ValueError`` naming the first damaged entry (from
    ``ids``, the entries of the rows; the row's index when None)."""
    images, damaged, reason = decode_rows(data, starts, stops, size)
    if damaged >= 0:
        entry = damaged if ids is None else ids[damaged]
        raise ValueError(f"{where}: damaged database, /tiny/{size} entry {entry}: {reason}")
    return images


def _file_offset(dataset: h5py.Dataset) -> int | None:
    """Byte of the file where a contiguous, unfiltered dataset's data begins, else None."""
    if dataset.chunks is not None or dataset.compression is not None:
        return None
    offset = dataset.id.get_offset()
    return None if offset is None else int(offset)


def open_database_file(path: Path) -> h5py.File:
    """Open a complete database file read-only, or raise a one-line ``ValueError``."""
    if not path.exists():
        raise ValueError(f"{path}: no such database file")
    if path.is_dir():
        raise ValueError(f"{path}: a folder, not a database file")
    try:
        file = h5py.File(path, "r")
    except OSError as error:
        reason = " ".join(str(error).split())  # HDF5's messages span lines
        raise ValueError(f"{path}: not a readable HDF5 file ({reason})") from error
    try:
        check_header(file, path)
    except Exception:
        file.close()
        raise
    return file


def check_header(file: h5py.File, path: Path) -> None:
    """The root attributes say this is a complete database of a format we read."""
    attrs = file.attrs
    if attrs.get("format") != FORMAT_NAME:
        raise ValueError(f"{path}: not a glove posture database")
    version = int(attrs.get("format_version", -1))
    if version > FORMAT_VERSION:
        raise ValueError(f"{path}: format version {version} is newer than this program reads")
    if version < 1:
        raise ValueError(f"{path}: damaged database, format_version {version}")
    if not bool(attrs.get("complete", False)):
        raise ValueError(
            f"{path}: unfinished database (an interrupted build); resume or rebuild it"
        )
    missing = [
        name
        for name in ("postures", "posture_names", "entries/posture_id", "entries/view_id",
                     "entries/rotation", "views/rotation", "tiny")
        if name not in file
    ]  # fmt: skip
    if missing:
        raise ValueError(f"{path}: damaged database, missing {', '.join(missing)}")
