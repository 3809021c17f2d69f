"""A Gaussian prior over natural hand postures (thesis ch. 5-6: the PCA posture prior).

Fitted to postures the project generates (:mod:`builder.sampling`'s natural synergy
postures around the named postures, written by ``scripts/make_posture_prior.py`` to
``configs/hand/posture_prior.npz``). The covariance is the postures' sample covariance
plus ``floor_deg**2`` on every joint, so that postures off the synergies (a single
finger bent alone) are unlikely but not forbidden. The prior is used through its
whitening matrix ``W`` (``W.T @ W`` is the inverse covariance): the Mahalanobis
residual of a posture is ``W @ (theta - mean)``.
"""

from __future__ import annotations

from dataclasses import dataclass
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
    """Mean and whitening matrix of a Gaussian over the 20 joint angles.

    Attributes
    ----------
    mean_rad : (20,) float64
    whitening : (20, 20) float64
        Per radian; ``whitening @ (theta - mean)`` is standard normal under the prior.
    """

    mean_rad: NDArray[np.float64]
    whitening: NDArray[np.float64]

    def residual(self, posture_rad: ArrayLike) -> NDArray[np.float64]:
        """``(20,)`` Mahalanobis residual of a posture."""
        posture = as_array("posture_rad", posture_rad, (N_JOINTS,), np.float64)
        return self.whitening @ (posture - self.mean_rad)


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
