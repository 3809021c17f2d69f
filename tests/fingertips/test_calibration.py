"""Calibrated confidences: the isotonic map, the model file, detection, reliability, CLI."""

import json
from dataclasses import asdict, replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from fingertip_toys import INTRINSICS, STRIDE_1, bar_scene, constant_verifier, toy_forest

from fingertips import Detection, detect_fingertips, name_fingers
from fingertips.calibration import (
    Calibration,
    ConfidenceMap,
    fit_isotonic,
    reliability_table,
)
from fingertips.calibration_training import (
    CalibrationConfig,
    calibrate_from_config,
    fit_calibration,
    without_calibration,
)
from fingertips.data import load_data_config
from fingertips.detect import calibrated_detections
from fingertips.evaluation import fingertip_metrics, read_annotated_depth
from fingertips.forest import load_forest, save_forest
from glove_cli.main import main

VERIFY = replace(STRIDE_1, min_tip_probability=0.5)


def _outcomes(score: float, n: int, right: int) -> tuple[list[float], list[bool]]:
    return [score] * n, [True] * right + [False] * (n - right)


def test_isotonic_map_reproduces_the_shares_of_monotone_groups() -> None:
    scores, correct = [], []
    for score, right in ((0.1, 2), (0.5, 6), (0.9, 9)):
        s, c = _outcomes(score, 10, right)
        scores += s
        correct += c
    mapping = fit_isotonic(scores, correct)
    np.testing.assert_allclose(mapping([0.1, 0.5, 0.9]), [0.2, 0.6, 0.9], atol=1e-12)
    np.testing.assert_allclose(
        mapping([0.3, 0.0, 1.0]), [0.4, 0.2, 0.9], atol=1e-12
    )  # linear, flat
    assert mapping(np.zeros((2, 3))).shape == (2, 3)


def test_isotonic_map_pools_violators_and_is_monotone() -> None:
    # 0.3 is right more often than 0.4: the two pool to (8 + 4) / 20.
    s1, c1 = _outcomes(0.3, 10, 8)
    s2, c2 = _outcomes(0.4, 10, 4)
    mapping = fit_isotonic(s1 + s2, c1 + c2)
    np.testing.assert_allclose(mapping([0.3, 0.35, 0.4]), 0.6, atol=1e-12)
    rng = np.random.default_rng(0)
    scores = rng.uniform(size=400)
    correct = rng.uniform(size=400) < scores**2
    values = fit_isotonic(scores, correct)(np.linspace(-0.5, 1.5, 2001))
    assert np.all(np.diff(values) >= 0)


def test_isotonic_map_matches_scikit_learn_and_clips_to_the_sample() -> None:
    isotonic = pytest.importorskip("sklearn.isotonic")
    rng = np.random.default_rng(1)
    scores = rng.uniform(size=300).round(2)
    correct = rng.uniform(size=300) < np.sqrt(scores)
    reference = isotonic.IsotonicRegression(out_of_bounds="clip").fit(scores, correct)
    grid = np.linspace(-0.1, 1.1, 500)
    ours = fit_isotonic(scores, correct, clip_to_sample=False)
    np.testing.assert_allclose(ours(grid), reference.predict(grid), atol=1e-12)
    clipped = fit_isotonic(scores, correct)(grid)
    assert clipped.min() >= 1 / 301 and clipped.max() <= 300 / 301


def test_confidence_map_and_calibration_refuse_bad_input() -> None:
    with pytest.raises(ValueError, match="non-decreasing"):
        ConfidenceMap(np.array([0.2, 0.1]), np.array([0.1, 0.2]))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        ConfidenceMap(np.array([0.1, 0.2]), np.array([0.5, 1.5]))
    with pytest.raises(ValueError, match="0/1"):
        fit_isotonic([0.1, 0.2], [0.5, 1.0])
    with pytest.raises(ValueError, match="'verifier'"):
        Calibration({"heatmap": ConfidenceMap(np.array([0.0]), np.array([0.5]))})
    calibration = Calibration({"verifier": ConfidenceMap(np.array([0.0]), np.array([0.5]))})
    with pytest.raises(ValueError, match="no confidence map for 'heatmap'"):
        calibration.confidence("heatmap", 0.9)


def _calibrated_toy(probability: float = 0.9, mapped: float = 0.97):
    """The toy forest, a constant verifier and a map taking ``probability`` to ``mapped``."""
    mapping = ConfidenceMap(np.array([0.0, probability, 1.0]), np.array([0.0, mapped, 1.0]))
    return replace(
        toy_forest(),
        verifier=constant_verifier(probability),
        calibration=Calibration({"verifier": mapping}),
    )


def test_model_file_keeps_the_maps_without_pickle(tmp_path: Path) -> None:
    model = _calibrated_toy()
    save_forest(model, tmp_path / "m.npz")
    with np.load(tmp_path / "m.npz", allow_pickle=False) as data:
        assert data["calibration_verifier_scores"].dtype == np.float64
        arrays = dict(data)
    loaded = load_forest(tmp_path / "m.npz")
    assert loaded.calibration is not None
    np.testing.assert_array_equal(loaded.calibration.maps["verifier"].scores, [0.0, 0.9, 1.0])
    np.testing.assert_array_equal(
        loaded.calibration.maps["verifier"].probabilities, [0.0, 0.97, 1.0]
    )
    # A model without maps (format 3, or one never calibrated) still loads.
    old = {k: v for k, v in arrays.items() if not k.startswith("calibration_")}
    np.savez(tmp_path / "v3.npz", **{**old, "format_version": np.array(3)})
    assert load_forest(tmp_path / "v3.npz").calibration is None
    with pytest.raises(ValueError, match="need the peak verifier"):
        replace(model, verifier=None)


def test_detections_carry_calibrated_confidences_and_raw_scores() -> None:
    depth, _ = bar_scene()
    (plain,) = detect_fingertips(depth, INTRINSICS, toy_forest(), config=STRIDE_1)
    (raw,) = detect_fingertips(
        depth, INTRINSICS, without_calibration(_calibrated_toy()), config=VERIFY
    )
    (calibrated,) = detect_fingertips(depth, INTRINSICS, _calibrated_toy(), config=VERIFY)
    assert raw.confidence == plain.confidence and raw.raw_confidence is None
    assert calibrated.confidence == pytest.approx(0.97)
    assert calibrated.tip_probability == pytest.approx(0.9)
    assert calibrated.raw_confidence == pytest.approx(plain.confidence)
    assert calibrated.uncalibrated_confidence == calibrated.raw_confidence


def test_calibrated_detections_are_ordered_by_confidence_and_named_as_before() -> None:
    mapping = ConfidenceMap(np.array([0.0, 1.0]), np.array([0.0, 1.0]))
    heat = ConfidenceMap(np.array([0.0, 1.0]), np.array([0.0, 0.5]))
    calibration = Calibration({"verifier": mapping, "heatmap": heat})
    weak = Detection(0, 0, 0.0, 0.0, 0.5, confidence=9.0, tip_probability=0.8)
    strong = Detection(0, 0, 0.03, 0.0, 0.5, confidence=2.0, tip_probability=0.9)
    hot = Detection(0, 0, 0.06, 0.0, 0.5, confidence=0.99, tip_probability=0.99, source="heatmap")
    ordered = calibrated_detections((weak, hot, strong), calibration)
    assert [d.tip_probability for d in ordered] == pytest.approx([0.9, 0.8, 0.99])
    assert [d.confidence for d in ordered] == pytest.approx([0.9, 0.8, 0.495])
    with pytest.raises(ValueError, match="tip_probability"):
        calibrated_detections((replace(weak, tip_probability=None),), calibration)
    # Eq. 11 without the verifier weighs the vote weights, calibrated or not.
    tips = np.array([[0.0, 0, 0.5], [0.03, 0, 0.5], [0.3, 0, 0.5], [0.4, 0, 0.5], [0.5, 0, 0.5]])
    named = name_fingers((weak, strong), tips, c_thr=0.5)
    named_calibrated = name_fingers(
        calibrated_detections((weak, strong), calibration), tips, c_thr=0.5
    )
    by_x = {d.x_m: d.finger for d in named}
    assert {d.x_m: d.finger for d in named_calibrated} == by_x


def test_reliability_table_gives_the_known_figures() -> None:
    confidences = [0.05, 0.05, 0.55, 0.55, 0.55, 0.55, 0.95, 1.0]
    correct = [False, False, True, True, True, False, True, True]
    table = reliability_table(confidences, correct)
    assert len(table.bins) == 10 and table.detections == 8
    counts = {round(b.low, 1): b.count for b in table.bins if b.count}
    assert counts == {0.0: 2, 0.5: 4, 0.9: 2}
    middle = table.bins[5]
    assert middle.mean_confidence == pytest.approx(0.55) and middle.share_correct == 0.75
    assert table.bins[9].mean_confidence == pytest.approx(0.975)
    # ECE: (2 * 0.05 + 4 * 0.2 + 2 * 0.025) / 8
    assert table.ece == pytest.approx(0.11875)
    assert np.isnan(table.bins[3].mean_confidence)
    with pytest.raises(ValueError, match="confidences"):
        reliability_table([1.2], [True])
    assert np.isnan(reliability_table(np.zeros(0), np.zeros(0, bool)).ece)


def test_metrics_report_the_reliability_of_the_detections() -> None:
    tips = np.full((1, 5, 3), np.nan)
    tips[0, 1] = (0.0, 0.0, 0.5)
    pixels = np.where(np.isnan(tips[..., :2]), np.nan, 0.0)
    right = Detection(0, 0, 0.0, 0.0, 0.5, confidence=0.9, tip_probability=0.6, raw_confidence=3)
    wrong = Detection(0, 0, 0.1, 0.0, 0.5, confidence=0.7, tip_probability=0.4, raw_confidence=2)
    metrics = fingertip_metrics([[right, wrong]], tips, pixels)
    assert metrics.calibrated and metrics.reliability is not None
    assert metrics.reliability.ece == pytest.approx((0.1 + 0.7) / 2)
    uncalibrated = [replace(d, confidence=5.0, raw_confidence=None) for d in (right, wrong)]
    before = fingertip_metrics([uncalibrated], tips, pixels)
    assert not before.calibrated and before.reliability is not None
    assert before.reliability.ece == pytest.approx((0.4 + 0.4) / 2)  # tip probabilities
    unverified = [replace(d, tip_probability=None) for d in uncalibrated]
    assert fingertip_metrics([unverified], tips, pixels).reliability is None


def _bar_folder(root: Path, frames_config: Path) -> None:
    """Four bar frames as synth would write them from ``frames_config``: the tip is
    annotated at the bar's end in frames 0 and 2 and elsewhere in 1 and 3."""
    depth, tip_m = bar_scene()
    fx, fy, cx, cy = INTRINSICS
    (root / "depth").mkdir(parents=True)
    matrix = [fx, 0, 0, 0, fy, 0, cx, cy, 1]
    (root / "intrinsic.json").write_text(
        json.dumps({"width": 80, "height": 80, "intrinsic_matrix": matrix})
    )
    records = []
    for frame in range(4):
        cv2.imwrite(str(root / "depth" / f"{frame:06d}.png"), (depth * 1000).astype(np.uint16))
        xyz = tip_m if frame % 2 == 0 else tip_m + (0.05, 0.0, 0.0)
        uv = [fx * xyz[0] / xyz[2] + cx, fy * xyz[1] / xyz[2] + cy]
        tip = {"xyz_m": xyz.tolist(), "uv_px": uv}
        records.append({"frame": frame, "fingertips": {"index": tip}})
    (root / "annotations.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    data = json.loads(json.dumps(asdict(load_data_config(frames_config))))
    (root / "meta.json").write_text(json.dumps({"settings": {"data": data}}))


def test_calibrate_fits_the_share_right_and_eval_reports_it(tmp_path: Path, capsys) -> None:
    frames_config = tmp_path / "frames.toml"
    frames_config.write_text("[data]\nn_images = 4\nseed = 3\nhalf_resolution_fraction = 0.0\n")
    _bar_folder(tmp_path / "frames", frames_config)
    model = replace(
        toy_forest(),
        verifier=constant_verifier(0.6),
        settings_json=json.dumps({"detector": VERIFY.as_dict()}),
    )
    config = CalibrationConfig(frames=str(frames_config))
    calibrated = calibrate_from_config(model, config, folder=tmp_path / "frames")
    assert calibrated.calibration is not None
    assert calibrated.calibration.maps["verifier"](0.6) == pytest.approx(0.5)
    assert calibrated.settings["calibration"]["samples"] == {"verifier": 4}
    with pytest.raises(ValueError, match="not rendered from"):
        calibrate_from_config(model, replace(config, n_images=5), folder=tmp_path / "frames")
    frames = read_annotated_depth(tmp_path / "frames", annotations="annotations.jsonl")
    right = [0, 2]
    with pytest.raises(ValueError, match="all right or all wrong"):
        fit_calibration(
            replace(frames, depth_m=frames.depth_m[right], tips_m=frames.tips_m[right],
                    tips_px=frames.tips_px[right], frames=frames.frames[right]),
            model,
            min_probability=0.05,
        )  # fmt: skip

    toml = tmp_path / "train.toml"
    toml.write_text('[verifier]\n[calibration]\nframes = "frames.toml"\n')
    save_forest(model, tmp_path / "m.npz")
    out = tmp_path / "calibrated.npz"
    args = ["fingertips", "calibrate", str(tmp_path / "m.npz"), str(toml), "--out", str(out)]
    assert main([*args, "--frames", str(tmp_path / "frames")]) == 0
    assert "verifier 2 of 4 right" in capsys.readouterr().out
    assert load_forest(out).calibration is not None
    assert (
        main(["fingertips", "eval", str(tmp_path / "frames"), "--model", str(out), "--json"]) == 0
    )
    result = json.loads(capsys.readouterr().out)
    assert result["calibrated"] and result["reliability"]["detections"] == 4
    assert result["reliability"]["ece"] == pytest.approx(0.0)
    assert main(["fingertips", "eval", str(tmp_path / "frames"), "--model", str(out)]) == 0
    text = capsys.readouterr().out
    assert "reliability of the calibrated confidence" in text
    assert "expected calibration error 0.000 (4 detections)" in text
