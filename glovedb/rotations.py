"""Rotation helpers on arrays: axis-angle, quaternions (w first), slerp, geodesic angle.

All functions broadcast over leading axes. Rotation matrices act on column vectors
(``p' = R @ p``); quaternions are ``(w, x, y, z)`` with ``w >= 0`` on output.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array


def axis_angle_to_matrix(axis: ArrayLike, angle_rad: ArrayLike) -> NDArray[np.float64]:
    """Rodrigues' formula.

    Parameters
    ----------
    axis : (..., 3) float
        Rotation axes; normalised here (a zero axis gives the identity).
    angle_rad : (...) float
        Angles in radians, right-handed about ``axis``.

    Returns
    -------
    (..., 3, 3) float64
    """
    axis = as_array("axis", axis, (..., 3), np.float64)
    angle = np.asarray(angle_rad, dtype=np.float64)
    if axis.ndim == 1 and angle.ndim == 0:
        return _one_axis_angle_to_matrix(axis, angle)
    norm = np.linalg.norm(axis, axis=-1, keepdims=True)
    unit = np.divide(axis, norm, out=np.zeros_like(axis), where=norm > 0)
    x, y, z = np.moveaxis(unit, -1, 0)
    angle = np.where(norm[..., 0] > 0, angle, 0.0)  # a zero axis turns by nothing
    c, s = np.cos(angle), np.sin(angle)
    shape = np.broadcast_shapes(x.shape, c.shape)
    x, y, z, c, s = (np.broadcast_to(a, shape) for a in (x, y, z, c, s))
    t = 1.0 - c
    return np.stack(
        [
            np.stack([c + x * x * t, x * y * t - z * s, x * z * t + y * s], -1),
            np.stack([y * x * t + z * s, c + y * y * t, y * z * t - x * s], -1),
            np.stack([z * x * t - y * s, z * y * t + x * s, c + z * z * t], -1),
        ],
        -2,
    )


def _one_axis_angle_to_matrix(
    axis: NDArray[np.float64], angle: NDArray[np.float64]
) -> NDArray[np.float64]:
    """:func:`axis_angle_to_matrix` of one ``(3,)`` axis and a 0-d angle, bit for bit,
    in scalar arithmetic: the same operations in the same order (the fit turns the
    hand by one such rotation per solver step, and the broadcasting path's array
    calls cost 0.19 ms where this costs about 0.01)."""
    x, y, z = (float(value) for value in axis)
    norm = float(np.sqrt(x * x + y * y + z * z))
    if not norm > 0:
        return np.eye(3)
    x, y, z = x / norm, y / norm, z / norm
    c, s = float(np.cos(angle)), float(np.sin(angle))
    t = 1.0 - c
    return np.array(
        [
            [c + x * x * t, x * y * t - z * s, x * z * t + y * s],
            [y * x * t + z * s, c + y * y * t, y * z * t - x * s],
            [z * x * t - y * s, z * y * t + x * s, c + z * z * t],
        ]
    )


def rotation_x(angle_rad: ArrayLike) -> NDArray[np.float64]:
    """Rotation about +x; ``(...)`` angles give ``(..., 3, 3)``."""
    return axis_angle_to_matrix(np.array([1.0, 0.0, 0.0]), angle_rad)


def rotation_y(angle_rad: ArrayLike) -> NDArray[np.float64]:
    """Rotation about +y; ``(...)`` angles give ``(..., 3, 3)``."""
    return axis_angle_to_matrix(np.array([0.0, 1.0, 0.0]), angle_rad)


def rotation_z(angle_rad: ArrayLike) -> NDArray[np.float64]:
    """Rotation about +z; ``(...)`` angles give ``(..., 3, 3)``."""
    return axis_angle_to_matrix(np.array([0.0, 0.0, 1.0]), angle_rad)


def matrix_to_quaternion(rotation: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrices ``(..., 3, 3)`` to unit quaternions ``(..., 4)`` (w, x, y, z), w >= 0.

    Uses the numerically stable branch per matrix (largest diagonal term).
    """
    R = as_array("rotation", rotation, (..., 3, 3), np.float64)
    if R.ndim == 2 and np.isfinite(R).all():
        return _one_matrix_to_quaternion(R)
    m = R.reshape(-1, 3, 3)
    trace = np.trace(m, axis1=1, axis2=2)
    candidates = np.stack(
        [
            np.stack(
                [
                    1 + trace,
                    m[:, 2, 1] - m[:, 1, 2],
                    m[:, 0, 2] - m[:, 2, 0],
                    m[:, 1, 0] - m[:, 0, 1],
                ],
                -1,
            ),
            np.stack(
                [
                    m[:, 2, 1] - m[:, 1, 2],
                    1 + m[:, 0, 0] - m[:, 1, 1] - m[:, 2, 2],
                    m[:, 0, 1] + m[:, 1, 0],
                    m[:, 0, 2] + m[:, 2, 0],
                ],
                -1,
            ),
            np.stack(
                [
                    m[:, 0, 2] - m[:, 2, 0],
                    m[:, 0, 1] + m[:, 1, 0],
                    1 - m[:, 0, 0] + m[:, 1, 1] - m[:, 2, 2],
                    m[:, 1, 2] + m[:, 2, 1],
                ],
                -1,
            ),
            np.stack(
                [
                    m[:, 1, 0] - m[:, 0, 1],
                    m[:, 0, 2] + m[:, 2, 0],
                    m[:, 1, 2] + m[:, 2, 1],
                    1 - m[:, 0, 0] - m[:, 1, 1] + m[:, 2, 2],
                ],
                -1,
            ),
        ],
        1,
    )
    pivots = np.stack([trace, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], -1).argmax(-1)
    q = candidates[np.arange(len(m)), pivots]
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q.reshape(R.shape[:-2] + (4,))


def _one_matrix_to_quaternion(m: NDArray[np.float64]) -> NDArray[np.float64]:
    """:func:`matrix_to_quaternion` of one finite ``(3, 3)`` matrix, bit for bit, in
    scalar arithmetic (the pose filter converts one a frame: 0.17 ms the batched way).
    The pivot's component is at least 1 for any finite matrix, so ``norm`` is too."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = m.tolist()
    trace = m00 + m11 + m22
    pivots = (trace, m00, m11, m22)
    pivot = max(range(4), key=lambda k: (pivots[k], -k))  # the first largest
    if pivot == 0:
        q = (1 + trace, m21 - m12, m02 - m20, m10 - m01)
    elif pivot == 1:
        q = (m21 - m12, 1 + m00 - m11 - m22, m01 + m10, m02 + m20)
    elif pivot == 2:
        q = (m02 - m20, m01 + m10, 1 - m00 + m11 - m22, m12 + m21)
    else:
        q = (m10 - m01, m02 + m20, m12 + m21, 1 - m00 - m11 + m22)
    w, x, y, z = q
    norm = float(np.sqrt(w * w + x * x + y * y + z * z))
    sign = -1.0 if w / norm < 0 else 1.0
    return np.array([w / norm * sign, x / norm * sign, y / norm * sign, z / norm * sign])


def quaternion_to_matrix(quat_wxyz: ArrayLike) -> NDArray[np.float64]:
    """Quaternions ``(..., 4)`` (w, x, y, z; normalised here) to matrices ``(..., 3, 3)``."""
    q = as_array("quat_wxyz", quat_wxyz, (..., 4), np.float64, finite=True)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(norm == 0):
        raise ValueError("quat_wxyz: zero-length quaternion")
    w, x, y, z = np.moveaxis(q / norm, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def slerp(quat_a_wxyz: ArrayLike, quat_b_wxyz: ArrayLike, fraction: ArrayLike) -> NDArray:
    """Spherical linear interpolation along the shorter arc.

    Parameters
    ----------
    quat_a_wxyz, quat_b_wxyz : (..., 4) float
        End points (normalised here).
    fraction : (...) float
        0 gives ``a``, 1 gives ``b``.

    Returns
    -------
    (..., 4) float64
        Unit quaternions (w, x, y, z).
    """
    a = as_array("quat_a_wxyz", quat_a_wxyz, (..., 4), np.float64)
    b = as_array("quat_b_wxyz", quat_b_wxyz, (..., 4), np.float64)
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    t = np.asarray(fraction, dtype=np.float64)[..., None]
    dot = np.sum(a * b, axis=-1, keepdims=True)
    b = np.where(dot < 0, -b, b)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_theta = np.sin(theta)
    near = sin_theta < 1e-9
    safe = np.where(near, 1.0, sin_theta)
    wa = np.where(near, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    wb = np.where(near, t, np.sin(t * theta) / safe)
    q = wa * a + wb * b
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def geodesic_angle(rotation_a: ArrayLike, rotation_b: ArrayLike) -> NDArray[np.float64]:
    """Angle in radians of ``R_a^T R_b`` for ``(..., 3, 3)`` pairs: the rotation error."""
    a = as_array("rotation_a", rotation_a, (..., 3, 3), np.float64)
    b = as_array("rotation_b", rotation_b, (..., 3, 3), np.float64)
    relative = np.swapaxes(a, -1, -2) @ b
    cos = (np.trace(relative, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.arccos(np.clip(cos, -1.0, 1.0))


def rotation_vector(rotation: ArrayLike) -> NDArray[np.float64]:
    """``(..., 3)`` axis times angle (radians, at most pi) of ``(..., 3, 3)`` rotations:
    the inverse of :func:`axis_angle_to_matrix`."""
    quat = matrix_to_quaternion(rotation)  # w >= 0: the angle is at most pi
    if quat.ndim == 1:  # one rotation, in scalar arithmetic (bit for bit the same)
        w, x, y, z = quat.tolist()
        sine = float(np.sqrt(x * x + y * y + z * z))
        factor = 2.0 if sine < 1e-12 else float(2.0 * np.arctan2(sine, w)) / max(sine, 1e-12)
        return np.array([x * factor, y * factor, z * factor])
    xyz = quat[..., 1:]
    sine = np.linalg.norm(xyz, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(sine, quat[..., :1])
    # Near the identity angle / sine -> 2.
    return xyz * np.where(sine < 1e-12, 2.0, angle / np.maximum(sine, 1e-12))


def look_at(eye: ArrayLike, target: ArrayLike, up: ArrayLike) -> NDArray[np.float64]:
    """Rotation ``cam_R_world`` of an OpenCV camera at ``eye`` looking at ``target``.

    The camera's +z points from ``eye`` to ``target`` and its -y (image up) points as
    close to ``up`` as possible. Rows of the result are the camera axes in world
    coordinates, so ``p_cam = R @ (p_world - eye)``.

    Parameters
    ----------
    eye, target, up : (3,) float
        World coordinates; ``up`` must not be parallel to ``target - eye``.

    Returns
    -------
    (3, 3) float64
    """
    eye = as_array("eye", eye, (3,), np.float64, finite=True)
    target = as_array("target", target, (3,), np.float64, finite=True)
    up = as_array("up", up, (3,), np.float64, finite=True)
    z = target - eye
    if np.linalg.norm(z) == 0:
        raise ValueError("look_at: eye and target coincide")
    z /= np.linalg.norm(z)
    x = np.cross(-up, z)
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: up is parallel to the viewing direction")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z])


def weighted_rotation_average(rotations: ArrayLike, weights: ArrayLike) -> NDArray[np.float64]:
    """Weighted mean rotation: principal eigenvector of ``sum_j w_j q_j q_j^T``.

    The quaternion outer products make the result independent of each quaternion's
    sign (``q`` and ``-q`` are the same rotation). It is the chordal L2 mean in
    quaternion space (Markley et al. 2007); for two rotations with equal weights it is
    exactly their geodesic midpoint.

    Parameters
    ----------
    rotations : (k, 3, 3) float
        Rotation matrices.
    weights : (k,) float
        Non-negative weights with a positive sum (normalisation is not needed).

    Returns
    -------
    (3, 3) float64
        The average rotation.
    """
    R = as_array("rotations", rotations, (None, 3, 3), np.float64, finite=True)
    w = as_array("weights", weights, (len(R),), np.float64, finite=True)
    if np.any(w < 0) or not np.sum(w) > 0:
        raise ValueError("weights: must be non-negative with a positive sum")
    q = matrix_to_quaternion(R)
    scatter = np.einsum("k,ki,kj->ij", w, q, q)
    _, vectors = np.linalg.eigh(scatter)
    return quaternion_to_matrix(vectors[:, -1])
