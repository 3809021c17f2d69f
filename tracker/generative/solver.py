"""Levenberg-Marquardt for the generative fit's sum of squares.

The problem is given by two functions: ``evaluate(state)`` returns the stacked
residuals ``r (M,)`` at a state and a function that gives their Jacobian ``J (M, K)``
there, ``advance(state, delta)`` applies a step ``delta (K,)``. Each iteration solves::

    (J^T J + lambda * (diag(J^T J) + eps)) delta = -J^T r

and keeps the step only if the energy ``r^T r`` at the new state (residuals and
correspondences evaluated afresh) is lower; lambda shrinks after a kept step and
grows after a refused one (Marquardt's scaling makes it unit-free). A refused step
costs one evaluation of the residuals, a kept one is the next iteration's
linearisation: the Jacobian is asked for only there, not at refused steps nor at the
state the solver ends on.

:func:`levenberg_marquardt_steps` is the solver as a generator that yields after each
iteration, so that a caller can spread one solve over several calls (the tracker's
deferred lookups run one iteration per frame, :mod:`tracker.background`);
:func:`run_to_end` and :func:`in_one_call` run such a generator in one call.
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from dataclasses import dataclass
from typing import Generic, ParamSpec, TypeVar

import numpy as np
from numpy.typing import NDArray

State = TypeVar("State")
Result = TypeVar("Result")
Params = ParamSpec("Params")
Jacobian = Callable[[], NDArray[np.float64]]
"""The function that gives the Jacobian ``J (M, K)`` of residuals at a state."""
Evaluation = tuple[NDArray[np.float64], Jacobian]
"""The residuals ``r (M,)`` at a state and their :data:`Jacobian` function."""

_EPS = 1e-9
_SHRINK, _GROW = 0.3, 5.0


@dataclass(frozen=True)
class SolverResult(Generic[State]):
    """Outcome of :func:`levenberg_marquardt_steps`.

    Attributes
    ----------
    state : State
        The lowest-energy state found.
    energy : float
        Its ``r^T r``.
    start_energy : float
    iterations : int
        Linear solves done.
    converged : bool
        Whether the last kept step changed the energy by less than the tolerance.
    """

    state: State
    energy: float
    start_energy: float
    iterations: int
    converged: bool


def levenberg_marquardt_steps(
    evaluate: Callable[[State], Evaluation],
    advance: Callable[[State, NDArray[np.float64]], State],
    start: State,
    *,
    iterations: int,
    damping: float = 1e-3,
    tolerance: float = 1e-4,
) -> Generator[None, None, SolverResult[State]]:
    """Minimise ``r(state)^T r(state)`` (module docstring), yielding after every
    iteration but the last.

    Parameters
    ----------
    evaluate : callable
        ``state -> (r (M,), jacobian)``, ``jacobian() -> J (M, K)`` (called at most
        once per evaluation, only where the solver linearises).
    advance : callable
        ``(state, delta (K,)) -> state``.
    start : State
    iterations : int
        Most linear solves.
    damping : float
        Initial lambda.
    tolerance : float
        Relative energy change under which a kept step ends the iterations.

    Returns
    -------
    SolverResult
        What the generator returns.
    """
    state = start
    residual, jacobian_at_state = evaluate(state)
    energy = start_energy = float(residual @ residual)
    converged = False
    done = 0
    normal = gradient = np.zeros(0)
    linearised = False  # normal and gradient are the state's
    for iteration in range(1, iterations + 1):
        if iteration > 1:
            yield
        done = iteration
        if len(residual) == 0:
            break
        if not linearised:
            jacobian = jacobian_at_state()
            normal = jacobian.T @ jacobian
            gradient = jacobian.T @ residual
            linearised = True
        damped = normal + damping * (np.diag(np.diag(normal)) + _EPS * np.eye(len(normal)))
        try:
            delta = np.asarray(-np.linalg.solve(damped, gradient), dtype=np.float64)
        except np.linalg.LinAlgError:
            damping *= _GROW
            continue
        candidate = advance(state, delta)
        new_residual, new_jacobian = evaluate(candidate)
        new_energy = float(new_residual @ new_residual)
        if new_energy < energy:
            converged = energy - new_energy < tolerance * energy
            state, residual, energy = candidate, new_residual, new_energy
            jacobian_at_state, linearised = new_jacobian, False
            damping *= _SHRINK
            if converged:
                break
        else:
            damping *= _GROW
    return SolverResult(state, energy, start_energy, done, converged)


def run_to_end(steps: Generator[None, None, Result]) -> Result:
    """Run a stepped computation (a generator that yields between its steps) to its end
    and return what it returns."""
    while True:
        try:
            next(steps)
        except StopIteration as finished:
            return finished.value


def in_one_call(
    stepped: Callable[Params, Generator[None, None, Result]], name: str
) -> Callable[Params, Result]:
    """The function ``name`` that runs ``stepped``'s generator to its end
    (:func:`run_to_end`): same parameters, returns what the generator returns."""

    def run(*args: Params.args, **kwargs: Params.kwargs) -> Result:
        return run_to_end(stepped(*args, **kwargs))

    run.__name__ = run.__qualname__ = name
    run.__module__ = stepped.__module__
    run.__doc__ = f":func:`{stepped.__name__}` run to its end in one call (same parameters)."
    return run


def eliminated_information(
    normal: NDArray[np.float64], eliminated: int, *, ridge: float
) -> NDArray[np.float64]:
    """Information about the unknowns after the first ``eliminated`` ones, those
    eliminated: the Schur complement ``C - B^T (A + ridge I)^-1 B`` of the normal
    matrix ``[[A, B], [B^T, C]]`` (what the data says about the rest when the first
    unknowns may take whatever value explains it best), symmetrised.

    Parameters
    ----------
    normal : (K, K) float
        ``J^T J``.
    eliminated : int
        How many leading unknowns to eliminate.
    ridge : float
        Added to the eliminated block's diagonal, so that unobserved unknowns do not
        make it singular.

    Returns
    -------
    (K - eliminated, K - eliminated) float64
    """
    block = normal[:eliminated, :eliminated] + ridge * np.eye(eliminated)
    cross = normal[:eliminated, eliminated:]
    information = normal[eliminated:, eliminated:] - cross.T @ np.linalg.solve(block, cross)
    return np.asarray(0.5 * (information + information.T), dtype=np.float64)
