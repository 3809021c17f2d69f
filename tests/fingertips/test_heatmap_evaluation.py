"""The heatmap network alone: its peaks as detections, scored per threshold."""

import numpy as np
import pytest

from fingertips.evaluation import AnnotatedDepth
from fingertips.heatmap import GRID, crop_cell_pixels, hand_centre
from fingertips.heatmap_evaluation import evaluate_network, network_detections

CAMERA = np.array([200.0, 200.0, 40.0, 40.0])
PEAKS = {(10, 20): 0.95, (25, 5): 0.6}
"""Cells (column, row) of the fake network's peaks and their heat."""


def _plate() -> np.ndarray:
    depth = np.zeros((80, 80), np.float32)
    depth[20:60, 20:60] = 0.5
    return depth


def _network(crop: np.ndarray) -> np.ndarray:
    """Two single-cell peaks, whatever the crop: maps of two passes."""
    assert crop.shape == (64, 64)
    heat = np.zeros((GRID, GRID), np.float32)
    for (column, row), value in PEAKS.items():
        heat[row, column] = value
    return np.stack([heat, heat])


def test_peaks_above_the_threshold_are_detections_at_their_cells() -> None:
    depth = _plate()
    centre = hand_centre(depth, CAMERA)
    found = network_detections(depth, CAMERA, _network, min_value=0.5)
    assert [d.confidence for d in found] == pytest.approx([0.6, 0.95])  # row-major order
    assert {d.source for d in found} == {"heatmap"}
    expected = crop_cell_pixels(np.array([[25.0, 5.0], [10.0, 20.0]]), centre, CAMERA)
    np.testing.assert_allclose([(d.u_px, d.v_px) for d in found], expected, atol=1e-9)
    assert len(network_detections(depth, CAMERA, _network, min_value=0.9)) == 1
    assert network_detections(np.zeros((80, 80), np.float32), CAMERA, _network, min_value=0.5) == ()


def test_each_threshold_keeps_the_peaks_above_it() -> None:
    depth = _plate()
    strong = network_detections(depth, CAMERA, _network, min_value=0.9)[0]
    tips_m = np.full((1, 5, 3), np.nan)
    tips_px = np.full((1, 5, 2), np.nan)
    tips_m[0, 1] = [strong.x_m, strong.y_m, strong.z_m]
    tips_px[0, 1] = [strong.u_px, strong.v_px]
    data = AnnotatedDepth(depth[None], CAMERA, tips_m, tips_px, np.zeros(1, np.int64))
    scores = evaluate_network(data, _network, thresholds=(0.5, 0.9))
    assert [scores[t].detections for t in (0.5, 0.9)] == [2, 1]
    assert scores[0.5].precision_15mm == pytest.approx(0.5)
    assert scores[0.9].precision_15mm == 1.0 and scores[0.9].recall_15mm == 1.0
    with pytest.raises(ValueError, match="thresholds"):
        evaluate_network(data, _network, thresholds=(1.0,))
