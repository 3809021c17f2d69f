"""A Gaussian prior over natural hand postures (thesis ch. 5-6: the PCA posture prior).

Fitted to postures the project generates (:mod:`builder.sampling`'s natural synergy
postures around the named postures, written by ``scripts/make_posture_prior.py`` to
``configs/hand/posture_prior.npz``). The covariance is the postures' sample covariance
plus ``floor_deg**2`` on every joint, so that postures off the synergies (a single
finger bent alone) are unlikely but not forbidden. The prior is used through its
whitening matrix ``W`` (``W.T @ W`` is the inverse covariance): the Mahalanobis
residual of a posture is ``W @ (theta - mean)``.

**Task postures.** A database is built for a task (open hand, pinch and power grasp
for teleoperation), and its postures say which postures the task holds. The single
Gaussian cannot know them: along the directions the camera barely observes (the
distal joints, the thumb of a power grasp seen from the back) it pulls every posture
toward the natural mean, which is not the task's grasp. :func:`with_task_postures`
turns the prior into a max-mixture (Olson and Agarwal, "Inference on networks of
mixtures for robust robot mapping", RSS 2012): the natural Gaussian, and one narrower
Gaussian per task posture ``t_k`` with the same shape, ``spread`` times the natural
standard deviations. A posture pays the cheapest of

    |W (theta - mean)|^2        and        |W (theta - t_k)|^2 / spread^2 + offset,

so near a task posture the prior holds the unobserved directions at the task's
values, and a posture far from every task posture (a finger moved alone, a grasp the
database does not hold) pays what its naturalness says, as before. The residual is
that of the cheapest component (:meth:`PosturePrior.whitened`); the energy is
continuous where the choice changes.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb import __version__
from glovedb._validate import as_array
from glovedb.hand_model import N_JOINTS
from glovedb.resources import config_path

PRIOR_FILE = "hand/posture_prior.npz"


@dataclass(frozen=True)
class PosturePrior:
    """Mean and whitening matrix of a Gaussian over the 20 joint angles, and the
    task postures that make it a max-mixture (module docstring).

    Attributes
    ----------
    mean_rad : (20,) float64
    whitening : (20, 20) float64
        Per radian; ``whitening @ (theta - mean)`` is standard normal under the prior.
    task_postures_rad : (K, 20) float64
        Centres of the task components; ``K = 0`` is the single Gaussian.
    task_spread : float
        Standard deviations of a task component relative to the natural ones.
    task_offset : float
        What choosing a task component costs, in squared standard deviations.
    """

    mean_rad: NDArray[np.float64]
    whitening: NDArray[np.float64]
    task_postures_rad: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, N_JOINTS)))
    task_spread: float = 1.0
    task_offset: float = 0.0
    _task_whitening: NDArray[np.float64] = field(init=False, repr=False, compare=False)
    _task_whitened: NDArray[np.float64] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        # The task centres whitened once: a posture's residual to centre k is then
        # ``W theta / spread - centre_k``, one matrix-vector product per posture.
        whitening = self.whitening / self.task_spread
        object.__setattr__(self, "_task_whitening", whitening)
        object.__setattr__(self, "_task_whitened", self.task_postures_rad @ whitening.T)

    def residual(self, posture_rad: ArrayLike) -> NDArray[np.float64]:
        """``(20,)`` Mahalanobis residual of a posture under the natural Gaussian."""
        posture = as_array("posture_rad", posture_rad, (N_JOINTS,), np.float64)
        return self.whitening @ (posture - self.mean_rad)

    def whitened(self, posture_rad: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Residual of the cheapest component and its whitening matrix.

        Parameters
        ----------
        posture_rad : (20,) float

        Returns
        -------
        residual : (21,) float64
            The component's Mahalanobis residual and, last, the square root of its
            offset (0 for the natural Gaussian): ``residual @ residual`` is the
            posture's cost.
        whitening : (20, 20) float64
            The derivative of the residual's first 20 entries by the posture (the
            last is constant).
        """
        posture = as_array("posture_rad", posture_rad, (N_JOINTS,), np.float64)
        residual = self.whitening @ (posture - self.mean_rad)
        if len(self.task_postures_rad) == 0:
            return np.append(residual, 0.0), self.whitening
        task = self._task_whitening @ posture - self._task_whitened
        costs = np.einsum("ij,ij->i", task, task)
        best = int(np.argmin(costs))
        if costs[best] + self.task_offset < residual @ residual:
            return np.append(task[best], np.sqrt(self.task_offset)), self._task_whitening
        return np.append(residual, 0.0), self.whitening


def with_task_postures(
    prior: PosturePrior, postures_rad: ArrayLike, *, spread: float, offset: float
) -> PosturePrior:
    """The prior with a narrower component at each task posture (module docstring).

    Parameters
    ----------
    prior : PosturePrior
    postures_rad : (K, 20) float
        The task's postures (a database's), radians.
    spread : float
        Standard deviations of a task component relative to the natural ones (> 0).
    offset : float
        What choosing a task component costs, squared standard deviations (>= 0).

    Returns
    -------
    PosturePrior
    """
    postures = as_array("postures_rad", postures_rad, (None, N_JOINTS), np.float64, finite=True)
    if not spread > 0:
        raise ValueError(f"spread: expected > 0, got {spread}")
    if not offset >= 0:
        raise ValueError(f"offset: expected >= 0, got {offset}")
    unique = np.unique(postures, axis=0)
    return replace(prior, task_postures_rad=unique, task_spread=float(spread),
                   task_offset=float(offset))  # fmt: skip


def fit_posture_prior(postures_rad: ArrayLike, *, floor_deg: float) -> PosturePrior:
    """Fit the prior to example postures (module docstring).

    Parameters
    ----------
    postures_rad : (N, 20) float
        N >= 2 postures.
    floor_deg : float
        Standard deviation added on every joint, degrees (> 0).

    Returns
    -------
    PosturePrior
    """
    postures = as_array("postures_rad", postures_rad, (None, N_JOINTS), np.float64, finite=True)
    if len(postures) < 2:
        raise ValueError(f"postures_rad: expected at least 2 postures, got {len(postures)}")
    if not floor_deg > 0:
        raise ValueError(f"floor_deg: expected > 0, got {floor_deg}")
    covariance = np.cov(postures, rowvar=False) + np.radians(floor_deg) ** 2 * np.eye(N_JOINTS)
    lower = np.linalg.cholesky(covariance)
    return PosturePrior(postures.mean(axis=0), np.linalg.inv(lower))


def save_posture_prior(path: str | Path, prior: PosturePrior, *, settings: str) -> Path:
    """Write the prior as ``.npz`` with the project version and the settings that made it."""
    target = Path(path)
    np.savez(
        target,
        mean_rad=prior.mean_rad,
        whitening=prior.whitening,
        version=np.array(__version__),
        settings=np.array(settings),
    )
    return target


def load_posture_prior(path: str | Path | None = None) -> PosturePrior:
    """Read a prior written by :func:`save_posture_prior` (default: the shipped one).

    Raises
    ------
    ValueError
        One line naming the file when it is missing or not a posture prior.
    """
    source = Path(path) if path is not None else config_path(PRIOR_FILE)
    try:
        with np.load(source, allow_pickle=False) as data:
            mean = as_array("mean_rad", data["mean_rad"], (N_JOINTS,), np.float64, finite=True)
            whitening = as_array(
                "whitening", data["whitening"], (N_JOINTS, N_JOINTS), np.float64, finite=True
            )
    except FileNotFoundError as error:
        raise ValueError(f"{source}: no such posture prior") from error
    except (OSError, KeyError, ValueError, TypeError) as error:
        raise ValueError(f"{source}: not a posture prior ({error})") from error
    return PosturePrior(mean, whitening)
