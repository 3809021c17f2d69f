"""Camera placements around the hand: named views and views from a direction.

A view is the global pose ``(R, t)`` (``p_cam = R @ p_hand + t``) that puts an OpenCV
camera at ``distance_m`` from a point of the hand, looking at it from a direction
given in the hand frame, with a roll about the optical axis.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array, check_choice
from glovedb.rotations import axis_angle_to_matrix, look_at

# Direction from the hand toward the camera, in the hand frame.
NAMED_VIEWS: dict[str, tuple[float, float, float]] = {
    "back": (0.0, 0.0, 1.0),
    "palm": (0.0, 0.0, -1.0),
    "thumb": (-1.0, 0.0, 0.0),
    "little": (1.0, 0.0, 0.0),
    "tips": (0.0, 1.0, 0.0),
    "wrist": (0.0, -1.0, 0.0),
}
# Middle of the hand in units of hand length: what the camera looks at by default.
HAND_CENTRE = (0.0, 0.42, 0.0)


def view_direction(azimuth_rad: float, elevation_rad: float) -> NDArray[np.float64]:
    """Unit direction in the hand frame: azimuth about +y from the back (+z) toward
    the little finger (+x), elevation toward the fingertips (+y)."""
    return np.array(
        [
            np.cos(elevation_rad) * np.sin(azimuth_rad),
            np.sin(elevation_rad),
            np.cos(elevation_rad) * np.cos(azimuth_rad),
        ]
    )


def pose_for_view(
    direction: ArrayLike,
    distance_m: float,
    *,
    target_m: ArrayLike = (0.0, 0.0, 0.0),
    roll_rad: float = 0.0,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Global hand pose seen by a camera placed along ``direction``.

    Parameters
    ----------
    direction : (3,) float
        From ``target_m`` toward the camera, hand frame (normalised here).
    distance_m : float
        Camera to ``target_m``.
    target_m : (3,) float
        Point of the hand on the optical axis, hand frame.
    roll_rad : float
        Rotation of the camera about its optical axis (image rotates by ``-roll``).

    Returns
    -------
    rotation : (3, 3) float64
        ``cam_R_hand``.
    translation_m : (3,) float64
        Wrist in the camera frame.

    Notes
    -----
    The image "up" is the hand's +y (toward the fingers) unless the camera looks
    along y, in which case it is the hand's +z (the back of the hand).
    """
    direction = as_array("direction", direction, (3,), np.float64, finite=True)
    target = as_array("target_m", target_m, (3,), np.float64, finite=True)
    if distance_m <= 0:
        raise ValueError(f"distance_m: expected > 0, got {distance_m}")
    unit = direction / np.linalg.norm(direction)
    eye = target + distance_m * unit
    up = np.array([0.0, 1.0, 0.0]) if abs(unit[1]) < 0.95 else np.array([0.0, 0.0, 1.0])
    rotation = axis_angle_to_matrix(np.array([0.0, 0.0, 1.0]), roll_rad) @ look_at(eye, target, up)
    return rotation, -rotation @ eye


def named_view(
    name: str, distance_m: float, hand_length_m: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pose for one of :data:`NAMED_VIEWS`, looking at the middle of the hand."""
    check_choice("view", name, tuple(NAMED_VIEWS))
    target = np.array(HAND_CENTRE) * hand_length_m
    return pose_for_view(NAMED_VIEWS[name], distance_m, target_m=target)
