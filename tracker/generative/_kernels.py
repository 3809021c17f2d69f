"""Compiled loops of :mod:`tracker.generative.model`, :mod:`.observation`,
:mod:`.visibility` and the data, silhouette and collision terms
(:mod:`tracker.generative.energy`), which document and check them. They assume
checked, C-contiguous inputs of the documented dtypes and release the GIL."""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray


@numba.njit(nogil=True, cache=True)
def pose_samples(
    bones: NDArray[np.int64],
    bone_weights: NDArray[np.float64],
    rest: NDArray[np.float64],
    rest_normals: NDArray[np.float64],
    skinning: NDArray[np.float64],
    rotation: NDArray[np.float64],
    translation: NDArray[np.float64],
    points: NDArray[np.float64],
    normals: NDArray[np.float64],
    facing: NDArray[np.bool_],
) -> None:
    """Skin ``(S, 3)`` samples and their normals, map them into the camera frame and
    mark those facing it, into ``points``, ``normals`` (unit) and ``facing``; each
    sample blends the skinning matrices of its ``bones (S, B)`` (-1 padded) by
    ``bone_weights (S, B)``: see :class:`tracker.generative.model.PosedHand`."""
    blend = np.empty((3, 4))  # the sample's blended skinning matrix
    for s in range(rest.shape[0]):
        blend[:] = 0.0
        for k in range(bones.shape[1]):
            bone = bones[s, k]
            if bone < 0:
                break
            w = bone_weights[s, k]
            for i in range(3):
                for j in range(4):
                    blend[i, j] += w * skinning[bone, i, j]
        for i in range(3):
            hand = blend[i, 0] * rest[s, 0] + blend[i, 1] * rest[s, 1] + blend[i, 2] * rest[s, 2]
            normal = (
                blend[i, 0] * rest_normals[s, 0]
                + blend[i, 1] * rest_normals[s, 1]
                + blend[i, 2] * rest_normals[s, 2]
            )
            points[s, i], normals[s, i] = hand + blend[i, 3], normal
        length = max(np.sqrt(normals[s, 0] ** 2 + normals[s, 1] ** 2 + normals[s, 2] ** 2), 1e-12)
        px, py, pz = points[s, 0], points[s, 1], points[s, 2]
        nx, ny, nz = normals[s, 0] / length, normals[s, 1] / length, normals[s, 2] / length
        along = 0.0
        for i in range(3):
            r0, r1, r2 = rotation[i, 0], rotation[i, 1], rotation[i, 2]
            points[s, i] = r0 * px + r1 * py + r2 * pz + translation[i]
            normals[s, i] = r0 * nx + r1 * ny + r2 * nz
            along += normals[s, i] * points[s, i]
        facing[s] = along < 0.0


@numba.njit(nogil=True, cache=True, inline="always")
def _directional_row(
    sample: int,
    point: NDArray[np.float64],
    direction: NDArray[np.float64],
    bones: NDArray[np.int64],
    bone_weights: NDArray[np.float64],
    rest: NDArray[np.float64],
    skinning: NDArray[np.float64],
    movers: NDArray[np.int64],
    axes: NDArray[np.float64],
    pivots: NDArray[np.float64],
    rotation: NDArray[np.float64],
    translation: NDArray[np.float64],
    arm: NDArray[np.float64],
    out: NDArray[np.float64],
) -> None:
    """The ``(26,)`` row ``direction . dp/dx`` of one sample at camera-frame ``point``
    into ``out``; ``bones, bone_weights (S, B)`` are the samples' skinning bones (-1
    padded) and weights, ``movers (16, K)`` lists the joint angles that move each bone
    (-1 padded), ``arm`` is ``(20, 3)`` scratch."""
    nx, ny, nz = direction[0], direction[1], direction[2]
    dx = point[0] - translation[0]
    dy = point[1] - translation[1]
    dz = point[2] - translation[2]
    out[0] = dy * nz - dz * ny
    out[1] = dz * nx - dx * nz
    out[2] = dx * ny - dy * nx
    out[3], out[4], out[5] = nx, ny, nz
    # The direction in the hand frame: R^T n.
    hx = rotation[0, 0] * nx + rotation[1, 0] * ny + rotation[2, 0] * nz
    hy = rotation[0, 1] * nx + rotation[1, 1] * ny + rotation[2, 1] * nz
    hz = rotation[0, 2] * nx + rotation[1, 2] * ny + rotation[2, 2] * nz
    arm[:] = 0.0
    moved = 0  # bit j: angle j moves one of the sample's bones
    for b in range(bones.shape[1]):
        bone = bones[sample, b]
        if bone < 0:
            break
        w = bone_weights[sample, b]
        m = skinning[bone]
        x, y, z = rest[sample, 0], rest[sample, 1], rest[sample, 2]
        vx = m[0, 0] * x + m[0, 1] * y + m[0, 2] * z + m[0, 3]
        vy = m[1, 0] * x + m[1, 1] * y + m[1, 2] * z + m[1, 3]
        vz = m[2, 0] * x + m[2, 1] * y + m[2, 2] * z + m[2, 3]
        for k in range(movers.shape[1]):
            joint = movers[bone, k]
            if joint < 0:
                break
            moved |= 1 << joint
            arm[joint, 0] += w * (vx - pivots[joint, 0])
            arm[joint, 1] += w * (vy - pivots[joint, 1])
            arm[joint, 2] += w * (vz - pivots[joint, 2])
    for joint in range(axes.shape[0]):
        if not (moved >> joint) & 1:
            out[6 + joint] = 0.0
            continue
        ax, ay, az = axes[joint, 0], axes[joint, 1], axes[joint, 2]
        rx, ry, rz = arm[joint, 0], arm[joint, 1], arm[joint, 2]
        # n_hand . (a x arm)
        out[6 + joint] = (
            hx * (ay * rz - az * ry) + hy * (az * rx - ax * rz) + hz * (ax * ry - ay * rx)
        )


@numba.njit(nogil=True, cache=True)
def directional_vertex_rows(
    ids: NDArray[np.int64],
    bones: NDArray[np.int64],
    bone_weights: NDArray[np.float64],
    rest: NDArray[np.float64],
    skinning: NDArray[np.float64],
    movers: NDArray[np.int64],
    axes: NDArray[np.float64],
    pivots: NDArray[np.float64],
    rotation: NDArray[np.float64],
    translation: NDArray[np.float64],
    points: NDArray[np.float64],
    directions: NDArray[np.float64],
    out: NDArray[np.float64],
) -> None:
    """Rows ``direction . dp/dx`` ``(P, 26)`` into ``out`` for samples ``ids`` at
    camera-frame ``points (P, 3)``: see
    :meth:`tracker.generative.model.PosedHand.directional_rows`."""
    arm = np.zeros((axes.shape[0], 3))
    for row in range(ids.shape[0]):
        _directional_row(
            ids[row], points[row], directions[row], bones, bone_weights, rest, skinning,
            movers, axes, pivots, rotation, translation, arm, out[row],
        )  # fmt: skip


@numba.njit(nogil=True, cache=True)
def _plane_distance(
    point: NDArray[np.float64], target: NDArray[np.float64], normal: NDArray[np.float64]
) -> float:
    """``(point - target) . normal`` for ``(3,)`` vectors, summed in a fixed order."""
    return (
        (point[0] - target[0]) * normal[0]
        + (point[1] - target[1]) * normal[1]
        + (point[2] - target[2]) * normal[2]
    )


@numba.njit(nogil=True, cache=True)
def plane_distances(
    ids: NDArray[np.int64],
    targets: NDArray[np.float64],
    points: NDArray[np.float64],
    normals: NDArray[np.float64],
    distance: NDArray[np.float64],
) -> None:
    """Distances ``(p_s - target) . n_s`` ``(P,)`` into ``distance`` for samples
    ``ids`` of all samples' camera-frame ``points`` and ``normals (S, 3)``: the
    first output of :func:`plane_rows`, to the bit."""
    for row in range(ids.shape[0]):
        s = ids[row]
        distance[row] = _plane_distance(points[s], targets[row], normals[s])


@numba.njit(nogil=True, cache=True)
def plane_rows(
    ids: NDArray[np.int64],
    targets: NDArray[np.float64],
    bones: NDArray[np.int64],
    bone_weights: NDArray[np.float64],
    rest: NDArray[np.float64],
    skinning: NDArray[np.float64],
    movers: NDArray[np.int64],
    axes: NDArray[np.float64],
    pivots: NDArray[np.float64],
    rotation: NDArray[np.float64],
    translation: NDArray[np.float64],
    points: NDArray[np.float64],
    normals: NDArray[np.float64],
    distance: NDArray[np.float64],
    out: NDArray[np.float64],
) -> None:
    """Distances ``(p_s - target) . n_s`` ``(P,)`` into ``distance`` and rows
    ``n_s . dp_s/dx`` ``(P, 26)`` into ``out``, for samples ``ids`` of all samples'
    camera-frame ``points`` and ``normals (S, 3)``: see
    :meth:`tracker.generative.model.PosedHand.plane_rows`. A sample's row is computed
    once and copied for its other pairs."""
    arm = np.zeros((axes.shape[0], 3))
    first = np.full(points.shape[0], -1, dtype=np.int64)
    for row in range(ids.shape[0]):
        s = ids[row]
        distance[row] = _plane_distance(points[s], targets[row], normals[s])
        if first[s] >= 0:
            out[row] = out[first[s]]
            continue
        first[s] = row
        _directional_row(
            s, points[s], normals[s], bones, bone_weights, rest, skinning, movers, axes,
            pivots, rotation, translation, arm, out[row],
        )  # fmt: skip


@numba.njit(nogil=True, cache=True)
def nearest_of_class(
    model: NDArray[np.float64],
    model_labels: NDArray[np.uint8],
    candidates: NDArray[np.bool_],
    observed: NDArray[np.float64],
    observed_labels: NDArray[np.uint8],
    radius: float,
    depth_scale: float,
    cell: float,
    nearest: NDArray[np.int64],
    distance: NDArray[np.float64],
) -> None:
    """For every observed point the nearest candidate model point of its class closer
    than ``radius`` (z counting ``depth_scale`` times) into ``nearest`` (-1: none) and
    ``distance`` (inf: none): see :func:`tracker.generative.energy.data.nearest_of_class`.

    The candidates are binned by class and by a square grid over x and y of side
    ``cell`` (at most 64 cells along each); a query visits the cells of its class in
    rings around its own until a ring's nearest possible point is no nearer than the
    best pair so far (exact: the distance is at least that along x or y).
    """
    nearest[:] = -1
    distance[:] = np.inf
    members = np.flatnonzero(candidates)
    n_model = members.shape[0]
    if n_model == 0:
        return
    dense = np.full(256, -1, dtype=np.int64)  # classes present, numbered densely
    n_classes = 0
    for i in members:
        if dense[model_labels[i]] < 0:
            dense[model_labels[i]] = n_classes
            n_classes += 1
    x0, y0 = model[members, 0].min(), model[members, 1].min()
    width, height = model[members, 0].max() - x0, model[members, 1].max() - y0
    side = max(cell, width / 64.0, height / 64.0)
    nx, ny = int(width / side) + 1, int(height / side) + 1
    # A counting sort of the candidates by (class, row, column), copied in that order
    # with z scaled.
    n_bins = n_classes * ny * nx
    key = np.empty(n_model, dtype=np.int64)
    starts = np.zeros(n_bins + 1, dtype=np.int64)
    for k in range(n_model):
        i = members[k]
        column = min(int((model[i, 0] - x0) / side), nx - 1)
        row = min(int((model[i, 1] - y0) / side), ny - 1)
        key[k] = (dense[model_labels[i]] * ny + row) * nx + column
        starts[key[k] + 1] += 1
    for b in range(n_bins):
        starts[b + 1] += starts[b]
    fill = starts[:n_bins].copy()
    order = np.empty(n_model, dtype=np.int64)
    points = np.empty((n_model, 3))
    for k in range(n_model):
        i, j = members[k], fill[key[k]]
        order[j] = i
        points[j, 0], points[j, 1], points[j, 2] = (
            model[i, 0],
            model[i, 1],
            model[i, 2] * depth_scale,
        )
        fill[key[k]] += 1
    bound = radius * radius
    for q in range(observed.shape[0]):
        c = dense[observed_labels[q]]
        if c < 0:
            continue
        x, y, z = observed[q, 0], observed[q, 1], observed[q, 2] * depth_scale
        u, v = (x - x0) / side, (y - y0) / side
        column = min(max(int(np.floor(u)), 0), nx - 1)
        row = min(max(int(np.floor(v)), 0), ny - 1)
        # How far inside its cell the query lies (0 when outside the grid), in cells.
        inset = max(min(u - column, column + 1 - u, v - row, row + 1 - v), 0.0)
        best, found = bound, -1
        ring = 0
        while ring <= max(nx, ny):
            reach = (ring - 1 + inset) * side if ring > 0 else 0.0
            if reach * reach >= best:
                break
            for r in range(max(row - ring, 0), min(row + ring, ny - 1) + 1):
                # Whole rows at the ring's top and bottom, its two ends in between.
                step = 1 if abs(r - row) == ring else max(2 * ring, 1)
                for col in range(column - ring, column + ring + 1, step):
                    if col < 0 or col >= nx:
                        continue
                    b = (c * ny + r) * nx + col
                    for j in range(starts[b], starts[b + 1]):
                        d = (points[j, 0] - x) ** 2 + (points[j, 1] - y) ** 2
                        d += (points[j, 2] - z) ** 2
                        if d < best:
                            best, found = d, j
            ring += 1
        if found >= 0:
            nearest[q] = order[found]
            distance[q] = np.sqrt(best)


@numba.njit(nogil=True, cache=True, inline="always")
def _segment_parameters(
    a0: NDArray[np.float64],
    a1: NDArray[np.float64],
    b0: NDArray[np.float64],
    b1: NDArray[np.float64],
) -> tuple[float, float]:
    """Parameters ``s, t`` in [0, 1] of the closest points of segments ``a0-a1`` and
    ``b0-b1`` (``(3,)`` each)."""
    aa = bb = ab = ar = br = 0.0
    for i in range(3):
        da, db, r = a1[i] - a0[i], b1[i] - b0[i], a0[i] - b0[i]
        aa += da * da
        bb += db * db
        ab += da * db
        ar += da * r
        br += db * r
    denominator = aa * bb - ab * ab
    s = 0.0
    if not denominator < 1e-12 * max(aa * bb, 1e-30):  # not parallel
        s = min(max((ab * br - bb * ar) / denominator, 0.0), 1.0)
    t = (ab * s + br) / max(bb, 1e-30)
    t_clipped = min(max(t, 0.0), 1.0)
    if t != t_clipped:
        s = min(max((ab * t_clipped - ar) / max(aa, 1e-30), 0.0), 1.0)
    return s, t_clipped


@numba.njit(nogil=True, cache=True)
def segment_parameters(
    a0: NDArray[np.float64],
    a1: NDArray[np.float64],
    b0: NDArray[np.float64],
    b1: NDArray[np.float64],
    s: NDArray[np.float64],
    t: NDArray[np.float64],
) -> None:
    """``s, t (P,)`` of the closest points of ``P`` segment pairs ``(P, 3)`` each: see
    :func:`tracker.generative.energy.collision.segment_closest_points`."""
    for p in range(a0.shape[0]):
        s[p], t[p] = _segment_parameters(a0[p], a1[p], b0[p], b1[p])


@numba.njit(nogil=True, cache=True)
def capsule_overlaps(
    transforms: NDArray[np.float64],
    bone: NDArray[np.int64],
    start_m: NDArray[np.float64],
    end_m: NDArray[np.float64],
    radius_start: NDArray[np.float64],
    radius_end: NDArray[np.float64],
    first: NDArray[np.int64],
    second: NDArray[np.int64],
    overlap: NDArray[np.float64],
    first_point: NDArray[np.float64],
    second_point: NDArray[np.float64],
) -> None:
    """Overlap ``(Q,)`` of capsule pairs ``first, second`` (sum of radii minus
    distance at the closest points of their axes) and those points ``(Q, 3)``, for
    capsules on bones ``bone (C,)`` with axis end points ``start_m, end_m (C, 3)`` in
    their bone's frame, posed by ``transforms (16, 4, 4)`` (the points are in the frame
    these map into): see :mod:`tracker.generative.energy.collision`."""
    count = bone.shape[0]
    start, end = np.empty((count, 3)), np.empty((count, 3))
    for c in range(count):
        m = transforms[bone[c]]
        sx, sy, sz = start_m[c, 0], start_m[c, 1], start_m[c, 2]
        ex, ey, ez = end_m[c, 0], end_m[c, 1], end_m[c, 2]
        for i in range(3):
            start[c, i] = m[i, 0] * sx + m[i, 1] * sy + m[i, 2] * sz + m[i, 3]
            end[c, i] = m[i, 0] * ex + m[i, 1] * ey + m[i, 2] * ez + m[i, 3]
    for q in range(first.shape[0]):
        a, b = first[q], second[q]
        s, t = _segment_parameters(start[a], end[a], start[b], end[b])
        gap = 0.0
        for i in range(3):
            first_point[q, i] = start[a, i] + s * (end[a, i] - start[a, i])
            second_point[q, i] = start[b, i] + t * (end[b, i] - start[b, i])
            gap += (first_point[q, i] - second_point[q, i]) ** 2
        radius_a = radius_start[a] + s * (radius_end[a] - radius_start[a])
        radius_b = radius_start[b] + t * (radius_end[b] - radius_start[b])
        overlap[q] = radius_a + radius_b - np.sqrt(gap)


@numba.njit(nogil=True, cache=True)
def point_jacobians(
    points: NDArray[np.float64],
    moved: NDArray[np.float64],
    share: NDArray[np.float64],
    axes: NDArray[np.float64],
    pivots: NDArray[np.float64],
    rotation: NDArray[np.float64],
    translation: NDArray[np.float64],
    out: NDArray[np.float64],
) -> None:
    """Derivatives ``(P, 3, 26)`` of camera-frame ``points (P, 3)`` into ``out`` (zeroed
    by the caller), from per joint the summed bone-moved positions ``moved (P, 20, 3)``
    and weight shares ``share (P, 20)`` (hand frame): see
    :class:`tracker.generative.model.PosedHand`."""
    for p in range(points.shape[0]):
        dx = points[p, 0] - translation[0]
        dy = points[p, 1] - translation[1]
        dz = points[p, 2] - translation[2]
        out[p, 0, 1], out[p, 0, 2] = dz, -dy
        out[p, 1, 0], out[p, 1, 2] = -dz, dx
        out[p, 2, 0], out[p, 2, 1] = dy, -dx
        out[p, 0, 3] = out[p, 1, 4] = out[p, 2, 5] = 1.0
        for joint in range(axes.shape[0]):
            w = share[p, joint]
            rx = moved[p, joint, 0] - w * pivots[joint, 0]
            ry = moved[p, joint, 1] - w * pivots[joint, 1]
            rz = moved[p, joint, 2] - w * pivots[joint, 2]
            ax, ay, az = axes[joint, 0], axes[joint, 1], axes[joint, 2]
            cx, cy, cz = ay * rz - az * ry, az * rx - ax * rz, ax * ry - ay * rx
            for i in range(3):
                out[p, i, 6 + joint] = (
                    rotation[i, 0] * cx + rotation[i, 1] * cy + rotation[i, 2] * cz
                )


@numba.njit(nogil=True, cache=True, inline="always")
def _crop_pixel(
    point: NDArray[np.float64],
    pinhole: NDArray[np.float64],
    origin: NDArray[np.int64],
    height: int,
    width: int,
) -> tuple[int, int, bool]:
    """Crop pixel (row, column, clipped to the crop) of a camera-frame point, and
    whether it projects into the crop at all."""
    z = max(point[2], 1e-3)
    col = np.int64(np.rint(pinhole[0] * point[0] / z + pinhole[2])) - origin[0]
    row = np.int64(np.rint(pinhole[1] * point[1] / z + pinhole[3])) - origin[1]
    inside = 0 <= col < width and 0 <= row < height
    return min(max(row, 0), height - 1), min(max(col, 0), width - 1), inside


@numba.njit(nogil=True, cache=True)
def crop_pixels(
    points: NDArray[np.float64],
    pinhole: NDArray[np.float64],
    origin: NDArray[np.int64],
    height: int,
    width: int,
    row: NDArray[np.int64],
    col: NDArray[np.int64],
    inside: NDArray[np.bool_],
) -> None:
    """Crop pixels of ``(P, 3)`` camera-frame points: see
    :func:`tracker.generative.observation.look_up`."""
    for p in range(points.shape[0]):
        row[p], col[p], inside[p] = _crop_pixel(points[p], pinhole, origin, height, width)


PULL = 1
"""Kind of a silhouette residual: the sample lies off the observed hand."""
PUSH = 2
"""Kind of a silhouette residual: the sample lies in front of the observed depth."""


@numba.njit(nogil=True, cache=True)
def silhouette_rows(
    points: NDArray[np.float64],
    pinhole: NDArray[np.float64],
    origin: NDArray[np.int64],
    outside_px: NDArray[np.float32],
    gradient: NDArray[np.float32],
    depth: NDArray[np.float32],
    margin_px: float,
    depth_margin: float,
    kind: NDArray[np.int8],
    value: NDArray[np.float64],
    direction: NDArray[np.float64],
) -> int:
    """Classify ``(P, 3)`` camera-frame samples against the observation's crop into
    ``kind`` (0, :data:`PULL` or :data:`PUSH`), with the residual ``value`` (metres)
    and its ``direction`` (its derivative by the sample's position) of those that
    have one; returns how many lie off the hand, not hidden. See
    :mod:`tracker.generative.energy.silhouette`."""
    height, width = outside_px.shape
    fx, fy = pinhole[0], pinhole[1]
    margin = np.float32(margin_px)
    depth_margin32 = np.float32(depth_margin)
    outside = 0
    for p in range(points.shape[0]):
        row, col, inside = _crop_pixel(points[p], pinhole, origin, height, width)
        x, y, z = points[p, 0], points[p, 1], max(points[p, 2], 1e-3)
        seen = depth[row, col]
        distance = outside_px[row, col] if inside else np.float32(np.inf)
        hidden = seen > 0 and seen < z - depth_margin
        off_mask = distance > margin and not hidden
        # Beyond the crop the distance is unknown: such a sample counts as outside the
        # hand but is not pulled.
        outside += off_mask or not (inside or hidden)
        kind[p] = 0
        if off_mask and inside:
            kind[p] = PULL
            metres_per_px = z / fx
            value[p] = np.float32(distance - margin) * metres_per_px
            gu, gv = np.float64(gradient[row, col, 0]), np.float64(gradient[row, col, 1])
            direction[p, 0] = gu * fx / z * metres_per_px
            direction[p, 1] = gv * fy / z * metres_per_px
            direction[p, 2] = -(gu * fx * x + gv * fy * y) / z**2 * metres_per_px
        elif inside and distance <= 0 and seen > 0 and z < seen - depth_margin32:
            # Only on the mask: within the margin but off it, ``seen`` is the
            # background's depth (a wall), which would push the edge far back.
            kind[p] = PUSH
            value[p] = z - (seen - depth_margin32)
            direction[p, 0], direction[p, 1], direction[p, 2] = 0.0, 0.0, 1.0
    return outside


@numba.njit(nogil=True, cache=True)
def proportion_differences(
    bones: NDArray[np.int64],
    bone_weights: NDArray[np.float64],
    rest_m: NDArray[np.float64],
    rest_maps: NDArray[np.float64],
    pose_maps: NDArray[np.float64],
    rotation: NDArray[np.float64],
    steps: NDArray[np.float64],
    out: NDArray[np.float64],
) -> None:
    """Finite differences of skinned samples by the proportions.

    ``bones, bone_weights (P, B)`` the samples' skinning bones (-1 padded) and
    weights, ``rest_m (P, 3)`` the model's rest samples,
    ``rest_maps, pose_maps (K, B, 3, 4)`` per proportion vector (the base first, then
    each stepped one) the bones' re-resting and posing maps, ``rotation (3, 3)`` the
    hand's, ``steps (K - 1,)`` each stepped vector's step; ``out (P, 3, K - 1)`` gets
    ``rotation @ (hand_k - hand_0) / steps[k - 1]`` where ``hand_k`` is the sample
    re-rested and posed with the blended maps of vector ``k``.
    """
    vectors = rest_maps.shape[0]
    hand = np.empty((vectors, 3))
    rested = np.empty(3)
    blend_rest = np.empty((3, 4))
    blend_pose = np.empty((3, 4))
    for sample in range(bones.shape[0]):
        count = 0
        while count < bones.shape[1] and bones[sample, count] >= 0:
            count += 1
        for vector in range(vectors):
            for i in range(3):
                for j in range(4):
                    blend_rest[i, j] = 0.0
                    blend_pose[i, j] = 0.0
            for index in range(count):
                bone = bones[sample, index]
                weight = bone_weights[sample, index]
                for i in range(3):
                    for j in range(4):
                        blend_rest[i, j] += weight * rest_maps[vector, bone, i, j]
                        blend_pose[i, j] += weight * pose_maps[vector, bone, i, j]
            for i in range(3):
                rested[i] = blend_rest[i, 3]
                for j in range(3):
                    rested[i] += blend_rest[i, j] * rest_m[sample, j]
            for i in range(3):
                hand[vector, i] = blend_pose[i, 3]
                for j in range(3):
                    hand[vector, i] += blend_pose[i, j] * rested[j]
        for vector in range(1, vectors):
            for i in range(3):
                total = 0.0
                for j in range(3):
                    total += rotation[i, j] * (hand[vector, j] - hand[0, j])
                out[sample, i, vector - 1] = total / steps[vector - 1]


@numba.njit(nogil=True, cache=True)
def keypoint_flags(
    points: NDArray[np.float64],
    facing: NDArray[np.bool_],
    keypoints: NDArray[np.float64],
    depth: NDArray[np.float32],
    pinhole: NDArray[np.float64],
    radius: float,
    margin: float,
    cell: int,
    flags: NDArray[np.int8],
) -> None:
    """The visibility of each of ``keypoints (K, 3)`` as an index into
    :data:`tracker.generative.visibility.VISIBILITY` into ``flags (K,)``, from the
    camera-facing ``points (S, 3)`` splatted into cells of ``cell`` pixels and the
    observed ``depth (H, W)``; ``pinhole`` is fx, fy, cx, cy: see
    :func:`tracker.generative.visibility.keypoint_visibility`."""
    fx, fy, cx, cy = pinhole[0], pinhole[1], pinhole[2], pinhole[3]
    height, width = depth.shape
    buffer = np.full((-(-height // cell), -(-width // cell)), np.inf)
    for s in range(points.shape[0]):
        z = points[s, 2]
        if not (facing[s] and z > 1e-3):
            continue
        u = np.rint(fx * points[s, 0] / z + cx)
        v = np.rint(fy * points[s, 1] / z + cy)
        if 0 <= u < width and 0 <= v < height:
            row, column = int(v) // cell, int(u) // cell
            buffer[row, column] = min(buffer[row, column], z)
    window = np.empty(9, depth.dtype)
    for k in range(keypoints.shape[0]):
        x, y, z = keypoints[k, 0], keypoints[k, 1], keypoints[k, 2]
        if not z > 0:
            flags[k] = 3  # out of view
            continue
        u = np.rint(fx * x / z + cx)
        v = np.rint(fy * y / z + cy)
        if not (0 <= u < width and 0 <= v < height):
            flags[k] = 3
            continue
        ku, kv = int(u), int(v)
        surface = buffer[kv // cell, ku // cell]
        if surface < z - radius - margin:
            flags[k] = 1  # self-occluded
            continue
        count = 0
        for row in range(max(kv - 1, 0), min(kv + 2, height)):
            for column in range(max(ku - 1, 0), min(ku + 2, width)):
                if depth[row, column] > 0:
                    window[count] = depth[row, column]
                    count += 1
        if count == 0:
            flags[k] = 2  # occluded: nothing measured there
            continue
        seen = np.sort(window[:count])
        half = count // 2
        # NumPy's median: the middle value, or the mean of the two middle ones in the
        # depth's own type.
        median = (
            seen[half] if count % 2 == 1 else (seen[half - 1] + seen[half]) / seen.dtype.type(2)
        )
        front = min(surface, z - radius)
        flags[k] = 2 if median < front - margin else 0
