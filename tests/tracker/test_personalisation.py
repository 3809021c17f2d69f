"""The tracker learns a user's hand from the first frames of a rendered sequence, and
keeps a hand that an object partly hides."""

import json
import sys

import numpy as np
import pytest

from builder.sequence import SequenceSettings, render_sequence
from glovedb.proportions import HandProportions, proportioned_mesh
from tracker.evaluation import evaluate
from tracker.generative.fit import fit_frame
from tracker.pipeline import Tracker, TrackerSettings
from tracker.run import HAND_FILE, POSES_FILE, track_source
from tracker.sources import open_source

pytestmark = pytest.mark.gl


def _track(database, sequence, out, settings=None):
    with Tracker(database, settings=settings) as tracker:
        track_source(open_source(sequence), tracker, out, overlay=False, bvh=False)
        # The mesh and skeleton follow the proportions (the mesh re-rested when asked for).
        expected = proportioned_mesh(tracker.model_mesh, tracker.proportions)
        np.testing.assert_array_equal(tracker.mesh.rest_vertices_m, expected.rest_vertices_m)
        np.testing.assert_array_equal(tracker.skeleton.offsets_m, expected.skeleton.offsets_m)
        np.testing.assert_array_equal(tracker.skeleton.lengths_m, expected.skeleton.lengths_m)
        # The fit's samples, which the tracker keeps from its last calibrating frame,
        # are the model's samples re-rested with the proportions.
        samples = proportioned_mesh(tracker.samples.model, tracker.proportions)
        np.testing.assert_array_equal(tracker.samples.mesh.rest_vertices_m, samples.rest_vertices_m)
    return evaluate(out / POSES_FILE, sequence / "groundtruth.jsonl")


def test_the_tracker_learns_a_smaller_hand(open_pinch_power_database, tmp_path, monkeypatch):
    import tracker.pipeline

    sequence = tmp_path / "small"
    settings = SequenceSettings(trajectory="tr1", frames=45, noise="kinect_v1", hand_length_m=0.17)
    render_sequence(settings, sequence)
    allowed = {True: set(), False: set()}  # iterations allowed, by estimating or not

    def recording(*args, **kwargs):
        if sys._getframe(1).f_code.co_name != "_warm_up":  # the frames' fits only
            allowed[kwargs.get("estimate_proportions", False)].add(kwargs["settings"].iterations)
        return fit_frame(*args, **kwargs)

    monkeypatch.setattr(tracker.pipeline, "fit_frame", recording)
    result = _track(open_pinch_power_database, sequence, tmp_path / "run")
    defaults = TrackerSettings()
    assert allowed == {True: {defaults.calibration_iterations}, False: {defaults.fit.iterations}}
    hand = json.loads((tmp_path / "run" / HAND_FILE).read_text())
    assert hand["complete"] and hand["source"] == "estimated online"
    assert hand["length_scale"] == pytest.approx(0.17 / 0.19, abs=0.015)
    late = result.per_frame.keypoint_error_px[30:]
    assert result.missed_frames == 0 and np.nanmean(late) < 3.0
    # Given back, the proportions are used from the first frame and not estimated.
    given = HandProportions(0.17 / 0.19)
    again = _track(
        open_pinch_power_database, sequence, tmp_path / "again",
        TrackerSettings(hand_proportions=given),
    )  # fmt: skip
    assert json.loads((tmp_path / "again" / HAND_FILE).read_text())["source"] == "given"
    assert np.nanmean(again.per_frame.keypoint_error_px[:30]) < 3.0


def test_a_ball_in_front_never_yields_a_wrong_pose_reported_as_found(
    open_pinch_power_database, tmp_path
):
    sequence = tmp_path / "ball"
    settings = SequenceSettings(
        trajectory="tr1", frames=90, noise="kinect_v1", occluder_radius_m=0.04,
        occluder_from_m=(-0.15, 0.04, -0.06), occluder_to_m=(0.15, 0.04, -0.06),
    )  # fmt: skip
    render_sequence(settings, sequence)
    hidden = [
        json.loads(line)["occluded_fraction"] for line in open(sequence / "groundtruth.jsonl")
    ]
    assert max(hidden) > 0.3  # the case must hide a large part of the hand
    result = _track(open_pinch_power_database, sequence, tmp_path / "run")
    found = result.per_frame.hand_found
    assert found.mean() > 0.9
    assert np.all(result.per_frame.keypoint_error_px[found] < 20.0)
