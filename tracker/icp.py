"""Color-sensitive rigid ICP of the glove model to the labeled point cloud (thesis 4.2.3).

With the posture fixed, every iteration

1. finds the model points that face the camera in the current pose,
2. pairs every observed point with the nearest front-facing model point of the same
   color class, in the hand frame, where the model does not move (the observed
   points are mapped into it): the compiled grid search of the generative fit's data
   term (:func:`tracker.generative.energy.data.nearest_of_class`), which replaced a
   k-d tree with the class as a fourth coordinate (same pairs, up to ties; the
   tree's queries took most of the 11 ms an ICP took); which side faces the camera
   is found again only when the view has turned by more than 3 degrees,
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

from glovedb._validate import as_array
from glovedb.rotations import axis_angle_to_matrix
from tracker.generative.energy.data import nearest_of_class

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
    source: NDArray[np.float64],
    target: NDArray[np.float64],
    weights: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Least-squares rotation and translation with ``target ~ R @ source + t``.

    Parameters
    ----------
    source, target : (N, 3) float
        Paired points, N >= 3 not all on a line.
    weights : (N,) float, optional
        Non-negative weight of each pair (default: all equal).

    Returns
    -------
    rotation : (3, 3) float64
    translation : (3,) float64
    """
    source = as_array("source", source, (None, 3), np.float64)
    target = as_array("target", target, (len(source), 3), np.float64)
    rotation, translation = batch_rigid_fit(
        source[None], target[None], None if weights is None else np.asarray(weights)[None]
    )
    return rotation[0], translation[0]


def batch_rigid_fit(
    source: NDArray[np.float64],
    target: NDArray[np.float64],
    weights: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`rigid_fit` of a batch of paired point sets at once (Kabsch).

    Parameters
    ----------
    source, target : (H, m, 3) float64
        ``m >= 3`` paired points per set.
    weights : (H, m) float, optional
        Non-negative weight of each pair (default: all equal).

    Returns
    -------
    rotation : (H, 3, 3) float64
    translation : (H, 3) float64
    """
    if weights is None:
        w = np.full(source.shape[:2], 1.0 / source.shape[1])
    else:
        w = weights / weights.sum(axis=1, keepdims=True)
    source_mean = np.einsum("hm,hmi->hi", w, source)
    target_mean = np.einsum("hm,hmi->hi", w, target)
    covariance = np.einsum(
        "hm,hmi,hmj->hij", w, target - target_mean[:, None], source - source_mean[:, None]
    )
    u, _, vt = np.linalg.svd(covariance)
    u[:, :, 2] *= np.sign(np.linalg.det(u @ vt))[:, None]
    rotation = u @ vt
    return rotation, target_mean - np.einsum("hij,hj->hi", rotation, source_mean)


def _point_to_plane_step(
    source: NDArray[np.float64],
    source_normals: NDArray[np.float64],
    target: NDArray[np.float64],
    rotation: NDArray[np.float64],
    translation: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """One linearised least-squares step on the distances of the targets to the
    model's tangent planes; returns the updated pose."""
    points = source @ rotation.T + translation
    normals = source_normals @ rotation.T
    jacobian = np.concatenate([np.cross(points, normals), normals], axis=1)
    residual = np.einsum("ij,ij->i", points - target, normals)
    # Normal equations: 6 unknowns against hundreds of pairs (lstsq's SVD costs more
    # than the rest of the step); a tiny damping keeps a flat patch solvable.
    normal = jacobian.T @ jacobian + 1e-12 * np.eye(6)
    delta = np.linalg.solve(normal, -(jacobian.T @ residual))
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
    # Only observed points of a class the model has can pair.
    rows = np.flatnonzero(np.isin(observed_classes, model_classes))
    row_classes = observed_classes[rows].astype(np.uint8)
    model_labels_u8 = model_classes.astype(np.uint8)

    cost, inliers, previous = np.inf, 0.0, np.inf
    gate = max_distance_m
    front = np.zeros(len(model), dtype=bool)
    built_for = np.full(3, np.nan)
    for iteration in range(1, iterations + 1):
        # Which side of the model faces the camera changes slowly: find it again only
        # when the view turned by more than 3 degrees.
        camera_in_hand = -R.T @ t
        view = camera_in_hand / np.linalg.norm(camera_in_hand)
        if not np.dot(view, built_for) > np.cos(np.radians(3.0)):
            front = np.einsum("ij,ij->i", normals, model - camera_in_hand) < 0
            built_for = view
        if not front.any() or len(rows) == 0:
            break
        in_hand = (observed[rows] - t) @ R  # R^T (p - t) for every row
        distance, matched = nearest_of_class(
            in_hand, row_classes, model, model_labels_u8, gate_m=np.inf, candidates=front
        )
        source, target = model[matched], observed[rows]  # row -1 where unpaired (inf)
        paired = np.isfinite(distance)
        if not paired.any():
            break
        gate = min(gate, max(3.0 * float(np.median(distance[paired])), 0.005))
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
