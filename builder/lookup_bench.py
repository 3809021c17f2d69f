"""``glove bench lookup``: speed and accuracy of the cascaded database search.

Queries are held out: postures drawn from the synergy space with a seed the databases
do not use, seen from uniformly random rotations at random places and distances in a
VGA camera, rendered, and spoiled with camera-like label noise (a ragged silhouette,
misclassified and missing glove pixels). Each query's exact nearest entry under the
last stage's distance is found by brute force over the whole (untiled) database, and
compared with what the cascade returns.
"""

from __future__ import annotations

import functools
import os
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from builder.render import GloveRenderer
from builder.sampling import synergy_postures
from glovedb.camera import KINECT_V1
from glovedb.chamfer import chamfer_maps
from glovedb.database import GloveDatabase
from glovedb.lookup import DatabaseIndex
from glovedb.postures import load_named_postures
from glovedb.rotations import quaternion_to_matrix
from glovedb.search import CoarseMaps, pack_tiny_images, parse_cascade, tiny_image_distances
from glovedb.tiny_images import tiny_images
from glovedb.views import HAND_CENTRE

_QUERY_SEED = 987_654
_BRUTE_FORCE_CHUNK = 65_536


@dataclass(frozen=True)
class LookupBenchmark:
    """Figures of one benchmark run (see :meth:`as_dict` for the JSON keys).

    ``rss_mb`` is the resident memory that opening the database index and searching
    it added to the process (the packed images, the entry tables, the mapped rows
    touched); ``process_rss_mb`` is the whole process, which also holds the libraries
    and the renderer that made the queries. ``first_stage_mb`` and
    ``first_stage_read_ms`` are the size of the first stage's resident codes and the
    time one core takes to read them once (the median of 5 plain sums): the memory
    speed of this machine, against which the first stage's time can be judged.
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

    def as_dict(self) -> dict[str, Any]:
        k = parse_cascade(self.cascade)[-1].k
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
            "first_stage_read_ms": round(self.first_stage_read_ms, 3),
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
    index: DatabaseIndex, query: NDArray[np.uint8], *, entries: int | None = None
) -> NDArray[np.float32]:
    """Directed distance of every distinct entry to a query image, chunk by chunk.

    Parameters
    ----------
    index : DatabaseIndex
    query : (s, s) uint8
    entries : int, optional
        Only the first ``entries`` entries of the file (a truncated database);
        default all of them (tiling repeats them, so adds nothing).
    """
    size = query.shape[0]
    maps = chamfer_maps(query)
    count = index.base_entries if entries is None else min(entries, index.base_entries)
    errors = np.empty(count, np.float32)
    for start in range(0, count, _BRUTE_FORCE_CHUNK):
        ids = np.arange(start, min(count, start + _BRUTE_FORCE_CHUNK))
        errors[start : start + len(ids)] = tiny_image_distances(
            maps, pack_tiny_images(index.rows(size, ids))
        )
    return errors


def exact_nearest_errors(
    database: str,
    query_images: list[dict[int, NDArray[np.uint8]]],
    size: int,
    *,
    entries: int | None = None,
) -> NDArray[np.float64]:
    """The smallest error of any searched entry for each query at ``size`` (brute force);
    ``entries`` as in :func:`brute_force_errors`."""
    with DatabaseIndex(database, resident_sizes=()) as index:
        return np.array(
            [float(brute_force_errors(index, q[size], entries=entries).min()) for q in query_images]
        )


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
) -> LookupBenchmark:
    """Time held-out lookups and score them against brute force.

    ``query_images`` and ``exact_errors`` (from :func:`held_out_queries` and
    :func:`exact_nearest_errors` at the cascade's last size) may be passed in to reuse
    them across runs; by default they are made here. ``coarse_maps`` as in
    :func:`glovedb.search.cascade_search`.
    """
    with GloveDatabase(database) as checked:  # a bad file or cascade fails before rendering
        parse_cascade(cascade, sizes=checked.resolutions)
    if query_images is None:
        query_images = held_out_queries(queries, seed=seed)
    last = parse_cascade(cascade)[-1]
    if exact_errors is None:
        exact_errors = exact_nearest_errors(database, query_images, last.size, entries=entries)
    rss_before = _resident_mb()
    with DatabaseIndex(database, tile_to=entries) as index:
        parse_cascade(cascade, sizes=index.resolutions)
        search = functools.partial(
            index.search, cascade=cascade, workers=workers, coarse_maps=coarse_maps
        )
        search(query_images[0])  # warm-up: compile, map pages
        latencies, stage_times, ranks = [], [], []
        for query, best in zip(query_images, exact_errors, strict=True):
            started = time.perf_counter()
            result = search(query)
            latencies.append((time.perf_counter() - started) * 1000.0)
            stage_times.append(result.stage_ms)
            # The exact nearest error: a returned entry with that error is a hit (ties).
            hits = np.flatnonzero(np.isclose(result.errors, best, rtol=0, atol=1e-5))
            ranks.append(int(hits[0]) + 1 if len(hits) else last.k + 1)
        first = index.packed(parse_cascade(cascade)[0].size)
        return LookupBenchmark(
            entries=index.entries,
            base_entries=index.base_entries,
            cascade=cascade,
            queries=len(query_images),
            latency_ms=np.array(latencies),
            stage_ms=np.array(stage_times),
            ranks=np.array(ranks),
            rss_mb=_resident_mb() - rss_before,
            process_rss_mb=_resident_mb(),
            first_stage_mb=first.codes.nbytes / 1e6,
            first_stage_read_ms=memory_read_ms(first.codes),
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
