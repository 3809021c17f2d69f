"""Chamfer maps of tiny label images and the Hausdorff-like tiny-image distance.

A tiny image is a square ``(s, s) uint8`` label image: 0 is background, 1..10 are the
glove's ten colour classes. Its chamfer maps are the exact Euclidean distance
transforms of the ten classes, ``maps[c - 1, y, x]`` = distance in pixels from pixel
``(y, x)`` to the nearest pixel of class ``c`` (zero on pixels of that class).

The distance between tiny images is Eq. 4.2 of Schröder (2015), after Huttenlocher
et al. (1993)::

    m(A, B) = 1 / |G_A| * sum over glove pixels a of A of
              (distance from a to the nearest pixel of B with the colour of a)

computed by looking every glove pixel of ``A`` up in ``B``'s chamfer maps. ``m`` is
directed: ``m(A, B)`` needs the maps of ``B`` only. The database search
(:mod:`glovedb.search`) ranks database entries ``D`` by ``m(D, Q)`` against the query
``Q``, so only the query's maps are ever computed (once per query and size) and
database images are stored as bare labels; see that module for why.

Two edge cases are fixed by definition, never by a division by zero:

* A class absent from ``B`` has the constant map :func:`absent_class_distance_px`,
  ``s * sqrt(2)``, one pixel diagonal more than any distance inside the image. A glove
  pixel whose colour ``B`` lacks costs that much.
* An image ``A`` without glove pixels has ``m(A, B) = inf`` for every ``B``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb import _chamfer_kernels
from glovedb._validate import as_array

NUM_CLASSES = 10
"""Number of glove colour classes; labels are 0 (background) and 1..NUM_CLASSES."""


def absent_class_distance_px(size: int) -> float:
    """Chamfer map value of a class that does not occur in an ``(s, s)`` image.

    Parameters
    ----------
    size : int
        Side length ``s`` of the tiny image in pixels.

    Returns
    -------
    float
        ``s * sqrt(2)`` pixels: larger than the largest distance inside the image,
        ``(s - 1) * sqrt(2)``, so a missing colour always costs more than a present one.
    """
    return size * math.sqrt(2.0)


def check_labels(
    name: str, labels: ArrayLike, shape: tuple[int | None, ...] | None = None
) -> NDArray[np.uint8]:
    """Check a label image (or stack) and return it as uint8.

    Parameters
    ----------
    name : str
        Argument name for error messages.
    labels : (..., s, s) int
        Labels in 0..NUM_CLASSES.
    shape : tuple of int or None, optional
        Exact expected shape (``None`` entries match any size). Default: any stack of
        square images, ``(..., s, s)``.

    Returns
    -------
    (..., s, s) uint8
    """
    array = as_array(name, labels, shape, kind="iu")
    if array.ndim < 2 or array.shape[-1] != array.shape[-2]:
        raise ValueError(f"{name}: expected square images of shape (..., s, s), got {array.shape}")
    if array.size and (array.min() < 0 or array.max() > NUM_CLASSES):
        raise ValueError(f"{name}: labels must be in 0..{NUM_CLASSES}")
    return array.astype(np.uint8, copy=False)


def chamfer_maps(labels: ArrayLike) -> NDArray[np.float32]:
    """Exact per-class Euclidean distance transforms of tiny label images.

    Parameters
    ----------
    labels : (..., s, s) uint8
        Label images, 0 = background, 1..10 = glove colour classes.

    Returns
    -------
    (..., 10, s, s) float32
        ``maps[..., c - 1, y, x]``: distance in pixels from ``(y, x)`` to the nearest
        pixel of class ``c``; :func:`absent_class_distance_px` where class ``c`` does
        not occur in the image.
    """
    images = check_labels("labels", labels)
    size = images.shape[-1]
    flat = np.ascontiguousarray(images.reshape(-1, size, size))
    maps = np.empty((flat.shape[0], NUM_CLASSES, size, size), np.float32)
    _chamfer_kernels.distance_maps(flat, absent_class_distance_px(size), maps)
    return maps.reshape((*images.shape[:-2], NUM_CLASSES, size, size))


def cell_mean_maps(maps: ArrayLike, size: int) -> NDArray[np.float32]:
    """Chamfer maps of a finer image averaged over the cells of a coarser grid.

    A pixel of a coarse tiny image stands for a cell of ``(S / s)**2`` pixels of the
    finer one; where in that cell its colour lies is lost. Looking it up in the mean
    of the fine maps over the cell is its expected distance under that uncertainty,
    instead of the distance from the cell's centre after the query, too, was
    quantised. The cascade's early stages use these maps (:mod:`glovedb.search`).

    Parameters
    ----------
    maps : (10, S, S) float32
        Chamfer maps of an ``S x S`` image (:func:`chamfer_maps`), in fine pixels.
    size : int
        Side ``s`` of the coarse grid; must divide ``S``.

    Returns
    -------
    (10, s, s) float32
        Mean of each cell, in coarse pixels (fine pixels times ``s / S``).
    """
    array = as_array("maps", maps, (NUM_CLASSES, None, None), np.float32)
    fine = array.shape[-1]
    if array.shape[-2] != fine or size < 1 or fine % size:
        raise ValueError(f"size: must divide the maps' side {fine}, got {size}")
    cells = np.empty((NUM_CLASSES, size, size), np.float32)
    _chamfer_kernels.cell_means(np.ascontiguousarray(array), cells)
    return cells


def directed_distance(labels_a: ArrayLike, maps_b: ArrayLike) -> NDArray[np.float32]:
    """Eq. 4.2, ``m(A, B)``, by lookup of ``A``'s glove pixels in ``B``'s chamfer maps.

    Parameters
    ----------
    labels_a : (..., s, s) uint8
        One image ``A`` or a stack of them.
    maps_b : (10, s, s) float32
        Chamfer maps of ``B`` (from :func:`chamfer_maps`).

    Returns
    -------
    (...) float32
        Mean distance in pixels from each glove pixel of ``A`` to the nearest pixel of
        the same colour in ``B``; ``inf`` where ``A`` has no glove pixels.
    """
    images = check_labels("labels_a", labels_a)
    size = images.shape[-1]
    maps = as_array("maps_b", maps_b, (NUM_CLASSES, size, size), np.float32)
    # Row 0 (background) contributes nothing, so the lookup needs no mask.
    lookup = np.concatenate([np.zeros((1, size * size), np.float32), maps.reshape(10, -1)])
    flat = images.reshape(-1, size * size)
    totals = lookup[flat, np.arange(size * size)].sum(axis=-1, dtype=np.float32)
    counts = np.count_nonzero(flat, axis=-1)
    means = np.divide(
        totals, counts, out=np.full(totals.shape, np.inf, np.float32), where=counts > 0
    )
    return means.astype(np.float32, copy=False).reshape(images.shape[:-2])


def symmetric_distance(labels_a: ArrayLike, labels_b: ArrayLike) -> NDArray[np.float32]:
    """``(m(A, B) + m(B, A)) / 2``: symmetric, but needs the maps of both images.

    Parameters
    ----------
    labels_a, labels_b : (..., s, s) uint8
        Images (or stacks of the same shape) to compare pairwise.

    Returns
    -------
    (...) float32
        Pixels; ``inf`` if either image has no glove pixels.
    """
    a = check_labels("labels_a", labels_a)
    b = check_labels("labels_b", labels_b, a.shape)
    size = a.shape[-1]
    flat_a, flat_b = a.reshape(-1, size, size), b.reshape(-1, size, size)
    maps_a, maps_b = chamfer_maps(flat_a), chamfer_maps(flat_b)
    forward = np.array([directed_distance(x, m) for x, m in zip(flat_a, maps_b, strict=True)])
    backward = np.array([directed_distance(x, m) for x, m in zip(flat_b, maps_a, strict=True)])
    return (0.5 * (forward + backward)).astype(np.float32).reshape(a.shape[:-2])
