"""Write the shipped posture prior, configs/hand/posture_prior.npz.

The generative fit's posture prior (:mod:`glovedb.posture_prior`) is a Gaussian fitted
to natural postures the project generates: the ten named postures and 20,000 synergy
postures around them, drawn as the natural1000 database draws them
(``configs/db/natural1000.toml``), with a floor of 12 degrees on every joint.
Deterministic: running it again writes the same numbers.

Usage::

    python scripts/make_posture_prior.py [--out configs/hand/posture_prior.npz]
"""

from __future__ import annotations

import argparse

import numpy as np

from builder.sampling import synergy_postures
from glovedb.posture_prior import fit_posture_prior, save_posture_prior
from glovedb.postures import load_named_postures

COUNT, SEED, SYNERGIES, SPREAD, NOISE_DEG, FLOOR_DEG = 20_000, 1000, 5, 1.0, 5.0, 12.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="configs/hand/posture_prior.npz")
    args = parser.parse_args()
    postures = load_named_postures()
    named = np.array(list(postures.values()))
    natural = synergy_postures(
        COUNT, named, synergies=SYNERGIES, spread=SPREAD, noise_deg=NOISE_DEG, seed=SEED
    )
    prior = fit_posture_prior(np.vstack([named, natural]), floor_deg=FLOOR_DEG)
    settings = (
        f"named postures {list(postures)} + synergy_postures(count={COUNT}, "
        f"synergies={SYNERGIES}, spread={SPREAD}, noise_deg={NOISE_DEG}, seed={SEED}); "
        f"floor_deg={FLOOR_DEG}"
    )
    print(f"wrote {save_posture_prior(args.out, prior, settings=settings)}")


if __name__ == "__main__":
    main()
