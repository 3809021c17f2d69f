"""The posture database file (HDF5): format, checks and a reader.

See ``docs/database_format.md`` for the layout. In short: entry ``e`` shows posture
``e // V`` from view ``e % V`` (V views per posture); ``/entries`` holds both ids and
the rotation ``cam_R_hand`` of every entry; ``/tiny/<s>`` holds the ``(N, s, s) uint8``
tiny images. A file is a database only when its root attribute ``complete`` is true:
the builder sets it last, then renames the file into place, so an interrupted build
never looks valid.

The reader opens files read-only and holds no lock, so many processes can read one
database at once.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from numpy.typing import NDArray

from glovedb._closing import Closing
from glovedb._validate import as_array

FORMAT_NAME = "glove-posture-db"
FORMAT_VERSION = 1
# Sizes up to this are chunked and compressed (read whole); larger ones are stored
# contiguous and uncompressed so that single rows can be read cheaply.
LARGEST_COMPRESSED_SIZE = 16


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
        }


def image_dataset_options(size: int, entries: int) -> dict[str, Any]:
    """h5py ``create_dataset`` options for the ``(entries, size, size)`` tiny images."""
    if size <= LARGEST_COMPRESSED_SIZE:
        rows = max(1, min(entries, (1 << 20) // (size * size)))
        return {"chunks": (rows, size, size), "compression": "gzip", "compression_opts": 4}
    return {}


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
            shape = file[f"tiny/{size}"].shape
            if shape != (entries, size, size):
                raise ValueError(f"{self.path}: /tiny/{size} has shape {shape}")
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
        return np.asarray(self._dataset(size)[()])

    def image_rows(self, size: int, ids: NDArray[np.integer]) -> NDArray[np.uint8]:
        """Tiny images of the given entries, ``(len(ids), s, s) uint8``, in ``ids`` order."""
        ids = as_array("ids", ids, (None,), np.int64)
        dataset = self._dataset(size)
        if len(ids) and (ids.min() < 0 or ids.max() >= dataset.shape[0]):
            raise ValueError(f"ids: entries must lie in 0..{dataset.shape[0] - 1}")
        order = np.argsort(ids, kind="stable")
        unique, inverse = np.unique(ids[order], return_inverse=True)
        rows = dataset[unique] if len(unique) else np.zeros((0, size, size), np.uint8)
        result = np.empty((len(ids), size, size), np.uint8)
        result[order] = rows[inverse]
        return result

    def _dataset(self, size: int) -> h5py.Dataset:
        if size not in self.resolutions:
            raise ValueError(
                f"size: the database has tiny images of {self.resolutions}, not {size}"
            )
        return self._file[f"tiny/{size}"]

    # Lifetime ------------------------------------------------------------------

    def close(self) -> None:
        """Close the file."""
        self._file.close()


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
