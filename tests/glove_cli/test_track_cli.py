"""glove track / eval / build on bad input: exit code 2 and one line; no glove: no hand."""

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from glovedb.camera import CameraIntrinsics, save_intrinsics


def run_glove(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "glove_cli", *args], capture_output=True, text=True, timeout=300
    )


def write_sequence(folder: Path, frames: int, *, color: int = 90, depth_mm: int = 0) -> Path:
    camera = CameraIntrinsics(64, 48, 60.0, 60.0, 31.5, 23.5)
    (folder / "color").mkdir(parents=True)
    (folder / "depth").mkdir()
    save_intrinsics(camera, folder / "intrinsic.json")
    for index in range(frames):
        cv2.imwrite(
            str(folder / "color" / f"{index:06d}.png"), np.full((48, 64, 3), color, np.uint8)
        )
        cv2.imwrite(
            str(folder / "depth" / f"{index:06d}.png"), np.full((48, 64), depth_mm, np.uint16)
        )
    return folder


def assert_one_line_error(result: subprocess.CompletedProcess, text: str) -> None:
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and text in lines[0] and "Traceback" not in result.stderr


@pytest.mark.gl
def test_frames_without_a_glove_give_no_hand_on_every_frame(small_database, tmp_path):
    for name, depth in (("bare", 700), ("no_depth", 0)):
        sequence = write_sequence(tmp_path / name, 3, depth_mm=depth)
        out = tmp_path / f"{name}_out"
        result = run_glove(
            "track", str(sequence), "--db", str(small_database), "--out", str(out), "--json"
        )
        assert result.returncode == 0, result.stderr
        records = [json.loads(line) for line in (out / "poses.jsonl").read_text().splitlines()]
        assert [r["frame"] for r in records] == [0, 1, 2]
        assert not any(r["hand_found"] for r in records)
        assert json.loads(result.stdout)["hand_found"] == 0
    # A second run into the same folder leaves none of the first run's outputs behind.
    (out / "overlay.mp4").write_bytes(b"an earlier run's video")
    (out / "hand.bvh").write_text("an earlier run's motion")
    argv = ["--db", str(small_database), "--out", str(out), "--no-overlay", "--no-bvh"]
    assert run_glove("track", str(sequence), *argv).returncode == 0
    assert sorted(p.name for p in out.iterdir()) == ["hand.json", "poses.jsonl", "timing.json"]


@pytest.mark.gl
def test_bad_databases_and_inputs_exit_2(small_database, tmp_path):
    sequence = write_sequence(tmp_path / "seq", 2)
    garbage = tmp_path / "garbage.h5"
    garbage.write_bytes(b"not hdf5 at all")
    truncated = tmp_path / "truncated.h5"
    truncated.write_bytes(small_database.read_bytes()[:4000])
    out = str(tmp_path / "out")
    assert_one_line_error(
        run_glove("track", str(sequence), "--db", str(garbage), "--out", out),
        "not a readable HDF5 file",
    )
    assert_one_line_error(
        run_glove("track", str(sequence), "--db", str(truncated), "--out", out),
        "not a readable HDF5 file",
    )
    assert_one_line_error(
        run_glove("track", str(tmp_path / "nowhere"), "--db", str(small_database), "--out", out),
        "no such folder",
    )
    assert_one_line_error(
        run_glove("eval", "--db", str(small_database), "--sequence", str(sequence)),
        "no groundtruth.jsonl",
    )
    assert_one_line_error(
        run_glove("build", str(tmp_path / "missing.toml"), "--out", out + ".h5"),
        "cannot read the config",
    )
    for option, value, message in (
        ("--min-confidence", "2", "--min-confidence: expected 0 to 1"),
        ("--icp-stride", "0", "--icp-stride: expected 1 to 64"),
        ("--fit-iterations", "100000", "--fit-iterations: expected 1 to 50"),
        ("--hand", str(tmp_path / "nohand.json"), "no such hand proportions file"),
        ("--hand", str(garbage), "not a hand proportions file"),
        ("--cascade", "8:0", "cascade: size and k must be positive, got 8:0"),
        ("--temporal-prior", "inf", "--temporal-prior: expected 0 or more"),
        ("--fingertip-weight", "2", "--fingertip-weight: needs --fingertips"),
        ("--fingertip-model", str(garbage), "garbage.h5"),
        ("--depth-scale", "0", "--depth-scale: expected a positive number, got 0"),
        ("--intrinsics", str(garbage), "--intrinsics: only for a live 'kinect'"),
    ):
        argv = ["--db", str(small_database), "--out", out, option, value]
        assert_one_line_error(run_glove("track", str(sequence), *argv), message)
    argv = ["--db", str(small_database), "--out", out, "--fingertips", "--fingertip-weight", "-1"]
    assert_one_line_error(run_glove("track", str(sequence), *argv), "expected 0 or more, got -1")


@pytest.mark.gl
def test_a_corrupt_frame_stops_with_one_line_and_keeps_the_frames_before(small_database, tmp_path):
    sequence = write_sequence(tmp_path / "seq", 3)
    (sequence / "depth" / "000002.png").write_bytes(b"\x89PNG broken")
    out = tmp_path / "out"
    result = run_glove("track", str(sequence), "--db", str(small_database), "--out", str(out))
    assert_one_line_error(result, "000002.png")
    assert len((out / "poses.jsonl").read_text().splitlines()) == 2


def test_eval_checks_the_ground_truth_against_the_images_before_tracking(small_database, tmp_path):
    sequence = write_sequence(tmp_path / "seq", 2)
    record = {
        "hand_visible": False,
        "posture_rad": [0.0] * 20,
        "rotation": np.eye(3).tolist(),
        "translation_m": [0.0, 0.0, 0.5],
        "keypoints_3d_m": [[0.0, 0.0, 0.5]] * 21,
        "keypoints_2d_px": [[31.5, 23.5]] * 21,
    }
    lines = [json.dumps({"frame": k, **record}) for k in range(3)]
    (sequence / "groundtruth.jsonl").write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    result = run_glove("eval", "--db", str(small_database), "--sequence", str(sequence),
                       "--out", str(out))  # fmt: skip
    assert_one_line_error(result, "frames 0..2, but the sequence has 2 images")
    assert not out.exists()


def test_calibrate_replaces_only_an_earlier_color_table(small_database, tmp_path):
    sequence = write_sequence(tmp_path / "seq", 1)
    other = tmp_path / "model.npz"  # e.g. a fingertip model
    np.savez(other, weights=np.arange(3))
    before = other.read_bytes()
    argv = ["calibrate", str(sequence), "--db", str(small_database), "--out", str(other)]
    assert_one_line_error(run_glove(*argv), "not a color table")
    assert other.read_bytes() == before
    database = tmp_path / "db.npz"  # a database saved under a table's suffix
    database.write_bytes(small_database.read_bytes())
    argv = ["calibrate", str(sequence), "--db", str(database), "--out", str(database)]
    assert_one_line_error(run_glove(*argv), "that is the database")
    assert database.read_bytes() == small_database.read_bytes()
    argv = ["calibrate", str(sequence), "--db", str(small_database), "--out", ""]
    assert_one_line_error(run_glove(*argv), "--out: expected a file name")
    argv = ["calibrate", str(sequence), "--db", str(small_database), "--out", "no/where.npz"]
    assert_one_line_error(run_glove(*argv), "no: folder does not exist")


def test_source_options_reach_the_source(tmp_path):
    import argparse

    from glove_cli.commands.track import source_options
    from tracker.sources import open_source

    sequence = write_sequence(tmp_path / "seq", 1, depth_mm=400)
    args = argparse.Namespace(input=str(sequence), depth_scale=500.0, intrinsics=None)
    frame = next(iter(open_source(args.input, **source_options(args))))
    assert np.allclose(frame.depth_m, 0.8)  # 400 units at 500 per metre, not 1000
    kinect = argparse.Namespace(input="kinect", depth_scale=None,
                                intrinsics=str(tmp_path / "missing.json"))  # fmt: skip
    with pytest.raises(ValueError, match=r"missing\.json: cannot read camera intrinsics"):
        source_options(kinect)
    save_intrinsics(CameraIntrinsics(64, 48, 60.0, 60.0, 31.5, 23.5), tmp_path / "k.json")
    kinect.intrinsics = str(tmp_path / "k.json")
    assert source_options(kinect)["intrinsics"].fx == 60.0


@pytest.mark.gl
def test_bench_track_reports_end_to_end_speed_and_stage_latency(small_database, tmp_path):
    sequence = write_sequence(tmp_path / "seq", 4, depth_mm=700)
    for read_ahead in ("2", "0"):
        result = run_glove(
            "bench", "track", str(sequence), "--db", str(small_database), "--json",
            "--read-ahead", read_ahead,
        )  # fmt: skip
        assert result.returncode == 0, result.stderr
        figures = json.loads(result.stdout)
        assert figures["frames"] == 4 and figures["hand_found"] == 0
        assert figures["read_ahead"] == int(read_ahead)
        assert 0 < figures["startup_s"] <= figures["first_pose_s"]
        # Python's start and the imports come before; the process is younger than 5 min.
        assert figures["first_pose_s"] < figures["first_pose_since_launch_s"] < 300
        assert figures["end_to_end_fps"] <= figures["tracking_fps"]
        read = figures["stages_ms"]["read"]
        assert 0 <= read["median"] <= read["p95"] <= read["p99"] <= read["max"]
        assert figures["machine"]["cores"] >= 1
    assert_one_line_error(
        run_glove("bench", "track", str(sequence), "--db", str(small_database), "--read-ahead",
                  "-1"), "--read-ahead")  # fmt: skip
