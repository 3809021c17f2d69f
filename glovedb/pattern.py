"""The glove pattern: 10 color classes on 20 patches, and the label of every triangle.

The pattern is data (``configs/glove/pattern.toml``, documented there); this module
loads and checks it and paints a :class:`~glovedb.mesh.HandMesh` with it. Class label
0 is the background; labels 1..10 are the glove colors.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import tomllib
from numpy.typing import NDArray

from glovedb._validate import check_choice
from glovedb.hand_model import BONE_NAMES
from glovedb.mesh import HandMesh
from glovedb.resources import config_path

N_CLASSES = 10
Region = Literal["wrist", "palm_radial", "palm_ulnar", "back_radial", "back_ulnar"]
REGIONS: tuple[str, ...] = ("wrist", "palm_radial", "palm_ulnar", "back_radial", "back_ulnar")
BACKGROUND_RGB = (0, 0, 0)


@dataclass(frozen=True)
class Patch:
    """One painted region of the glove.

    Attributes
    ----------
    name : str
    label : int
        Color class 1..10.
    bones : tuple of str
        Bones (:data:`~glovedb.hand_model.BONE_NAMES`) whose triangles it covers.
    region : str or None
        For palm patches, which part of the palm bone's surface.
    """

    name: str
    label: int
    bones: tuple[str, ...]
    region: Region | None = None


@dataclass(frozen=True)
class GlovePattern:
    """Colors and patches of the glove.

    Attributes
    ----------
    color_names : tuple of str
        Name of class ``k`` at index ``k - 1``.
    colors_rgb : (10, 3) uint8
        Nominal sRGB color of each class.
    patches : tuple of Patch
    wrist_y : float
        Palm triangles below this height (units of hand length) form the wrist patch.
    radial_ulnar_x : float
        Palm triangles with x below this (units of hand length) are radial.
    """

    color_names: tuple[str, ...]
    colors_rgb: NDArray[np.uint8]
    patches: tuple[Patch, ...]
    wrist_y: float
    radial_ulnar_x: float

    def palette(self) -> NDArray[np.uint8]:
        """``(11, 3)`` uint8 colors indexed by label, background black at 0."""
        return np.concatenate([np.array([BACKGROUND_RGB], np.uint8), self.colors_rgb])

    def colorize(self, labels: NDArray[np.integer]) -> NDArray[np.uint8]:
        """Paint a label image ``(H, W)`` with the nominal colors; returns ``(H, W, 3)`` uint8."""
        return self.palette()[np.asarray(labels)]


def load_pattern(path: str | Path | None = None) -> GlovePattern:
    """Read and check a glove pattern TOML file (default: the project's pattern).

    Raises
    ------
    ValueError
        If the file breaks a rule: 10 colors labelled 1..10, every color on exactly
        two patches, known bone and region names.
    """
    path = Path(path) if path is not None else config_path("glove/pattern.toml")
    with open(path, "rb") as stream:
        data = tomllib.load(stream)
    return pattern_from_dict(data, source=str(path))


def pattern_from_dict(data: dict[str, Any], *, source: str = "pattern") -> GlovePattern:
    """Build a :class:`GlovePattern` from the parsed TOML tables."""
    colors = sorted(data.get("colors", []), key=lambda c: c["label"])
    if [c["label"] for c in colors] != list(range(1, N_CLASSES + 1)):
        raise ValueError(f"{source}: expected colors labelled 1..{N_CLASSES}")
    rgb = np.array([c["rgb"] for c in colors])
    if rgb.shape != (N_CLASSES, 3) or rgb.min() < 0 or rgb.max() > 255:
        raise ValueError(f"{source}: every color needs rgb = [r, g, b] in 0..255")
    patches = []
    for entry in data.get("patches", []):
        for bone in entry["bones"]:
            check_choice(f"{source}: patch {entry['name']} bone", bone, BONE_NAMES)
        region = entry.get("region")
        if region is not None:
            check_choice(f"{source}: patch {entry['name']} region", region, REGIONS)
        patches.append(Patch(entry["name"], int(entry["color"]), tuple(entry["bones"]), region))
    uses = np.bincount([p.label for p in patches], minlength=N_CLASSES + 1)[1:]
    if len(patches) != 2 * N_CLASSES or np.any(uses != 2):
        raise ValueError(f"{source}: expected 20 patches, every color on exactly two")
    return GlovePattern(
        color_names=tuple(c["name"] for c in colors),
        colors_rgb=rgb.astype(np.uint8),
        patches=tuple(patches),
        wrist_y=float(data["wrist_y"]),
        radial_ulnar_x=float(data["radial_ulnar_x"]),
    )


def palm_regions(
    points_m: NDArray[np.float64], pattern: GlovePattern, hand_length_m: float
) -> NDArray:
    """Region name of rest-posture palm points ``(N, 3)``; returns ``(N,)`` str."""
    x, y, z = (points_m / hand_length_m).T
    side = np.where(z >= 0.0, "back", "palm")
    half = np.where(x < pattern.radial_ulnar_x, "radial", "ulnar")
    named = np.char.add(np.char.add(side, "_"), half)
    return np.where(y < pattern.wrist_y, "wrist", named)


def face_patches(mesh: HandMesh, pattern: GlovePattern) -> NDArray[np.int64]:
    """Index into ``pattern.patches`` of every triangle of the mesh; ``(F,)`` int64.

    A triangle belongs to the bone with the largest summed skinning weight over its
    corners; palm triangles are then split by the region of their rest centroid.
    """
    bone = np.argmax(mesh.weights[mesh.faces].sum(axis=1), axis=1)
    centroids = mesh.rest_vertices_m[mesh.faces].mean(axis=1)
    region = palm_regions(centroids, pattern, mesh.skeleton.hand_length_m)
    result = np.full(len(mesh.faces), -1, dtype=np.int64)
    for index, patch in enumerate(pattern.patches):
        bone_ids = [BONE_NAMES.index(b) for b in patch.bones]
        selected = np.isin(bone, bone_ids)
        if patch.region is not None:
            selected &= region == patch.region
        result[selected & (result < 0)] = index
    if np.any(result < 0):
        missing = sorted({BONE_NAMES[b] for b in bone[result < 0]})
        raise ValueError(f"pattern leaves triangles of {', '.join(missing)} unpainted")
    return result


def face_labels(mesh: HandMesh, pattern: GlovePattern) -> NDArray[np.uint8]:
    """Color class 1..10 of every triangle; ``(F,)`` uint8."""
    labels = np.array([p.label for p in pattern.patches], dtype=np.uint8)
    return labels[face_patches(mesh, pattern)]


@dataclass(frozen=True)
class LabeledVertices:
    """The mesh with vertices split on patch borders, so every vertex has one class.

    Attributes
    ----------
    source_vertex : (M,) int64
        Mesh vertex each split vertex copies.
    labels : (M,) uint8
        Class 1..10 of each split vertex.
    faces : (F, 3) int64
        The mesh's triangles re-indexed into the split vertices.
    """

    source_vertex: NDArray[np.int64]
    labels: NDArray[np.uint8]
    faces: NDArray[np.int64]


def split_by_label(mesh: HandMesh, pattern: GlovePattern) -> LabeledVertices:
    """Split vertices where patches meet (a renderer colors vertices, not faces)."""
    labels = face_labels(mesh, pattern).astype(np.int64)
    corner_keys = mesh.faces.astype(np.int64) * 16 + labels[:, None]
    keys, inverse = np.unique(corner_keys.ravel(), return_inverse=True)
    return LabeledVertices(
        source_vertex=keys // 16,
        labels=(keys % 16).astype(np.uint8),
        faces=inverse.reshape(-1, 3).astype(np.int64),
    )


def chroma_uv(rgb: NDArray) -> NDArray[np.float64]:
    """Brightness-normalised chroma of sRGB colors ``(..., 3)``: (U, V) of YUV divided by Y.

    Dividing by luma makes the coordinates invariant to a global gain in exposure;
    it is the space in which the classes must be well separated.
    """
    rgb = np.asarray(rgb, dtype=np.float64) / 255.0
    y = rgb @ np.array([0.299, 0.587, 0.114])
    u = 0.492 * (rgb[..., 2] - y)
    v = 0.877 * (rgb[..., 0] - y)
    return np.stack([u, v], -1) / np.maximum(y, 1e-6)[..., None]
