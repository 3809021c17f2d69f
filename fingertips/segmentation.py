"""Bare-hand segmentation from depth alone: support planes, nearest surface, forearm cut.

The detector's default hand pixels are the depth within a band behind the nearest
surface (:func:`fingertips.features.nearest_band`). That keeps a table the hand rests
on, and loses the hand when a tilted table or a forearm is nearer than the fingers.
:func:`segment_hand` finds the hand without a glove, on any depth stream:

1. **Working grid.** Every ``stride``-th pixel, the stride chosen so that the grid
   samples the nearest surface about every ``grid_spacing_m``.
2. **Support planes** (:func:`find_support_planes`). Seeded RANSAC on at most a few
   thousand of the grid's 3D points, refined by least squares, finds the plane with
   the largest area within a margin: ``plane_margin_m`` plus a sensor noise allowance
   of ``noise_at_1m_m`` times depth squared. Its inliers' connected regions at least
   ``min_plane_area_m2`` large and ``min_plane_width_m`` wide (several times a hand)
   are a support surface, a table or a wall, and are removed; then the next plane.
   Areas are metric (each point stands for the surface its pixel sees), so the
   thresholds do not depend on distance. A hand resting on a table keeps all that lies
   higher than the margin (a palm is about 25 mm thick, a finger 15 mm); a forearm
   and hand seen from the side, a planar strip, are too narrow to be removed.
3. **Nearest connected surface** (:func:`surface_components`). The remaining grid
   points are split into 4-connected components wherever neighbours differ in depth
   by more than a surface sloped at ``max_slope`` plus twice the noise allowance
   (the threshold grows with depth and grid step). The hand is the component with the
   nearest point among those of at least ``min_component_area_m2`` (a few stray pixels
   never win; when none is that large, the largest one). Components that come within
   ``join_radius_m`` of it in the image at most ``join_jump_m`` in front of or behind
   it join it, repeatedly: the fingers that a depth jump separates from the palm.
4. **Forearm cut** (:func:`cut_forearm`). If the hand's points span more than
   ``hand_length_m`` along their principal 3D direction, they hold a forearm too. Of
   the two end regions (``end_length_m`` long), the hand is the one that does not touch
   the image border when exactly one does (an arm enters the picture from outside);
   otherwise the more ragged one: more outline cells over the square root of all its
   cells (a perimeter over the square root of an area, independent of size; fingers
   and the gaps between them make a long outline, a forearm a short one); on a tie the
   nearer one. Points farther than ``hand_length_m`` from the hand's extreme along
   the direction are cut.
5. **Full resolution.** A pixel is kept when its grid cell or a neighbouring one is
   kept, its depth lies within the jump threshold of those cells' depths, it is not
   within the margin of a support plane and it lies on the hand's side of the cut.

How well it does on rendered frames: docs/fingertips.md, "Bare-hand segmentation".

Limits: a table or wall that shows less than ``min_plane_area_m2`` stays, and a hand
that touches it stays joined to it (the forearm cut then bounds the mask to a hand
length); a hand flat on a table loses what lies within the margin (the lower sides of
the fingers); a piece of a plane nearer than the hand, too small to be a support
surface (a corner of a tilted table), wins; a fist at the end of a forearm that ends
in view is no more ragged than the arm's end, and the rule may keep the wrong end; an
object nearer than the hand and larger than ``min_component_area_m2`` wins. The rules
are geometric: no learned mask.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from fingertips.features import intrinsics_array, nearest_depth
from glovedb._validate import as_array

SegmentationMethod = Literal["band", "surface"]
SEGMENTATION_METHODS: tuple[SegmentationMethod, ...] = ("band", "surface")
"""Hand segmentations of the detector: ``"band"`` (depth within a band behind the
nearest surface, :func:`fingertips.features.nearest_band`) and ``"surface"``
(:func:`segment_hand`)."""

_MAX_PLANE_POINTS = 6000
"""About the most grid points the support plane search looks at."""
_MAX_AREA_FACTOR = 4.0
"""Largest ratio of a plane's area to the area facing the camera (the plane seen at a
grazing angle)."""


@dataclass(frozen=True)
class SurfaceSegmentationConfig:
    """Settings of :func:`segment_hand` (module doc); lengths in metres.

    Attributes
    ----------
    grid_spacing_m : float
        Lateral spacing of the working grid at the nearest depth, metres.
    plane_margin_m : float
        Points this close to a support plane (plus the noise allowance) are removed,
        metres.
    noise_at_1m_m : float
        Depth noise allowance at 1 m, metres; it grows with depth squared.
    min_plane_area_m2 : float
        Smallest area of a support plane, square metres (a hand seen from the back
        shows about 0.015 m²).
    min_plane_width_m : float
        Smallest width of a support plane across its longest direction, metres (a
        forearm and hand seen from the side make a long, narrow planar strip).
    max_planes : int
        Most support planes removed.
    ransac_samples : int
        Grid points a RANSAC round scores hypotheses on.
    ransac_iterations : int
        Plane hypotheses per round.
    max_slope : float
        Steepest surface (depth change per lateral distance) that stays connected.
    min_component_area_m2 : float
        Smallest area, square metres, of the component chosen as the hand.
    join_radius_m : float
        Components that come this close (laterally, metres) to the chosen one ...
    join_jump_m : float
        ... at most this far in front of or behind it (metres) join it: the parts of a
        hand split by depth jumps (fingers in front of the palm).
    hand_length_m : float
        What is kept from the hand end along the principal direction, metres (a hand
        is 0.16-0.21 m long).
    end_length_m : float
        Length of the two end regions compared by the forearm rule, metres.
    seed : int
        Seed of the RANSAC draws.
    """

    grid_spacing_m: float = 0.004
    plane_margin_m: float = 0.006
    noise_at_1m_m: float = 0.006
    min_plane_area_m2: float = 0.04
    min_plane_width_m: float = 0.15
    max_planes: int = 3
    ransac_samples: int = 600
    ransac_iterations: int = 150
    max_slope: float = 2.5
    min_component_area_m2: float = 0.002
    join_radius_m: float = 0.01
    join_jump_m: float = 0.05
    hand_length_m: float = 0.22
    end_length_m: float = 0.08
    seed: int = 0

    def __post_init__(self) -> None:
        positive = (
            "grid_spacing_m",
            "plane_margin_m",
            "min_plane_area_m2",
            "min_plane_width_m",
            "max_slope",
            "min_component_area_m2",
            "join_radius_m",
            "join_jump_m",
            "hand_length_m",
            "end_length_m",
        )
        for name in positive:
            value = getattr(self, name)
            if not 0 < value < math.inf:
                raise ValueError(f"{name}: expected a positive, finite value, got {value}")
        if not 0 <= self.noise_at_1m_m < math.inf:
            raise ValueError(f"noise_at_1m_m: expected >= 0, got {self.noise_at_1m_m}")
        if self.max_planes < 0:
            raise ValueError(f"max_planes: expected >= 0, got {self.max_planes}")
        if self.ransac_samples < 3 or self.ransac_iterations < 1:
            raise ValueError(
                "ransac_samples, ransac_iterations: expected at least 3 and 1, got "
                f"{self.ransac_samples}, {self.ransac_iterations}"
            )


DEFAULT_SEGMENTATION = SurfaceSegmentationConfig()
"""The default surface segmentation settings (immutable)."""


@dataclass(frozen=True)
class HandSegmentation:
    """What :func:`segment_hand` found.

    Attributes
    ----------
    mask : (H, W) bool
        The hand's pixels.
    planes : (P, 4) float64
        Removed support planes ``(nx, ny, nz, offset_m)``: ``n . p = offset`` in the
        camera frame, unit normal toward the camera.
    plane_areas_m2 : (P,) float64
        Their areas within the margin, square metres.
    stride : int
        Pixel step of the working grid.
    component_area_m2 : float
        Area of the hand's grid cells (facing the camera) before the forearm cut,
        square metres; 0 when nothing was found.
    nearest_m : float
        Nearest depth of the component chosen as the hand, metres; 0 when nothing was
        found.
    cut_point_m : (3,) float64
        A point of the forearm cut plane, camera frame, metres; NaN without a cut.
    cut_axis : (3,) float64
        Unit normal of the cut plane, pointing to the hand; NaN without a cut.
    """

    mask: NDArray[np.bool_]
    planes: NDArray[np.float64]
    plane_areas_m2: NDArray[np.float64]
    stride: int
    component_area_m2: float
    nearest_m: float
    cut_point_m: NDArray[np.float64]
    cut_axis: NDArray[np.float64]

    @property
    def cut(self) -> bool:
        """Whether a forearm was cut."""
        return bool(np.isfinite(self.cut_axis).all())


def noise_allowance(depth_m: NDArray[np.floating], noise_at_1m_m: float) -> NDArray[np.float32]:
    """Depth noise allowance ``noise_at_1m_m * z²`` (metres) at each depth (metres)."""
    return (np.float32(noise_at_1m_m) * np.square(depth_m)).astype(np.float32)


def find_support_planes(
    points_m: ArrayLike,
    area_m2: ArrayLike,
    *,
    config: SurfaceSegmentationConfig = DEFAULT_SEGMENTATION,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Large planes in an organised point cloud, by seeded RANSAC and least squares.

    Each round draws ``ransac_iterations`` planes through three of ``ransac_samples``
    random points and keeps the one with the largest area within the margin, refined
    twice by a least-squares fit to its inliers. Its inliers are split into
    8-connected regions of the grid; regions of at least ``min_plane_area_m2`` and
    ``min_plane_width_m`` are support surfaces and are removed (a forearm with its hand
    seen from the side is a long, narrow planar strip; a plane through it also cuts a
    wall along a line, which is not connected to the strip). The rounds stop at the
    first plane without such a region.

    Parameters
    ----------
    points_m : (H, W, 3) float
        Camera-frame points of a grid of pixels, metres; z = 0 where missing.
    area_m2 : (H, W) float
        Area each point stands for, facing the camera (``(stride z)² / (fx fy)``),
        square metres; on a plane it is divided by the cosine of the viewing angle.
    config : SurfaceSegmentationConfig

    Returns
    -------
    planes : (P, 4) float64
        ``(nx, ny, nz, offset_m)``, normal toward the camera, in the order found.
    areas_m2 : (P,) float64
        Areas of their removed regions, square metres.
    on_plane : (H, W) bool
        Points removed as support surfaces.
    """
    grid = as_array("points_m", points_m, (None, None, 3), np.float64, kind="fiu")
    grid_area = as_array("area_m2", area_m2, grid.shape[:2], np.float64, kind="fiu")
    # The search runs on a coarser grid of at most about _MAX_PLANE_POINTS points.
    step = max(1, math.ceil(math.sqrt(np.count_nonzero(grid[..., 2] > 0) / _MAX_PLANE_POINTS)))
    coarse = grid[::step, ::step]
    valid = coarse[..., 2] > 0
    points, area = coarse[valid], grid_area[::step, ::step][valid] * step**2
    margin = _plane_margin(points[:, 2], config)
    rng = np.random.default_rng(config.seed)
    removed = np.zeros(len(points), bool)
    planes: list[NDArray[np.float64]] = []
    areas: list[float] = []
    on_plane = np.zeros(grid.shape[:2], bool)
    for _ in range(config.max_planes):
        left = np.flatnonzero(~removed)
        if left.size < 3:
            break
        sample = rng.choice(left, size=min(config.ransac_samples, left.size), replace=False)
        plane = _best_hypothesis(points[sample], area[sample], margin[sample], rng, config)
        if plane is None:
            break
        for _refinement in range(2):
            inliers = ~removed & (np.abs(points @ plane[:3] - plane[3]) < margin)
            if np.count_nonzero(inliers) < 3:
                break
            plane = _fit_plane(points[inliers])
        inliers = ~removed & (np.abs(points @ plane[:3] - plane[3]) < margin)
        # A pixel at depth z sees z / |offset| times its facing area on the plane.
        weight = area * np.minimum(points[:, 2] / max(abs(plane[3]), 1e-9), _MAX_AREA_FACTOR)
        regions = _support_regions(valid, inliers, points, weight, config)
        if not regions.any():
            break
        planes.append(plane)
        areas.append(float(weight[regions].sum()))
        removed |= regions
        on_plane |= _near_regions(grid, valid, regions, step, plane, config)
    return np.array(planes, np.float64).reshape(-1, 4), np.array(areas, np.float64), on_plane


def _plane_margin(depth_m: NDArray[np.floating], config: SurfaceSegmentationConfig) -> NDArray:
    """Distance from a support plane within which points are removed, metres."""
    return np.float32(config.plane_margin_m) + noise_allowance(depth_m, config.noise_at_1m_m)


def _near_regions(
    grid: NDArray[np.float64],
    valid: NDArray[np.bool_],
    regions: NDArray[np.bool_],
    step: int,
    plane: NDArray[np.float64],
    config: SurfaceSegmentationConfig,
) -> NDArray[np.bool_]:
    """Points of the full grid within the margin of a plane whose nearest cell of the
    coarse grid (of step ``step``) or a neighbour of it belongs to the plane's regions."""
    found = np.zeros(valid.shape, np.uint8)
    found[valid] = regions
    around = cv2.dilate(found, np.ones((3, 3), np.uint8))
    rows = _nearest_cell(np.arange(grid.shape[0]), step, valid.shape[0])
    cols = _nearest_cell(np.arange(grid.shape[1]), step, valid.shape[1])
    z = grid[..., 2]
    near = around[np.ix_(rows, cols)].astype(bool) & (z > 0)
    return near & (np.abs(grid @ plane[:3] - plane[3]) < _plane_margin(z, config))


def _nearest_cell(pixels: NDArray[np.intp], step: int, n_cells: int) -> NDArray[np.intp]:
    """Index of the nearest of every ``step``-th pixel (``n_cells`` of them) to pixels."""
    return np.minimum((pixels + step // 2) // step, n_cells - 1)


def _support_regions(
    valid: NDArray[np.bool_],
    inliers: NDArray[np.bool_],
    points: NDArray[np.float64],
    weight: NDArray[np.float64],
    config: SurfaceSegmentationConfig,
) -> NDArray[np.bool_]:
    """Inliers (of the valid grid points) in 8-connected regions as large and as wide as a
    support surface must be."""
    image = np.zeros(valid.shape, bool)
    image[valid] = inliers
    labels = ndimage.label(image, structure=np.ones((3, 3), bool))[0][valid]
    region_area = np.bincount(labels[inliers], weights=weight[inliers])
    keep = np.zeros(len(region_area), bool)
    for label in np.flatnonzero(region_area >= config.min_plane_area_m2):
        if label > 0:
            keep[label] = _plane_width(points[labels == label]) >= config.min_plane_width_m
    return inliers & keep[labels]


def _plane_width(points: NDArray[np.float64]) -> float:
    """Width (metres) of a uniform strip with the spread of planar points across their
    longest direction: ``sqrt(12)`` standard deviations."""
    variances = np.linalg.eigvalsh(np.cov(points, rowvar=False, bias=True))  # ascending
    return float(math.sqrt(12.0 * max(variances[1], 0.0)))


def _best_hypothesis(
    points: NDArray[np.float64],
    area: NDArray[np.float64],
    margin: NDArray[np.float32],
    rng: np.random.Generator,
    config: SurfaceSegmentationConfig,
) -> NDArray[np.float64] | None:
    """The plane through three sampled points with the largest area (facing the camera)
    within the margin."""
    triples = rng.integers(0, len(points), size=(config.ransac_iterations, 3))
    a, b, c = (points[triples[:, k]] for k in range(3))
    normals = np.cross(b - a, c - a)
    length = np.linalg.norm(normals, axis=1)
    good = length > 1e-12
    if not good.any():
        return None
    normals = normals[good] / length[good, None]
    offsets = np.einsum("ij,ij->i", normals, a[good])
    normals[offsets > 0] *= -1  # toward the camera: the origin lies on the positive side
    offsets = -np.abs(offsets)
    residual = np.abs(points.astype(np.float32) @ normals.T.astype(np.float32) - offsets[None])
    inside = (residual < margin[:, None]).astype(np.float32)
    best = int(np.argmax(area.astype(np.float32) @ inside))
    return np.append(normals[best], offsets[best])


def _fit_plane(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Least-squares plane ``(n, offset)`` through points, normal toward the camera."""
    centre = points.mean(axis=0)
    normal = np.linalg.eigh(np.cov(points, rowvar=False, bias=True))[1][:, 0]
    offset = float(normal @ centre)
    if offset > 0:
        normal, offset = -normal, -offset
    return np.append(normal, offset)


def surface_components(depth_m: ArrayLike, max_jump_m: ArrayLike) -> tuple[NDArray[np.int32], int]:
    """4-connected components of a depth image that do not cross depth jumps.

    Two measured 4-neighbours are connected when their depths differ by at most the
    larger of their ``max_jump_m``.

    Parameters
    ----------
    depth_m : (H, W) float
        Depth in metres, 0 where missing (or removed).
    max_jump_m : (H, W) float
        Largest depth step to a neighbour on the same surface, metres.

    Returns
    -------
    labels : (H, W) int32
        1..n per component, 0 where depth is missing.
    n : int
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
    jump = as_array("max_jump_m", max_jump_m, depth.shape, np.float32, kind="fiu")
    height, width = depth.shape
    valid = depth > 0
    # Pixels at even coordinates of a doubled grid, links between them at odd ones: its
    # 4-connected components are those of the graph of continuous neighbours.
    doubled = np.zeros((2 * height - 1, 2 * width - 1), bool)
    doubled[::2, ::2] = valid
    for axis, target in ((1, doubled[::2, 1::2]), (0, doubled[1::2, ::2])):
        first = [slice(None), slice(None)]
        second = [slice(None), slice(None)]
        first[axis], second[axis] = slice(None, -1), slice(1, None)
        a, b = tuple(first), tuple(second)
        step = np.abs(depth[a] - depth[b])
        target[...] = valid[a] & valid[b] & (step <= np.maximum(jump[a], jump[b]))
    labels, n = ndimage.label(doubled)
    return labels[::2, ::2].astype(np.int32), int(n)


def cut_forearm(
    points_m: ArrayLike,
    at_border: ArrayLike,
    on_outline: ArrayLike,
    *,
    config: SurfaceSegmentationConfig = DEFAULT_SEGMENTATION,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The plane that cuts a forearm off a hand's points (module doc, step 4).

    Parameters
    ----------
    points_m : (N, 3) float
        The component's camera-frame points (grid cells), metres.
    at_border : (N,) bool
        Points on the image border.
    on_outline : (N,) bool
        Points on the component's outline: a 4-neighbour cell is not in it.
    config : SurfaceSegmentationConfig

    Returns
    -------
    cut_point_m : (3,) float64
        A point of the cut plane; NaN when nothing is cut (the points span at most
        ``hand_length_m`` along their principal direction).
    cut_axis : (3,) float64
        Unit normal of the cut plane toward the hand: points ``p`` with
        ``(p - cut_point_m) . cut_axis >= 0`` are kept. NaN when nothing is cut.
    """
    points = as_array("points_m", points_m, (None, 3), np.float64, kind="fiu")
    border = as_array("at_border", at_border, (len(points),), bool)
    outline = as_array("on_outline", on_outline, (len(points),), bool)
    none = np.full(3, np.nan)
    if len(points) < 3:
        return none, none
    centre = points.mean(axis=0)
    direction = np.linalg.svd(points - centre, full_matrices=False)[2][0]
    along = (points - centre) @ direction
    low, high = np.percentile(along, [1.0, 99.0])
    if high - low <= config.hand_length_m:
        return none, none
    ends = (along <= low + config.end_length_m, along >= high - config.end_length_m)
    if _hand_is_high_end(points[:, 2], ends, border, outline):
        return centre + (high - config.hand_length_m) * direction, direction
    return centre + (low + config.hand_length_m) * direction, -direction


def _hand_is_high_end(
    depth: NDArray[np.float64],
    ends: tuple[NDArray[np.bool_], NDArray[np.bool_]],
    border: NDArray[np.bool_],
    outline: NDArray[np.bool_],
) -> bool:
    """Whether the hand is the second of two end regions (module doc, step 4)."""
    touches = [bool(border[end].any()) for end in ends]
    if touches[0] != touches[1]:
        return touches[0]
    # Outline cells over the square root of all cells: a shape's perimeter over the
    # square root of its area, which does not depend on its size in the image.
    ragged = [
        np.count_nonzero(outline[end]) / math.sqrt(max(int(np.count_nonzero(end)), 1))
        for end in ends
    ]
    if ragged[0] != ragged[1]:
        return bool(ragged[1] > ragged[0])
    return bool(np.median(depth[ends[1]]) < np.median(depth[ends[0]]))


def segment_hand(
    depth_m: ArrayLike,
    intrinsics: ArrayLike,
    *,
    config: SurfaceSegmentationConfig = DEFAULT_SEGMENTATION,
) -> HandSegmentation:
    """The hand's pixels in a depth frame, without a glove (module doc).

    Parameters
    ----------
    depth_m : (H, W) float
        Depth in metres, 0 where missing (restrict it to a working range first, e.g.
        :func:`fingertips.features.mask_depth_range`).
    intrinsics : (4,) float
        ``(fx, fy, cx, cy)`` in pixels.
    config : SurfaceSegmentationConfig

    Returns
    -------
    HandSegmentation
        An empty mask when no depth is measured.
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
    camera = intrinsics_array(intrinsics)
    grid = _working_grid(depth, camera, config.grid_spacing_m)
    planes, plane_areas, on_plane = find_support_planes(
        grid.organised_points(),
        np.square(grid.stride * grid.depth_m.astype(np.float64)) / (camera[0] * camera[1]),
        config=config,
    )
    kept = np.where(on_plane, np.float32(0.0), grid.depth_m)
    max_jump = np.float32(config.max_slope * grid.stride / camera[0]) * grid.depth_m
    max_jump += 2 * noise_allowance(grid.depth_m, config.noise_at_1m_m)
    labels, n = surface_components(kept, max_jump)
    mask = np.zeros(depth.shape, bool)
    if n == 0:
        nothing = np.full(3, np.nan)
        return HandSegmentation(mask, planes, plane_areas, grid.stride, 0.0, 0.0, nothing, nothing)
    cell_area = grid.stride**2 / (camera[0] * camera[1])  # times depth squared, m²
    chosen, nearest = _choose_component(labels, kept, cell_area, n, config.min_component_area_m2)
    radius = math.ceil(config.join_radius_m * camera[0] / (grid.stride * nearest))
    cells = _join_parts(labels, kept, labels == chosen, radius, config.join_jump_m)
    cut_point, cut_axis = _cut_of_cells(cells, grid, config)
    window = _cell_window(cells, depth.shape, grid.stride)
    mask[window] = _full_resolution(depth, window, cells, grid, max_jump)
    mask[window] &= ~_on_planes(depth, window, planes, camera, config)
    mask[window] &= _hand_side(depth, window, camera, cut_point, cut_axis)
    return HandSegmentation(
        mask=mask,
        planes=planes,
        plane_areas_m2=plane_areas,
        stride=grid.stride,
        component_area_m2=float(np.sum(np.square(kept[cells].astype(np.float64)))) * cell_area,
        nearest_m=nearest,
        cut_point_m=cut_point,
        cut_axis=cut_axis,
    )


@dataclass(frozen=True)
class _Grid:
    """Every ``stride``-th pixel of a depth image and the rays through them."""

    depth_m: NDArray[np.float32]
    stride: int
    rays_x: NDArray[np.float64]
    rays_y: NDArray[np.float64]

    def organised_points(self) -> NDArray[np.float64]:
        """Camera-frame points ``(h, w, 3)`` of all cells, metres; 0 where missing."""
        z = self.depth_m.astype(np.float64)
        return np.stack([self.rays_x[None, :] * z, self.rays_y[:, None] * z, z], axis=-1)

    def points(self, rows: NDArray[np.intp], cols: NDArray[np.intp]) -> NDArray[np.float64]:
        """Camera-frame points ``(N, 3)`` of grid cells, metres."""
        z = self.depth_m[rows, cols].astype(np.float64)
        return np.stack([self.rays_x[cols] * z, self.rays_y[rows] * z, z], axis=1)


def _working_grid(
    depth: NDArray[np.float32], camera: NDArray[np.float64], spacing_m: float
) -> _Grid:
    """The grid that samples the nearest surface about every ``spacing_m``."""
    fx, fy, cx, cy = camera
    nearest = nearest_depth(depth)
    stride = max(1, round(spacing_m * fx / nearest)) if nearest > 0 else 1
    sampled = depth[::stride, ::stride]
    return _Grid(
        depth_m=np.where(np.isfinite(sampled) & (sampled > 0), sampled, np.float32(0.0)),
        stride=stride,
        rays_x=(np.arange(0, depth.shape[1], stride) - cx) / fx,
        rays_y=(np.arange(0, depth.shape[0], stride) - cy) / fy,
    )


def _cut_of_cells(
    cells: NDArray[np.bool_], grid: _Grid, config: SurfaceSegmentationConfig
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`cut_forearm` of the chosen grid cells."""
    rows, cols = np.nonzero(cells)
    height, width = cells.shape
    at_border = (rows == 0) | (cols == 0) | (rows == height - 1) | (cols == width - 1)
    cross = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], np.uint8)
    inner = cv2.erode(cells.astype(np.uint8), cross).astype(bool)  # the image border is inside
    return cut_forearm(grid.points(rows, cols), at_border, ~inner[rows, cols], config=config)


def _choose_component(
    labels: NDArray[np.int32],
    depth: NDArray[np.float32],
    cell_area: float,
    n: int,
    min_area_m2: float,
) -> tuple[int, float]:
    """Label (of ``n`` > 0) and nearest depth of the nearest component of at least
    ``min_area_m2`` (the largest one when none is). A cell's area is ``cell_area``
    times its depth squared."""
    on = labels > 0
    flat, z = labels[on], depth[on].astype(np.float64)
    areas = np.bincount(flat, weights=np.square(z) * cell_area, minlength=n + 1)
    nearest = np.full(n + 1, np.inf)
    np.minimum.at(nearest, flat, z)
    large = np.flatnonzero(areas[1:] >= min_area_m2) + 1
    if large.size:
        chosen = int(large[np.argmin(nearest[large])])
    else:
        chosen = int(np.argmax(areas[1:])) + 1
    return chosen, float(nearest[chosen])


def _join_parts(
    labels: NDArray[np.int32],
    depth: NDArray[np.float32],
    cells: NDArray[np.bool_],
    radius_cells: int,
    join_jump_m: float,
) -> NDArray[np.bool_]:
    """``cells`` grown by the components that come within ``radius_cells`` of them with a
    cell at most ``join_jump_m`` in front of or behind the nearby chosen cells."""
    kernel = np.ones((2 * radius_cells + 1, 2 * radius_cells + 1), np.uint8)
    jump = np.float32(join_jump_m)
    while True:
        low = cv2.erode(np.where(cells, depth - jump, np.float32(np.inf)), kernel)
        high = cv2.dilate(np.where(cells, depth + jump, np.float32(-np.inf)), kernel)
        near = (labels > 0) & ~cells & (depth >= low) & (depth <= high)
        if not near.any():
            return cells
        cells = cells | np.isin(labels, np.unique(labels[near]))


def _cell_window(
    cells: NDArray[np.bool_], shape: tuple[int, ...], stride: int
) -> tuple[slice, slice]:
    """The full-resolution window of the chosen grid cells and their neighbours."""
    rows, cols = np.nonzero(cells)
    top = max(0, (int(rows.min()) - 1) * stride - stride // 2)
    left = max(0, (int(cols.min()) - 1) * stride - stride // 2)
    bottom = min(shape[0], (int(rows.max()) + 2) * stride)
    right = min(shape[1], (int(cols.max()) + 2) * stride)
    return slice(top, bottom), slice(left, right)


def _full_resolution(
    depth: NDArray[np.float32],
    window: tuple[slice, slice],
    cells: NDArray[np.bool_],
    grid: _Grid,
    max_jump: NDArray[np.float32],
) -> NDArray[np.bool_]:
    """Pixels of a window whose nearest grid cell or a neighbour of it is chosen, at a
    depth within the jump threshold of those cells."""
    kernel = np.ones((3, 3), np.uint8)
    low = cv2.erode(np.where(cells, grid.depth_m - max_jump, np.float32(np.inf)), kernel)
    high = cv2.dilate(np.where(cells, grid.depth_m + max_jump, np.float32(-np.inf)), kernel)
    rows, cols = window
    cell = np.ix_(
        _nearest_cell(np.arange(rows.start, rows.stop), grid.stride, cells.shape[0]),
        _nearest_cell(np.arange(cols.start, cols.stop), grid.stride, cells.shape[1]),
    )
    inside = depth[window]
    return (inside > 0) & (inside >= low[cell]) & (inside <= high[cell])


def _window_rays(
    window: tuple[slice, slice], camera: NDArray[np.float64]
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Rays ``x / z`` ``(1, w)`` and ``y / z`` ``(h, 1)`` of a window's pixels."""
    fx, fy, cx, cy = camera
    rows, cols = window
    rays_x = ((np.arange(cols.start, cols.stop) - cx) / fx).astype(np.float32)
    rays_y = ((np.arange(rows.start, rows.stop) - cy) / fy).astype(np.float32)
    return rays_x[None, :], rays_y[:, None]


def _on_planes(
    depth: NDArray[np.float32],
    window: tuple[slice, slice],
    planes: NDArray[np.float64],
    camera: NDArray[np.float64],
    config: SurfaceSegmentationConfig,
) -> NDArray[np.bool_]:
    """Pixels of a window within the margin of a plane."""
    inside = depth[window]
    rays_x, rays_y = _window_rays(window, camera)
    margin = _plane_margin(inside, config)
    on = np.zeros(inside.shape, bool)
    for nx, ny, nz, offset in planes.astype(np.float32):
        on |= np.abs(inside * (nx * rays_x + ny * rays_y + nz) - offset) < margin
    return on


def _hand_side(
    depth: NDArray[np.float32],
    window: tuple[slice, slice],
    camera: NDArray[np.float64],
    cut_point: NDArray[np.float64],
    cut_axis: NDArray[np.float64],
) -> NDArray[np.bool_]:
    """Pixels of a window on the hand's side of the forearm cut (all without a cut)."""
    inside = depth[window]
    if not np.isfinite(cut_axis).all():
        return np.ones(inside.shape, bool)
    rays_x, rays_y = _window_rays(window, camera)
    ax, ay, az = cut_axis.astype(np.float32)
    along = inside * (ax * rays_x + ay * rays_y + az)
    return along >= np.float32(cut_point @ cut_axis)
