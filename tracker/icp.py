"""Color-sensitive rigid ICP of the glove model to the labeled point cloud (thesis 4.2.3).

With the posture fixed, every iteration

1. finds the model points that face the camera in the current pose,
2. pairs every observed point with the nearest front-facing model point of the same
   color class (one k-d tree per class, built once in the hand frame, where the model
   does not move; the observed points are mapped into it, and of the four nearest
   model points the nearest front-facing one is taken),
3. drops pairs farther apart than a distance that shrinks from ``max_distance_m``
   toward three times the median pair distance (outliers: sensor noise, the other
   hand, misclassified background),
4. solves the rigid pose that best maps the paired model points onto the observed
   ones in closed form (Horn / Kabsch, via SVD) while the pairs are still rough, and
   with linearised point-to-plane steps once the outlier gate is tight,

until the RMS distance stops improving by more than ``tolerance_m``. The model is
sampled by the vertices of the skinned mesh (about 2-3 mm apart): "closest point on
a front-facing triangle of the same color" is the closest vertex, and the point-to-
plane steps measure the distance to its tangent plane, so the vertex spacing does
not limit the accuracy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from glovedb._validate import as_array

# Once the outlier gate is this tight the pairs are right and point-to-plane steps
# (which converge in a few iterations and are not limited by the vertex spacing) take
# over from point-to-point ones.
_PLANE_GATE_M = 0.012


@dataclass(frozen=True)
class IcpResult:
    """Outcome of :func:`color_icp`.

    Attributes
    ----------
    rotation : (3, 3) float64
        ``cam_R_hand``.
    translation_m : (3,) float64
        Wrist in the camera frame.
    cost_m : float
        RMS distance of the kept pairs in the last iteration (inf if none).
    inlier_fraction : float
        Share of observed points kept in the last iteration.
    iterations : int
    converged : bool
        The cost stopped changing before the iteration limit.
    """

    rotation: NDArray[np.float64]
    translation_m: NDArray[np.float64]
    cost_m: float
    inlier_fraction: float
    iterations: int
    converged: bool


def rigid_fit(
    source: NDArray[np.float64], target: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Least-squares rotation and translation with ``target ~ R @ source + t``.

    Parameters
    ----------
    source, target : (N, 3) float
        Paired points, N >= 3 not all on a line.

    Returns
    -------
    rotation : (3, 3) float64
    translation : (3,) float64
    """
    source = as_array("source", source, (None, 3), np.float64)
    target = as_array("target", target, (len(source), 3), np.float64)
    source_mean, target_mean = source.mean(axis=0), target.mean(axis=0)
    covariance = (target - target_mean).T @ (source - source_mean)
    u, _, vt = np.linalg.svd(covariance)
    reflection = np.sign(np.linalg.det(u @ vt))
    rotation = u @ np.diag([1.0, 1.0, reflection]) @ vt
    return rotation, target_mean - rotation @ source_mean


def _point_to_plane_step(
    source: NDArray[np.float64],
    source_normals: NDArray[np.float64],
    target: NDArray[np.float64],
    rotation: NDArray[np.float64],
    translation: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """One linearised least-squares step on the distances of the targets to the
    model's tangent planes; returns the updated pose."""
    from glovedb.rotations import axis_angle_to_matrix

    points = source @ rotation.T + translation
    normals = source_normals @ rotation.T
    jacobian = np.concatenate([np.cross(points, normals), normals], axis=1)
    residual = np.einsum("ij,ij->i", points - target, normals)
    delta, *_ = np.linalg.lstsq(jacobian, -residual, rcond=None)
    angle = float(np.linalg.norm(delta[:3]))
    turn = axis_angle_to_matrix(delta[:3], angle) if angle > 0 else np.eye(3)
    return turn @ rotation, turn @ translation + delta[3:]


def color_icp(
    observed_m: ArrayLike,
    observed_labels: ArrayLike,
    model_m: ArrayLike,
    model_normals: ArrayLike,
    model_labels: ArrayLike,
    rotation: ArrayLike,
    translation_m: ArrayLike,
    *,
    iterations: int = 30,
    max_distance_m: float = 0.04,
    tolerance_m: float = 5e-5,
) -> IcpResult:
    """Align the model (hand frame) to the observed points (camera frame).

    Parameters
    ----------
    observed_m : (N, 3) float
        Labeled point cloud, camera frame.
    observed_labels : (N,) uint8
        Classes 1..10.
    model_m : (M, 3) float
        Model surface points in the hand frame (the posed mesh's vertices).
    model_normals : (M, 3) float
        Their outward unit normals, hand frame.
    model_labels : (M,) uint8
    rotation, translation_m : (3, 3), (3,) float
        Initial pose ``p_cam = R @ p_hand + t``.
    iterations : int
        At most this many.
    max_distance_m : float
        Pairs farther apart are never used.
    tolerance_m : float
        Stop when the RMS distance changes by less.

    Returns
    -------
    IcpResult
    """
    observed = as_array("observed_m", observed_m, (None, 3), np.float64, finite=True)
    observed_classes = as_array("observed_labels", observed_labels, (len(observed),), kind="iu")
    model = as_array("model_m", model_m, (None, 3), np.float64, finite=True)
    normals = as_array("model_normals", model_normals, (len(model), 3), np.float64)
    model_classes = as_array("model_labels", model_labels, (len(model),), kind="iu")
    R = as_array("rotation", rotation, (3, 3), np.float64, finite=True).copy()
    t = as_array("translation_m", translation_m, (3,), np.float64, finite=True).copy()
    classes = np.intersect1d(np.unique(observed_classes), np.unique(model_classes))
    by_class = [(np.flatnonzero(observed_classes == c), model_classes == c) for c in classes]

    cost, inliers, previous = np.inf, 0.0, np.inf
    gate = max_distance_m
    trees: list[tuple[NDArray[np.int64], NDArray[np.int64], cKDTree]] = []
    built_for = np.full(3, np.nan)
    for iteration in range(1, iterations + 1):
        # Which side of the model faces the camera changes slowly: rebuild the
        # per-class trees of front-facing points only when the view turned by > 3 deg.
        camera_in_hand = -R.T @ t
        view = camera_in_hand / np.linalg.norm(camera_in_hand)
        if not np.dot(view, built_for) > np.cos(np.radians(3.0)):
            front = np.einsum("ij,ij->i", normals, model - camera_in_hand) < 0
            trees = []
            for rows, in_class in by_class:
                members = np.flatnonzero(front & in_class)
                if len(members):
                    trees.append((rows, members, cKDTree(model[members])))
            built_for = view
        in_hand = (observed - t) @ R  # R^T (p - t) for every row
        pairs = [(rows, members[tree.query(in_hand[rows])[1]]) for rows, members, tree in trees]
        if not pairs:
            break
        rows = np.concatenate([r for r, _ in pairs])
        matched = np.concatenate([m for _, m in pairs])
        source, target = model[matched], observed[rows]
        distance = np.linalg.norm(in_hand[rows] - source, axis=1)
        gate = min(gate, max(3.0 * float(np.median(distance)), 0.005))
        keep = distance < gate
        if keep.sum() < 6:
            break
        source, target, source_normals = source[keep], target[keep], normals[matched[keep]]
        if gate > _PLANE_GATE_M:
            R, t = rigid_fit(source, target)
        else:
            R, t = _point_to_plane_step(source, source_normals, target, R, t)
        residual = source @ R.T + t - target
        cost = float(np.sqrt(np.mean(np.sum(residual**2, axis=1))))
        inliers = float(keep.sum()) / len(observed)
        if abs(previous - cost) < tolerance_m:
            return IcpResult(R, t, cost, inliers, iteration, True)
        previous = cost
    return IcpResult(R, t, cost, inliers, iterations, False)
