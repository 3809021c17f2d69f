"""Cascaded k-nearest-neighbour lookup of a query's tiny images in a posture database.

The cascade (Schröder 2015, Sec. 4.2.2, Fig. 4.5) is written ``"8:2000,16:200,64:3"``:
scan every entry at 8x8 and keep the 2000 nearest, re-rank those at 16x16 and keep
200, re-rank those at 64x64 and keep 3. :func:`interpolate_pose` then blends the
postures and rotations of the survivors, weighted by their matching errors.

Which distance
    Every stage ranks entries ``D`` by the directed distance ``m(D, Q)`` of Eq. 4.2
    (:mod:`glovedb.chamfer`): the mean distance from each glove pixel of the database
    image to the nearest query pixel of the same colour. It needs the chamfer maps of
    the query only, computed once per query, while a database entry costs only
    lookups of its glove pixels in those maps and nothing is stored per entry but its
    labels. The last stage uses the query's exact maps at its size, so its errors and
    order are exactly Eq. 4.2, as brute force gives them. Earlier stages, by default
    (``coarse_maps="cell_mean"``), look up the last stage's maps averaged over each
    coarse cell (:func:`glovedb.chamfer.cell_mean_maps`): a coarse database pixel is
    the majority colour of its cell, wherever in the cell that colour lies, and its
    expected distance ranks far better than the distance to a re-quantised query.
    On 40 held-out noisy queries against 756,000 entries, the exact nearest entry at
    32x32 ranked at most 437th in the 8x8 scan with cell-mean maps, and up to
    59,653rd with the exact 8x8 maps (``coarse_maps="exact"``). ``m(Q, D)``
    (or the symmetric mean) would need the maps of every database image: ten values
    per pixel, 2.6 GB at 1,000,000 entries of 16x16 even as bytes, or an exact
    transform per candidate per query. Known weakness of the directed form: an entry
    whose glove pixels all lie on same-coloured query pixels scores 0 even if it shows
    only part of the hand. Tiny images are normalised to the hand's bounding box,
    which keeps such subsets rare.

Resident layout
    The first stage scans images in the compact layout of :mod:`glovedb.packed_images`
    (16 lookups and 32 bytes per 8x8 image). The scan runs in chunks on a thread pool
    (the compiled kernel releases the GIL). The quantile of a strided sample bounds the
    k smallest errors, so only a few thousand candidates are sorted; ties are broken by
    the lower entry id.

Distinct images
    The first stage's source may instead be a
    :class:`~glovedb.distinct_images.DistinctTinyImages`: each distinct image is scored
    once and its error handed to all its entries. The stage's result is the same as
    the full scan's (same entries, errors and order), at the cost of scanning the
    distinct images only; :class:`glovedb.lookup.DatabaseIndex` uses it when images
    repeat (see :mod:`glovedb.distinct_images`).

Inverted lists
    Or an :class:`~glovedb.inverted_lists.InvertedLists`: the images grouped into
    lists of similar images, of which a query scans the few whose mean distance to it
    is smallest (:mod:`glovedb.inverted_lists`). Approximate: an entry in a list that
    is not scanned is not found; scanning every list gives the full scan's result.

Sources
    Each size in the ``database`` mapping is a :class:`PackedTinyImages` or, for the
    first stage only, a :class:`~glovedb.distinct_images.DistinctTinyImages` or
    :class:`~glovedb.inverted_lists.InvertedLists` (resident; the first stage needs one
    of them), an ``(N, s, s) uint8`` array, a
    :data:`RowLoader` ``ids -> (len(ids), s, s) uint8`` that the HDF5 reader can supply
    for the large sizes (the few rows a later stage needs are scanned as plain labels:
    packing them would cost more than scanning them), or, for a later stage, a
    :class:`RowScorer` that scores the rows where they are: the database file's
    run-length coded rows cost a few hundred steps each at 64 x 64 instead of
    decoding and 4,096 lookups (their errors agree with a scan of the decoded images
    to float32 rounding).
"""

from __future__ import annotations

import itertools
import math
import os
import time
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass
from typing import Literal, TypeAlias

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb import _search_kernels
from glovedb._ordering import split_keys, value_id_order
from glovedb._threads import run_parts, thread_pool
from glovedb._validate import as_array, check_choice
from glovedb.chamfer import (
    NUM_CLASSES,
    cell_mean_maps,
    chamfer_maps,
    check_labels,
)
from glovedb.distinct_images import DistinctTinyImages, range_positions
from glovedb.inverted_lists import InvertedLists, probed_lists
from glovedb.packed_images import PackedTinyImages, code_table, pack_tiny_images
from glovedb.rotations import weighted_rotation_average

CoarseMaps: TypeAlias = Literal["cell_mean", "exact"]
COARSE_MAPS: tuple[CoarseMaps, ...] = ("cell_mean", "exact")

RowLoader: TypeAlias = Callable[[NDArray[np.int64]], ArrayLike]
"""Loads the tiny images of the given entry ids (ascending, unique) as ``(m, s, s)``."""


@dataclass(frozen=True)
class RowScorer:
    """A later stage's source that scores rows where they are stored, without handing
    out their images (the run-length coded rows of a database file:
    :func:`glovedb.database.score_file_rows`).

    Attributes
    ----------
    score : callable
        ``score(ids, maps) -> (m,) float32``: ``m(D, Q)`` of the entries ``ids``
        (ascending, unique) for the query's chamfer maps ``(10, s, s) float32``.
    """

    score: Callable[[NDArray[np.int64], NDArray[np.float32]], NDArray[np.float32]]


_MIN_ROWS_PER_CHUNK = 1 << 14
"""Smaller scans run on the calling thread alone. On a 2-core KVM machine, waking a
pool thread that idled for a millisecond took 120-180 microseconds, and splitting the
cascade's later stages (2,000 rows of 16x16, 100-200 of 64x64) or the lists' ranking
over two threads gained nothing."""
_SAMPLE_SIZE = 1 << 14


@dataclass(frozen=True)
class CascadeStage:
    """One stage of the cascade: re-rank at ``size`` and keep the ``k`` nearest."""

    size: int
    k: int


TinyImageSource: TypeAlias = (
    PackedTinyImages
    | DistinctTinyImages
    | InvertedLists
    | NDArray[np.uint8]
    | RowLoader
    | RowScorer
)
"""The images of one size in ``cascade_search``'s ``database`` mapping."""


@dataclass(frozen=True)
class SearchResult:
    """Outcome of :func:`cascade_search`, nearest first.

    Attributes
    ----------
    entry_ids : (k,) int64
        Database entry ids, by increasing error (ties: lower id first). ``k`` is the
        last stage's k, or fewer if the database is smaller.
    errors : (k,) float32
        Matching error ``m(D, Q)`` in pixels at the last stage's size.
    stage_ms : tuple of float
        Wall time of each stage in milliseconds (query maps, loading, scan, selection).
    cascade : tuple of CascadeStage
        The stages that ran.
    """

    entry_ids: NDArray[np.int64]
    errors: NDArray[np.float32]
    stage_ms: tuple[float, ...]
    cascade: tuple[CascadeStage, ...]


@dataclass(frozen=True)
class InterpolatedPose:
    """Posture and rotation blended from the nearest entries by :func:`interpolate_pose`.

    Attributes
    ----------
    posture_rad : (20,) float64
        Weighted mean joint angles in radians (NaN when not ``valid``).
    rotation : (3, 3) float64
        Weighted average rotation (NaN when not ``valid``).
    weights : (k,) float64
        Normalised weight of each entry (zeros when not ``valid``).
    valid : bool
        False when no entry had a finite error.
    """

    posture_rad: NDArray[np.float64]
    rotation: NDArray[np.float64]
    weights: NDArray[np.float64]
    valid: bool


def parse_cascade(spec: str, *, sizes: Collection[int] | None = None) -> tuple[CascadeStage, ...]:
    """Parse ``"size:k,size:k,..."`` into cascade stages.

    Parameters
    ----------
    spec : str
        Comma-separated ``size:k`` pairs, e.g. ``"8:2000,16:200,64:3"``.
    sizes : collection of int, optional
        Tiny image sizes the database holds; every stage size must be one of them.

    Returns
    -------
    tuple of CascadeStage

    Raises
    ------
    ValueError
        On a malformed pair, a non-positive size or k, sizes that do not strictly
        increase, k values that increase, or a size not in ``sizes``.
    """
    if not isinstance(spec, str):
        raise TypeError(f"cascade: expected a string such as '8:2000,64:3', got {type(spec)}")
    stages = []
    for part in spec.split(","):
        fields = part.strip().split(":")
        if len(fields) != 2 or not all(f.strip().isdigit() for f in fields):
            raise ValueError(f"cascade: expected 'size:k' pairs like '8:2000,64:3', got {spec!r}")
        stages.append(CascadeStage(size=int(fields[0]), k=int(fields[1])))
    return check_cascade(stages, sizes=sizes)


def check_cascade(
    stages: Sequence[CascadeStage], *, sizes: Collection[int] | None = None
) -> tuple[CascadeStage, ...]:
    """Check cascade stages (see :func:`parse_cascade` for the rules) and return them."""
    stages = tuple(stages)
    if not stages:
        raise ValueError("cascade: needs at least one stage")
    for stage in stages:
        if stage.size < 1 or stage.k < 1:
            raise ValueError(f"cascade: size and k must be positive, got {stage.size}:{stage.k}")
        if sizes is not None and stage.size not in sizes:
            raise ValueError(
                f"cascade: size {stage.size} is not in the database (has {sorted(sizes)})"
            )
    for before, after in itertools.pairwise(stages):
        if after.size <= before.size:
            raise ValueError(f"cascade: sizes must increase, got {before.size} then {after.size}")
        if after.k > before.k:
            raise ValueError(f"cascade: k must not increase, got {before.k} then {after.k}")
    return stages


def tiny_image_distances(
    query_maps: ArrayLike, packed: PackedTinyImages, *, workers: int | None = None
) -> NDArray[np.float32]:
    """Directed distance ``m(D, Q)`` of every packed image ``D`` to the query ``Q``.

    Parameters
    ----------
    query_maps : (10, s, s) float32
        Chamfer maps of the query (:func:`glovedb.chamfer.chamfer_maps`).
    packed : PackedTinyImages
        Database images of the same size ``s``.
    workers : int, optional
        Threads for the scan; default ``os.cpu_count()``.

    Returns
    -------
    (N,) float32
        Pixels; ``inf`` for images without glove pixels.
    """
    return _scan(query_maps, packed, workers)


def cascade_search(
    query_images: Mapping[int, ArrayLike],
    database: Mapping[int, TinyImageSource],
    cascade: str | Sequence[CascadeStage],
    *,
    workers: int | None = None,
    coarse_maps: CoarseMaps = "cell_mean",
) -> SearchResult:
    """Cascaded k-NN search of a query's tiny images (see the module docstring).

    Parameters
    ----------
    query_images : mapping of int to (s, s) uint8
        The query's tiny image for every size in the cascade. Each must have at least
        one glove pixel.
    database : mapping of int to TinyImageSource
        Tiny images of all ``N`` entries per size (module docstring). The first
        stage's size must be in memory (packed, distinct, lists, or an array that is
        packed on every call, which is slow); distinct images and lists serve the
        first stage only, loaders and scorers the later ones.
    cascade : str or sequence of CascadeStage
        E.g. ``"8:2000,16:200,64:3"``; checked by :func:`check_cascade`.
    workers : int, optional
        Threads for the scans; default ``os.cpu_count()``.
    coarse_maps : {"cell_mean", "exact"}
        The query maps of the stages before the last: the last stage's maps averaged
        over the coarse cells (when the sizes divide; see the module docstring), or
        the exact maps of the query's tiny image at the stage's size.

    Returns
    -------
    SearchResult
    """
    check_choice("coarse_maps", coarse_maps, COARSE_MAPS)
    stages = (
        parse_cascade(cascade, sizes=database.keys())
        if isinstance(cascade, str)
        else check_cascade(cascade, sizes=database.keys())
    )
    num_entries = _num_entries(database, stages[0].size)
    ids: NDArray[np.int64] | None = None
    ranked_ids = np.empty(0, np.int64)
    errors = np.empty(0, np.float32)
    stage_ms = []
    for stage in stages:
        start = time.perf_counter()
        if stage is stages[0]:  # timed with the first stage
            last_maps = chamfer_maps(_query_image(query_images, stages[-1].size))
        if stage.size == stages[-1].size:
            maps = last_maps
        elif coarse_maps == "cell_mean" and stages[-1].size % stage.size == 0:
            maps = cell_mean_maps(last_maps, stage.size)
        else:
            maps = chamfer_maps(_query_image(query_images, stage.size))
        source = database[stage.size]
        if isinstance(source, DistinctTinyImages):  # the first stage (_num_entries)
            image_errors = _scan(maps, source.images, workers)
            ranked_ids, errors = _smallest_entries(source, image_errors, stage.k)
        elif isinstance(source, InvertedLists):  # the first stage (_num_entries)
            ranked_ids, errors = _scan_lists(maps, source, stage.k, workers)
        else:
            if isinstance(source, RowScorer):  # a later stage (_num_entries)
                assert ids is not None
                stage_errors = as_array(
                    f"errors scored for database[{stage.size}]", source.score(ids, maps),
                    (len(ids),), np.float32,
                )  # fmt: skip
            else:
                stage_errors = _scan(maps, _rows(source, ids, stage.size, num_entries), workers)
            keep = _smallest(stage_errors, stage.k)
            ranked_ids = keep if ids is None else ids[keep]
            errors = stage_errors[keep]
        ascending = np.argsort(ranked_ids)
        ids = ranked_ids[ascending]
        stage_ms.append(1000.0 * (time.perf_counter() - start))
    return SearchResult(
        entry_ids=ranked_ids.astype(np.int64),
        errors=errors,
        stage_ms=tuple(stage_ms),
        cascade=stages,
    )


def interpolate_pose(
    errors: ArrayLike,
    postures_rad: ArrayLike,
    rotations: ArrayLike,
    *,
    epsilon_px: float = 0.01,
    power: float = 2.0,
) -> InterpolatedPose:
    """Blend the nearest entries' poses with weights ``1 / (error + epsilon_px)**power``.

    Shepard's inverse distance weighting; with the classic ``power`` 2 the best entry
    dominates more than with 1, and when the nearest entries come from different
    postures their blend is less of a compromise. On DB_open+pinch+power and the
    noisy Tr1-Tr5, power 2 instead of 1 lowered the tracker's mean posture error from
    2.20 to 2.03 degrees (Tr4: 2.42 to 2.00; Tr5: 2.97 to 2.73). Joint angles are
    averaged arithmetically (they lie within joint limits, far from the +-pi wrap);
    rotations with :func:`glovedb.rotations.weighted_rotation_average`.

    Parameters
    ----------
    errors : (k,) float32
        Matching errors in pixels (``SearchResult.errors``); ``inf`` gets weight 0.
    postures_rad : (k, 20) float
        Postures of the entries in radians.
    rotations : (k, 3, 3) float
        Rotations of the entries.
    epsilon_px : float
        Keeps the weight of an exact match (error 0) finite, in pixels.
    power : float
        Exponent of the inverse error (positive).

    Returns
    -------
    InterpolatedPose
    """
    error = as_array("errors", errors, (None,), np.float64, kind="fiu")
    postures = as_array("postures_rad", postures_rad, (len(error), 20), np.float64, finite=True)
    rotation = as_array("rotations", rotations, (len(error), 3, 3), np.float64, finite=True)
    if not epsilon_px > 0:
        raise ValueError(f"epsilon_px: must be positive, got {epsilon_px}")
    if not power > 0:
        raise ValueError(f"power: must be positive, got {power}")
    if np.any(np.isnan(error)) or np.any(error < 0):
        raise ValueError("errors: must be non-negative (inf allowed)")
    weights = np.where(np.isfinite(error), (error + epsilon_px) ** -power, 0.0)
    if not np.any(weights > 0):
        return InterpolatedPose(
            posture_rad=np.full(20, np.nan),
            rotation=np.full((3, 3), np.nan),
            weights=np.zeros(len(error)),
            valid=False,
        )
    weights /= weights.sum()
    return InterpolatedPose(
        posture_rad=weights @ postures,
        rotation=weighted_rotation_average(rotation, weights),
        weights=weights,
        valid=True,
    )


def _scan(
    query_maps: ArrayLike, rows: PackedTinyImages | NDArray[np.uint8], workers: int | None
) -> NDArray[np.float32]:
    """``m(D, Q)`` of all rows, scanned in chunks on ``workers`` threads.

    ``rows`` are packed images or ``(M, s * s) uint8`` labels (a few loaded
    candidates, for which packing would cost more than the scan).
    """
    workers = (os.cpu_count() or 1) if workers is None else workers
    if workers < 1:
        raise ValueError(f"workers: must be at least 1, got {workers}")
    if isinstance(rows, PackedTinyImages):
        size = rows.size
        maps = as_array("query_maps", query_maps, (NUM_CLASSES, size, size), np.float32)
        table = code_table(maps, rows.group)
        codes, glove_pixels = rows.codes, rows.glove_pixels
        num_rows = len(codes)

        def score(start_stop: tuple[int, int]) -> None:
            _search_kernels.score_rows(codes, glove_pixels, table, *start_stop, errors)

    else:
        size = math.isqrt(rows.shape[1])
        maps = as_array("query_maps", query_maps, (NUM_CLASSES, size, size), np.float32)
        background = np.zeros((1, size * size), np.float32)
        lookup = np.concatenate([background, maps.reshape(NUM_CLASSES, -1)])
        labels = rows
        num_rows = len(labels)

        def score(start_stop: tuple[int, int]) -> None:
            _search_kernels.score_label_rows(labels, lookup, *start_stop, errors)

    # A few chunks per thread balance the load when another process takes a core.
    num_chunks = max(1, min(4 * workers, num_rows // _MIN_ROWS_PER_CHUNK))
    bounds = np.linspace(0, num_rows, num_chunks + 1)
    starts_stops = list(itertools.pairwise(bounds.astype(np.int64).tolist()))
    errors = np.empty(num_rows, np.float32)
    if workers == 1 or len(starts_stops) == 1:
        for start_stop in starts_stops:
            score(start_stop)
    else:
        list(thread_pool(workers).map(score, starts_stops))
    return errors


def _smallest(
    errors: NDArray[np.float32], k: int, ids: NDArray[np.int64] | None = None
) -> NDArray[np.int64]:
    """Indices of the ``k`` smallest errors, ascending by (error, index), or by
    (error, ``ids[index]``) when ``ids`` are given.

    A strided sample's quantile, a little above ``k / N``, bounds the candidates so
    that only a few thousand are sorted; if it is too tight, all are.
    """
    k = min(k, len(errors))
    if k == 0:
        return np.empty(0, np.int64)
    rows = np.flatnonzero(errors <= _candidate_bound(errors, k))
    if len(rows) < k:
        rows = np.arange(len(errors))
    return rows[value_id_order(errors[rows], rows if ids is None else ids[rows])[:k]]


def _candidate_bound(errors: NDArray[np.float32], k: int) -> np.float32:
    """A strided sample's quantile a little above ``k / N`` of ``errors`` (``k >= 1``):
    usually a few thousand errors lie at or below it, and at least ``k``."""
    stride = max(1, len(errors) // _SAMPLE_SIZE)
    sample = errors[::stride]
    rank = min(len(sample) - 1, math.ceil(1.5 * k / stride) + 32)
    return np.partition(sample, rank)[rank]


def _smallest_in_ranges(
    errors: NDArray[np.float32],
    entry_ids: NDArray[np.int64],
    starts: NDArray[np.int64],
    lengths: NDArray[np.int64],
    k: int,
) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
    """:func:`_smallest_entries` of images that each show one entry, scanned in the
    ranges ``starts[i]:starts[i] + lengths[i]`` (``errors`` in that order), without
    listing the scanned positions: one compiled pass keeps the candidates."""
    k = min(k, len(errors))
    if k == 0:
        return np.empty(0, np.int64), np.empty(0, np.float32)
    keys = np.empty(len(errors), np.uint64)
    bound = _candidate_bound(errors, k)
    count = _search_kernels.keys_at_most(errors, entry_ids, starts, lengths, bound, keys)
    if count < k:
        count = _search_kernels.keys_at_most(
            errors, entry_ids, starts, lengths, np.float32(np.inf), keys
        )
    return split_keys(np.sort(keys[:count])[:k])


def _smallest_entries(
    distinct: DistinctTinyImages,
    image_errors: NDArray[np.float32],
    k: int,
    images: NDArray[np.int64] | None = None,
) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
    """The ``k`` entries with the smallest errors, ascending by (error, entry id), and
    their errors, from the errors of the distinct images (of all, or of the scanned
    ``images``, ascending, which hold at least ``k`` entries or all of them): what
    :func:`_smallest` gives on the errors of their entries.

    The ``k`` best images hold at least ``k`` entries; those up to the one that
    completes ``k`` entries, and every image tied with it, are expanded to entries.
    """
    offsets = distinct.offsets
    scanned = np.arange(len(image_errors)) if images is None else images
    k = min(k, distinct.num_entries)  # scanned images hold at least k entries
    if k == 0:
        return np.empty(0, np.int64), np.empty(0, np.float32)
    if distinct.num_entries == distinct.num_images:  # one entry per image
        entry_ids = distinct.entry_ids[scanned]
        keep = _smallest(image_errors, k, entry_ids)
        return entry_ids[keep], image_errors[keep]
    candidates = _smallest(image_errors, k)
    covered = np.cumsum(offsets[scanned[candidates] + 1] - offsets[scanned[candidates]])
    cut = image_errors[candidates[int(np.searchsorted(covered, k))]]
    if len(candidates) < len(image_errors) and image_errors[candidates[-1]] <= cut:
        chosen = np.flatnonzero(image_errors <= cut)  # ties beyond the candidates
    else:
        chosen = candidates[image_errors[candidates] <= cut]
    starts = offsets[scanned[chosen]]
    lengths = offsets[scanned[chosen] + 1] - starts
    entry_ids = distinct.entry_ids[range_positions(starts, lengths)]
    entry_errors = np.repeat(image_errors[chosen], lengths)
    order = value_id_order(entry_errors, entry_ids)[:k]
    return entry_ids[order], entry_errors[order]


def _scan_lists(
    query_maps: NDArray[np.float32], lists: InvertedLists, k: int, workers: int | None
) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
    """The ``k`` nearest entries among the lists a query probes, and their errors."""
    workers = (os.cpu_count() or 1) if workers is None else workers
    if workers < 1:
        raise ValueError(f"workers: must be at least 1, got {workers}")
    packed = lists.images.images
    size = packed.size
    maps = as_array("query_maps", query_maps, (NUM_CLASSES, size, size), np.float32)
    probed = probed_lists(lists, maps, k)
    starts = lists.list_offsets[probed]
    stops = lists.list_offsets[probed + 1]
    table = code_table(maps, packed.group)
    lengths = stops - starts
    ends = np.cumsum(lengths)
    errors = np.empty(int(ends[-1]), np.float32)  # of the probed images, in order

    def score(first: int, last: int) -> None:
        written = errors[ends[first] - lengths[first] : ends[last - 1]]
        _search_kernels.score_ranges(
            packed.codes, packed.glove_pixels, table, starts[first:last], stops[first:last], written
        )

    # ``workers`` parts of about equal rows.
    cuts = np.searchsorted(ends, ends[-1] * np.arange(1, workers) / workers).tolist()
    run_parts(score, [0, *cuts, len(starts)], workers)
    if lists.images.num_entries == lists.images.num_images:  # one entry per image
        return _smallest_in_ranges(errors, lists.images.entry_ids, starts, lengths, k)
    return _smallest_entries(lists.images, errors, k, range_positions(starts, lengths))


def _query_image(query_images: Mapping[int, ArrayLike], size: int) -> NDArray[np.uint8]:
    if size not in query_images:
        raise ValueError(f"query_images: no tiny image of size {size}")
    name = f"query_images[{size}]"
    image = check_labels(name, query_images[size], (size, size))
    if not np.any(image):
        raise ValueError(f"{name}: has no glove pixels")
    return image


def _num_entries(database: Mapping[int, TinyImageSource], first_size: int) -> int:
    """Entries in the database; checks that the first stage's images are in memory
    and that distinct images and lists (which have no rows by entry) serve only that
    stage."""
    for size, source in database.items():
        if isinstance(source, DistinctTinyImages | InvertedLists):
            distinct = source if isinstance(source, DistinctTinyImages) else source.images
            images = distinct.images
            if size != first_size:
                raise ValueError(
                    f"database[{size}]: distinct images and lists serve the first stage only"
                )
            if images.size != size:
                raise ValueError(f"database[{size}]: holds {images.size}x{images.size} images")
    counts = {
        size: source.num_entries
        if isinstance(source, PackedTinyImages | DistinctTinyImages | InvertedLists)
        else len(source)
        for size, source in database.items()
        if not callable(source) and not isinstance(source, RowScorer)
    }
    if first_size not in counts:
        raise ValueError(f"database[{first_size}]: the first stage's images must be in memory")
    if len(set(counts.values())) > 1:
        raise ValueError(f"database: sizes hold different numbers of entries: {counts}")
    return counts[first_size]


def _rows(
    source: TinyImageSource,
    ids: NDArray[np.int64] | None,
    size: int,
    num_entries: int,
) -> PackedTinyImages | NDArray[np.uint8]:
    """The images of ``ids`` (ascending), or of all entries when ``ids`` is None:
    packed, or as ``(M, s * s)`` labels when loaded or sliced for a few ids."""
    name = f"database[{size}]"
    assert not isinstance(source, DistinctTinyImages | InvertedLists)  # first stage only
    assert not isinstance(source, RowScorer)  # scored by cascade_search
    if isinstance(source, PackedTinyImages):
        if source.size != size:
            raise ValueError(f"{name}: holds {source.size}x{source.size} images")
        return source if ids is None else source.take(ids)
    if callable(source):
        assert ids is not None  # _num_entries rejects a loader in the first stage
        loaded = as_array(f"rows loaded for {name}", source(ids), (len(ids), size, size))
        return _flat_labels(check_labels(f"rows loaded for {name}", loaded))
    images = as_array(name, source, (num_entries, size, size), kind="iu")
    if ids is None:
        return pack_tiny_images(images)
    return _flat_labels(check_labels(name, images[ids]))


def _flat_labels(images: NDArray[np.uint8]) -> NDArray[np.uint8]:
    return np.ascontiguousarray(images.reshape(len(images), -1))
