"""The shipped posture prior and its file."""

import numpy as np
import pytest

from glovedb.posture_prior import fit_posture_prior, load_posture_prior, save_posture_prior
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
