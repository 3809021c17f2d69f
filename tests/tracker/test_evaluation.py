"""Scoring against ground truth: metrics on hand-made cases, file reading, CSV, plot."""

import json
import subprocess
import sys

import numpy as np
import pytest

from glovedb.rotations import axis_angle_to_matrix
from tracker.evaluation import (
    GroundTruth,
    TrackedPoses,
    error_plot,
    evaluate,
    keyframe_indices,
    keypoint_error_px,
    position_error_mm,
    posture_error_deg,
    read_groundtruth,
    read_poses,
    rotation_error_deg,
    score,
    summarize,
    write_errors_csv,
)

RNG = np.random.default_rng(7)


def random_rotations(count: int) -> np.ndarray:
    axes = RNG.normal(size=(count, 3))
    return axis_angle_to_matrix(axes / np.linalg.norm(axes, axis=1, keepdims=True),
                                RNG.uniform(0, np.pi, count))  # fmt: skip


def truth_records(count: int = 6) -> list[dict]:
    rotations = random_rotations(count)
    return [
        {
            "frame": k,
            "hand_visible": k != count - 1,
            "posture_rad": RNG.uniform(0, 1, 20).tolist(),
            "rotation": rotations[k].tolist(),
            "translation_m": [0.01 * k, 0.0, 0.6],
            "keypoints_3d_m": RNG.uniform(0, 1, (21, 3)).tolist(),
            "keypoints_2d_px": RNG.uniform(0, 640, (21, 2)).tolist(),
        }
        for k in range(count)
    ]


def pose_record(truth: dict, found: bool = True) -> dict:
    if not found:
        return {"frame": truth["frame"], "hand_found": False}
    keys = ("posture_rad", "rotation", "translation_m", "keypoints_3d_m", "keypoints_2d_px")
    return {"frame": truth["frame"], "hand_found": True, **{key: truth[key] for key in keys}}


def write_jsonl(path, records) -> None:
    path.write_text("".join(json.dumps(record) + "\n" for record in records))


def test_identical_estimates_score_zero():
    postures = RNG.uniform(0, 1, (4, 20))
    rotations = random_rotations(4)
    np.testing.assert_allclose(posture_error_deg(postures, postures), 0.0, atol=1e-12)
    np.testing.assert_allclose(rotation_error_deg(rotations, rotations), 0.0, atol=1e-5)
    points = RNG.uniform(size=(4, 3))
    np.testing.assert_allclose(position_error_mm(points, points), 0.0, atol=1e-12)
    pixels = RNG.uniform(size=(4, 21, 2))
    np.testing.assert_allclose(keypoint_error_px(pixels, pixels), 0.0, atol=1e-12)


def test_known_offsets_give_their_size():
    truth = random_rotations(5)
    axes = RNG.normal(size=(5, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.array([1.0, 10.0, 45.0, 90.0, 170.0])
    # The offset may sit on either side: both R_true @ dR and dR @ R_true are that far.
    offset = axis_angle_to_matrix(axes, np.radians(angles))
    np.testing.assert_allclose(rotation_error_deg(truth @ offset, truth), angles, atol=1e-6)
    np.testing.assert_allclose(rotation_error_deg(offset @ truth, truth), angles, atol=1e-6)

    wrist = RNG.uniform(size=(3, 3))
    np.testing.assert_allclose(position_error_mm(wrist + [0.003, 0.004, 0.0], wrist), 5.0)

    postures = RNG.uniform(size=(2, 20))
    shifted = postures.copy()
    shifted[:, :5] += np.radians(2.0)
    np.testing.assert_allclose(posture_error_deg(shifted, postures), 0.5)

    pixels = RNG.uniform(size=(2, 21, 2))
    np.testing.assert_allclose(keypoint_error_px(pixels + [3.0, -4.0], pixels), 5.0)


def test_metric_shapes_are_checked():
    with pytest.raises(ValueError, match="estimate_rad"):
        posture_error_deg(np.zeros((3, 19)), np.zeros((3, 19)))
    with pytest.raises(ValueError, match="truth"):
        rotation_error_deg(np.zeros((2, 3, 3)), np.zeros((3, 3, 3)))


def test_summary_of_values_and_of_nothing():
    summary = summarize([1.0, np.nan, 3.0, 8.0])
    assert (summary.mean, summary.median, summary.max) == (4.0, 3.0, 8.0)
    assert summarize([np.nan]).as_dict() == {"mean": None, "median": None, "max": None}


def test_missed_frames_are_counted_apart_and_excluded(tmp_path):
    truth = truth_records(6)  # frame 5: hand not visible
    poses = [pose_record(record) for record in truth]
    poses[1] = pose_record(truth[1], found=False)  # missed
    poses[2]["translation_m"] = (np.array(truth[2]["translation_m"]) + [0.0, 0.0, 0.02]).tolist()
    write_jsonl(tmp_path / "groundtruth.jsonl", truth)
    write_jsonl(tmp_path / "poses.jsonl", poses)
    result = evaluate(tmp_path / "poses.jsonl", tmp_path / "groundtruth.jsonl")
    scores = result.as_dict()
    assert scores["frames"] == 6 and scores["visible_frames"] == 5
    assert scores["missed_frames"] == 1 and scores["false_detections"] == 1
    assert scores["scored_frames"] == 4
    # Frames 0, 2, 3, 4 are scored; only frame 2 is off, by 20 mm.
    assert scores["position_error_mm"]["max"] == pytest.approx(20.0)
    assert scores["position_error_mm"]["mean"] == pytest.approx(5.0)
    assert scores["position_error_mm"]["median"] == pytest.approx(0.0, abs=1e-9)
    for name in ("posture_error_deg", "rotation_error_deg", "keypoint_error_px"):
        assert scores[name]["max"] == pytest.approx(0.0, abs=1e-4)
    assert np.isnan(result.per_frame.position_error_mm[[1, 5]]).all()
    json.dumps(scores, allow_nan=False)


def test_partial_poses_need_require_all_false():
    records = truth_records(4)
    truth = read_records_as_truth(records)
    poses = TrackedPoses(
        truth.frames[:2], np.ones(2, bool), truth.posture_rad[:2], truth.rotation[:2],
        truth.translation_m[:2], truth.keypoints_2d_px[:2],
    )  # fmt: skip
    with pytest.raises(ValueError, match="cover 2 of 4 frames"):
        score(truth, poses)
    assert score(truth, poses, require_all=False).frames == 2


def read_records_as_truth(records: list[dict]) -> GroundTruth:
    return GroundTruth(
        np.array([r["frame"] for r in records]),
        np.array([r["hand_visible"] for r in records]),
        *(np.array([r[key] for r in records], float) for key in
          ("posture_rad", "rotation", "translation_m", "keypoints_3d_m", "keypoints_2d_px")),
    )  # fmt: skip


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("{not json", "not valid JSON"),
        ("[1, 2]", "expected a JSON object"),
        ('{"frame": 2, "hand_found": false}', "frame 2 follows frame 0"),
        ('{"frame": "1", "hand_found": false}', "'frame' a non-negative integer"),
        ('{"frame": 1, "hand_found": "yes"}', "'hand_found' true or false"),
        ('{"frame": 1, "hand_found": true}', "missing 'posture_rad'"),
    ],
)
def test_malformed_poses_lines_raise_one_line(tmp_path, line, message):
    path = tmp_path / "poses.jsonl"
    path.write_text('{"frame": 0, "hand_found": false}\n' + line + "\n")
    with pytest.raises(ValueError, match=message) as error:
        read_poses(path)
    assert f"{path}:2" in str(error.value) and "\n" not in str(error.value)


def test_malformed_groundtruth_shapes_and_missing_file(tmp_path):
    record = truth_records(1)[0]
    record["keypoints_2d_px"] = record["keypoints_2d_px"][:20]
    path = tmp_path / "groundtruth.jsonl"
    write_jsonl(path, [record])
    with pytest.raises(ValueError, match=r"groundtruth.jsonl:1: keypoints_2d_px: expected shape"):
        read_groundtruth(path)
    with pytest.raises(ValueError, match="cannot read"):
        read_groundtruth(tmp_path / "missing.jsonl")
    (tmp_path / "empty.jsonl").write_text("\n")
    with pytest.raises(ValueError, match="no frames"):
        read_poses(tmp_path / "empty.jsonl")


def test_per_frame_csv_and_plot(tmp_path):
    truth = truth_records(6)
    poses = [pose_record(record) for record in truth]
    poses[3] = pose_record(truth[3], found=False)
    write_jsonl(tmp_path / "groundtruth.jsonl", truth)
    write_jsonl(tmp_path / "poses.jsonl", poses)
    errors = evaluate(tmp_path / "poses.jsonl", tmp_path / "groundtruth.jsonl").per_frame
    lines = write_errors_csv(errors, tmp_path / "errors.csv").read_text().splitlines()
    assert lines[0].startswith("frame,hand_visible,hand_found,missed,posture_error_deg")
    assert len(lines) == 7 and lines[4] == "3,1,0,1,,,,"
    thumbnails = {k: np.full((60, 80, 3), 40 * k, np.uint8) for k in keyframe_indices(6, 3)}
    picture = error_plot(errors, fps=30.0, thumbnails=thumbnails, title="test")
    assert picture.dtype == np.uint8 and picture.ndim == 3 and picture.shape[1] == 1200
    plain = error_plot(errors, fps=30.0)
    assert plain.shape[0] < picture.shape[0]
    with pytest.raises(ValueError, match="fps"):
        error_plot(errors, fps=0.0)


def test_plot_of_one_missed_frame(tmp_path):
    """A one-frame sequence whose hand was missed still gets its picture, band and all."""
    truth = truth_records(2)[:1]  # the last record of truth_records has no visible hand
    write_jsonl(tmp_path / "groundtruth.jsonl", truth)
    write_jsonl(tmp_path / "poses.jsonl", [pose_record(truth[0], found=False)])
    errors = evaluate(tmp_path / "poses.jsonl", tmp_path / "groundtruth.jsonl").per_frame
    picture = error_plot(errors, fps=30.0, thumbnails={0: np.zeros((60, 80, 3), np.uint8)})
    missed_shade = (250, 205, 205)
    first_panel = picture[200:350, 80:1170]  # below the thumbnail strip
    assert np.all(first_panel == missed_shade, axis=2).mean() > 0.4


def test_keyframe_indices_include_both_ends():
    assert keyframe_indices(100, 5) == [0, 25, 50, 74, 99]
    assert keyframe_indices(3, 6) == [0, 1, 2]
    assert keyframe_indices(0, 4) == []


def test_tracker_evaluation_imports_no_builder_pyrender_or_matplotlib():
    code = (
        "import sys, tracker.evaluation; "
        "bad = [m for m in ('builder', 'pyrender', 'matplotlib') if m in sys.modules]; "
        "sys.exit(1 if bad else 0)"
    )
    assert subprocess.run([sys.executable, "-c", code], timeout=120).returncode == 0
