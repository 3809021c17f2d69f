"""Hand trajectories: keyframes of posture and global pose, interpolated over time.

File format (docs/conventions.md)::

    {"fps": 30, "keyframes": [{"time_s": 0.0, "posture": "open" | [20 floats],
      "rotation_quat_wxyz": [4], "translation_m": [3]}, ...]}

Postures and translations interpolate linearly, rotations by slerp. A trajectory
holds still before its first and after its last keyframe.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array
from glovedb.hand_model import N_JOINTS
from glovedb.postures import load_named_postures
from glovedb.rotations import quaternion_to_matrix, slerp


@dataclass(frozen=True)
class Trajectory:
    """Keyframes of a hand motion.

    Attributes
    ----------
    fps : float
        Frame rate of sequences rendered from it.
    times_s : (K,) float64
        Strictly increasing keyframe times.
    postures_rad : (K, 20) float64
    quaternions_wxyz : (K, 4) float64
        ``cam_R_hand`` of each keyframe.
    translations_m : (K, 3) float64
        Wrist position in the camera frame.
    """

    fps: float
    times_s: NDArray[np.float64]
    postures_rad: NDArray[np.float64]
    quaternions_wxyz: NDArray[np.float64]
    translations_m: NDArray[np.float64]

    @property
    def duration_s(self) -> float:
        """Time of the last keyframe."""
        return float(self.times_s[-1])

    def frame_times(self) -> NDArray[np.float64]:
        """Times of the frames at :attr:`fps` from 0 to the last keyframe."""
        count = int(np.floor(self.duration_s * self.fps + 1e-9)) + 1
        return np.arange(count) / self.fps

    def sample(
        self, times_s: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Posture, rotation and translation at the given times.

        Parameters
        ----------
        times_s : (T,) float

        Returns
        -------
        postures_rad : (T, 20) float64
        rotations : (T, 3, 3) float64
        translations_m : (T, 3) float64
        """
        times = np.clip(as_array("times_s", times_s, (None,), np.float64, finite=True),
                        self.times_s[0], self.times_s[-1])  # fmt: skip
        upper = np.clip(
            np.searchsorted(self.times_s, times, side="right"), 1, len(self.times_s) - 1
        )
        lower = upper - 1
        span = self.times_s[upper] - self.times_s[lower]
        fraction = np.clip((times - self.times_s[lower]) / np.where(span > 0, span, 1.0), 0, 1)
        if len(self.times_s) == 1:
            lower = upper = np.zeros(len(times), dtype=np.int64)
        f = fraction[:, None]
        postures = (1 - f) * self.postures_rad[lower] + f * self.postures_rad[upper]
        translations = (1 - f) * self.translations_m[lower] + f * self.translations_m[upper]
        quaternions = slerp(self.quaternions_wxyz[lower], self.quaternions_wxyz[upper], fraction)
        return postures, quaternion_to_matrix(quaternions), translations


def trajectory_from_dict(data: dict[str, Any], *, source: str = "trajectory") -> Trajectory:
    """Build a :class:`Trajectory` from the parsed JSON object; ``ValueError`` names the problem."""
    try:
        fps = float(data.get("fps", 30))
        keyframes = list(data["keyframes"])
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"{source}: expected {{'fps', 'keyframes': [...]}} ({error})") from error
    if not keyframes:
        raise ValueError(f"{source}: no keyframes")
    if not fps > 0:
        raise ValueError(f"{source}: fps must be positive")
    named = load_named_postures()
    times, postures, quaternions, translations = [], [], [], []
    for index, frame in enumerate(keyframes):
        where = f"{source}: keyframe {index}"
        try:
            posture = frame["posture"]
            if isinstance(posture, str):
                if posture not in named:
                    raise ValueError(f"unknown posture {posture!r}")
                posture = named[posture]
            postures.append(
                as_array(f"{where} posture", posture, (N_JOINTS,), np.float64, finite=True)
            )
            quaternions.append(as_array(f"{where} rotation_quat_wxyz", frame["rotation_quat_wxyz"],
                                        (4,), np.float64, finite=True))  # fmt: skip
            translations.append(as_array(f"{where} translation_m", frame["translation_m"], (3,),
                                         np.float64, finite=True))  # fmt: skip
            times.append(float(frame["time_s"]))
        except KeyError as error:
            raise ValueError(f"{where}: missing {error}") from error
    times_array = np.array(times)
    if np.any(np.diff(times_array) <= 0):
        raise ValueError(f"{source}: keyframe times must increase")
    quaternion_array = np.array(quaternions)
    if np.any(np.linalg.norm(quaternion_array, axis=1) < 1e-9):
        raise ValueError(f"{source}: a rotation quaternion is zero")
    return Trajectory(
        fps, times_array, np.array(postures), quaternion_array, np.array(translations)
    )


def load_trajectory(path: str | Path) -> Trajectory:
    """Read a trajectory JSON file; one-line ``ValueError`` if it is missing or malformed."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except OSError as error:
        raise ValueError(f"{path}: cannot read the trajectory ({error.strerror})") from error
    except json.JSONDecodeError as error:
        raise ValueError(f"{path}: not valid JSON ({error})") from error
    except UnicodeDecodeError as error:
        raise ValueError(f"{path}: not UTF-8 text (byte {error.start})") from error
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a trajectory object with fps and keyframes")
    return trajectory_from_dict(data, source=str(path))
