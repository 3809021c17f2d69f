"""Inverted lists: a first stage that scans only the lists of images like the query's.

A million-entry first stage that scores every image reads all of them for every
query (32 MB at 8x8). Images can be grouped once instead: the directed distance of
Eq. 4.2 (:mod:`glovedb.search`) is linear in an image's normalised one-hot labels,
``m(D, Q) = <u_D, M_Q>`` with ``u_D[c, p] = [D(p) = c + 1] / n_D`` (``n_D`` glove
pixels) and ``M_Q`` the query's chamfer maps, so the mean distance of a group of
images to a query is the distance of the group's mean ``u``: one dot product per
group, exactly.

Building (:func:`inverted_lists`) groups the first stage's images into about
``4 sqrt(G)`` lists (4,000 for a million images) by two-level k-means (scikit-learn)
on a blurred one-hot image reduced by PCA to :data:`_FEATURES` dimensions: images
whose colours lie a pixel apart are near in it, as they are under the chamfer
distance, and the two levels (64 lists of up to 64) keep the clustering to seconds.
The images are then stored list by list, with each list's mean and variance of ``u``.
A query (:func:`probed_lists`) ranks the lists by their mean distance less twice its
spread (the standard deviation of the members' distances, from the variances with
the components taken as independent), so that a loose list whose best members are
close still gets scanned, and takes the best until they hold ``probe_share`` of the
images and at least the stage's ``k`` entries; the search scans those ranges only.

It is approximate: an image in a list that ranks poorly is not scanned. The share and
the spread weight were chosen on 300 held-out queries (``held_out_queries`` of
:mod:`builder.lookup_bench` with seed 1234, not the benchmark's) against natural1323's
1,000,188 entries: the exhaustive cascade's top-1 entry was found in 280, 287, 294 of
300 at 3, 5, 8 % of the images ranked by mean distance alone, in 288, 292, 296, 298,
300 at 3, 5, 8, 10, 12 % with twice the spread (294 and 299 at 10 and 12 % with
three times). So
:data:`PROBE_SHARE` is 12 %. ``glove bench lookup`` measures the recall against the
exhaustive cascade on its own queries. Lists need a dense database: on 2,268 entries
of DB_open+pinch+power, lists of about 13 dissimilar images rank poorly, which is why
:class:`glovedb.lookup.DatabaseIndex` uses them only on large databases.

Deterministic for a given machine (fixed seeds); lists of large databases are kept
between runs (:mod:`glovedb.stage_cache`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from glovedb import _list_kernels
from glovedb._validate import as_array
from glovedb.chamfer import NUM_CLASSES
from glovedb.distinct_images import DistinctTinyImages, range_positions
from glovedb.packed_images import PackedTinyImages, unpack_tiny_images

PROBE_SHARE = 0.12
"""Share of the first stage's images a query scans (module docstring)."""
_SPREAD_WEIGHT = 2.0

_FEATURES = 48
_TOP_LISTS = 64
_SAMPLE = 100_000
_PCA_SAMPLE = 20_000
_CHUNK = 65_536


LIST_ARRAYS = ("list_offsets", "support_offsets", "support", "means", "variances")
"""The array fields of :class:`InvertedLists` besides its images (what a cache stores)."""


@dataclass(frozen=True)
class InvertedLists:
    """A first stage's images grouped into lists of similar images.

    Each list's mean and variance of the normalised one-hot labels ``u`` (module
    docstring) are stored sparsely, for the components ``c * s * s + p`` (class ``c``,
    pixel ``p``) that some image of the list has (about a quarter of them): the
    support of list ``l`` is ``support[support_offsets[l]:support_offsets[l + 1]]``.

    Attributes
    ----------
    images : DistinctTinyImages
        The images and the entries that show each (one per image when images do not
        repeat), stored list by list.
    list_offsets : (L + 1,) int64
        List ``l`` holds images ``list_offsets[l]:list_offsets[l + 1]``.
    support_offsets : (L + 1,) int64
        Where each list's support starts in ``support``.
    support : (S,) uint16
        Components of ``u`` with a non-zero mean, ascending within each list.
    means, variances : (S,) float32
        Mean and variance of those components over the list's images.
    probe_share : float
        Share of the images a query scans, in (0, 1].
    """

    images: DistinctTinyImages
    list_offsets: NDArray[np.int64]
    support_offsets: NDArray[np.int64]
    support: NDArray[np.uint16]
    means: NDArray[np.float32]
    variances: NDArray[np.float32]
    probe_share: float = PROBE_SHARE

    def __post_init__(self) -> None:
        components = NUM_CLASSES * self.images.images.size**2
        offsets = as_array("list_offsets", self.list_offsets, (None,), np.int64)
        support = as_array("support_offsets", self.support_offsets, (len(offsets),), np.int64)
        as_array("support", self.support, (None,), np.uint16)
        as_array("means", self.means, (len(self.support),), np.float32)
        as_array("variances", self.variances, (len(self.support),), np.float32)
        dtypes = (offsets.dtype, support.dtype, self.support.dtype, self.means.dtype,
                  self.variances.dtype)  # fmt: skip
        if dtypes != (np.int64, np.int64, np.uint16, np.float32, np.float32):
            raise TypeError("offsets: expected int64, support uint16, moments float32")
        if len(offsets) < 2 or offsets[0] != 0 or offsets[-1] != self.images.num_images:
            raise ValueError("list_offsets: must run from 0 to the number of images")
        if np.any(np.diff(offsets) < 1):
            raise ValueError("list_offsets: every list needs at least one image")
        if support[0] != 0 or support[-1] != len(self.support) or np.any(np.diff(support) < 0):
            raise ValueError("support_offsets: must rise from 0 to the support's length")
        if len(self.support) and int(self.support.max()) >= components:
            raise ValueError(f"support: components must be below {components}")
        if not 0 < self.probe_share <= 1:
            raise ValueError(f"probe_share: expected a share in (0, 1], got {self.probe_share}")

    @property
    def num_entries(self) -> int:
        """Number of entries ``N``."""
        return self.images.num_entries

    @property
    def num_lists(self) -> int:
        """Number of lists ``L``."""
        return len(self.list_offsets) - 1

    @functools.cached_property
    def list_images(self) -> NDArray[np.int64]:
        """``(L,)``: images in each list."""
        return np.diff(self.list_offsets)

    @functools.cached_property
    def list_entries(self) -> NDArray[np.int64]:
        """``(L,)``: entries that the images of each list show (kept: reading them from
        the entry offsets after the list distances missed the cache on every list)."""
        return np.diff(self.images.offsets[self.list_offsets])

    @property
    def nbytes(self) -> int:
        """Bytes held: the images and their entries, the lists and their moments."""
        return self.images.nbytes + sum(getattr(self, name).nbytes for name in LIST_ARRAYS)


def inverted_lists(
    stage: PackedTinyImages | DistinctTinyImages,
    *,
    probe_share: float = PROBE_SHARE,
    seed: int = 0,
) -> InvertedLists:
    """Group a first stage's images into lists (module docstring).

    Parameters
    ----------
    stage : PackedTinyImages or DistinctTinyImages
        Every entry's images (entry ``n`` is row ``n``), or the distinct images.
    probe_share : float
        Stored in the result: the share of images a query scans.
    seed : int
        Seed of the sample and the clustering.

    Returns
    -------
    InvertedLists
    """
    from sklearn.decomposition import PCA  # scikit-learn: a build-time dependency only

    distinct = _as_distinct(stage)
    packed = distinct.images
    count = packed.num_entries
    rng = np.random.default_rng(seed)
    sample = np.sort(rng.choice(count, size=min(count, _SAMPLE), replace=False))
    pca = PCA(min(_FEATURES, len(sample)), random_state=seed)
    blur = _blur_matrix(packed.size)
    pca.fit(_one_hot(unpack_tiny_images(packed.take(sample[:_PCA_SAMPLE]))) @ blur)
    # The features are linear in the one-hot labels: blur, then PCA's projection.
    weights = (blur @ pca.components_.T).astype(np.float32)
    weights = np.ascontiguousarray(weights.reshape(NUM_CLASSES, packed.size**2, -1))
    features = np.empty((count, pca.n_components_), np.float32)
    for start in range(0, count, _CHUNK):
        rows = np.arange(start, min(count, start + _CHUNK))
        labels = unpack_tiny_images(packed.take(rows)).reshape(len(rows), -1)
        _list_kernels.project_rows(labels, weights, features[start : start + len(rows)])
    features -= (pca.mean_ @ pca.components_.T).astype(np.float32)
    lists = _two_level_kmeans(features, sample, _list_count(count), seed)
    order = np.argsort(lists, kind="stable")
    counts = np.bincount(lists)
    list_offsets = np.concatenate([[0], np.cumsum(counts[counts > 0])]).astype(np.int64)
    grouped = _reordered(distinct, order)
    means, variances = _list_moments(grouped.images, list_offsets)
    present = means > 0
    return InvertedLists(
        images=grouped,
        list_offsets=list_offsets,
        support_offsets=np.concatenate([[0], np.cumsum(present.sum(axis=1))]).astype(np.int64),
        support=np.nonzero(present)[1].astype(np.uint16),
        means=means[present],
        variances=variances[present],
        probe_share=probe_share,
    )


def list_distances(
    lists: InvertedLists, maps: NDArray[np.float32]
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Each list's mean distance to a query and its spread.

    Parameters
    ----------
    lists : InvertedLists
    maps : (10, s, s) float32
        The query's chamfer maps at the lists' size (checked by the caller).

    Returns
    -------
    mean, spread : (L,) float32
        Mean of the list's images' distances ``m(D, Q)`` (exact), and the standard
        deviation they would have if the components of ``u`` varied independently,
        pixels.
    """
    mean = np.empty(lists.num_lists, np.float32)
    spread = np.empty(lists.num_lists, np.float32)
    _list_kernels.list_distances(
        lists.support_offsets, lists.support, lists.means, lists.variances,
        np.ascontiguousarray(maps, dtype=np.float32).reshape(-1), mean, spread,
    )  # fmt: skip
    return mean, spread


def probed_lists(
    lists: InvertedLists, maps: NDArray[np.float32], min_entries: int
) -> NDArray[np.int64]:
    """The lists a query scans, most promising first (mean distance less twice its
    spread, module docstring), until they hold ``probe_share`` of the images and at
    least ``min_entries`` entries (all lists when the database holds fewer). Ties go to
    the lower list. The cut is found without sorting all lists
    (:func:`glovedb._list_kernels.probe_prefix`): 17 microseconds for 3,969 lists.

    Parameters
    ----------
    lists : InvertedLists
    maps : (10, s, s) float32
        The query's chamfer maps at the lists' size (checked by the caller).
    min_entries : int
        The stage's ``k``.

    Returns
    -------
    (P,) int64
        List indices, ascending.
    """
    mean, spread = list_distances(lists, maps)
    score = mean - _SPREAD_WEIGHT * spread
    if not np.all(np.isfinite(score)):
        raise ValueError("maps: expected finite chamfer distances")
    chosen = np.empty(len(score), np.bool_)
    _list_kernels.probe_prefix(
        score, lists.list_images, lists.list_entries,
        lists.probe_share * lists.images.num_images, min_entries, chosen,
    )  # fmt: skip
    return np.flatnonzero(chosen)


def _as_distinct(stage: PackedTinyImages | DistinctTinyImages) -> DistinctTinyImages:
    """Distinct images as they are; every entry's images as one image per entry."""
    if isinstance(stage, DistinctTinyImages):
        return stage
    count = stage.num_entries
    return DistinctTinyImages(
        images=stage,
        entry_ids=np.arange(count, dtype=np.int64),
        offsets=np.arange(count + 1, dtype=np.int64),
    )


def _one_hot(images: NDArray[np.uint8]) -> NDArray[np.float32]:
    """``(M, 10 * s * s)`` class masks over each image's glove pixel count (``u``)."""
    classes = np.arange(1, NUM_CLASSES + 1, dtype=np.uint8)[None, :, None, None]
    masks = (images[:, None] == classes).astype(np.float32)
    glove_pixels = np.maximum(1, np.count_nonzero(images.reshape(len(images), -1), axis=1))
    return masks.reshape(len(images), -1) / glove_pixels.astype(np.float32)[:, None]


def _blur_matrix(size: int) -> NDArray[np.float64]:
    """``(10 s s, 10 s s)``: ``u @ blur`` blurs each class mask by [1/4, 1/2, 1/4]
    along both axes (edges repeated)."""
    one_axis = 0.5 * np.eye(size)
    one_axis += 0.25 * np.eye(size, k=1) + 0.25 * np.eye(size, k=-1)
    one_axis[0, 0] += 0.25
    one_axis[-1, -1] += 0.25
    return np.kron(np.eye(NUM_CLASSES), np.kron(one_axis, one_axis))


def _list_count(images: int) -> int:
    return max(1, min(_TOP_LISTS * _TOP_LISTS, round(4 * np.sqrt(images))))


def _two_level_kmeans(
    features: NDArray[np.float32],
    sample: NDArray[np.int64],
    lists: int,
    seed: int,
) -> NDArray[np.int64]:
    """List of every row: k-means on the sample into up to 64 groups, then each
    group's sample into up to 64 lists; every row goes to its nearest list."""
    from sklearn.cluster import KMeans

    top = max(1, min(_TOP_LISTS, round(np.sqrt(lists)), len(sample)))
    coarse = KMeans(top, n_init=1, max_iter=20, random_state=seed).fit(features[sample])
    group = _nearest(features, coarse.cluster_centers_)
    sample_group = group[sample]
    labels = np.empty(len(features), np.int64)
    for index in range(top):
        members = np.flatnonzero(group == index)
        in_sample = sample[sample_group == index]
        fine = max(1, min(_TOP_LISTS, lists // top, len(in_sample) // 8))
        if len(members) == 0:
            continue
        if fine == 1:
            labels[members] = index * _TOP_LISTS
            continue
        clustering = KMeans(fine, n_init=1, max_iter=20, random_state=seed)
        clustering.fit(features[in_sample])
        labels[members] = index * _TOP_LISTS + _nearest(
            features[members], clustering.cluster_centers_
        )
    return labels


def _nearest(features: NDArray[np.float32], centres: NDArray[np.float64]) -> NDArray[np.int64]:
    """Index of the nearest centre of each feature row, in chunks."""
    centres = centres.astype(np.float32)
    squared = np.einsum("ij,ij->i", centres, centres)
    nearest = np.empty(len(features), np.int64)
    for start in range(0, len(features), _CHUNK):
        chunk = features[start : start + _CHUNK]
        nearest[start : start + _CHUNK] = np.argmin(squared - 2.0 * chunk @ centres.T, axis=1)
    return nearest


def _reordered(distinct: DistinctTinyImages, order: NDArray[np.int64]) -> DistinctTinyImages:
    """The same images and entries, the images in ``order``."""
    starts = distinct.offsets[order]
    lengths = distinct.offsets[order + 1] - starts
    return DistinctTinyImages(
        images=distinct.images.take(order),
        entry_ids=distinct.entry_ids[range_positions(starts, lengths)],
        offsets=np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64),
    )


def _list_moments(
    packed: PackedTinyImages, list_offsets: NDArray[np.int64]
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Mean and variance of ``u`` over each list's images (stored list by list)."""
    sums = np.zeros((len(list_offsets) - 1, NUM_CLASSES * packed.size**2), np.float64)
    squares = np.zeros_like(sums)
    list_of_image = np.repeat(np.arange(len(list_offsets) - 1), np.diff(list_offsets))
    for start in range(0, packed.num_entries, _CHUNK):
        rows = np.arange(start, min(packed.num_entries, start + _CHUNK))
        labels = unpack_tiny_images(packed.take(rows)).reshape(len(rows), -1)
        _list_kernels.add_list_sums(labels, list_of_image[rows], sums, squares)
    counts = np.diff(list_offsets)[:, None]
    means = sums / counts
    variances = np.maximum(0.0, squares / counts - means * means)
    return means.astype(np.float32), variances.astype(np.float32)
