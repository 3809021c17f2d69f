"""Is the fit's energy or its search what is wrong? The fit's energy at the true pose
against the tracked pose, frame by frame, and the signed error of every joint.

    .venv/bin/python scripts/energy_at_truth.py SEQUENCE --db DB [--every N] [--json]

SEQUENCE is a folder rendered by ``glove render-sequence`` (its ``groundtruth.jsonl``
gives the true poses). It is tracked with the default settings but the model's own
hand proportions (the renderer's hand unless ``--hand-length`` or ``--finger-length``
were given) and without the pose filter, so that the tracked pose is the fit's
solution; then every ``N``-th frame's energy terms (``tracker.generative.fit.
frame_energy``, the reference and temporal terms left out: they depend on the start)
are evaluated at both poses. Where the truth has the lower energy the optimiser
stopped short of it (a better start or search would help); where the tracked pose has
the lower energy the energy itself prefers a wrong pose (a term, the prior or the
model is biased). The second table gives the mean signed error of each joint
(tracked minus true, degrees): biases that one term causes show as a sign that holds.

On Tr3 rendered without noise (``glove render-sequence --trajectory tr3 --seed 1``)
with DB_open+pinch+power the tracked pose had the lower energy in 79 % of the frames:
the silhouette term's depth test at a curled finger's contour and, more, the posture
prior where the data cannot tell two thumb postures apart (issue 21's note of
2026-11-26).
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from glovedb.hand_model import JOINT_NAMES
from glovedb.proportions import HandProportions
from tracker.evaluation import read_groundtruth, read_poses
from tracker.generative.fit import frame_energy
from tracker.generative.model import HandPose
from tracker.pipeline import Tracker, TrackerSettings
from tracker.run import POSES_FILE, track_source
from tracker.sources import open_source


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequence", type=Path, help="folder from glove render-sequence")
    parser.add_argument("--db", required=True, type=Path, help="posture database (.h5)")
    parser.add_argument("--every", type=int, default=4, help="every N-th frame (default 4)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args()
    truth = read_groundtruth(args.sequence / "groundtruth.jsonl")
    settings = TrackerSettings(hand_proportions=HandProportions(), smoothing=None)
    with Tracker(args.db, settings=settings) as tracker, tempfile.TemporaryDirectory() as out:
        track_source(open_source(args.sequence), tracker, Path(out), overlay=False, bvh=False)
        tracked = read_poses(Path(out) / POSES_FILE)
        rows = []
        for index, frame in enumerate(open_source(args.sequence)):
            if index % args.every or not (truth.hand_visible[index] and tracked.hand_found[index]):
                continue
            observation = tracker.prepare(frame).observation
            if observation is None:
                continue
            energies = []
            for poses in (truth, tracked):
                pose = HandPose.of(
                    poses.posture_rad[index], poses.rotation[index], poses.translation_m[index]
                )
                terms, _, _ = frame_energy(
                    tracker.samples, pose, observation, settings=settings.fit, prior=tracker.prior
                )
                energies.append({term.name: term.energy for term in terms})
            error = np.degrees(np.abs(tracked.posture_rad[index] - truth.posture_rad[index]))
            rows.append({"frame": index, "error_deg": float(error.mean()),
                         "truth": energies[0], "tracked": energies[1]})  # fmt: skip
    found = tracked.hand_found & truth.hand_visible
    signed = np.degrees(tracked.posture_rad[found] - truth.posture_rad[found]).mean(axis=0)
    lower = [sum(r["truth"].values()) < sum(r["tracked"].values()) for r in rows]
    summary = {
        "frames": len(rows),
        "truth_lower_share": float(np.mean(lower)) if rows else float("nan"),
        "mean_terms_truth": _mean_terms(rows, "truth"),
        "mean_terms_tracked": _mean_terms(rows, "tracked"),
        "signed_error_deg": dict(zip(JOINT_NAMES, np.round(signed, 2).tolist(), strict=True)),
        "per_frame": rows,
    }
    if args.json:
        print(json.dumps(summary))
        return
    print(f"{args.sequence}: {len(rows)} frames compared (every {args.every}-th)")
    print(f"  the truth has the lower energy in {summary['truth_lower_share']:.0%} of them")
    print("  term          at truth   tracked   (mean over the frames)")
    for name, value in summary["mean_terms_truth"].items():
        print(f"  {name:12s} {value:9.4f} {summary['mean_terms_tracked'][name]:9.4f}")
    print("  joint               signed error (deg, tracked - true)")
    for name, value in summary["signed_error_deg"].items():
        print(f"  {name:18s} {value:+6.2f}")


def _mean_terms(rows: list[dict], which: str) -> dict[str, float]:
    """Mean of every energy term over the frames, at the truth or the tracked pose."""
    names = rows[0][which].keys() if rows else ()
    return {name: float(np.mean([r[which][name] for r in rows])) for name in names}


if __name__ == "__main__":
    main()
