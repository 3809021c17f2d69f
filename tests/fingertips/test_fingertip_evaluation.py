"""Reading annotated depth folders and scoring detections."""

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from fingertips import Detection
from fingertips.evaluation import (
    fingertip_metrics,
    match_frame_2d,
    match_within,
    read_annotated_depth,
)
from fingertips.features import project

REAL_DEPTH = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "real_depth"
INTRINSICS = np.array([300.0, 310.0, 31.5, 23.5])
_TIP_NAN_XYZ = '{"xyz_m": [NaN, 0, 0.3], "uv_px": [3, 4]}'


def _write_folder(root: Path, records: list[dict], name: str) -> None:
    (root / "depth").mkdir(parents=True)
    fx, fy, cx, cy = INTRINSICS
    intrinsic = {"width": 64, "height": 48, "intrinsic_matrix": [fx, 0, 0, 0, fy, 0, cx, cy, 1]}
    (root / "intrinsic.json").write_text(json.dumps(intrinsic))
    (root / "meta.json").write_text(json.dumps({"depth_scale": 4000.0}))
    for record in records:
        depth = np.full((48, 64), 1200 + record["frame"], np.uint16)
        cv2.imwrite(str(root / "depth" / f"{record['frame']:06d}.png"), depth)
    (root / name).write_text("".join(json.dumps(r) + "\n" for r in records))


def _detections(points_m: np.ndarray, intrinsics: np.ndarray = INTRINSICS) -> list[Detection]:
    uv = project(points_m, intrinsics)
    return [
        Detection(u_px=q[0], v_px=q[1], x_m=p[0], y_m=p[1], z_m=p[2], confidence=5.0)
        for q, p in zip(uv.tolist(), points_m.tolist(), strict=True)
    ]


def test_reads_named_fingertips(tmp_path: Path) -> None:
    tips = {"thumb": {"xyz_m": [0.01, 0.02, 0.3], "uv_px": [41.5, 44.2]}}
    tips["little"] = {"xyz_m": [-0.03, -0.01, 0.31], "uv_px": [2.5, 13.5]}
    _write_folder(tmp_path, [{"frame": 3, "fingertips": tips}], "annotations.jsonl")
    data = read_annotated_depth(tmp_path)
    assert data.depth_m.shape == (1, 48, 64) and data.depth_m.dtype == np.float32
    np.testing.assert_allclose(data.depth_m[0, 0, 0], 1203 / 4000.0, rtol=1e-6)
    np.testing.assert_allclose(data.intrinsics, INTRINSICS)
    np.testing.assert_array_equal(data.frames, [3])
    np.testing.assert_allclose(data.tips_m[0, 0], [0.01, 0.02, 0.3])
    np.testing.assert_allclose(data.tips_px[0, 4], [2.5, 13.5])
    assert np.all(np.isnan(data.tips_m[0, 1:4]))


def test_reads_mediapipe_keypoints(tmp_path: Path) -> None:
    keypoints = np.arange(63, dtype=float).reshape(21, 3) / 100.0
    records = [
        {
            "frame": 0,
            "hand_visible": True,
            "keypoints_3d_m": keypoints.tolist(),
            "keypoints_2d_px": keypoints[:, :2].tolist(),
        },
        {"frame": 1, "hand_visible": False},
    ]
    _write_folder(tmp_path, records, "groundtruth.jsonl")
    data = read_annotated_depth(tmp_path, annotations="groundtruth.jsonl")
    np.testing.assert_allclose(data.tips_m[0], keypoints[[4, 8, 12, 16, 20]])
    assert np.all(np.isnan(data.tips_m[1]))
    assert data.keypoints_m is not None
    np.testing.assert_allclose(data.keypoints_m[0], keypoints)
    assert np.all(np.isnan(data.keypoints_m[1]))
    # Beside annotations.jsonl (a rendered folder), the keypoints come from groundtruth.jsonl.
    tips = {"thumb": {"xyz_m": [0.01, 0.02, 0.3], "uv_px": [41.5, 44.2]}}
    annotations = [{"frame": 1, "fingertips": {}}, {"frame": 0, "fingertips": tips}]
    (tmp_path / "annotations.jsonl").write_text("".join(json.dumps(r) + "\n" for r in annotations))
    both = read_annotated_depth(tmp_path)
    assert both.keypoints_m is not None
    assert np.all(np.isnan(both.keypoints_m[0]))
    np.testing.assert_allclose(both.keypoints_m[1], keypoints)
    (tmp_path / "groundtruth.jsonl").write_text('{"frame": 0, "keypoints_3d_m": [[0, 0, 1]]}\n')
    with pytest.raises(ValueError, match=r"groundtruth\.jsonl:1: keypoints_3d_m: expected"):
        read_annotated_depth(tmp_path)
    (tmp_path / "groundtruth.jsonl").unlink()
    assert read_annotated_depth(tmp_path).keypoints_m is None


def test_missing_annotations_raise(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"annotations\.jsonl"):
        read_annotated_depth(tmp_path)


def test_bad_annotation_lines_and_depth_sizes_raise_one_line_errors(tmp_path: Path) -> None:
    no_tips = {"fingertips": {}}
    _write_folder(tmp_path, [{"frame": 0} | no_tips, {"frame": 1} | no_tips], "annotations.jsonl")
    path = tmp_path / "annotations.jsonl"
    path.write_text('{"frame": 0, "fingertips": {}}\nnot json\n')
    with pytest.raises(ValueError, match=r"annotations\.jsonl:2: not an annotation record"):
        read_annotated_depth(tmp_path)
    path.write_text('{"frame": 0, "fingertips": [1, 2]}\n')
    with pytest.raises(ValueError, match=r"annotations\.jsonl:1: fingertips: expected an object"):
        read_annotated_depth(tmp_path)
    path.write_text("\n")
    with pytest.raises(ValueError, match="no annotated frames"):
        read_annotated_depth(tmp_path)
    path.write_text('{"frame": 0, "fingertips": {}}\n')
    (tmp_path / "meta.json").write_text('{"depth_scale": Infinity}')  # all depth would be 0
    with pytest.raises(ValueError, match="depth_scale must be positive and finite"):
        read_annotated_depth(tmp_path)
    (tmp_path / "meta.json").write_text('{"depth_scale": 4000}')
    path.write_bytes(b'{"frame": 0, "fingertips": {"\xff": null}}\n')
    with pytest.raises(ValueError, match=r"annotations\.jsonl: not UTF-8 text \(byte 29\)"):
        read_annotated_depth(tmp_path)
    # A depth image of another size than intrinsic.json says: the intrinsics would
    # put its points in the wrong place, so it is refused.
    path.write_text('{"frame": 0, "fingertips": {}}\n{"frame": 1, "fingertips": {}}\n')
    cv2.imwrite(str(tmp_path / "depth" / "000001.png"), np.full((24, 32), 1000, np.uint16))
    with pytest.raises(
        ValueError, match=r"000001\.png: 32x24 pixels, but intrinsic\.json gives 64x48"
    ):
        read_annotated_depth(tmp_path)


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ('{"frame": 0}', "expected fingertips, keypoints_3d_m"),
        ('{"frame": 0, "tips": {}}', "expected fingertips, keypoints_3d_m"),
        ('{"frame": 0, "fingertips": {"pinky": null}}', "unknown finger 'pinky'"),
        (f'{{"frame": 0, "fingertips": {{"thumb": {_TIP_NAN_XYZ}}}}}', "thumb.xyz_m: contains NaN"),
        ('{"frame": 0, "fingertips": {"ring": {"xyz_m": [0, 0, 0.3]}}}', "'uv_px'"),
        ('{"frame": 0.9, "fingertips": {}}', "frame: expected a whole number"),
        ('{"frame": 0, "fingertips": {}}\n{"frame": 0, "fingertips": {}}', "annotated twice"),
        ('{"frame": 0, "keypoints_3d_m": [[0, 0, 0.3]], "keypoints_2d_px": []}', "shape"),
    ],
)
def test_annotations_that_would_change_the_scores_are_refused(
    tmp_path: Path, line: str, message: str
) -> None:
    """Unknown names, half-given tips and repeated frames: an error, not dropped tips."""
    _write_folder(tmp_path, [{"frame": 0, "fingertips": {}}], "annotations.jsonl")
    (tmp_path / "annotations.jsonl").write_text(line + "\n")
    with pytest.raises(ValueError, match=r"annotations\.jsonl:\d: .*" + message):
        read_annotated_depth(tmp_path)


def test_metrics_refuse_tips_with_only_one_position() -> None:
    tips = np.zeros((1, 5, 3)) + [0.0, 0.0, 0.3]
    tips_px = project(tips, INTRINSICS)
    tips[0, 2] = np.nan
    with pytest.raises(ValueError, match="both positions or neither"):
        fingertip_metrics([[]], tips, tips_px)


def test_metrics_known_values() -> None:
    tips = np.full((2, 5, 3), np.nan)
    tips[0, :3] = [[0.0, 0.0, 0.3], [0.02, 0.0, 0.3], [0.04, 0.0, 0.3]]
    tips[1, 0] = [0.0, 0.01, 0.4]
    tips_px = project(tips, INTRINSICS)
    frame0 = np.array([[0.005, 0.0, 0.3], [0.04, 0.0, 0.31], [0.2, 0.0, 0.3]])
    detections = [_detections(frame0), _detections(np.zeros((0, 3)))]
    metrics = fingertip_metrics(detections, tips, tips_px)
    assert (metrics.frames, metrics.detections, metrics.annotated_tips) == (2, 3, 4)
    np.testing.assert_allclose(metrics.precision_15mm, 2 / 3)
    np.testing.assert_allclose(metrics.recall_15mm, 2 / 4)
    np.testing.assert_allclose(metrics.error_3d_mm, (5.0 + 10.0) / 2, atol=1e-9)
    # 5 mm sideways at 0.3 m is 5 px; 10 mm deeper at (0.04, 0) moves the image 1.29 px.
    expected_px = (300 * 0.005 / 0.3 + 300 * 0.04 * (1 / 0.3 - 1 / 0.31)) / 2
    np.testing.assert_allclose(metrics.error_2d_px, expected_px, atol=1e-9)
    np.testing.assert_allclose(metrics.recall_10px, 2 / 4)
    assert math.isnan(metrics.ms_per_frame)


def test_match_within_prefers_more_pairs() -> None:
    # Greedy nearest-first would take (0, 0) and leave row 1 unmatched.
    distance = np.array([[1.0, 2.0], [1.5, 9.0]])
    rows, cols = match_within(distance, gate=2.5)
    assert sorted(zip(rows.tolist(), cols.tolist(), strict=True)) == [(0, 1), (1, 0)]


def test_match_frame_2d_marks_found_tips_and_matched_detections() -> None:
    tips = np.full((5, 2), np.nan)
    tips[[0, 2, 3]] = [[10.0, 10.0], [50.0, 10.0], [58.0, 10.0]]
    # Detection 0 is 3 px from tip 0; detection 1 lies between tips 2 and 3 (4 px from
    # each) and can only take one; detection 2 is 30 px from everything; the NaN tips
    # 1 and 4 are never found.
    uv = np.array([[13.0, 10.0], [54.0, 10.0], [30.0, 40.0]])
    found, matched = match_frame_2d(uv, tips, gate_px=10.0)
    assert matched.tolist() == [True, True, False]
    assert found[[0, 1, 4]].tolist() == [True, False, False]
    assert found[2] != found[3]
    assert found.sum() == matched.sum() == 2
    found, matched = match_frame_2d(np.zeros((0, 2)), tips)
    assert not found.any() and matched.shape == (0,)


@pytest.mark.skipif(not REAL_DEPTH.is_dir(), reason="shared/data/real_depth not present")
def test_real_frames_and_annotations_agree() -> None:
    data = read_annotated_depth(REAL_DEPTH / "hmodel_andrii")
    assert data.depth_m.shape == (11, 240, 320)
    assert np.all(np.isfinite(data.tips_m))
    np.testing.assert_allclose(project(data.tips_m, data.intrinsics), data.tips_px, atol=0.05)
    hand = data.depth_m[(data.depth_m > 0.2) & (data.depth_m < 0.4)]
    assert hand.size > 11 * 2000
    perfect = [_detections(tips, data.intrinsics) for tips in data.tips_m]
    metrics = fingertip_metrics(perfect, data.tips_m, data.tips_px)
    assert metrics.precision_15mm == metrics.recall_15mm == metrics.recall_10px == 1.0
    assert metrics.error_2d_px < 0.05
