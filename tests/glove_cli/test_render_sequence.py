"""``glove render-sequence``: one-line errors for bad input, and the folder it writes."""

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from glove_cli.main import main
from glovedb.camera import load_intrinsics
from tracker.evaluation import read_groundtruth


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--trajectory", "tr9"], "unknown trajectory 'tr9'; known: free_fingers, tr1_pinch"),
        (["--trajectory", "no/such/file.json"], "cannot read the trajectory"),
        (["--trajectory", "tr1", "--camera", "kinect2"], "unknown camera 'kinect2'"),
        (["--trajectory", "tr1", "--background", "forest"], "background: expected one of"),
        (["--trajectory", "tr1", "--noise", "film"], "invalid choice: 'film'"),
        (["--trajectory", "tr1", "--frames", "0"], "frames: expected at least 1"),
        (["--trajectory", "tr1", "--frames", "100000000"], "a sequence holds at most 1000000"),
    ],
)
def test_bad_input_exits_2_with_one_line(capsys, tmp_path, args, message):
    assert main(["render-sequence", "--out", str(tmp_path / "seq"), *args]) == 2
    err = capsys.readouterr().err
    assert message in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "seq").exists()


def test_malformed_trajectory_file_and_busy_folder_exit_2(capsys, tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('{"fps": 30, "keyframes": [{"time_s": 0}]}')
    assert main(["render-sequence", "--trajectory", str(bad), "--out", str(tmp_path / "a")]) == 2
    assert "keyframe 0: missing 'posture'" in capsys.readouterr().err
    bad.write_text("[1, 2]")
    assert main(["render-sequence", "--trajectory", str(bad), "--out", str(tmp_path / "a")]) == 2
    assert "bad.json: expected a trajectory object" in capsys.readouterr().err
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "x.txt").write_text("x")
    assert main(["render-sequence", "--trajectory", "tr1", "--out", str(busy)]) == 2
    assert "exists and is not an empty folder" in capsys.readouterr().err
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    for out in (a_file, a_file / "seq"):  # a file, and a folder under a file
        assert main(["render-sequence", "--trajectory", "tr1", "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err.startswith("glove: error:") and len(err.strip().splitlines()) == 1


@pytest.mark.gl
def test_writes_an_rgbd_folder_with_ground_truth(tmp_path):
    out = tmp_path / "seq"
    command = [sys.executable, "-m", "glove_cli", "render-sequence", "--trajectory", "tr3",
               "--frames", "3", "--noise", "kinect_v1", "--background", "clutter",
               "--out", str(out)]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert "3 frames" in result.stdout
    camera = load_intrinsics(out / "intrinsic.json")
    assert (camera.width, camera.height, camera.fx) == (640, 480, 525.0)
    names = [f"{k:06d}.png" for k in range(3)]
    assert sorted(p.name for p in (out / "color").iterdir()) == names
    assert sorted(p.name for p in (out / "depth").iterdir()) == names
    for name in names:
        color = cv2.imread(str(out / "color" / name), cv2.IMREAD_UNCHANGED)
        depth = cv2.imread(str(out / "depth" / name), cv2.IMREAD_UNCHANGED)
        assert color is not None and depth is not None
        assert color.shape == (480, 640, 3) and color.dtype == np.uint8
        assert depth.shape == (480, 640) and depth.dtype == np.uint16
        assert 300 < np.median(depth[depth > 0]) < 2500  # millimetres
    meta = json.loads((out / "meta.json").read_text())
    assert meta["depth_scale"] == 1000.0 and meta["fps"] == 30 and meta["frames"] == 3
    assert meta["version"] and meta["settings"]["noise"] == "kinect_v1"
    records = [json.loads(line) for line in (out / "groundtruth.jsonl").read_text().splitlines()]
    assert [r["frame"] for r in records] == [0, 1, 2]
    assert set(records[0]) == {
        "frame", "hand_visible", "posture_rad", "rotation", "translation_m",
        "keypoints_3d_m", "keypoints_2d_px",
    }  # fmt: skip
    truth = read_groundtruth(out / "groundtruth.jsonl")
    assert truth.hand_visible.all() and truth.keypoints_2d_px.shape == (3, 21, 2)
