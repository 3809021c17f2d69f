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
    looking, eye = _unrolled_camera(direction, distance_m, target_m)
    return _rolled(looking, eye, axis_angle_to_matrix(np.array([0.0, 0.0, 1.0]), roll_rad))


def _unrolled_camera(
    direction: ArrayLike, distance_m: float, target_m: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``cam_R_hand`` of :func:`pose_for_view` at roll 0, and the camera's position."""
    direction = as_array("direction", direction, (3,), np.float64, finite=True)
    target = as_array("target_m", target_m, (3,), np.float64, finite=True)
    if distance_m <= 0:
        raise ValueError(f"distance_m: expected > 0, got {distance_m}")
    unit = direction / np.linalg.norm(direction)
    eye = target + distance_m * unit
    up = np.array([0.0, 1.0, 0.0]) if abs(unit[1]) < 0.95 else np.array([0.0, 0.0, 1.0])
    return look_at(eye, target, up), eye


def _rolled(
    looking: NDArray[np.float64], eye: NDArray[np.float64], roll: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The pose of the camera ``looking`` from ``eye``, turned by ``roll`` about its axis."""
    rotation = roll @ looking
    return rotation, -rotation @ eye


def named_view(
    name: str, distance_m: float, hand_length_m: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pose for one of :data:`NAMED_VIEWS`, looking at the middle of the hand."""
    check_choice("view", name, tuple(NAMED_VIEWS))
    target = np.array(HAND_CENTRE) * hand_length_m
    return pose_for_view(NAMED_VIEWS[name], distance_m, target_m=target)


def icosphere(subdivisions: int) -> NDArray[np.float64]:
    """Vertices of a subdivided icosahedron on the unit sphere.

    Every subdivision splits each triangle into four; the vertex count is
    ``10 * 4**subdivisions + 2`` (12, 42, 162, 642, ...).

    Parameters
    ----------
    subdivisions : int
        0 to 6.

    Returns
    -------
    (V, 3) float64
        Unit vectors, in a fixed deterministic order.
    """
    if not 0 <= subdivisions <= 6:
        raise ValueError(f"subdivisions: expected 0-6, got {subdivisions}")
    golden = (1.0 + np.sqrt(5.0)) / 2.0
    vertices = [
        (-1, golden, 0), (1, golden, 0), (-1, -golden, 0), (1, -golden, 0),
        (0, -1, golden), (0, 1, golden), (0, -1, -golden), (0, 1, -golden),
        (golden, 0, -1), (golden, 0, 1), (-golden, 0, -1), (-golden, 0, 1),
    ]  # fmt: skip
    faces = [
        (0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11),
        (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6), (7, 1, 8),
        (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9),
        (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1),
    ]  # fmt: skip
    points = [np.array(v, dtype=np.float64) / np.linalg.norm(v) for v in vertices]
    for _ in range(subdivisions):
        midpoints: dict[tuple[int, int], int] = {}
        refined = []
        for a, b, c in faces:
            middle = []
            for first, second in ((a, b), (b, c), (c, a)):
                key = (min(first, second), max(first, second))
                if key not in midpoints:
                    point = points[first] + points[second]
                    points.append(point / np.linalg.norm(point))
                    midpoints[key] = len(points) - 1
                middle.append(midpoints[key])
            ab, bc, ca = middle
            refined += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = refined
    return np.array(points)


def database_views(
    subdivisions: int = 1, rolls: int = 18, *, distance_m: float = 0.5, hand_length_m: float = 0.19
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The views of a posture database: icosphere camera positions times rolls.

    Parameters
    ----------
    subdivisions : int
        Of the icosahedron (1 gives 42 camera positions).
    rolls : int
        Rotations about the optical axis per position, evenly spaced over 360 degrees.
    distance_m, hand_length_m : float
        Camera distance from the middle of the hand, and the hand's size.

    Returns
    -------
    rotations : (P * R, 3, 3) float64
        ``cam_R_hand`` of every view, position-major (view ``p * R + r``).
    translations_m : (P * R, 3) float64
        The wrist in the camera frame.
    roll_rad : (R,) float64
        The roll angles.
    """
    if rolls < 1:
        raise ValueError(f"rolls: expected at least 1, got {rolls}")
    roll_rad = np.arange(rolls, dtype=np.float64) * (2 * np.pi / rolls)
    target = np.array(HAND_CENTRE) * hand_length_m
    # pose_for_view of every position and roll, each camera and roll rotation made once.
    turns = [axis_angle_to_matrix(np.array([0.0, 0.0, 1.0]), roll) for roll in roll_rad]
    rotations, translations = [], []
    for direction in icosphere(subdivisions):
        looking, eye = _unrolled_camera(direction, distance_m, target)
        for turn in turns:
            rotation, translation = _rolled(looking, eye, turn)
            rotations.append(rotation)
            translations.append(translation)
    return np.array(rotations), np.array(translations), roll_rad
