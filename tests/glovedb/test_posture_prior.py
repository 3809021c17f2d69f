"""The shipped posture prior and its file."""

import numpy as np
import pytest

from glovedb.posture_prior import (
    fit_posture_prior,
    load_posture_prior,
    save_posture_prior,
    with_task_postures,
)
from glovedb.postures import load_named_postures


def test_the_shipped_prior_finds_named_postures_likely_and_wild_ones_unlikely():
    prior = load_posture_prior()
    named = [np.sum(prior.residual(p) ** 2) for p in load_named_postures().values()]
    wild = np.radians(np.array([60.0, -20.0, 60.0, 80.0] + [20.0, -20.0, 100.0, 0.0] * 4))
    assert max(named) < 20 < np.sum(prior.residual(wild) ** 2)


def test_prior_file_round_trip_and_bad_files(tmp_path):
    prior = fit_posture_prior(np.random.default_rng(0).normal(size=(100, 20)), floor_deg=5.0)
    path = save_posture_prior(tmp_path / "prior.npz", prior, settings="test")
    again = load_posture_prior(path)
    np.testing.assert_array_equal(again.whitening, prior.whitening)
    with pytest.raises(ValueError, match="no such posture prior"):
        load_posture_prior(tmp_path / "missing.npz")
    np.savez(tmp_path / "bad.npz", mean_rad=np.zeros(3))
    with pytest.raises(ValueError, match="not a posture prior"):
        load_posture_prior(tmp_path / "bad.npz")


def test_task_postures_make_a_max_mixture_with_the_natural_gaussian():
    prior = load_posture_prior()
    power = load_named_postures()["power"]
    task = with_task_postures(prior, [power, power], spread=0.5, offset=0.5)
    assert len(task.task_postures_rad) == 1  # repeated postures (a database's views) once
    natural = float(np.sum(prior.residual(power) ** 2))
    residual, whitening = task.whitened(power)
    assert residual @ residual == pytest.approx(0.5) and natural > 0.5
    np.testing.assert_allclose(whitening, prior.whitening / 0.5)
    # Far from the task posture the natural Gaussian decides, unchanged.
    far = load_named_postures()["point"]
    residual, whitening = task.whitened(far)
    np.testing.assert_allclose(residual, np.append(prior.residual(far), 0.0))
    np.testing.assert_array_equal(whitening, prior.whitening)
    # Along the way the cost is the cheaper component's, and continuous where it switches.
    path = [power + t * (far - power) for t in np.linspace(0.0, 1.0, 401)]
    costs = np.array([task.whitened(p)[0] @ task.whitened(p)[0] for p in path])
    natural_costs = np.array([np.sum(prior.residual(p) ** 2) for p in path])
    task_costs = np.array(
        [np.sum(((p - power) @ prior.whitening.T / 0.5) ** 2) + 0.5 for p in path]
    )
    np.testing.assert_allclose(costs, np.minimum(natural_costs, task_costs), rtol=1e-9)
    assert np.abs(np.diff(costs)).max() < 0.1
    untouched = prior.whitened(power)
    assert untouched[0][-1] == 0 and untouched[0][:-1] @ untouched[0][:-1] == pytest.approx(natural)
    with pytest.raises(ValueError, match="spread"):
        with_task_postures(prior, [power], spread=0.0, offset=0.5)
    with pytest.raises(ValueError, match="offset"):
        with_task_postures(prior, [power], spread=0.5, offset=-1.0)
    with pytest.raises(ValueError, match="postures_rad"):
        with_task_postures(prior, np.zeros((2, 19)), spread=0.5, offset=0.5)
