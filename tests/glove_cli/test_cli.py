"""The ``glove`` command line: help, exit codes, one-line errors, the render picture."""

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from glove_cli.main import main


def run_glove(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "glove_cli", *args], capture_output=True, text=True, timeout=300
    )


def test_help_lists_the_commands(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    for command in ("demo", "render", "pattern", "build", "db", "bench", "calibrate", "track",
                    "eval", "render-sequence"):  # fmt: skip
        assert command in out


def test_track_help_states_the_fits_default_iterations(capsys):
    from tracker.generative.fit import FitSettings

    with pytest.raises(SystemExit):
        main(["track", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert f"per start (default {FitSettings().iterations})" in help_text


def test_bench_lookup_defaults_to_the_trackers_cascade():
    """The command line spells the library's defaults and choices out (importing them
    is slow): they must stay the library's."""
    from glove_cli.main import build_parser
    from glovedb.lookup import DEFAULT_CASCADE, FIRST_STAGES
    from glovedb.search import COARSE_MAPS

    parser = build_parser()
    assert parser.parse_args(["bench", "lookup", "--db", "x.h5"]).cascade == DEFAULT_CASCADE
    for first_stage in FIRST_STAGES:
        args = parser.parse_args(["bench", "lookup", "--db", "x.h5", "--first-stage", first_stage])
        assert args.first_stage == first_stage
    for maps in COARSE_MAPS:
        assert (
            parser.parse_args(["bench", "lookup", "--db", "x", "--coarse-maps", maps]).coarse_maps
            == maps
        )


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ([], "required: COMMAND"),
        (["render"], "--posture"),
        (["render", "--posture", "wave"], "unknown posture 'wave'"),
        (["render", "--posture", "open", "--view", "left"], "invalid choice"),
        (["render", "--posture", "open", "--out", "x.txt"], ".png or .jpg"),
        (["render", "--posture", "open", "--out", "/no/such/dir/x.png"], "does not exist"),
        (["render", "--posture", "open", "--elevation", "45"], "--elevation needs --azimuth"),
        (["render", "--posture", "open", "--distance", "0.01"], "--distance: expected 0.1 to 5"),
        (["render", "--posture", "open", "--azimuth", "nan"], "--azimuth: expected a finite"),
    ],
)
def test_bad_input_exits_2_with_one_line(capsys, args, message):
    assert main(args) == 2
    err = capsys.readouterr().err
    assert message in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


@pytest.mark.gl
def test_render_writes_color_labels_and_depth_side_by_side(tmp_path):
    out = tmp_path / "pinch.png"
    result = run_glove("render", "--posture", "pinch", "--view", "thumb", "--out", str(out))
    assert result.returncode == 0, result.stderr
    picture = cv2.imread(str(out))
    assert picture.shape[1] == 3 * 640 and picture.shape[0] > 480
    panels = np.split(picture[:480], 3, axis=1)
    # Every panel shows the same silhouette (the hand covers the same pixels).
    masks = [panel[40:].max(axis=2) > 0 for panel in panels]
    assert masks[0].sum() > 5000
    assert np.mean(masks[0] == masks[1]) > 0.99 and np.mean(masks[1] == masks[2]) > 0.99


@pytest.mark.gl
def test_demo_runs_the_whole_job(tmp_path):
    result = run_glove("demo", "--out", str(tmp_path / "demo"), "--frames", "8",
                       "--cache", str(tmp_path / "cache"))  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert "thesis (Fig. 4.6)" in result.stdout and "8 frames" in result.stdout
    assert (tmp_path / "demo" / "tracking" / "poses.jsonl").read_text().count("\n") == 8
    assert cv2.imread(str(tmp_path / "demo" / "errors.png")) is not None
    summary = json.loads((tmp_path / "demo" / "summary.json").read_text())
    assert summary["missed_frames"] == 0 and summary["rotation_error_deg"]["median"] < 5
    # A second run reuses the cached database.
    again = run_glove("demo", "--out", str(tmp_path / "demo"), "--frames", "2",
                      "--cache", str(tmp_path / "cache"))  # fmt: skip
    assert again.returncode == 0 and "reusing" in again.stdout
    # A sequence folder the demo did not render is never deleted, nor for a bad trajectory.
    notes = tmp_path / "mine" / "sequence" / "notes.txt"
    notes.parent.mkdir(parents=True)
    notes.write_text("precious")
    for extra in ([], ["--trajectory", "nope"]):
        refused = run_glove("demo", "--out", str(tmp_path / "mine"), "--frames", "2", *extra)
        assert refused.returncode == 2 and notes.read_text() == "precious"
    (tmp_path / "a_file").write_text("x")
    argv = ["--out", str(tmp_path / "new"), "--cache", str(tmp_path / "a_file")]
    refused = run_glove("demo", "--frames", "2", *argv)
    assert refused.returncode == 2 and "is a file" in refused.stderr
    assert not (tmp_path / "new").exists()
