"""Pictures a person looks at: posture renders, the printable glove pattern, sheets.

Functions here return ``(H, W, 3) uint8`` RGB images; writing them is the caller's job
(:func:`save_rgb`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from builder.render import GloveRenderer, Rendering
from glovedb.hand_model import N_JOINTS
from glovedb.pattern import GlovePattern
from glovedb.views import named_view
from tracker.overlay import write_rgb

_FONT = cv2.FONT_HERSHEY_SIMPLEX


def depth_to_rgb(depth_m: NDArray[np.floating]) -> NDArray[np.uint8]:
    """Color-map the valid depths of an ``(H, W)`` image (near red, far blue); 0 stays black."""
    valid = depth_m > 0
    picture = np.zeros(depth_m.shape + (3,), np.uint8)
    if not valid.any():
        return picture
    near, far = np.percentile(depth_m[valid], [1, 99])
    scaled = np.clip((depth_m - near) / max(far - near, 1e-6), 0, 1)
    mapped = cv2.applyColorMap((255 * (1 - scaled)).astype(np.uint8), cv2.COLORMAP_TURBO)
    picture[valid] = mapped[valid][:, ::-1]
    return picture


def caption(image: NDArray[np.uint8], text: str, *, scale: float = 0.6) -> NDArray[np.uint8]:
    """A copy of ``image`` with ``text`` written in its top-left corner."""
    out = image.copy()
    cv2.putText(out, text, (10, 28), _FONT, scale, (255, 255, 255), 2, cv2.LINE_AA)
    return out


def title_bar(image: NDArray[np.uint8], text: str) -> NDArray[np.uint8]:
    """``image`` with a 36-pixel bar holding ``text`` added below it."""
    bar = np.zeros((36, image.shape[1], 3), np.uint8)
    cv2.putText(bar, text, (10, 25), _FONT, 0.7, (255, 255, 255), 2, cv2.LINE_AA)
    return np.vstack([image, bar])


def rendering_panels(rendering: Rendering, pattern: GlovePattern) -> NDArray[np.uint8]:
    """Color, labels (in the nominal colors) and depth side by side."""
    return np.hstack(
        [
            caption(rendering.color, "color"),
            caption(pattern.colorize(rendering.labels), "labels"),
            caption(depth_to_rgb(rendering.depth_m), "depth"),
        ]
    )


def grid(images: Sequence[NDArray[np.uint8]], columns: int) -> NDArray[np.uint8]:
    """Tile equally sized images row by row, padding the last row with black."""
    if not images:
        raise ValueError("grid: no images")
    blank = np.zeros_like(images[0])
    rows = []
    for start in range(0, len(images), columns):
        row = list(images[start : start + columns])
        row += [blank] * (columns - len(row))
        rows.append(np.hstack(row))
    return np.vstack(rows)


def pattern_sheet(renderer: GloveRenderer, *, distance_m: float = 0.32) -> NDArray[np.uint8]:
    """The glove pattern to paint a real glove: back and palm of the open hand, and a
    legend of the ten colors with the two patches each one covers."""
    hand_length = renderer.mesh.skeleton.hand_length_m
    views = []
    for view in ("back", "palm"):
        rotation, translation = named_view(view, distance_m, hand_length)
        rendering = renderer.render(np.zeros(N_JOINTS), rotation, translation)
        views.append(
            caption(renderer.pattern.colorize(rendering.labels), f"{view} of a right hand")
        )
    pattern = renderer.pattern
    legend = np.zeros((views[0].shape[0], 330, 3), np.uint8)
    for index, name in enumerate(pattern.color_names):
        label = index + 1
        top = 20 + 44 * index
        cv2.rectangle(legend, (10, top), (44, top + 30), pattern.colors_rgb[index].tolist(), -1)
        patches = [p.name for p in pattern.patches if p.label == label]
        cv2.putText(legend, f"{label} {name}", (54, top + 12), _FONT, 0.45, (255, 255, 255), 1)
        cv2.putText(legend, ", ".join(patches), (54, top + 29), _FONT, 0.4, (200, 200, 200), 1)
    return np.hstack(views + [legend])


def check_image_path(path: str | Path) -> Path:
    """``path`` as a Path if an image can be written there; else a one-line ``ValueError``."""
    path = Path(path)
    if path.suffix.lower() not in (".png", ".jpg", ".jpeg"):
        raise ValueError(f"{path}: expected a .png or .jpg file name")
    if not path.parent.is_dir():
        raise ValueError(f"{path.parent}: folder does not exist")
    return path


def save_rgb(path: str | Path, image: NDArray[np.uint8]) -> Path:
    """Write an RGB image (PNG or JPEG by extension); ``ValueError`` if it cannot."""
    return write_rgb(check_image_path(path), image)
