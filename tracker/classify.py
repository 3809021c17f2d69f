"""Color classification of glove pixels with a lookup table (thesis 4.2.1).

Every 8-bit RGB color is quantised to 5 bits per channel; a 32 x 32 x 32 table gives
its class (0 background, 1..10 glove colors), so classifying a VGA frame is one
compiled pass of table lookups (:mod:`tracker._classify_kernels`, 0.3 ms).

The table is decided in a lighting-robust feature space: YUV chroma divided by luma
(:func:`glovedb.pattern.chroma_uv`), which does not change when a surface gets
brighter or darker, plus a little luma so that black, white and grey (no reliable
chroma) stay background.

- :func:`nominal_table` builds it from the glove pattern's nominal colors: a cell is
  the class of the nearest nominal chroma if that is close enough, else background.
- :func:`calibrated_table` learns it from labelled samples of the user's real glove
  (and of the background): k-nearest-neighbour vote of the samples in the same
  space, cells far from every glove sample stay background.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

import glovedb
from glovedb._validate import as_array
from glovedb.pattern import GlovePattern, chroma_uv
from tracker import _classify_kernels

_BITS = 5
_LEVELS = 1 << _BITS
_SHIFT = 8 - _BITS
_LUMA_WEIGHT = 0.5


@dataclass(frozen=True)
class ColorTable:
    """A color lookup table.

    Attributes
    ----------
    table : (32, 32, 32) uint8
        Class of every 5-bit RGB cell.
    source : str
        How it was made ("nominal" or "calibrated from N samples").
    """

    table: NDArray[np.uint8]
    source: str

    def classify(self, color: ArrayLike) -> NDArray[np.uint8]:
        """Class of every pixel of an ``(H, W, 3) uint8`` RGB image; ``(H, W) uint8``."""
        rgb = as_array("color", color, (None, None, 3), kind="u")
        if rgb.dtype != np.uint8:
            raise TypeError(f"color: expected uint8, got {rgb.dtype}")
        labels = np.empty(rgb.shape[:2], dtype=np.uint8)
        _classify_kernels.classify_into(rgb, self.table, _SHIFT, labels)
        return labels

    def save(self, path: str | Path) -> None:
        """Write the table as ``.npz`` (with the project version)."""
        np.savez_compressed(path, table=self.table, source=self.source, version=glovedb.__version__)


def load_table(path: str | Path) -> ColorTable:
    """Read a table written by :meth:`ColorTable.save`; one-line ``ValueError`` if bad."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            table = np.asarray(data["table"])
            source = str(data["source"])
    except (OSError, KeyError, ValueError) as error:
        raise ValueError(f"{path}: not a color table ({error})") from error
    if table.shape != (_LEVELS,) * 3 or table.dtype != np.uint8:
        raise ValueError(f"{path}: not a color table (shape {table.shape}, {table.dtype})")
    if table.max() > 10:
        raise ValueError(f"{path}: not a color table (label {table.max()}; labels are 0 to 10)")
    return ColorTable(table, source)


def color_features(rgb: ArrayLike) -> NDArray[np.float64]:
    """``(..., 3)`` features of sRGB colors: luma-normalised U, V and weighted luma."""
    colors = np.asarray(rgb, dtype=np.float64)
    luma = colors @ np.array([0.299, 0.587, 0.114]) / 255.0
    return np.concatenate([chroma_uv(colors), _LUMA_WEIGHT * luma[..., None]], axis=-1)


def _cell_colors() -> NDArray[np.float64]:
    """``(32768, 3)`` centre color of every table cell, table order."""
    levels = (np.arange(_LEVELS) << _SHIFT) + (1 << (_SHIFT - 1))
    grid = np.stack(np.meshgrid(levels, levels, levels, indexing="ij"), -1)
    return grid.reshape(-1, 3).astype(np.float64)


def nominal_table(
    pattern: GlovePattern,
    *,
    max_chroma_distance: float = 0.3,
    min_luma: float = 0.06,
    min_chroma: float = 0.25,
) -> ColorTable:
    """Table from the pattern's nominal colors (see the module docstring).

    Parameters
    ----------
    pattern : GlovePattern
    max_chroma_distance : float
        Largest distance in normalised chroma from a nominal color still given its class.
    min_luma : float
        Darker cells (luma in 0..1) are background: their chroma is noise.
    min_chroma : float
        Cells whose normalised chroma is closer to grey than this are background.
    """
    cells = _cell_colors()
    chroma = chroma_uv(cells)
    luma = cells @ np.array([0.299, 0.587, 0.114]) / 255.0
    nominal = chroma_uv(pattern.colors_rgb)
    distance = np.linalg.norm(chroma[:, None] - nominal[None], axis=-1)
    best = np.argmin(distance, axis=1)
    accept = (
        (distance[np.arange(len(cells)), best] < max_chroma_distance)
        & (luma >= min_luma)
        & (np.linalg.norm(chroma, axis=1) >= min_chroma)
    )
    table = np.where(accept, best + 1, 0).astype(np.uint8).reshape((_LEVELS,) * 3)
    return ColorTable(table, "nominal")


def calibrated_table(
    colors: ArrayLike,
    labels: ArrayLike,
    *,
    neighbours: int = 7,
    max_distance: float = 0.2,
) -> ColorTable:
    """Table learned from labelled color samples.

    Parameters
    ----------
    colors : (N, 3) uint8
        Sample RGB colors, glove and background.
    labels : (N,) uint8
        Their classes (0 background, 1..10 glove).
    neighbours : int
        Samples voting for each cell.
    max_distance : float
        Cells farther than this (feature space) from their nearest glove sample are
        background.

    Returns
    -------
    ColorTable
    """
    samples = as_array("colors", colors, (None, 3), kind="u")
    classes = as_array("labels", labels, (len(samples),), kind="iu").astype(np.int64)
    if len(samples) < neighbours or not np.any(classes > 0):
        raise ValueError("calibration needs glove samples (and at least `neighbours` samples)")
    if classes.max() > 10:
        raise ValueError("labels: classes must be 0..10")
    # One sample per distinct (color, class) is enough and keeps the trees small.
    unique, counts = np.unique(
        np.concatenate([samples.astype(np.int64), classes[:, None]], axis=1), axis=0,
        return_counts=True,
    )  # fmt: skip
    from scipy.spatial import cKDTree  # here: 0.18 s of every tracker's start otherwise

    features = color_features(unique[:, :3])
    cells = color_features(_cell_colors())
    tree = cKDTree(features)
    k = min(neighbours, len(unique))
    _, nearest = tree.query(cells, k=k)
    nearest = nearest.reshape(len(cells), k)
    votes = np.zeros((len(cells), 11))
    for column in range(k):
        np.add.at(
            votes,
            (np.arange(len(cells)), unique[nearest[:, column], 3]),
            counts[nearest[:, column]],
        )
    table = np.argmax(votes, axis=1)
    glove = unique[:, 3] > 0
    nearest_glove, _ = cKDTree(features[glove]).query(cells)
    table[nearest_glove > max_distance] = 0
    table = table.astype(np.uint8).reshape((_LEVELS,) * 3)
    return ColorTable(table, f"calibrated from {len(samples)} samples")
