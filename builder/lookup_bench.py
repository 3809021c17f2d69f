"""``glove bench lookup``: speed and accuracy of the cascaded database search.

Queries are held out: postures drawn from the synergy space with a seed the databases
do not use, seen from uniformly random rotations at random places and distances in a
VGA camera, rendered, and spoiled with camera-like label noise (a ragged silhouette,
misclassified and missing glove pixels). Each query's exact nearest entry under the
last stage's distance is found by brute force over the whole (untiled) database, and
compared with what the cascade returns.

The default index (``DatabaseIndex(first_stage="auto")``: distinct images when they
repeat, :mod:`glovedb.distinct_images`) is also checked against the exhaustive cascade,
the same cascade with a first stage that scans every entry's packed images: its top-1
must be the same database entry (tiled copies count as the same entry). The exhaustive
cascade's first-stage data, 32 bytes per entry at 8x8, read once by one core, is the
memory reference the first stage and the whole lookup are judged against.
"""

from __future__ import annotations

import functools
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from builder.render import GloveRenderer
from builder.sampling import synergy_postures
from glovedb.camera import KINECT_V1
from glovedb.chamfer import chamfer_maps
from glovedb.database import GloveDatabase
from glovedb.distinct_images import DistinctTinyImages
from glovedb.inverted_lists import InvertedLists
from glovedb.lookup import DatabaseIndex, FirstStage, FirstStageImages
from glovedb.postures import load_named_postures
from glovedb.rotations import quaternion_to_matrix
from glovedb.search import (
    CoarseMaps,
    SearchResult,
    pack_tiny_images,
    parse_cascade,
    tiny_image_distances,
)
from glovedb.tiny_images import tiny_images
from glovedb.views import HAND_CENTRE

_QUERY_SEED = 987_654
_BRUTE_FORCE_CHUNK = 65_536


@dataclass(frozen=True)
class PairedCascades:
    """The benchmark's cascade and another, searched alternately on the same queries.

    Separate runs of one command on a shared virtual machine differ by up to a third
    in speed; searches that alternate query by query in one process see the same
    machine. Each query is searched with both cascades, in alternating order, and one
    core's read of the first stage's data (as :attr:`LookupBenchmark.first_stage_read_ms`)
    is timed after every tenth query.

    Attributes
    ----------
    cascade : str
        The other cascade (``--against``).
    latency_ms, own_latency_ms : (Q,) float64
        Wall time per query of the other cascade and of the benchmark's, in these
        alternating searches.
    read_ms : (R,) float64
        The read reference, measured between the queries.
    same_top1 : (Q,) bool
        Whether both cascades return the same top entry (tiled copies count as one).
    """

    cascade: str
    latency_ms: NDArray[np.float64]
    own_latency_ms: NDArray[np.float64]
    read_ms: NDArray[np.float64]
    same_top1: NDArray[np.bool_]

    def as_dict(self) -> dict[str, Any]:
        median, own = float(np.median(self.latency_ms)), float(np.median(self.own_latency_ms))
        read = float(np.median(self.read_ms))
        return {
            "cascade": self.cascade,
            "median_ms": round(median, 3),
            "own_median_ms": round(own, 3),
            "paired_difference_ms_median": round(
                float(np.median(self.latency_ms - self.own_latency_ms)), 3
            ),
            "read_ms_median": round(read, 3),
            "median_over_read": round(median / read, 2),
            "own_median_over_read": round(own / read, 2),
            "same_top1": round(float(np.mean(self.same_top1)), 4),
        }


@dataclass(frozen=True)
class LookupBenchmark:
    """Figures of one benchmark run (see :meth:`as_dict` for the JSON keys).

    ``rss_mb`` is the resident memory that opening the database index and searching
    it added to the process (the packed images, the entry tables, the mapped rows
    touched); ``process_rss_mb`` is the whole process, which also holds the libraries
    and the renderer that made the queries. ``first_stage_mb`` and
    ``first_stage_read_ms`` are the size of the first stage's resident codes and the
    time one core takes to read them once (the median of 5 plain sums): the memory
    speed of this machine, against which the first stage's time can be judged. They
    are those of the exhaustive cascade (every entry's packed codes), whatever
    ``first_stage`` the timed index uses. ``exhaustive_latency_ms`` times that
    cascade, ``same_top1`` says per query whether the timed index's top-1 is the
    exhaustive cascade's entry, ``index_build_s`` and ``index_mb`` are the time to
    open the timed index (file read, first-stage structures built) and the bytes of
    its first-stage structure, ``scanned_images`` the number of images it scans
    (of which a query scans ``probe_share`` in ``lists`` inverted lists when the first
    stage is ``"lists"``; :mod:`glovedb.inverted_lists`). ``against`` holds the
    searches alternated with another cascade, when one was given.
    """

    entries: int
    base_entries: int
    cascade: str
    queries: int
    latency_ms: NDArray[np.float64]
    stage_ms: NDArray[np.float64]
    ranks: NDArray[np.int64]
    rss_mb: float
    process_rss_mb: float
    first_stage_mb: float = 0.0
    first_stage_read_ms: float = 0.0
    first_stage: str = "scan"
    exhaustive_latency_ms: NDArray[np.float64] | None = None
    same_top1: NDArray[np.bool_] | None = None
    index_build_s: float = 0.0
    index_mb: float = 0.0
    scanned_images: int = 0
    lists: int = 0
    probe_share: float = 1.0
    against: PairedCascades | None = None

    def as_dict(self) -> dict[str, Any]:
        k = parse_cascade(self.cascade)[-1].k
        median = float(np.median(self.latency_ms))
        first_median = float(np.median(self.stage_ms[:, 0]))
        read = self.first_stage_read_ms
        exhaustive = self.exhaustive_latency_ms
        return {
            "entries": self.entries,
            "base_entries": self.base_entries,
            "cascade": self.cascade,
            "queries": self.queries,
            "latency_ms": {
                "median": round(float(np.median(self.latency_ms)), 3),
                "p95": round(float(np.percentile(self.latency_ms, 95)), 3),
            },
            "stage_ms_median": [round(float(x), 3) for x in np.median(self.stage_ms, axis=0)],
            "queries_per_s": round(1000.0 / float(np.mean(self.latency_ms)), 1),
            "recall_top1": round(float(np.mean(self.ranks == 1)), 4),
            "mean_rank_true_nn": round(float(np.mean(self.ranks)), 3),
            "rank_if_missed": k + 1,
            "rss_mb": round(self.rss_mb, 1),
            "process_rss_mb": round(self.process_rss_mb, 1),
            "first_stage_mb": round(self.first_stage_mb, 3),
            "first_stage_read_ms": round(read, 3),
            "median_over_read": round(median / read, 2) if read > 0 else None,
            "first_stage_over_read": round(first_median / read, 2) if read > 0 else None,
            "first_stage": self.first_stage,
            "scanned_images": self.scanned_images,
            "lists": self.lists,
            "probe_share": self.probe_share,
            "index_build_s": round(self.index_build_s, 3),
            "index_mb": round(self.index_mb, 1),
            "exhaustive_latency_ms_median": None
            if exhaustive is None
            else round(float(np.median(exhaustive)), 3),
            "recall_top1_vs_exhaustive": None
            if self.same_top1 is None
            else round(float(np.mean(self.same_top1)), 4),
            "against": None if self.against is None else self.against.as_dict(),
        }


def held_out_queries(
    count: int, *, seed: int = _QUERY_SEED, noise: bool = True
) -> list[dict[int, NDArray[np.uint8]]]:
    """Tiny images of ``count`` rendered query views (see the module docstring)."""
    rng = np.random.default_rng(seed)
    noise_rng = np.random.default_rng(seed + 1)  # poses must not depend on ``noise``
    named = np.array(list(load_named_postures().values()))
    postures = synergy_postures(count, named, seed=seed)
    queries = []
    with GloveRenderer(KINECT_V1) as renderer:
        centre = np.array(HAND_CENTRE) * renderer.mesh.skeleton.hand_length_m
        for posture in postures:
            quaternion = rng.standard_normal(4)
            rotation = quaternion_to_matrix(quaternion / np.linalg.norm(quaternion))
            place = np.array(
                [rng.uniform(-0.08, 0.08), rng.uniform(-0.06, 0.06), rng.uniform(0.5, 0.9)]
            )
            labels = renderer.render_labels(posture, rotation, place - rotation @ centre).labels
            if noise:
                labels = label_noise(labels, noise_rng)
            queries.append(tiny_images(labels))
    return queries


def label_noise(labels: NDArray[np.uint8], rng: np.random.Generator) -> NDArray[np.uint8]:
    """Camera-like damage to a label image: the silhouette grows or shrinks by a pixel
    in places, 2% of glove pixels take a wrong class and 3% go missing."""
    import cv2

    noisy = labels.copy()
    kernel = np.ones((3, 3), np.uint8)
    grown = cv2.dilate(labels, kernel)
    shrunk = cv2.erode((labels > 0).astype(np.uint8), kernel)
    patchy = rng.random(labels.shape) < 0.5
    noisy[patchy & (labels == 0)] = grown[patchy & (labels == 0)]
    noisy[~patchy & (shrunk == 0)] = 0
    glove = np.flatnonzero(noisy)
    wrong = rng.choice(glove, size=len(glove) // 50, replace=False)
    noisy.flat[wrong] = rng.integers(1, 11, size=len(wrong))
    missing = rng.choice(glove, size=len(glove) * 3 // 100, replace=False)
    noisy.flat[missing] = 0
    return noisy


def brute_force_errors(
    index: DatabaseIndex, queries: NDArray[np.uint8], *, entries: int | None = None
) -> NDArray[np.float32]:
    """Directed distance of every distinct entry to each query image, chunk by chunk.

    Each chunk of entries is read and packed once for all the queries (reading and
    packing 756,000 images of 64 x 64 take far longer than scanning them).

    Parameters
    ----------
    index : DatabaseIndex
    queries : (..., s, s) uint8
        One query image or a stack of them.
    entries : int, optional
        Only the first ``entries`` entries of the file (a truncated database);
        default all of them (tiling repeats them, so adds nothing).

    Returns
    -------
    (..., entries) float32
    """
    size = queries.shape[-1]
    stack = queries.reshape(-1, size, size)
    maps = [chamfer_maps(query) for query in stack]
    count = index.base_entries if entries is None else min(entries, index.base_entries)
    errors = np.empty((len(stack), count), np.float32)
    for start in range(0, count, _BRUTE_FORCE_CHUNK):
        ids = np.arange(start, min(count, start + _BRUTE_FORCE_CHUNK))
        packed = pack_tiny_images(index.rows(size, ids))
        for query_maps, query_errors in zip(maps, errors, strict=True):
            query_errors[start : start + len(ids)] = tiny_image_distances(query_maps, packed)
    return errors.reshape((*queries.shape[:-2], count))


def exact_nearest_errors(
    database: str,
    query_images: list[dict[int, NDArray[np.uint8]]],
    size: int,
    *,
    entries: int | None = None,
) -> NDArray[np.float64]:
    """The smallest error of any searched entry for each query at ``size`` (brute force);
    ``entries`` as in :func:`brute_force_errors`."""
    queries = np.stack([query[size] for query in query_images])
    with DatabaseIndex(database, resident_sizes=()) as index:
        return brute_force_errors(index, queries, entries=entries).min(axis=1).astype(np.float64)


def run_lookup_benchmark(
    database: str,
    *,
    cascade: str,
    entries: int | None = None,
    queries: int = 20,
    workers: int | None = None,
    seed: int = _QUERY_SEED,
    query_images: list[dict[int, NDArray[np.uint8]]] | None = None,
    exact_errors: NDArray[np.float64] | None = None,
    coarse_maps: CoarseMaps = "cell_mean",
    first_stage: FirstStage = "auto",
    against: str | None = None,
) -> LookupBenchmark:
    """Time held-out lookups and score them against brute force and the exhaustive cascade.

    ``query_images`` and ``exact_errors`` (from :func:`held_out_queries` and
    :func:`exact_nearest_errors` at the cascade's last size) may be passed in to reuse
    them across runs; by default they are made here. ``coarse_maps`` as in
    :func:`glovedb.search.cascade_search`, ``first_stage`` as in
    :class:`glovedb.lookup.DatabaseIndex`. ``against``: another cascade, timed
    alternately with ``cascade`` on the same queries (:class:`PairedCascades`).
    """
    with GloveDatabase(database) as checked:  # a bad file or cascade fails before rendering
        parse_cascade(cascade, sizes=checked.resolutions)
        if against is not None:
            parse_cascade(against, sizes=checked.resolutions)
    if query_images is None:
        query_images = held_out_queries(queries, seed=seed)
    stages = parse_cascade(cascade)
    if exact_errors is None:
        exact_errors = exact_nearest_errors(
            database, query_images, stages[-1].size, entries=entries
        )

    def searcher(index: DatabaseIndex) -> Callable[[dict[int, NDArray[np.uint8]]], SearchResult]:
        return functools.partial(
            index.search, cascade=cascade, workers=workers, coarse_maps=coarse_maps
        )

    with DatabaseIndex(database, tile_to=entries, first_stage="scan") as exhaustive:
        exhaustive_results, exhaustive_ms = _timed_searches(searcher(exhaustive), query_images)
        packed = exhaustive.packed(stages[0].size)
        first_stage_mb, read_ms = packed.codes.nbytes / 1e6, memory_read_ms(packed.codes)
        codes_shape, codes_dtype = packed.codes.shape, packed.codes.dtype
        exhaustive_top1 = exhaustive.base_ids(
            np.array([result.entry_ids[0] for result in exhaustive_results])
        )
    del exhaustive, packed
    rss_before = _resident_mb()
    started = time.perf_counter()
    with DatabaseIndex(database, tile_to=entries, first_stage=first_stage) as index:
        build_s = time.perf_counter() - started
        scanned = index.first_stage_images(stages[0].size)
        results, latencies = _timed_searches(searcher(index), query_images)
        ranks = []
        for result, best in zip(results, exact_errors, strict=True):
            # The exact nearest error: a returned entry with that error is a hit (ties).
            hits = np.flatnonzero(np.isclose(result.errors, best, rtol=0, atol=1e-5))
            ranks.append(int(hits[0]) + 1 if len(hits) else stages[-1].k + 1)
        top1 = index.base_ids(np.array([result.entry_ids[0] for result in results]))
        rss_mb, process_rss_mb = _resident_mb() - rss_before, _resident_mb()
        paired = None
        if against is not None:
            reference = np.ones(codes_shape, codes_dtype)  # as large as the first stage
            paired = _paired_searches(
                index, query_images, cascade, against, reference,
                workers=workers, coarse_maps=coarse_maps,
            )  # fmt: skip
        return LookupBenchmark(
            entries=index.entries,
            base_entries=index.base_entries,
            cascade=cascade,
            queries=len(query_images),
            latency_ms=latencies,
            stage_ms=np.array([result.stage_ms for result in results]),
            ranks=np.array(ranks),
            rss_mb=rss_mb,
            process_rss_mb=process_rss_mb,
            first_stage_mb=first_stage_mb,
            first_stage_read_ms=read_ms,
            first_stage=_first_stage_name(scanned),
            exhaustive_latency_ms=exhaustive_ms,
            same_top1=top1 == exhaustive_top1,
            index_build_s=build_s,
            index_mb=scanned.nbytes / 1e6,
            scanned_images=_scanned_images(scanned),
            lists=scanned.num_lists if isinstance(scanned, InvertedLists) else 0,
            probe_share=scanned.probe_share if isinstance(scanned, InvertedLists) else 1.0,
            against=paired,
        )


def _first_stage_name(stage: FirstStageImages) -> str:
    if isinstance(stage, InvertedLists):
        return "lists"
    return "distinct" if isinstance(stage, DistinctTinyImages) else "scan"


def _scanned_images(stage: FirstStageImages) -> int:
    """Images the first stage holds: distinct ones, or one per entry."""
    if isinstance(stage, InvertedLists):
        return stage.images.num_images
    return stage.num_images if isinstance(stage, DistinctTinyImages) else stage.num_entries


def _timed_searches(
    search: Callable[[dict[int, NDArray[np.uint8]]], SearchResult],
    query_images: list[dict[int, NDArray[np.uint8]]],
) -> tuple[list[SearchResult], NDArray[np.float64]]:
    """Results and wall times (ms) of searching every query, after a warm-up search
    (compiling, mapping pages)."""
    search(query_images[0])
    results, latencies = [], []
    for query in query_images:
        started = time.perf_counter()
        results.append(search(query))
        latencies.append((time.perf_counter() - started) * 1000.0)
    return results, np.array(latencies)


def _paired_searches(
    index: DatabaseIndex,
    query_images: list[dict[int, NDArray[np.uint8]]],
    cascade: str,
    against: str,
    reference: NDArray[Any],
    *,
    workers: int | None,
    coarse_maps: CoarseMaps,
) -> PairedCascades:
    """Search every query with both cascades, in alternating order, after a warm-up
    search with each; time ``reference``'s read after every tenth query."""
    times: dict[str, list[float]] = {cascade: [], against: []}
    top: dict[str, list[int]] = {cascade: [], against: []}
    reads = []
    for name in (cascade, against):
        index.search(query_images[0], name, workers=workers, coarse_maps=coarse_maps)
    for number, query in enumerate(query_images):
        for name in (cascade, against) if number % 2 else (against, cascade):
            started = time.perf_counter()
            result = index.search(query, name, workers=workers, coarse_maps=coarse_maps)
            times[name].append((time.perf_counter() - started) * 1000.0)
            top[name].append(int(result.entry_ids[0]))
        if number % 10 == 0:
            reads.append(memory_read_ms(reference))
    return PairedCascades(
        cascade=against,
        latency_ms=np.array(times[against]),
        own_latency_ms=np.array(times[cascade]),
        read_ms=np.array(reads),
        same_top1=index.base_ids(np.array(top[cascade])) == index.base_ids(np.array(top[against])),
    )


def memory_read_ms(array: NDArray[Any], repeats: int = 5) -> float:
    """Milliseconds one core takes to read ``array`` once (median of ``repeats`` sums
    over it as 64-bit words; the sum's arithmetic hides behind the memory reads)."""
    flat = array.reshape(-1).view(np.uint8)
    words = flat[: len(flat) // 8 * 8].view(np.uint64)
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        np.add.reduce(words, dtype=np.uint64)
        times.append((time.perf_counter() - started) * 1000.0)
    return float(np.median(times))


def _resident_mb() -> float:
    """Resident memory of this process now, MB (Linux /proc; 0 elsewhere)."""
    try:
        with open(f"/proc/{os.getpid()}/status") as status:
            for line in status:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return 0.0
