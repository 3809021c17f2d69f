"""What every energy term returns, and the robust weights they share."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from glovedb.proportions import N_PROPORTIONS
from tracker.generative.model import N_PARAMS

Derivatives = tuple[NDArray[np.float64], NDArray[np.float64] | None]
"""A term's ``jacobian (M, 26)`` and ``proportion_jacobian (M, 7)`` or None."""


class Residuals:
    """Weighted residuals of one energy term and their derivatives.

    The derivatives may be given, or computed when first asked for
    (:meth:`deferred`): the solver needs them only at the states it linearises at,
    not at a step it refuses nor at the state it ends on, and a fit's terms spend
    about as long on their Jacobians as on their values.

    Parameters
    ----------
    name : str
    values : (M,) float64
    jacobian : (M, 26) float64
    proportion_jacobian : (M, 7) float64, optional

    Attributes
    ----------
    name : str
    values : (M,) float64
        The term's energy is ``sum(values**2)``.
    jacobian : (M, 26) float64
        By the pose step and the joint angles (:data:`~tracker.generative.model.N_PARAMS`).
    proportion_jacobian : (M, 7) float64 or None
        By the hand proportions, where the term depends on them and they were asked for.
    """

    __slots__ = ("_derivatives", "_derive", "name", "values")

    def __init__(
        self,
        name: str,
        values: NDArray[np.float64],
        jacobian: NDArray[np.float64],
        proportion_jacobian: NDArray[np.float64] | None = None,
    ) -> None:
        self.name = name
        self.values = values
        self._derivatives: Derivatives | None = (jacobian, proportion_jacobian)
        self._derive: Callable[[], Derivatives] | None = None

    @classmethod
    def deferred(
        cls, name: str, values: NDArray[np.float64], derive: Callable[[], Derivatives]
    ) -> Residuals:
        """Residuals whose derivatives ``derive()`` computes on first use (once)."""
        residuals = cls.__new__(cls)
        residuals.name, residuals.values = name, values
        residuals._derivatives, residuals._derive = None, derive
        return residuals

    def _computed(self) -> Derivatives:
        if self._derivatives is None:
            assert self._derive is not None
            self._derivatives, self._derive = self._derive(), None
        return self._derivatives

    @property
    def jacobian(self) -> NDArray[np.float64]:
        return self._computed()[0]

    @property
    def proportion_jacobian(self) -> NDArray[np.float64] | None:
        return self._computed()[1]

    @property
    def energy(self) -> float:
        return float(self.values @ self.values)

    def __len__(self) -> int:
        return len(self.values)

    @classmethod
    def empty(cls, name: str, *, proportions: bool = False) -> Residuals:
        return cls(
            name,
            np.zeros(0),
            np.zeros((0, N_PARAMS)),
            np.zeros((0, N_PROPORTIONS)) if proportions else None,
        )


def huber_weights(residual: NDArray[np.float64], delta: float) -> NDArray[np.float64]:
    """Row weights that turn squares into the Huber loss (iteratively reweighted).

    ``w * r`` squared is ``r**2`` within ``delta`` and ``delta * (2|r| - delta)``
    beyond, up to a constant: ``w = sqrt(min(1, delta / |r|))`` (the weight's
    derivative is left out of the Jacobian, as in IRLS).

    Parameters
    ----------
    residual : (M,) float
    delta : float
        Same unit as the residuals.

    Returns
    -------
    (M,) float64
    """
    size = np.maximum(np.abs(residual), np.finfo(np.float64).tiny)
    return np.sqrt(np.minimum(1.0, delta / size))


def project_rows(jacobian: NDArray[np.float64], directions: NDArray[np.float64]) -> NDArray:
    """``(P, K)`` rows ``d_p . J_p`` from ``(P, 3, K)`` point Jacobians and ``(P, 3)``
    directions."""
    return np.einsum("pi,pik->pk", directions, jacobian)
