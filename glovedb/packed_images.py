"""The compact layout in which tiny images are scanned: pixel-group codes and a per-query table.

:func:`pack_tiny_images` stores each image as ``s * s / g`` uint16 codes, one per group
of ``g`` consecutive pixels (``code = sum label_i * 11 ** (g - 1 - i)``), and its glove
pixel count. Per query and size, :func:`code_table` holds the summed chamfer distances
of every code at every group position, so an image costs ``s * s / g`` lookups instead
of ``s * s``. With ``g = 4`` an 8x8 image is 16 lookups and 32 bytes (32 MB per million
images; table 0.9 MB, in L2). :mod:`glovedb.search` scans this layout.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb import _packed_kernels
from glovedb._validate import as_array
from glovedb.chamfer import NUM_CLASSES, check_labels

_NUM_LABELS = NUM_CLASSES + 1
_GROUPS = (4, 2, 1)  # 11 ** g codes must fit uint16
_MAX_TABLE_ENTRIES = 1 << 18  # 1 MB of float32 per query and size: stays in L2


@dataclass(frozen=True)
class PackedTinyImages:
    """Tiny images of one size in the compact scan layout of :func:`pack_tiny_images`.

    Attributes
    ----------
    codes : (N, s * s // group) uint16, C-contiguous
        Code of each group of ``group`` consecutive pixels (row-major order).
    glove_pixels : (N,) uint16
        Number of non-background pixels per image.
    size : int
        Side length ``s`` in pixels.
    group : int
        Pixels per code: 1, 2 or 4.
    """

    codes: NDArray[np.uint16]
    glove_pixels: NDArray[np.uint16]
    size: int
    group: int

    def __post_init__(self) -> None:
        if self.group not in _GROUPS or (self.size * self.size) % self.group:
            raise ValueError(f"group: expected one of {_GROUPS} dividing s * s, got {self.group}")
        positions = self.size * self.size // self.group
        as_array("codes", self.codes, (None, positions), np.uint16)
        as_array("glove_pixels", self.glove_pixels, (len(self.codes),), np.uint16)
        if self.codes.dtype != np.uint16 or self.glove_pixels.dtype != np.uint16:
            raise TypeError("codes, glove_pixels: expected uint16 arrays")
        if not self.codes.flags.c_contiguous:
            raise ValueError("codes: expected a C-contiguous array")

    @property
    def num_entries(self) -> int:
        """Number of images ``N``."""
        return len(self.codes)

    @property
    def nbytes(self) -> int:
        """Bytes of the codes and glove pixel counts."""
        return self.codes.nbytes + self.glove_pixels.nbytes

    def take(self, rows: NDArray[np.int64]) -> PackedTinyImages:
        """The images at ``rows`` (int indices), in that order, as a new copy."""
        return PackedTinyImages(
            codes=np.ascontiguousarray(self.codes[rows]),
            glove_pixels=self.glove_pixels[rows],
            size=self.size,
            group=self.group,
        )


def pack_tiny_images(images: ArrayLike, *, group: int | None = None) -> PackedTinyImages:
    """Convert label images to the compact scan layout.

    Parameters
    ----------
    images : (N, s, s) uint8
        Labels 0..10.
    group : {1, 2, 4}, optional
        Pixels per code. Default: the largest whose per-query table has at most 2**18
        entries (4 for 8x8, 2 for 16x16 up to 64x64).

    Returns
    -------
    PackedTinyImages
    """
    labels = check_labels("images", images, (None, None, None))
    size = labels.shape[-1]
    group = _default_group(size) if group is None else group
    if group not in _GROUPS or (size * size) % group:
        raise ValueError(f"group: expected one of {_GROUPS} dividing s * s, got {group}")
    grouped = labels.reshape(len(labels), size * size // group, group)
    codes = np.zeros(grouped.shape[:2], np.uint16)
    for index in range(group):
        codes *= _NUM_LABELS
        codes += grouped[:, :, index]
    flat = labels.reshape(len(labels), size * size)
    glove_pixels = np.count_nonzero(flat, axis=1).astype(np.uint16)
    return PackedTinyImages(codes=codes, glove_pixels=glove_pixels, size=size, group=group)


def unpack_tiny_images(packed: PackedTinyImages) -> NDArray[np.uint8]:
    """The label images of :func:`pack_tiny_images`' layout, ``(N, s, s) uint8``."""
    codes = packed.codes.astype(np.int64)
    digits = np.empty((*codes.shape, packed.group), np.uint8)
    for index in range(packed.group - 1, -1, -1):
        digits[:, :, index] = codes % _NUM_LABELS
        codes //= _NUM_LABELS
    return digits.reshape(packed.num_entries, packed.size, packed.size)


def code_table(maps: NDArray[np.float32], group: int) -> NDArray[np.float32]:
    """Summed chamfer distances of every code at every group position.

    Parameters
    ----------
    maps : (10, s, s) float32
        Chamfer maps of the query (checked by the caller).
    group : {1, 2, 4}
        Pixels per code, as in :class:`PackedTinyImages`.

    Returns
    -------
    (s * s // group, 11 ** group) float32, C-contiguous
        ``table[p, code]``, pixels.
    """
    size = maps.shape[-1]
    per_pixel = np.zeros((size * size, _NUM_LABELS), np.float32)
    per_pixel[:, 1:] = maps.reshape(NUM_CLASSES, -1).T
    table = np.empty((size * size // group, _NUM_LABELS**group), np.float32)
    _packed_kernels.fill_code_table(per_pixel, group, table)
    return table


def _default_group(size: int) -> int:
    positions = size * size
    return next(
        g
        for g in _GROUPS
        if positions % g == 0 and positions // g * _NUM_LABELS**g <= _MAX_TABLE_ENTRIES
    )
