"""``glove fingertips``: exit codes, one JSON object, detect outputs, train on a tiny set."""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from fingertips.detector import FingertipDetector
from fingertips.forest import load_forest
from fingertips.heatmap import HeatmapNetwork
from fingertips.miss_causes import MISS_CAUSES
from fingertips.pictures import cause_legend, scored_overlay
from glove_cli.main import main

REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "real_depth" / "hmodel_andrii"
REPO = Path(__file__).resolve().parents[2]
HELDOUT = str(REPO / "configs" / "fingertips" / "heldout.toml")
DEFAULT = str(REPO / "configs" / "fingertips" / "default.toml")
EVAL_KEYS = {
    "frames",
    "precision",
    "recall",
    "error_mm_mean",
    "error_px_mean",
    "recall_at_10px",
    "ms_per_frame",
}


def _write_folder(root: Path, n_frames: int = 2) -> None:
    """A tiny annotated folder: a box with a 'finger' sticking up, tips annotated."""
    (root / "depth").mkdir(parents=True)
    intrinsic = {"width": 80, "height": 60, "intrinsic_matrix": [70, 0, 0, 0, 70, 0, 39.5, 29.5, 1]}
    (root / "intrinsic.json").write_text(json.dumps(intrinsic))
    records = []
    for frame in range(n_frames):
        depth = np.zeros((60, 80), np.uint16)
        depth[30:55, 20:60] = 400
        depth[10:30, 36:42] = 390
        cv2.imwrite(str(root / "depth" / f"{frame:06d}.png"), depth)
        tip = {"xyz_m": [0.0, -0.11, 0.39], "uv_px": [39.5, 10.0]}
        records.append({"frame": frame, "fingertips": {"index": tip}})
    (root / "annotations.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))


def run_glove(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "glove_cli", *args], capture_output=True, text=True, timeout=300
    )


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["fingertips"], "ACTION"),
        (["fingertips", "eval", "/no/such/folder"], "/no/such/folder"),
        (["fingertips", "detect", "/no/such/folder", "--out", "x"], "no such folder or file"),
        (["fingertips", "eval", ".", "--model", "/no/model.npz"], "no such model file"),
        (["fingertips", "train", "/no/config.toml", "--out", "m.npz"], "cannot read config"),
        (["fingertips", "train", "/no/config.toml", "--out", "m.txt"], "ends in .npz"),
        (["fingertips", "eval", ".", "--min-tip-probability", "2"], "expected a probability"),
        (["fingertips", "eval", ".", "--heatmap-min-probability", "-1"], "expected a probability"),
        (["fingertips", "train", HELDOUT, "--out", "m.npz", "--keep-verifier"], "needs --forest"),
        (
            ["fingertips", "train", HELDOUT, "--out", "m.npz", "--heatmap-network", "/no/n.onnx"],
            "cannot read",
        ),
        (["fingertips", "eval", ".", "--c-thr", "inf"], "expected a positive, finite"),
        (["fingertips", "eval", str(REAL), "--pose-guess"], "need groundtruth.jsonl"),
        (["fingertips", "eval", ".", "--sheet", "scores.txt"], "expected a .png"),
        (["fingertips", "synth", "x.toml", "--out", "d", "--noise", "loud"], "invalid choice"),
        (["fingertips", "synth", HELDOUT, "--out", str(REPO)], "exists and is not an empty"),
        (["fingertips", "crops", HELDOUT, "--out", "c.npz"], "no [heatmap] table"),
        (["fingertips", "crops", DEFAULT, "--out", "c.txt"], "a crop file name ends in .npz"),
        (["fingertips", "train-heatmap", HELDOUT, "--out", "n.onnx"], "no [heatmap] table"),
        (["fingertips", "train-heatmap", DEFAULT, "--out", "n.npz"], "ends in .onnx"),
        (["fingertips", "eval-heatmap", "/no/n.onnx", "."], "/no/n.onnx: cannot read"),
        (["fingertips", "eval-heatmap", HELDOUT, "."], "not a glove-fingertip-forest"),
        (["fingertips", "eval-heatmap", "/no/m.npz", "."], "no such model file"),
    ],
)
def test_bad_input_exits_2_with_one_line(capsys, args, message) -> None:
    assert main(args) == 2
    err = capsys.readouterr().err
    assert message in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_eval_json_prints_one_object(tmp_path: Path, capsys) -> None:
    _write_folder(tmp_path)
    assert main(["fingertips", "eval", str(tmp_path), "--json"]) == 0
    out = capsys.readouterr().out
    result = json.loads(out)
    assert len(out.strip().splitlines()) == 1
    assert EVAL_KEYS <= set(result)
    assert result["frames"] == 2 and result["annotated_tips"] == 2
    # Every missed tip is counted once, under one cause, at each gate.
    by_cause = result["missed_by_cause"]
    assert set(by_cause) == {"15mm", "10px"}
    assert list(by_cause["15mm"]) == list(by_cause["10px"]) == list(MISS_CAUSES)
    missed = {"15mm": 1 - result["recall"], "10px": 1 - result["recall_at_10px"]}
    for gate, share in missed.items():
        assert sum(by_cause[gate].values()) == round(2 * share)


def test_eval_segmentation_option_selects_the_hand_pixels(tmp_path: Path, capsys) -> None:
    _write_folder(tmp_path)
    argv = ["fingertips", "eval", str(tmp_path), "--json", "--segmentation", "surface"]
    assert main(argv) == 0
    assert json.loads(capsys.readouterr().out)["detector"]["segmentation"] == "surface"
    assert main([*argv[:-1], "glove"]) == 2


@pytest.mark.parametrize("candidates", ["forest", "union"])
def test_eval_candidates_option_selects_what_the_verifier_scores(
    tmp_path: Path, capsys, candidates: str
) -> None:
    _write_folder(tmp_path)
    argv = ["fingertips", "eval", str(tmp_path), "--json", "--candidates", candidates]
    assert main(argv) == 0
    assert json.loads(capsys.readouterr().out)["detector"]["candidates"] == candidates
    assert main([*argv[:-1], "geodesic"]) == 2


def test_eval_text_lists_the_misses_by_cause(tmp_path: Path, capsys) -> None:
    _write_folder(tmp_path)
    (tmp_path / "annotations.jsonl").write_text(  # a tip on the image border: missed
        "".join(
            json.dumps({"frame": k, "fingertips": {"thumb": {"xyz_m": [0.0, -0.163, 0.4],
                        "uv_px": [39.5, 1.0]}}}) + "\n"
            for k in range(2)
        )
    )  # fmt: skip
    assert main(["fingertips", "eval", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "missed within 15 mm by cause: 2 (border 2, segmentation 0, distance 0" in out
    assert "missed within 10 px by cause: 2 (border 2," in out


def test_detect_writes_a_record_and_an_overlay_per_frame(tmp_path: Path, capsys) -> None:
    _write_folder(tmp_path / "seq", n_frames=3)
    out = tmp_path / "out"
    assert main(["fingertips", "detect", str(tmp_path / "seq"), "--out", str(out)]) == 0
    records = [json.loads(line) for line in (out / "fingertips.jsonl").read_text().splitlines()]
    assert [r["frame"] for r in records] == [0, 1, 2]
    for record in records:
        for tip in record["fingertips"]:
            assert set(tip) == {"finger", "u_px", "v_px", "x_m", "y_m", "z_m", "confidence"}
    assert len(list((out / "overlay").glob("*.png"))) == 3
    # The Python API gives the same records.
    assert list(FingertipDetector().run(tmp_path / "seq")) == records
    guessed = tmp_path / "guessed"
    argv = ["fingertips", "detect", str(tmp_path / "seq"), "--out", str(guessed), "--pose-guess"]
    assert main(argv) == 0
    lines = (guessed / "fingertips.jsonl").read_text().splitlines()
    assert all(json.loads(line)["pose_guess"] is None for line in lines)  # < 3 detections
    assert main(["fingertips", "detect", str(tmp_path / "seq"), "--out", str(out), "--sheet"]) == 0
    assert cv2.imread(str(out / "contact_sheet.png")).shape == (60, 3 * 80, 3)
    assert not (out / "overlay").exists()  # the earlier overlays went with their folder


def test_detect_reads_recordings_and_cameras_through_the_tracker_sources(
    tmp_path: Path, capsys, monkeypatch
) -> None:
    from glovedb.camera import CameraIntrinsics
    from tracker import sources

    _write_folder(tmp_path / "seq", n_frames=2)
    depth = cv2.imread(str(tmp_path / "seq" / "depth" / "000000.png"), cv2.IMREAD_UNCHANGED)
    camera = CameraIntrinsics(80, 60, 70.0, 70.0, 39.5, 29.5)
    opened = []

    def fake_camera(spec, **options):  # what open_source("realsense") gives with a camera
        opened.append(spec)
        frames = [(np.zeros((60, 80, 3), np.uint8), depth, camera)] * 2
        return sources.Source(sources.frames_from_arrays(frames), "realsense", "realsense")

    monkeypatch.setattr(sources, "open_source", fake_camera)
    assert main(["fingertips", "detect", "realsense", "--out", str(tmp_path / "live")]) == 0
    assert main(["fingertips", "detect", str(tmp_path / "seq"), "--out", str(tmp_path / "f")]) == 0
    assert opened == ["realsense"]  # the folder did not go through open_source
    live = (tmp_path / "live" / "fingertips.jsonl").read_text()
    assert live == (tmp_path / "f" / "fingertips.jsonl").read_text()
    assert len(list((tmp_path / "live" / "overlay").glob("*.png"))) == 2
    capsys.readouterr()
    argv = ["fingertips", "detect", "realsense", "--out", str(tmp_path / "x"), "--sheet"]
    assert main(argv) == 2
    assert "a camera, whose frames do not end" in capsys.readouterr().err
    # A depth scale reaches the frames of a folder as of a recording.
    from fingertips.depth_input import open_depth_source

    halved = next(iter(open_depth_source(tmp_path / "seq", depth_scale=500.0)))
    assert halved.depth_m.max() == pytest.approx(0.8)  # 400 units at 500 per metre
    # --out - streams the same records to standard output, for another program.
    assert main(["fingertips", "detect", "realsense", "--out", "-"]) == 0
    streamed = capsys.readouterr()
    assert streamed.out == live and "2 frames" in streamed.err
    assert not (Path("-")).exists()


def test_detect_replaces_an_earlier_run_and_refuses_odd_names(tmp_path: Path, capsys) -> None:
    _write_folder(tmp_path / "long", n_frames=3)
    _write_folder(tmp_path / "short", n_frames=1)
    out = tmp_path / "out"
    assert main(["fingertips", "detect", str(tmp_path / "long"), "--out", str(out)]) == 0
    assert main(["fingertips", "detect", str(tmp_path / "short"), "--out", str(out)]) == 0
    assert sorted(p.name for p in (out / "overlay").iterdir()) == ["000000.png"]
    # An overlay that cannot be written is an error, not a silent gap.
    (out / "overlay" / "000000.png").unlink()
    (out / "overlay" / "000000.png").mkdir()
    assert main(["fingertips", "detect", str(tmp_path / "short"), "--out", str(out)]) == 2
    assert "000000.png: could not write the picture" in capsys.readouterr().err
    # Frames are read back by their six-digit names: other numbered names are refused.
    depth = tmp_path / "short" / "depth"
    (depth / "000000.png").rename(depth / "0000000.png")
    assert main(["fingertips", "detect", str(tmp_path / "short"), "--out", str(out)]) == 2
    assert "0000000.png: depth images must be named by six-digit" in capsys.readouterr().err


def test_eval_sheet_draws_every_frame_and_marks_tips(tmp_path: Path, capsys) -> None:
    _write_folder(tmp_path / "seq", n_frames=3)
    sheet = tmp_path / "sheet" / "scored.png"
    argv = ["fingertips", "eval", str(tmp_path / "seq"), "--json", "--sheet", str(sheet)]
    assert main(argv) == 0
    result = json.loads(capsys.readouterr().out)  # stdout stays one JSON object
    picture = cv2.imread(str(sheet))[..., ::-1]
    # The tiles, then the legend of the causes' letters.
    assert picture.shape == (60 + cause_legend(3 * 80).shape[0], 3 * 80, 3)
    # Each tile circles the annotated tip (39.5, 10): green if found, red if missed.
    found = round(3 * result["recall_at_10px"])
    for k in range(3):
        ring = picture[10 - 10 : 10 + 11, 80 * k + 29 : 80 * k + 51].reshape(-1, 3)
        green = np.any(np.all(ring == (0, 220, 0), axis=1))
        red = np.any(np.all(ring == (255, 40, 40), axis=1))
        assert green != red
        found -= green
    assert found == 0


def test_scored_overlay_colours_found_and_missed_tips() -> None:
    depth = np.full((60, 80), 0.5, np.float32)
    tips = np.full((5, 2), np.nan)
    tips[:2] = [[20.0, 30.0], [60.0, 30.0]]
    uv = np.array([[23.0, 30.0], [40.0, 50.0]])  # finds tip 0; the other is false
    picture = scored_overlay(depth, uv, tips)

    def has(colour, u, v, r=12):
        patch = picture[max(v - r, 0) : v + r + 1, max(u - r, 0) : u + r + 1].reshape(-1, 3)
        return bool(np.any(np.all(patch == colour, axis=1)))

    green, red, cyan, orange = (0, 220, 0), (255, 40, 40), (0, 230, 255), (255, 150, 0)
    assert has(green, 20, 30) and not has(red, 20, 30)
    assert has(red, 60, 30) and not has(green, 60, 30)
    assert has(cyan, 23, 30, r=4) and has(orange, 40, 50, r=4) and not has(cyan, 40, 50, r=4)
    # VGA frames are halved so that a sheet of many frames stays readable.
    assert scored_overlay(np.zeros((480, 640), np.float32), uv, tips).shape == (240, 320, 3)
    # With causes, the miss carries its cause's letter up and right of its circle.
    causes = ("border", "curled", None, None, None)
    marked = scored_overlay(depth, uv, tips, causes=causes)
    changed = np.any(marked != picture, axis=2)
    assert changed[10:21, 70:80].any()  # beside the missed tip (60, 30), radius 10
    assert not changed[:, :50].any()  # nothing beside the found tip
    with pytest.raises(ValueError, match="causes: expected 5"):
        scored_overlay(depth, uv, tips, causes=causes[:2])


def test_the_legend_wraps_to_the_sheet_width() -> None:
    wide, narrow = cause_legend(1920), cause_legend(240)
    assert wide.shape[1] == 1920 and narrow.shape[1] == 240 and wide.dtype == np.uint8
    assert narrow.shape[0] > wide.shape[0]  # more lines
    assert not np.any(narrow[:, -4:])  # every line fits


@pytest.mark.skipif(not REAL.is_dir(), reason="shared real depth data not available")
def test_eval_on_the_real_frames(capsys) -> None:
    assert main(["fingertips", "eval", str(REAL), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["frames"] == 11 and result["annotated_tips"] == 55
    assert result["recall_at_10px"] > 0.2


@pytest.mark.gl
def test_train_and_synth_on_a_tiny_config(tmp_path: Path) -> None:
    config = tmp_path / "tiny.toml"
    config.write_text(
        "[data]\nn_images = 6\nseed = 2\nhalf_resolution_fraction = 0.0\n"
        "[training]\nn_features = 20\npixels_per_image = 200\nn_trees = 2\nmax_depth = 6\n"
        "depth_band_m = 0.2\n[detector]\nc_thr = 2.0\n"
    )
    model = tmp_path / "tiny.npz"
    result = run_glove("fingertips", "train", str(config), "--out", str(model), "--noise", "none")
    assert result.returncode == 0, result.stderr
    folder = tmp_path / "synth"
    result = run_glove("fingertips", "synth", str(config), "--out", str(folder), "--images", "2")
    assert result.returncode == 0, result.stderr
    result = run_glove(
        "fingertips", "eval", str(folder), "--model", str(model), "--json", "--pose-guess"
    )
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["frames"] == 2
    truth = [json.loads(line) for line in (folder / "groundtruth.jsonl").read_text().splitlines()]
    right = sum(r["hand"] == "right" and r["hand_visible"] for r in truth)
    assert json.loads(result.stdout)["pose_guess"]["frames"] == right
    assert json.loads(result.stdout)["detector"]["depth_band_m"] == 0.2
    del truth[1]["rotation"]  # a later record without its pose: FILE:LINE, not a KeyError
    (folder / "groundtruth.jsonl").write_text("".join(json.dumps(r) + "\n" for r in truth))
    result = run_glove("fingertips", "eval", str(folder), "--model", str(model), "--pose-guess")
    assert result.returncode == 2 and "groundtruth.jsonl:2" in result.stderr
    # Then only a peak verifier for that forest, with looser candidates.
    with open(config, "a") as stream:
        stream.write(
            "min_tip_probability = 0.5\n[detector.voting]\nmin_probability = 0.2\n"
            "[verifier]\nn_images = 6\nn_trees = 3\n"
        )
    config.write_text(config.read_text().replace("c_thr = 2.0", "c_thr = 0.5"))
    checked = tmp_path / "checked.npz"
    result = run_glove(
        "fingertips", "train", str(config), "--forest", str(model), "--out", str(checked)
    )
    assert result.returncode == 0, result.stderr
    verifier = load_forest(checked).verifier
    assert verifier is not None and verifier.n_trees == 3
    np.testing.assert_array_equal(
        load_forest(checked).node_feature, load_forest(model).node_feature
    )
    result = run_glove("fingertips", "eval", str(folder), "--model", str(checked), "--json")
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["detector"]["min_tip_probability"] == 0.5
    # Then only a heatmap stage for that forest and verifier.
    with open(config, "a") as stream:
        stream.write(
            "[heatmap]\ncrop_seeds = [3]\ncrops_per_seed = 8\nwidth = 2\nbatch_size = 4\n"
            "whole_hand_epochs = 1\nall_epochs = 1\nverifier_seeds = [4]\nverifier_images = 12\n"
            "verifier_iterations = 5\nmin_value = 0.0\n[heatmap.data]\ncurl_fraction = 0.5\n"
        )
    config.write_text(
        config.read_text().replace(
            "min_tip_probability = 0.5", "min_tip_probability = 0.5\nheatmap_min_probability = 0.5"
        )
    )
    staged = tmp_path / "staged.npz"
    result = run_glove(
        "fingertips",
        "train",
        str(config),
        "--forest",
        str(checked),
        "--keep-verifier",
        "--out",
        str(staged),
    )
    if importlib.util.find_spec("torch") is None:
        assert result.returncode == 2 and "scripts/setup.sh --train" in result.stderr
        pytest.skip("training the heatmap stage needs the train extra (scripts/setup.sh --train)")
    assert result.returncode == 0, result.stderr
    heatmap = load_forest(staged).heatmap
    assert heatmap is not None and heatmap.tree_roots.size == 5
    np.testing.assert_array_equal(
        load_forest(staged).verifier.node_threshold, verifier.node_threshold
    )
    result = run_glove("fingertips", "eval", str(folder), "--model", str(staged), "--json")
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["detector"]["heatmap_min_probability"] == 0.5
    # The same verifier again for the same network, without training it.
    again = tmp_path / "again.npz"
    result = run_glove(
        "fingertips",
        "train",
        str(config),
        "--forest",
        str(staged),
        "--keep-verifier",
        "--heatmap-network",
        str(staged),
        "--out",
        str(again),
    )
    assert result.returncode == 0, result.stderr
    repeated = load_forest(again).heatmap
    assert repeated is not None
    np.testing.assert_array_equal(repeated.network_onnx, heatmap.network_onnx)
    np.testing.assert_array_equal(repeated.node_value, heatmap.node_value)
    assert load_forest(again).settings["heatmap"]["network"] == "given"


TINY_HEATMAP_CONFIG = """
[data]
n_images = 6
seed = 2
half_resolution_fraction = 0.0
[training]
n_features = 20
pixels_per_image = 200
n_trees = 2
max_depth = 6
depth_band_m = 0.2
[verifier]
n_images = 6
n_trees = 3
[heatmap]
crop_seeds = [3, 4]
crops_per_seed = 4
width = 2
batch_size = 4
whole_hand_epochs = 1
all_epochs = 1
min_value = 0.0
verifier_seeds = [5]
verifier_images = 12
verifier_iterations = 5
[heatmap.data]
curl_fraction = 0.5
[detector]
c_thr = 0.5
min_tip_probability = 0.5
heatmap_min_probability = 0.5
[detector.voting]
min_probability = 0.2
"""


@pytest.mark.gl
def test_the_documented_sequence_on_a_tiny_config(tmp_path: Path) -> None:
    """crops per seed, train-heatmap on them, eval-heatmap, then train with the network."""
    config = tmp_path / "tiny.toml"
    config.write_text(TINY_HEATMAP_CONFIG)
    for seed in (3, 4):
        out = tmp_path / f"crops_{seed}.npz"
        result = run_glove(
            "fingertips", "crops", str(config), "--seed", str(seed), "--out", str(out)
        )
        assert result.returncode == 0, result.stderr
    parts = [str(tmp_path / "crops_3.npz"), str(tmp_path / "crops_4.npz")]
    network = tmp_path / "heatmap.onnx"
    result = run_glove(
        "fingertips", "train-heatmap", str(config), "--crops", *parts, "--out", str(network)
    )
    if importlib.util.find_spec("torch") is None:
        assert result.returncode == 2 and "scripts/setup.sh --train" in result.stderr
        pytest.skip("training the heatmap network needs the train extra (scripts/setup.sh --train)")
    assert result.returncode == 0, result.stderr
    # Crops rendered in parts train the network that crops rendered at once train.
    at_once = tmp_path / "at_once.onnx"
    result = run_glove("fingertips", "train-heatmap", str(config), "--out", str(at_once))
    assert result.returncode == 0, result.stderr
    crop = np.random.default_rng(0).uniform(-1, 1, (64, 64)).astype(np.float32)
    np.testing.assert_allclose(
        HeatmapNetwork(network.read_bytes(), 1)(crop),
        HeatmapNetwork(at_once.read_bytes(), 1)(crop),
        atol=1e-6,
    )
    folder = tmp_path / "synth"
    result = run_glove("fingertips", "synth", str(config), "--out", str(folder), "--images", "2")
    assert result.returncode == 0, result.stderr
    result = run_glove(
        "fingertips", "eval-heatmap", str(network), str(folder), "--threshold", "0.1", "--json"
    )
    assert result.returncode == 0, result.stderr
    scores = json.loads(result.stdout)[str(folder)]
    assert list(scores) == ["0.1"] and scores["0.1"]["frames"] == 2
    model = tmp_path / "model.npz"
    result = run_glove(
        "fingertips", "train", str(config), "--heatmap-network", str(network), "--out", str(model)
    )
    assert result.returncode == 0, result.stderr
    trained = load_forest(model)
    assert trained.verifier is not None and trained.heatmap is not None
    np.testing.assert_array_equal(
        trained.heatmap.network_onnx, np.frombuffer(network.read_bytes(), np.uint8)
    )
