"""Tiny images: the glove's class labels cropped, normalised and shrunk to s x s pixels.

The builder and the tracker make tiny images with this one function, so a database
entry and a camera frame are compared like with like (thesis 4.2.2).

Normalisation: the glove pixels' bounding box is grown to a square about its centre
(aspect preserved), then divided into s x s cells. Every cell takes the class that
covers most of it, background included (ties go to the glove class with the lowest
label), so labels stay exact: classes are never blended. The counts of the largest
size are summed 2 x 2 to give the next smaller size, so every size is an exact
majority over the same crop.

Rotations about the optical axis: rotating a camera about its optical axis rotates
its image about the principal point (``K Rz K^-1`` is a rotation of the image when
``fx == fy``), and the crop is recomputed after rotating, so one rendering gives the
tiny images of every roll angle by rotating the glove pixels' coordinates.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb import _tiny_kernels
from glovedb._validate import as_array

N_LABELS = 11  # background and 10 glove classes
DEFAULT_SIZES: tuple[int, ...] = (8, 16, 32, 64)


def check_sizes(sizes: Sequence[int]) -> tuple[int, ...]:
    """Sorted sizes, each a power of two from 4 to 256; ``ValueError`` otherwise."""
    result = tuple(sorted(int(s) for s in sizes))
    if not result or any(s < 4 or s > 256 or s & (s - 1) for s in result):
        raise ValueError(f"tiny image sizes must be powers of two in 4..256, got {list(sizes)}")
    if len(set(result)) != len(result):
        raise ValueError(f"tiny image sizes repeat: {list(sizes)}")
    return result


def tiny_images_from_pixels(
    pixels_uv: ArrayLike,
    labels: ArrayLike,
    sizes: Sequence[int] = DEFAULT_SIZES,
    *,
    rolls_rad: ArrayLike = (0.0,),
) -> dict[int, NDArray[np.uint8]]:
    """Tiny images of a set of labelled glove pixels, for one or many image rotations.

    Parameters
    ----------
    pixels_uv : (N, 2) float
        Pixel centres (column, row) of the glove pixels; every pixel covers a unit
        square around its centre.
    labels : (N,) uint8
        Their glove classes 1..10.
    sizes : sequence of int
        Powers of two; every one must divide the largest.
    rolls_rad : (R,) float
        Make the images a camera would see if it were rotated by each of these angles
        about its optical axis (+z), as ``roll_rad`` of :func:`glovedb.views.pose_for_view`.

    Returns
    -------
    dict of int to (R, s, s) uint8
        For every size, one tiny image per roll. With no glove pixels every image is
        background (all zeros).
    """
    sizes = check_sizes(sizes)
    uv = as_array("pixels_uv", pixels_uv, (None, 2), np.float64, finite=True)
    classes = as_array("labels", labels, (len(uv),), kind="iu").astype(np.int64)
    rolls = as_array("rolls_rad", rolls_rad, (None,), np.float64, finite=True)
    if len(classes) and (classes.min() < 1 or classes.max() >= N_LABELS):
        raise ValueError("labels: glove pixels must have classes 1..10")
    if len(uv) == 0:
        return {s: np.zeros((len(rolls), s, s), np.uint8) for s in sizes}

    # Rotate about the centroid: the crop is recomputed, so the centre does not matter.
    # A camera turned by phi about +z sees x' = x cos - y sin, y' = x sin + y cos, and
    # with fx == fy its pixels turn the same way about the principal point.
    centred = uv - uv.mean(axis=0)
    outs = tuple(np.empty((len(rolls), s, s), np.uint8) for s in reversed(sizes))
    _tiny_kernels.tiny_images_into(
        np.ascontiguousarray(centred[:, 0]),
        np.ascontiguousarray(centred[:, 1]),
        np.ascontiguousarray(classes),
        np.cos(rolls),
        np.sin(rolls),
        outs,
        0,
        N_LABELS,
    )
    return dict(zip(reversed(sizes), outs, strict=True))


def tiny_images_of_label_images(
    label_images: ArrayLike,
    sizes: Sequence[int] = DEFAULT_SIZES,
    *,
    rolls_rad: ArrayLike = (0.0,),
) -> dict[int, NDArray[np.uint8]]:
    """Tiny images of many label images, each for many image rotations.

    The same images as :func:`tiny_images_from_pixels` of each image's glove pixels,
    in one compiled pass without intermediate arrays (the database builder's path).

    Parameters
    ----------
    label_images : (P, H, W) uint8
        0 background, 1..10 glove classes.
    sizes : sequence of int
        Powers of two; every one must divide the largest.
    rolls_rad : (R,) float
        As in :func:`tiny_images_from_pixels`.

    Returns
    -------
    dict of int to (P * R, s, s) uint8
        Image ``p``, roll ``r`` at row ``p * R + r``.
    """
    sizes = check_sizes(sizes)
    images = as_array("label_images", label_images, (None, None, None), kind="u")
    rolls = as_array("rolls_rad", rolls_rad, (None,), np.float64, finite=True)
    if images.size and images.max() >= N_LABELS:
        raise ValueError("label_images: classes must be 0..10")
    images = images.astype(np.uint8, copy=False)
    outs = tuple(np.empty((len(images) * len(rolls), s, s), np.uint8) for s in reversed(sizes))
    _tiny_kernels.label_images_into(
        np.ascontiguousarray(images), np.cos(rolls), np.sin(rolls), outs, N_LABELS
    )
    return dict(zip(reversed(sizes), outs, strict=True))


def tiny_images(
    label_image: ArrayLike, sizes: Sequence[int] = DEFAULT_SIZES
) -> dict[int, NDArray[np.uint8]]:
    """Tiny images of one class-label image.

    Parameters
    ----------
    label_image : (H, W) uint8
        0 background, 1..10 glove classes.
    sizes : sequence of int

    Returns
    -------
    dict of int to (s, s) uint8
        All zeros when the image has no glove pixels.
    """
    image = as_array("label_image", label_image, (None, None), kind="iu")
    rows, cols = np.nonzero(image)
    pixels = np.stack([cols, rows], axis=1).astype(np.float64)
    stacked = tiny_images_from_pixels(pixels, image[rows, cols], sizes)
    return {size: stack[0] for size, stack in stacked.items()}
