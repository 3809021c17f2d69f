"""Compiled loop of :func:`tracker.icp.color_icp`, which documents and checks its
inputs: the same iterations as its NumPy form, without the per-iteration overhead of
some twenty small array operations on a few hundred points."""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

from tracker.generative._kernels import nearest_of_class

_COS_3_DEG = np.cos(np.radians(3.0))


@numba.njit(nogil=True, cache=True)
def color_icp(
    observed: NDArray[np.float64],
    classes: NDArray[np.uint8],
    model: NDArray[np.float64],
    normals: NDArray[np.float64],
    model_labels: NDArray[np.uint8],
    rotation: NDArray[np.float64],
    translation: NDArray[np.float64],
    iterations: int,
    max_distance: float,
    tolerance: float,
    plane_gate: float,
    cell: float,
    total: int,
) -> tuple[float, float, int, bool]:
    """Align in place: ``rotation (3, 3)`` and ``translation (3,)`` start as the initial
    pose and end as the result. ``observed (N, 3)`` are the camera-frame points whose
    ``classes`` the model has, ``total`` the number of observed points the inlier share
    counts against. Returns the RMS pair distance, the inlier share, the iterations
    (the limit unless converged) and whether the cost stopped changing."""
    n, m = observed.shape[0], model.shape[0]
    cost, inliers, previous, gate = np.inf, 0.0, np.inf, max_distance
    front = np.zeros(m, dtype=np.bool_)
    built = np.full(3, np.nan)
    in_hand = np.empty((n, 3))
    nearest = np.empty(n, dtype=np.int64)
    distance = np.empty(n)
    camera = np.empty(3)
    for iteration in range(1, iterations + 1):
        # The camera in the hand frame, -R^T t; the front side again only when the view
        # turned by more than 3 degrees.
        for j in range(3):
            camera[j] = -(
                rotation[0, j] * translation[0]
                + rotation[1, j] * translation[1]
                + rotation[2, j] * translation[2]
            )
        norm = np.sqrt(camera[0] ** 2 + camera[1] ** 2 + camera[2] ** 2)
        cosine = (camera[0] * built[0] + camera[1] * built[1] + camera[2] * built[2]) / norm
        if not cosine > _COS_3_DEG:
            for i in range(m):
                front[i] = (
                    normals[i, 0] * (model[i, 0] - camera[0])
                    + normals[i, 1] * (model[i, 1] - camera[1])
                    + normals[i, 2] * (model[i, 2] - camera[2])
                ) < 0.0
            for j in range(3):
                built[j] = camera[j] / norm
        if not front.any() or n == 0:
            break
        for k in range(n):  # R^T (p - t)
            for j in range(3):
                in_hand[k, j] = (
                    (observed[k, 0] - translation[0]) * rotation[0, j]
                    + (observed[k, 1] - translation[1]) * rotation[1, j]
                    + (observed[k, 2] - translation[2]) * rotation[2, j]
                )
        nearest_of_class(
            model, model_labels, front, in_hand, classes, np.inf, 1.0, cell, nearest, distance
        )
        paired = distance[np.isfinite(distance)]
        if paired.shape[0] == 0:
            break
        gate = min(gate, max(3.0 * np.median(paired), 0.005))
        keep = np.flatnonzero(distance < gate)
        count = keep.shape[0]
        if count < 6:
            break
        source = model[nearest[keep]]
        target = observed[keep]
        if gate > plane_gate:
            _kabsch(source, target, rotation, translation)
        else:
            _point_to_plane_step(source, normals[nearest[keep]], target, rotation, translation)
        total_squared = 0.0
        for k in range(count):
            for i in range(3):
                d = (
                    rotation[i, 0] * source[k, 0]
                    + rotation[i, 1] * source[k, 1]
                    + rotation[i, 2] * source[k, 2]
                    + translation[i]
                    - target[k, i]
                )
                total_squared += d * d
        cost = np.sqrt(total_squared / count)
        inliers = count / total
        if abs(previous - cost) < tolerance:
            return cost, inliers, iteration, True
        previous = cost
    return cost, inliers, iterations, False


@numba.njit(nogil=True, cache=True)
def _kabsch(
    source: NDArray[np.float64],
    target: NDArray[np.float64],
    rotation: NDArray[np.float64],
    translation: NDArray[np.float64],
) -> None:
    """The least-squares rigid map of ``source`` onto ``target`` (equal weights) into
    ``rotation`` and ``translation``: :func:`tracker.icp.batch_rigid_fit`."""
    source_mean = np.zeros(3)
    target_mean = np.zeros(3)
    count = source.shape[0]
    for k in range(count):
        for i in range(3):
            source_mean[i] += source[k, i] / count
            target_mean[i] += target[k, i] / count
    covariance = np.zeros((3, 3))
    for k in range(count):
        for i in range(3):
            for j in range(3):
                covariance[i, j] += (
                    (target[k, i] - target_mean[i]) * (source[k, j] - source_mean[j]) / count
                )
    u, _, vt = np.linalg.svd(covariance)
    if np.linalg.det(u @ vt) < 0.0:
        u[:, 2] = -u[:, 2]
    rotation[:] = u @ vt
    translation[:] = target_mean - rotation @ source_mean


@numba.njit(nogil=True, cache=True)
def _point_to_plane_step(
    source: NDArray[np.float64],
    source_normals: NDArray[np.float64],
    target: NDArray[np.float64],
    rotation: NDArray[np.float64],
    translation: NDArray[np.float64],
) -> None:
    """One linearised least-squares step on the targets' distances to the model's
    tangent planes, applied to ``rotation`` and ``translation`` in place:
    ``tracker.icp._point_to_plane_step``."""
    normal = 1e-12 * np.eye(6)
    right = np.zeros(6)
    row = np.empty(6)
    for k in range(source.shape[0]):
        p = rotation @ source[k] + translation
        nrm = rotation @ source_normals[k]
        row[0] = p[1] * nrm[2] - p[2] * nrm[1]
        row[1] = p[2] * nrm[0] - p[0] * nrm[2]
        row[2] = p[0] * nrm[1] - p[1] * nrm[0]
        row[3], row[4], row[5] = nrm[0], nrm[1], nrm[2]
        residual = (
            (p[0] - target[k, 0]) * nrm[0]
            + (p[1] - target[k, 1]) * nrm[1]
            + (p[2] - target[k, 2]) * nrm[2]
        )
        for i in range(6):
            right[i] -= row[i] * residual
            for j in range(6):
                normal[i, j] += row[i] * row[j]
    delta = np.linalg.solve(normal, right)
    angle = np.sqrt(delta[0] ** 2 + delta[1] ** 2 + delta[2] ** 2)
    turn = np.eye(3)
    if angle > 0.0:
        x, y, z = delta[0] / angle, delta[1] / angle, delta[2] / angle
        c, s = np.cos(angle), np.sin(angle)
        t = 1.0 - c
        turn[0, 0], turn[0, 1], turn[0, 2] = c + x * x * t, x * y * t - z * s, x * z * t + y * s
        turn[1, 0], turn[1, 1], turn[1, 2] = y * x * t + z * s, c + y * y * t, y * z * t - x * s
        turn[2, 0], turn[2, 1], turn[2, 2] = z * x * t - y * s, z * y * t + x * s, c + z * z * t
    rotation[:] = turn @ rotation
    translation[:] = turn @ translation + delta[3:]
