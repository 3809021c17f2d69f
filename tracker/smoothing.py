"""Speed-adaptive smoothing of the reported pose: the One Euro filter.

A hand held still should not tremble with the sensor's noise, and a moving hand
should not lag. The One Euro filter (Casiez, Roussel and Vogel, "1 Euro Filter: A
Simple Speed-based Low-pass Filter for Noisy Input in Interactive Systems", CHI 2012)
does both: an exponential low-pass filter whose cutoff frequency rises with the
signal's speed::

    cutoff = min_cutoff_hz + beta * |speed|,   alpha = 1 / (1 + 1 / (2 pi cutoff dt))

with the velocity itself low-passed at ``derivative_cutoff_hz``. :class:`PoseFilter`
applies it to the 20 joint angles, each with its own speed (beta per radian/s), and to
the wrist position (per metre/s) and the rotation (the rotation vector of the step
from the last filtered rotation, per radian/s), each moving as one: their speed is the
length of the low-passed velocity *vector*. Low-passing the signed velocity before
taking its length matters: a still hand's noise moves the wrist a fraction of a
millimetre each frame in random directions, which averages out in the velocity but
not in its length; with the length low-passed (the speed of every step) that noise
alone kept the cutoff high and the still wrist trembling, and with a speed per
coordinate a hand moving mostly along x was filtered hard, that is lagged, along y
and z. Only the reported pose is filtered: the fit starts every frame from its own
unfiltered solution.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from glovedb.rotations import axis_angle_to_matrix, rotation_vector


def smoothing_factor(cutoff_hz: NDArray[np.float64] | float, dt_s: float) -> NDArray[np.float64]:
    """``alpha`` of an exponential filter with the given cutoff, for a step ``dt_s``."""
    tau = 1.0 / (2.0 * np.pi * np.asarray(cutoff_hz, dtype=np.float64))
    return 1.0 / (1.0 + tau / dt_s)


@dataclass(frozen=True)
class OneEuroSettings:
    """One channel's parameters (module docstring).

    Attributes
    ----------
    min_cutoff_hz : float
        Cutoff of a still signal: lower is smoother and lags more when slow.
    beta : float
        Cutoff added per unit of speed (the channel's unit per second).
    derivative_cutoff_hz : float
        Cutoff of the speed estimate.
    """

    min_cutoff_hz: float
    beta: float
    derivative_cutoff_hz: float = 1.0

    def __post_init__(self) -> None:
        if not (self.min_cutoff_hz > 0 and self.derivative_cutoff_hz > 0 and self.beta >= 0):
            raise ValueError(f"OneEuroSettings: cutoffs must be > 0 and beta >= 0, got {self}")


class OneEuroFilter:
    """The One Euro filter over a vector of coordinates.

    Parameters
    ----------
    settings : OneEuroSettings
    vector : bool
        One cutoff for all coordinates, from the length of the low-passed velocity
        (a position); False gives each coordinate the cutoff of its own speed.
    """

    def __init__(self, settings: OneEuroSettings, *, vector: bool = False) -> None:
        self.settings = settings
        self.vector = vector
        self._value: NDArray[np.float64] | None = None
        self._speed: NDArray[np.float64] | None = None

    def reset(self) -> None:
        self._value = self._speed = None

    def __call__(self, value: NDArray[np.float64], dt_s: float) -> NDArray[np.float64]:
        """The filtered value of a new sample ``dt_s`` seconds after the last."""
        value = np.asarray(value, dtype=np.float64)
        if self._value is None or self._speed is None:
            self._value, self._speed = value.copy(), np.zeros_like(value)
            return value.copy()
        s = self.settings
        speed = (value - self._value) / dt_s
        self._speed += smoothing_factor(s.derivative_cutoff_hz, dt_s) * (speed - self._speed)
        size = (
            np.full_like(self._speed, np.linalg.norm(self._speed))
            if self.vector
            else np.abs(self._speed)
        )
        alpha = smoothing_factor(s.min_cutoff_hz + s.beta * size, dt_s)
        self._value = self._value + alpha * (value - self._value)
        return self._value.copy()


@dataclass(frozen=True)
class PoseFilterSettings:
    """The One Euro settings of the three parts of a hand pose.

    Defaults: chosen on a rendered still hand (3 s, Kinect-like noise) and the moving
    Tr1-Tr5 (docs/RESULTS.md), tracked with open_pinch_power: keypoint jitter of the
    still hand 0.18 px / 0.27 mm RMS frame to frame (unfiltered 0.63 / 0.89); mean
    wrist error over Tr1-Tr5 0.44-0.61 mm (unfiltered 0.40-0.60) and keypoint error
    1.19 px (unfiltered 1.12): the lag the filter adds to a moving hand.
    """

    posture: OneEuroSettings = OneEuroSettings(min_cutoff_hz=0.4, beta=20.0)
    translation: OneEuroSettings = OneEuroSettings(min_cutoff_hz=0.4, beta=1500.0)
    rotation: OneEuroSettings = OneEuroSettings(min_cutoff_hz=0.4, beta=80.0)


class PoseFilter:
    """One Euro filtering of posture, wrist position and rotation (module docstring).

    The rotation is filtered on its error: the rotation vector ``e`` of the turn from
    the last output to the new estimate; the output turns by ``alpha * e``, with
    ``alpha`` from the cutoff at the length of the low-passed angular velocity
    ``e / dt``.
    """

    def __init__(self, settings: PoseFilterSettings | None = None) -> None:
        self.settings = settings or PoseFilterSettings()
        self._posture = OneEuroFilter(self.settings.posture)
        self._translation = OneEuroFilter(self.settings.translation, vector=True)
        self._rotation: NDArray[np.float64] | None = None
        self._angular_velocity = np.zeros(3)

    def reset(self) -> None:
        self._posture.reset()
        self._translation.reset()
        self._rotation = None
        self._angular_velocity = np.zeros(3)

    def __call__(
        self,
        posture_rad: NDArray[np.float64],
        rotation: NDArray[np.float64],
        translation_m: NDArray[np.float64],
        dt_s: float,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """The filtered ``(posture (20,), rotation (3, 3), translation (3,))``."""
        posture = self._posture(posture_rad, dt_s)
        translation = self._translation(translation_m, dt_s)
        if self._rotation is None:
            self._rotation = np.asarray(rotation, dtype=np.float64).copy()
            return posture, self._rotation.copy(), translation
        s = self.settings.rotation
        error = rotation_vector(rotation @ self._rotation.T)
        self._angular_velocity += smoothing_factor(s.derivative_cutoff_hz, dt_s) * (
            error / dt_s - self._angular_velocity
        )
        speed = float(np.linalg.norm(self._angular_velocity))
        alpha = float(smoothing_factor(s.min_cutoff_hz + s.beta * speed, dt_s))
        step = alpha * error
        size = float(np.linalg.norm(step))
        turn = axis_angle_to_matrix(step / size, size) if size > 0 else np.eye(3)
        self._rotation = turn @ self._rotation
        return posture, self._rotation.copy(), translation
