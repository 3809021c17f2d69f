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

The iterations run compiled (:mod:`tracker._icp_kernels`): on the 23 lookups of a
tracked Tr3 sequence 3.0 ms per ICP against 6.0 ms for the same loop in NumPy, whose
twenty-odd small array operations per iteration cost more than the pairing; the poses
agree to 1e-5 degrees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array
from tracker import _icp_kernels
from tracker.generative.energy.data import CELL_M

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
    cost, inliers, done, converged = _icp_kernels.color_icp(
        np.ascontiguousarray(observed[rows]), observed_classes[rows].astype(np.uint8),
        np.ascontiguousarray(model), np.ascontiguousarray(normals),
        model_classes.astype(np.uint8), R, t, iterations, float(max_distance_m),
        float(tolerance_m), _PLANE_GATE_M, CELL_M, len(observed),
    )  # fmt: skip
    return IcpResult(R, t, float(cost), float(inliers), int(done), bool(converged))
