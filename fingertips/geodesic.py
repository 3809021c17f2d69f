"""Fingertip candidates that need no learning: geodesic extrema of the hand's surface.

An extended finger is a far end of the hand's surface: walking on the surface from the
middle of the palm, its tip is farther than anything around it. This stage finds
those ends in one depth frame of the segmented hand (issue 23), after Plagemann et
al., "Real-time identification and localization of body parts from depth images"
(ICRA 2010: accumulative geodesic extrema, AGEX). Lengths are in metres throughout,
so the settings hold at every distance and resolution.

1. **Metric grid.** The frame is reduced to cells of about ``cell_m`` (4 mm) at the
   nearest surface: the pixel stride is ``cell_m`` times the focal length over the
   nearest depth (:func:`fingertips.features.stride_for_spacing`), so an open hand
   covers 800-1,200 cells at 0.3, 0.6 and 1 m alike (at VGA, 52,000, 12,800 and 4,600
   pixels), and the cost does not grow as the hand comes closer. When more than
   ``max_cells`` cells would be measured (a wall or a table in the depth band), the
   hand is first found (step 3) on a grid of at most that many cells, and only its
   bounding box, grown by ``max_bridge_m``, is gridded finely (coarser still if it
   holds more than ``max_cells``). A cell's
   depth is the lower median of a 3 x 3 lattice of its pixels (an existing value,
   never a mix of a finger and the palm behind it), when at least half of them are
   measured.
2. **Surface graph.** Each cell joins its 8 neighbours, except across a depth step
   steeper than ``max_slope`` (3: 72 degrees) times the lateral length of the edge: a
   finger lying in front of the palm is not joined to it, a tilted palm is. An edge is
   as long as the 3D distance between its cells' points after a 3 x 3 median of the
   cell depths (:func:`median_3x3`): sensor noise of a few millimetres on 4 mm cells
   would otherwise lengthen every path by up to a third and make pockets along the
   fingers look like ends.
3. **Hand and palm centre.** The hand is the nearest (smallest median depth)
   connected component whose projected area lies within ``min_hand_area_m2`` and
   ``max_hand_area_m2`` (15-500 cm²; a hand with its forearm covers up to about
   350 cm²; a wall or table in the depth band is cut from the hand by its depth step
   and is larger). The palm centre, the source, is the centre of the largest disc
   inscribed in the hand: the maximum of the distance transform of its cells, the
   cells on a cut edge counted as outside so that the disc lies on one continuous
   surface. The palm is the thickest part of a hand (a forearm seen from the front
   is narrower); a centroid would drift toward the fingers or the arm.
4. **Separated parts.** A finger seen behind another finger or the palm is a
   component of its own. Components of at most ``max_part_area_m2`` (100 cm²) are
   joined to the hand, nearest first, by one edge between the closest outline cells
   (3D) when they are at most ``max_bridge_m`` (7 cm) apart: the geodesic may jump
   through the air, at the price of the jump's length. Outline cells are compared
   rather than grid neighbours because a sensor loses the pixels along a depth step.
5. **Geodesic extrema.** Dijkstra gives every cell's geodesic distance from the palm
   centre (its *reach*). Then, up to ``max_extrema`` times, the cell farthest from
   every source so far, among the local maxima of the reach (a point halfway along a
   finger is far from every source but is no end of anything), becomes an extremum
   and a source itself; its distances are folded in by a search bounded by the
   current largest distance. The search stops when the farthest such cell is closer
   than ``min_separation_m`` (3 cm) to a source: extrema are never closer than that on
   the surface.
6. **Candidates.** An extremum is a candidate when its reach is at least
   ``min_reach_m`` (5 cm: the tips of an open hand reach 11-15 cm from the palm
   centre, the rim of the palm and the wrist 5-10 cm, which is left to the width test),
   no cell within
   ``peak_radius_m`` (1.5 cm, geodesic) reaches more than ``peak_tolerance_m`` (3 mm)
   farther, and no earlier candidate lies within ``duplicate_radius_m`` (15 mm, 3D;
   parts split by noise or occlusion are far apart on the graph but not in space).
   Its point is its cell's surface point moved ``tip_depth_m`` (6 mm) along the
   viewing ray: the fingertip keypoint is the end of the finger's centre line, behind
   the surface the camera sees.
7. **Fingers and the rest.** A finger is narrow: ``width_radius_m`` (3 cm) from its
   tip, the surface is a cut across the finger, 1-2 cm wide (projected); from a corner
   of the wrist cuff, the end of a forearm or a corner of the palm it is an arc of 4 cm
   or more. The width is the projected area of the ring of cells between
   ``width_radius_m -+ width_band_m / 2`` from the extremum over ``width_band_m`` (the
   length of the level line). A candidate is flagged a finger when that width is at
   most ``max_finger_width_m`` (3.5 cm) and it is not on the image border (an arm cut
   by the border ends there; a fingertip outside the image cannot be seen). The others
   stay in the result, flagged, and :meth:`GeodesicCandidates.fingers` drops them.

The settings were chosen on rendered open hands (the tests) and on 150 frames drawn
like ``configs/fingertips/validation.toml`` with another seed (11), scored by
:func:`fingertips.geodesic_evaluation.score_candidates` (recall of the visible tips
within 15 mm: 0.69 with 3.3 finger candidates per frame matching no tip). Around the
chosen values, ``max_slope`` (2-4), ``max_bridge_m`` (4-12 cm), ``max_extrema``
(12-20), ``min_reach_m`` (4-6 cm), ``min_separation_m`` (3-4 cm), ``tip_depth_m``
(4-8 mm) and ``max_finger_width_m`` (3-4 cm) each moved that recall by at most 0.03;
without joining separated parts it is 0.53. ``peak_radius_m`` and
``duplicate_radius_m`` trade recall for fewer extra candidates (2.5 cm instead of
1.5 cm: 0.01 less recall, 0.4 fewer extras; no duplicate test: 0.01 more recall,
0.2 more extras). The tip is the extremum itself, since the mean of the surface
around it (within 0.6-1.5 cm) lay farther from the keypoint.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import distance_transform_edt
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from fingertips._features_kernels import count_measured
from fingertips._geodesic_kernels import (
    block_medians,
    lower_distances,
    neighbour_pairs,
    surface_medians,
    symmetric_csr,
)
from fingertips.features import intrinsics_array, stride_for_budget, stride_for_spacing
from fingertips.voting import apart_in_order
from glovedb._validate import as_array

NEIGHBOUR_OFFSETS = ((0, 1), (1, 0), (1, 1), (1, -1))
"""Row and column steps to the neighbours each cell links to (the other four link back)."""

BLOCK_SAMPLES = 3
"""A cell's depth comes from a lattice of at most this many pixels squared."""


@dataclass(frozen=True)
class GeodesicConfig:
    """Settings of the geodesic candidate stage (see the module docstring).

    Attributes
    ----------
    cell_m : float
        Wanted lateral size of a grid cell at the nearest surface, metres.
    max_cells : int
        With more measured cells than this, the hand is found on a coarser grid first
        and only its window is gridded at ``cell_m`` (coarser if it still holds more).
    max_slope : float
        An edge is cut when its depth step exceeds this times its lateral length.
    min_hand_area_m2, max_hand_area_m2 : float
        Projected area of a component that can be the hand, m² (the nearest such one
        is; without one, the nearest component of at least ``min_hand_area_m2``).
    max_part_area_m2 : float
        Largest separated component joined to the hand, m².
    max_bridge_m : float
        Longest jump (3D) that joins a separated component, metres.
    max_extrema : int
        Most geodesic extrema taken (each costs one bounded Dijkstra search).
    min_separation_m : float
        Extrema are at least this far from each other and from the palm centre on the
        surface, metres.
    min_reach_m : float
        Least geodesic distance of a candidate from the palm centre, metres.
    peak_radius_m, peak_tolerance_m : float
        No cell within ``peak_radius_m`` (geodesic) of a candidate lies more than
        ``peak_tolerance_m`` farther from the palm centre, metres.
    duplicate_radius_m : float
        A candidate within this (3D) of an earlier one is dropped, metres.
    tip_depth_m : float
        A candidate's point lies this far behind its surface point along the viewing
        ray, metres.
    width_radius_m, width_band_m : float
        The width of the surface is measured on the ring between ``width_radius_m -
        width_band_m / 2`` and ``width_radius_m + width_band_m / 2`` (geodesic) from a
        candidate, metres.
    max_finger_width_m : float
        A candidate wider than this is not a finger, metres.
    """

    cell_m: float = 0.004
    max_cells: int = 6000
    max_slope: float = 3.0
    min_hand_area_m2: float = 0.0015
    max_hand_area_m2: float = 0.05
    max_part_area_m2: float = 0.01
    max_bridge_m: float = 0.07
    max_extrema: int = 16
    min_separation_m: float = 0.03
    min_reach_m: float = 0.05
    peak_radius_m: float = 0.015
    peak_tolerance_m: float = 0.003
    duplicate_radius_m: float = 0.015
    tip_depth_m: float = 0.006
    width_radius_m: float = 0.03
    width_band_m: float = 0.01
    max_finger_width_m: float = 0.035

    def __post_init__(self) -> None:
        positive = (
            "cell_m", "max_slope", "min_separation_m", "peak_radius_m", "width_radius_m",
            "width_band_m", "max_finger_width_m",
        )  # fmt: skip
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: expected a positive number, got {getattr(self, name)}")
        non_negative = (
            "min_hand_area_m2", "max_part_area_m2", "max_bridge_m", "min_reach_m",
            "peak_tolerance_m", "duplicate_radius_m", "tip_depth_m",
        )  # fmt: skip
        for name in non_negative:
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name}: expected 0 or more, got {getattr(self, name)}")
        if not self.max_hand_area_m2 >= self.min_hand_area_m2:
            raise ValueError(
                "max_hand_area_m2: expected at least min_hand_area_m2 "
                f"({self.min_hand_area_m2}), got {self.max_hand_area_m2}"
            )
        for name in ("max_cells", "max_extrema"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}: expected at least 1, got {getattr(self, name)}")
        if not self.width_band_m < 2 * self.width_radius_m:
            raise ValueError(
                f"width_band_m: expected less than twice width_radius_m, got {self.width_band_m}"
            )


DEFAULT_GEODESIC = GeodesicConfig()


@dataclass(frozen=True)
class GeodesicCandidates:
    """Fingertip candidates of one frame, in the order they were found.

    Attributes
    ----------
    points_m : (K, 3) float32
        Candidate fingertips in the camera frame, metres.
    pixels_uv : (K, 2) float32
        Their projections ``(u, v)`` into the image, pixels.
    reach_m : (K,) float32
        Geodesic distance from the palm centre, metres.
    separation_m : (K,) float32
        Geodesic distance to the nearest earlier source (the palm centre or an earlier
        extremum) when the candidate was taken, metres.
    width_m : (K,) float32
        Width of the surface ``width_radius_m`` from the candidate, metres.
    is_finger : (K,) bool
        Narrow and not on the image border: a finger rather than the end of a forearm,
        the wrist or a corner of the palm.
    palm_m : (3,) float32
        Palm centre (on the surface) in the camera frame, metres; NaN without a hand.
    palm_uv : (2,) float32
        Its pixel; NaN without a hand.
    palm_radius_m : float
        Radius of the largest disc inscribed in the hand, metres; 0 without a hand.
    cell_m : float
        Lateral size of a grid cell at the nearest surface, metres; 0 without depth.
    """

    points_m: NDArray[np.float32]
    pixels_uv: NDArray[np.float32]
    reach_m: NDArray[np.float32]
    separation_m: NDArray[np.float32]
    width_m: NDArray[np.float32]
    is_finger: NDArray[np.bool_]
    palm_m: NDArray[np.float32]
    palm_uv: NDArray[np.float32]
    palm_radius_m: float
    cell_m: float

    def __len__(self) -> int:
        return len(self.reach_m)

    def fingers(self) -> GeodesicCandidates:
        """The candidates flagged as fingers, with the same palm."""
        return self.select(self.is_finger)

    def select(self, keep: ArrayLike) -> GeodesicCandidates:
        """The candidates picked by a ``(K,)`` bool mask or an index array, same palm."""
        index = np.arange(len(self))[as_array("keep", keep, (None,), kind="biu")]
        return GeodesicCandidates(
            points_m=self.points_m[index],
            pixels_uv=self.pixels_uv[index],
            reach_m=self.reach_m[index],
            separation_m=self.separation_m[index],
            width_m=self.width_m[index],
            is_finger=self.is_finger[index],
            palm_m=self.palm_m,
            palm_uv=self.palm_uv,
            palm_radius_m=self.palm_radius_m,
            cell_m=self.cell_m,
        )


def no_candidates(cell_m: float = 0.0) -> GeodesicCandidates:
    """The result for a frame without a hand."""
    return GeodesicCandidates(
        points_m=np.zeros((0, 3), np.float32),
        pixels_uv=np.zeros((0, 2), np.float32),
        reach_m=np.zeros(0, np.float32),
        separation_m=np.zeros(0, np.float32),
        width_m=np.zeros(0, np.float32),
        is_finger=np.zeros(0, bool),
        palm_m=np.full(3, np.nan, np.float32),
        palm_uv=np.full(2, np.nan, np.float32),
        palm_radius_m=0.0,
        cell_m=cell_m,
    )


def geodesic_candidates(
    depth_m: ArrayLike,
    intrinsics: ArrayLike,
    *,
    config: GeodesicConfig = DEFAULT_GEODESIC,
) -> GeodesicCandidates:
    """Fingertip candidates: geodesic extrema of the hand's depth surface from the palm.

    Parameters
    ----------
    depth_m : (H, W) float
        Depth of the segmented hand in metres, 0 (or NaN) elsewhere, such as
        :func:`fingertips.detect.hand_depth`. Other surfaces may remain when a depth
        step separates them from the hand (module docstring, step 3).
    intrinsics : (4,) float
        ``(fx, fy, cx, cy)``, pixels.
    config : GeodesicConfig

    Returns
    -------
    GeodesicCandidates
        Empty, with a NaN palm, when no surface is large enough to be a hand.
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
    camera = intrinsics_array(intrinsics)
    crop, origin_uv = measured_crop(depth)
    if crop.size == 0:
        return no_candidates()
    focal = math.sqrt(camera[0] * camera[1])
    stride = stride_for_spacing(crop, focal, spacing_m=config.cell_m)
    if count_measured(crop) > config.max_cells * stride**2:
        crop, origin_uv = _hand_window(crop, origin_uv, camera, config)
        stride = max(stride, stride_for_budget(crop, config.max_cells))
    grid = cell_grid(crop, stride, origin_uv=origin_uv)
    if not grid.depth_m.any():
        return no_candidates()
    cell_m = float(stride * grid.depth_m[grid.depth_m > 0].min() / focal)
    hand = hand_surface(grid, camera, config)
    if hand is None:
        return no_candidates(cell_m)
    extrema, separation, reach = geodesic_extrema(
        hand.edges, hand.palm, max_extrema=config.max_extrema,
        min_separation_m=config.min_separation_m,
    )  # fmt: skip
    far_enough = reach[extrema] >= config.min_reach_m
    extrema, separation = extrema[far_enough], separation[far_enough]
    around = _distances_around(hand.edges, extrema, config)
    peaks = _peaks(around, reach, extrema, config)
    extrema, separation, around = extrema[peaks], separation[peaks], around[peaks]
    apart = _apart(hand.graph.points_m[extrema], config.duplicate_radius_m)
    extrema, separation, around = extrema[apart], separation[apart], around[apart]
    surface = hand.graph.points_m[extrema].astype(np.float64)
    points = (surface * (1.0 + config.tip_depth_m / surface[:, 2:])).astype(np.float32)
    ring = np.abs(around - config.width_radius_m) <= config.width_band_m / 2
    width = ring @ hand.graph.area_m2.astype(np.float64) / config.width_band_m
    on_border = _on_border(hand.graph.pixels_uv[extrema], depth.shape, stride)
    palm_z = float(hand.graph.points_m[hand.palm, 2])
    return GeodesicCandidates(
        points_m=points,
        pixels_uv=_project(points, camera),
        reach_m=reach[extrema].astype(np.float32),
        separation_m=separation.astype(np.float32),
        width_m=width.astype(np.float32),
        is_finger=(width <= config.max_finger_width_m) & ~on_border,
        palm_m=hand.graph.points_m[hand.palm].copy(),
        palm_uv=hand.graph.pixels_uv[hand.palm].copy(),
        palm_radius_m=hand.palm_radius_cells * stride * palm_z / focal,
        cell_m=cell_m,
    )


@dataclass(frozen=True)
class HandSurface:
    """The hand's graph, ready for geodesic distances (:func:`hand_surface`).

    Attributes
    ----------
    graph : SurfaceGraph
        All measured cells.
    edges : (N, N) scipy.sparse.csr_matrix of float64
        ``graph.edges`` plus the edges that join separated parts to the hand, metres.
    palm : int
        Node of the palm centre.
    palm_radius_cells : float
        Radius of the largest disc inscribed in the hand, grid cells.
    """

    graph: SurfaceGraph
    edges: csr_matrix
    palm: int
    palm_radius_cells: float


def hand_surface(
    grid: CellGrid, intrinsics: NDArray[np.float64], config: GeodesicConfig
) -> HandSurface | None:
    """Graph of the cells, the hand's component, its palm centre and joined parts.

    Steps 2-4 of the module docstring; None when no component can be the hand.
    """
    graph = surface_graph(grid, intrinsics, max_slope=config.max_slope)
    labels, hand = hand_component(
        graph, min_area_m2=config.min_hand_area_m2, max_area_m2=config.max_hand_area_m2
    )
    if hand < 0:
        return None
    palm, radius_cells = palm_centre(graph, labels == hand)
    bridges, lengths = bridge_parts(
        graph, labels, hand, max_part_area_m2=config.max_part_area_m2,
        max_bridge_m=config.max_bridge_m,
    )  # fmt: skip
    edges = graph.edges
    if len(bridges):
        edges = (edges + symmetric_edges(bridges, lengths, len(graph.points_m))).tocsr()
    return HandSurface(graph, edges, palm, radius_cells)


def _hand_window(
    crop: NDArray[np.float32],
    origin_uv: tuple[int, int],
    intrinsics: NDArray[np.float64],
    config: GeodesicConfig,
) -> tuple[NDArray[np.float32], tuple[int, int]]:
    """The part of ``crop`` around the hand, found on a grid of at most ``max_cells``.

    The window is the bounding box of the hand's component on that coarse grid, grown
    by ``max_bridge_m`` so that separated parts can still be joined; the whole crop
    when no component can be the hand.
    """
    stride = stride_for_budget(crop, config.max_cells)
    coarse = cell_grid(crop, stride, origin_uv=origin_uv)
    graph = surface_graph(coarse, intrinsics, max_slope=config.max_slope)
    labels, hand = hand_component(
        graph, min_area_m2=config.min_hand_area_m2, max_area_m2=config.max_hand_area_m2
    )
    if hand < 0:
        return crop, origin_uv
    inside = labels == hand
    margin = config.max_bridge_m * math.sqrt(intrinsics[0] * intrinsics[1])
    margin = margin / float(graph.points_m[inside, 2].min()) + stride
    low = np.floor(graph.pixels_uv[inside].min(axis=0) - margin).astype(int) - origin_uv
    high = np.ceil(graph.pixels_uv[inside].max(axis=0) + margin).astype(int) - origin_uv
    (left, top), (right, bottom) = np.maximum(low, 0), high + 1
    window = crop[top:bottom, left:right]
    return window, (origin_uv[0] + int(left), origin_uv[1] + int(top))


def measured_crop(depth_m: NDArray[np.float32]) -> tuple[NDArray[np.float32], tuple[int, int]]:
    """The bounding box of the finite positive depth, with everything else set to 0.

    Returns
    -------
    crop : (h, w) float32
        Empty ``(0, 0)`` when nothing is measured.
    origin_uv : tuple of int
        Pixel ``(u, v)`` of the crop's first pixel.
    """
    measured = (depth_m > 0) & (depth_m < np.inf)
    rows = np.flatnonzero(measured.any(axis=1))
    cols = np.flatnonzero(measured.any(axis=0))
    if rows.size == 0:
        return np.zeros((0, 0), np.float32), (0, 0)
    window = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
    crop = np.where(measured[window], depth_m[window], np.float32(0.0)).astype(np.float32)
    return crop, (int(cols[0]), int(rows[0]))


@dataclass(frozen=True)
class CellGrid:
    """Depth reduced to square cells of ``stride`` pixels (:func:`cell_grid`).

    Attributes
    ----------
    depth_m : (h, w) float32
        Depth of each cell, metres; 0 where missing.
    pixels_uv : (h, w, 2) float32
        Pixel ``(u, v)`` of each cell's centre in the full image.
    stride : int
        Cell size in pixels.
    """

    depth_m: NDArray[np.float32]
    pixels_uv: NDArray[np.float32]
    stride: int


def cell_grid(
    depth_m: NDArray[np.float32], stride: int, *, origin_uv: tuple[int, int] = (0, 0)
) -> CellGrid:
    """Reduce depth to ``stride`` x ``stride`` pixel cells.

    A cell's depth is the lower median of the measured pixels of a lattice of
    ``min(stride, BLOCK_SAMPLES)`` squared pixels spread over it, when at least half of
    them are measured; else 0.

    Parameters
    ----------
    depth_m : (h, w) float32
        Metres, 0 where missing (finite).
    stride : int
        At least 1.
    origin_uv : tuple of int
        Pixel ``(u, v)`` of ``depth_m[0, 0]`` in the full image.

    Returns
    -------
    CellGrid
    """
    samples = min(stride, BLOCK_SAMPLES)
    offsets = (2 * np.arange(samples) + 1) * stride // (2 * samples)
    grid = block_medians(depth_m, stride, offsets.astype(np.int64))
    h, w = grid.shape
    centre = (stride - 1) / 2
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    pixels = np.stack(
        [origin_uv[0] + centre + stride * u, origin_uv[1] + centre + stride * v], axis=-1
    )
    return CellGrid(grid.astype(np.float32), pixels.astype(np.float32), stride)


def median_3x3(depth_m: NDArray[np.float32], *, max_step: float) -> NDArray[np.float32]:
    """Lower median of each measured cell's 3 x 3 neighbourhood on the same surface.

    Parameters
    ----------
    depth_m : (h, w) float32
        Metres, 0 where missing.
    max_step : float
        Neighbours whose depth differs from the cell's by more than ``max_step`` times
        the cell's depth (another surface, across a depth step) do not count, nor do
        missing ones; missing cells stay 0.

    Returns
    -------
    (h, w) float32
        An existing value of each neighbourhood, metres.
    """
    return surface_medians(depth_m, np.float32(max_step))


@dataclass(frozen=True)
class SurfaceGraph:
    """The measured cells of a :class:`CellGrid` as a graph (:func:`surface_graph`).

    Attributes
    ----------
    edges : (N, N) scipy.sparse.csr_matrix of float64
        Both directions of every kept edge, weighted by its 3D length in metres.
    points_m : (N, 3) float32
        Camera-frame point of each node, metres.
    pixels_uv : (N, 2) float32
        Pixel of each node.
    cells : (N, 2) intp
        Grid row and column of each node.
    node_of_cell : (h, w) intp
        Node of each cell, -1 where the cell is missing.
    cut_pairs : (M, 2) intp
        Neighbouring nodes whose edge was cut at a depth step.
    area_m2 : (N,) float32
        Projected area of each node's cell at its depth, m².
    """

    edges: csr_matrix
    points_m: NDArray[np.float32]
    pixels_uv: NDArray[np.float32]
    cells: NDArray[np.intp]
    node_of_cell: NDArray[np.intp]
    cut_pairs: NDArray[np.intp]
    area_m2: NDArray[np.float32]


def surface_graph(
    grid: CellGrid, intrinsics: NDArray[np.float64], *, max_slope: float
) -> SurfaceGraph:
    """8-neighbour graph of the measured cells, cut at depth steps steeper than ``max_slope``.

    Parameters
    ----------
    grid : CellGrid
    intrinsics : (4,) float64
        ``(fx, fy, cx, cy)``, pixels.
    max_slope : float
        Largest depth step per lateral metre that keeps an edge.

    Returns
    -------
    SurfaceGraph
    """
    fx, fy, cx, cy = intrinsics
    measured = grid.depth_m > 0
    cells = np.argwhere(measured)
    node_of_cell = np.full(grid.depth_m.shape, -1, np.intp)
    node_of_cell[measured] = np.arange(len(cells))
    z = grid.depth_m[measured].astype(np.float64)
    uv = grid.pixels_uv[measured]
    points = np.stack([(uv[:, 0] - cx) * z / fx, (uv[:, 1] - cy) * z / fy, z], axis=1)
    lateral_per_m = grid.stride / math.sqrt(fx * fy)
    # An edge is cut where |za - zb| > limit * (za + zb) / 2 (compiled; offsets in turn).
    limits = np.array(
        [max_slope * math.hypot(dr, dc) * lateral_per_m for dr, dc in NEIGHBOUR_OFFSETS]
    )
    kept_pairs, cut_pairs = neighbour_pairs(
        node_of_cell, z, np.array(NEIGHBOUR_OFFSETS, dtype=np.int64), limits
    )
    # Steps at most as steep as a kept diagonal edge stay on the same surface.
    same_surface = max_slope * math.sqrt(2) * lateral_per_m
    smooth_z = median_3x3(grid.depth_m, max_step=same_surface)[measured].astype(np.float64)
    smooth = np.stack(
        [(uv[:, 0] - cx) * smooth_z / fx, (uv[:, 1] - cy) * smooth_z / fy, smooth_z], 1
    )
    lengths = np.linalg.norm(smooth[kept_pairs[:, 0]] - smooth[kept_pairs[:, 1]], axis=1)
    area = (grid.stride**2 / (fx * fy)) * z**2
    return SurfaceGraph(
        edges=symmetric_edges(kept_pairs, lengths, len(cells)),
        points_m=points.astype(np.float32),
        pixels_uv=uv,
        cells=cells,
        node_of_cell=node_of_cell,
        cut_pairs=cut_pairs,
        area_m2=area.astype(np.float32),
    )


def symmetric_edges(pairs: NDArray[np.intp], lengths: NDArray[np.float64], n: int) -> csr_matrix:
    """Both directions of distinct node pairs ``(E, 2)`` with lengths ``(E,)``, as
    ``(n, n)`` CSR in SciPy's canonical form, built compiled (SciPy's conversion from
    coordinates was about half of :func:`surface_graph`'s time, profiled)."""
    data, indices, indptr = symmetric_csr(
        np.ascontiguousarray(pairs, dtype=np.intp), np.ascontiguousarray(lengths, np.float64), n
    )
    return csr_matrix((data, indices, indptr), shape=(n, n))


def hand_component(
    graph: SurfaceGraph, *, min_area_m2: float, max_area_m2: float
) -> tuple[NDArray[np.intp], int]:
    """Connected components of the graph, and the hand's.

    The hand is the component of smallest median depth among those with a projected
    area in ``[min_area_m2, max_area_m2]``, or among those of at least ``min_area_m2``
    if none is.

    Returns
    -------
    labels : (N,) intp
        Component of each node.
    hand : int
        The hand's component; -1 when none is large enough.
    """
    n_components, labels = connected_components(graph.edges, directed=False)
    area = np.bincount(labels, weights=graph.area_m2, minlength=n_components)
    choice = np.flatnonzero((area >= min_area_m2) & (area <= max_area_m2))
    if choice.size == 0:
        choice = np.flatnonzero(area >= min_area_m2)
    if choice.size == 0:
        return labels.astype(np.intp), -1
    depth = graph.points_m[:, 2]
    medians = [np.median(depth[labels == label]) for label in choice]
    return labels.astype(np.intp), int(choice[int(np.argmin(medians))])


def palm_centre(graph: SurfaceGraph, inside: NDArray[np.bool_]) -> tuple[int, float]:
    """The node at the centre of the largest disc inscribed in the ``inside`` nodes.

    Nodes on a cut edge count as outside, so that the disc lies on one continuous
    surface (unless that leaves nothing).

    Parameters
    ----------
    graph : SurfaceGraph
    inside : (N,) bool
        The hand's nodes, at least one.

    Returns
    -------
    node : int
    radius_cells : float
        Radius of the disc in grid cells.
    """
    on_cut = np.zeros(len(inside), bool)
    on_cut[graph.cut_pairs.ravel()] = True
    core = inside & ~on_cut if (inside & ~on_cut).any() else inside
    mask = np.zeros(graph.node_of_cell.shape, np.uint8)
    rows, cols = graph.cells[core].T
    mask[rows, cols] = 1
    # Exact, and the same on every run: OpenCV's precise transform is off by a rounding
    # step in some cells, differently when other threads keep its thread pool busy.
    distance = distance_transform_edt(np.pad(mask, 1))[1:-1, 1:-1].astype(np.float32)
    row, col = np.unravel_index(int(np.argmax(distance)), distance.shape)
    return int(graph.node_of_cell[row, col]), float(distance[row, col])


def bridge_parts(
    graph: SurfaceGraph,
    labels: NDArray[np.intp],
    hand: int,
    *,
    max_part_area_m2: float,
    max_bridge_m: float,
) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """Edges that join small separated parts (a finger seen behind another) to the hand.

    Starting from the hand's component, every component of at most ``max_part_area_m2``
    whose outline comes within ``max_bridge_m`` (3D) of the joined outline is joined by
    its shortest link, round after round until none is left within reach. Outline
    nodes have fewer than 8 kept edges: they border a depth step or missing cells (a
    sensor often loses the pixels along a step, so parts need not be grid neighbours).

    Returns
    -------
    pairs : (B, 2) intp
        Node pairs to join.
    lengths_m : (B,) float64
        Their 3D distances, metres.
    """
    n_components = int(labels.max()) + 1
    area = np.bincount(labels, weights=graph.area_m2, minlength=n_components)
    outline = np.diff(graph.edges.indptr) < 2 * len(NEIGHBOUR_OFFSETS)
    joined = np.zeros(n_components, bool)
    joined[hand] = True
    joinable = (area <= max_part_area_m2) & ~joined
    pairs, lengths = [], []
    while joinable.any():
        ends = np.flatnonzero(outline & joined[labels])
        starts = np.flatnonzero(outline & joinable[labels])
        if starts.size == 0 or ends.size == 0:
            break
        gap, nearest = cKDTree(graph.points_m[ends]).query(
            graph.points_m[starts], distance_upper_bound=max_bridge_m
        )
        close = np.isfinite(gap)
        if not close.any():
            break
        starts, gap, nearest = starts[close], gap[close], ends[nearest[close]]
        part = labels[starts]
        order = np.lexsort((gap, part))
        shortest = order[np.r_[True, part[order][1:] != part[order][:-1]]]
        pairs.append(np.stack([starts[shortest], nearest[shortest]], axis=1))
        lengths.append(gap[shortest])
        joined[part[shortest]] = True
        joinable[part[shortest]] = False
    if not pairs:
        return np.zeros((0, 2), np.intp), np.zeros(0, np.float64)
    return np.concatenate(pairs).astype(np.intp), np.concatenate(lengths).astype(np.float64)


def shortest_paths(
    edges: csr_matrix, source: int, *, limit: float = math.inf
) -> NDArray[np.float64]:
    """Geodesic distances ``(N,)`` from ``source`` over ``edges``; inf beyond ``limit``."""
    distance = np.full(edges.shape[0], np.inf)
    lower_distances(edges.indptr, edges.indices, edges.data, distance, source, limit)
    return distance


def local_maxima(edges: csr_matrix, values: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Nodes with a finite value and no neighbour of a larger one, ``(N,)`` bool."""
    rows = np.repeat(np.arange(edges.shape[0]), np.diff(edges.indptr))
    higher = values[edges.indices] > values[rows]
    has_higher = np.bincount(rows[higher], minlength=edges.shape[0]) > 0
    return np.isfinite(values) & ~has_higher


def geodesic_extrema(
    edges: csr_matrix, source: int, *, max_extrema: int, min_separation_m: float
) -> tuple[NDArray[np.intp], NDArray[np.float64], NDArray[np.float64]]:
    """Accumulative geodesic extrema (AGEX) of a graph from one source.

    Repeatedly, the node farthest from all sources so far, among the local maxima of
    the distance from ``source``, is taken and made a source, until ``max_extrema`` are
    taken or it is closer than ``min_separation_m`` to a source.

    Parameters
    ----------
    edges : (N, N) csr_matrix
        Symmetric edge lengths, metres.
    source : int
        The first source (the palm centre).
    max_extrema : int
    min_separation_m : float

    Returns
    -------
    extrema : (K,) intp
        Nodes, in the order taken.
    separation_m : (K,) float64
        Distance of each to the nearest earlier source when taken, metres.
    from_source_m : (N,) float64
        Geodesic distance of every node from ``source``; inf where unreachable.
    """
    from_source = shortest_paths(edges, source)
    allowed = local_maxima(edges, from_source)
    nearest = from_source.copy()
    extrema, separation = [], []
    for _ in range(max_extrema):
        candidates = np.where(allowed, nearest, -1.0)
        far = int(np.argmax(candidates))
        if candidates[far] < min_separation_m:
            break
        extrema.append(far)
        separation.append(candidates[far])
        allowed[far] = False
        lower_distances(edges.indptr, edges.indices, edges.data, nearest, far, math.inf)
    return np.array(extrema, np.intp), np.array(separation, np.float64), from_source


def _distances_around(
    edges: csr_matrix, extrema: NDArray[np.intp], config: GeodesicConfig
) -> NDArray[np.float64]:
    """Geodesic distances ``(K, N)`` from each extremum, inf beyond the radii used."""
    if len(extrema) == 0:
        return np.zeros((0, edges.shape[0]))
    radius = max(config.peak_radius_m, config.width_radius_m + config.width_band_m / 2)
    return np.array([shortest_paths(edges, node, limit=radius) for node in extrema])


def _peaks(
    around: NDArray[np.float64],
    reach: NDArray[np.float64],
    extrema: NDArray[np.intp],
    config: GeodesicConfig,
) -> NDArray[np.bool_]:
    """Whether no node within ``peak_radius_m`` of each extremum reaches much farther."""
    near = around <= config.peak_radius_m
    highest = np.where(near, reach[None, :], -np.inf).max(axis=1, initial=-np.inf)
    return highest <= reach[extrema] + config.peak_tolerance_m


def _apart(points_m: NDArray[np.float32], radius_m: float) -> NDArray[np.bool_]:
    """Whether each point ``(K, 3)`` is at least ``radius_m`` from every earlier kept one."""
    return apart_in_order(points_m, np.arange(len(points_m)), radius_m)


def _on_border(pixels_uv: NDArray[np.float32], shape: tuple[int, ...], stride: int) -> NDArray:
    """Whether each cell centre ``(K, 2)`` lies within one cell of the image border."""
    height, width = shape
    u, v = pixels_uv[:, 0], pixels_uv[:, 1]
    return (u < stride) | (v < stride) | (u > width - 1 - stride) | (v > height - 1 - stride)


def _project(points_m: NDArray[np.float32], camera: NDArray[np.float64]) -> NDArray[np.float32]:
    fx, fy, cx, cy = camera
    x, y, z = points_m.astype(np.float64).T
    return np.stack([fx * x / z + cx, fy * y / z + cy], axis=1).astype(np.float32)
