"""Training of the fingertip heatmap stage: targets, augmentation, export, labels."""

from __future__ import annotations

import numpy as np
import pytest

from fingertips.heatmap import HeatmapNetwork

torch = pytest.importorskip(
    "torch", reason="training the heatmap network needs the train extra (scripts/setup.sh --train)"
)
from fingertips.heatmap_training import (  # noqa: E402
    HeatNet,
    augment,
    export_onnx,
    heat_targets,
    label_heat_peaks,
)


def test_targets_peak_at_the_tip_cell_and_ignore_hidden_tips() -> None:
    tips = torch.full((1, 5, 2), float("nan"))
    tips[0, 1] = torch.tensor([-0.5, 0.25])  # cell (8 - 0.5, 20 - 0.5) in the 32 x 32 map
    target = heat_targets(tips, sigma_cells=1.2)[0]
    row, column = np.unravel_index(int(target.argmax()), target.shape)
    assert (column, row) in {(7, 19), (7, 20), (8, 19), (8, 20)}
    assert float(target.max()) == pytest.approx(np.exp(-0.5 / (2 * 1.2**2)), rel=1e-5)
    assert float(target[0, 31]) < 1e-6
    assert float(heat_targets(torch.full((1, 5, 2), float("nan")), 1.2).max()) == 0.0


def test_augmentation_moves_the_tips_with_the_image() -> None:
    torch.manual_seed(3)
    n = 64
    images = torch.ones(n, 1, 64, 64)
    tips = torch.full((n, 5, 2), float("nan"))
    tips[:, 0] = torch.tensor([0.4, -0.3])
    column, row = (np.array([0.4, -0.3]) + 1) / 2 * 64 - 0.5
    images[:, 0, round(row) - 1 : round(row) + 2, round(column) - 1 : round(column) + 2] = -1.0
    turned, moved = augment(images.clone(), tips.clone())
    for k in range(n):
        blob = np.argwhere(turned[k, 0].numpy() < 0)
        assert len(blob) > 0
        found = (blob.mean(axis=0)[::-1] + 0.5) / 64 * 2 - 1
        np.testing.assert_allclose(found, moved[k, 0].numpy(), atol=0.06)
    assert torch.isnan(moved[:, 1:]).all()


def test_onnx_export_computes_what_torch_computes() -> None:
    torch.manual_seed(0)
    net = HeatNet(width=2).eval()
    crops = np.random.default_rng(0).uniform(-1, 1, (3, 1, 64, 64)).astype(np.float32)
    with torch.no_grad():
        expected = torch.sigmoid(net(torch.from_numpy(crops))).numpy()
    network = HeatmapNetwork(export_onnx(net), passes=1)
    for k in range(3):
        np.testing.assert_allclose(network(crops[k, 0])[0], expected[k], atol=1e-5)


def test_peaks_are_true_within_the_radius_of_any_visible_tip() -> None:
    tips = np.array([[0, 0, 0.5], [np.nan] * 3, [0.05, 0, 0.5], [np.nan] * 3, [np.nan] * 3])
    peaks = np.array([[0.01, 0, 0.5], [0.0, 0.0, 0.52], [0.05, 0.005, 0.5], [0.1, 0, 0.5]])
    np.testing.assert_array_equal(
        label_heat_peaks(peaks, tips, radius_m=0.015), [True, False, True, False]
    )
    assert label_heat_peaks(peaks, np.full((5, 3), np.nan), radius_m=0.015).sum() == 0
