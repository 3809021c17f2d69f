"""Training of the fingertip heatmap stage: targets, augmentation, export, labels, config."""

from __future__ import annotations

import numpy as np
import pytest

from builder.fingertip_data import FingertipDataConfig
from tracker.fingertips.heatmap import GRID, HeatmapNetwork, crop_cell_pixels

torch = pytest.importorskip(
    "torch", reason="training the heatmap network needs the train extra (scripts/setup.sh --train)"
)
from builder.fingertip_heatmap import (  # noqa: E402
    HeatNet,
    augment,
    crop_units,
    export_onnx,
    heat_targets,
    heatmap_config_from_dict,
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


def test_crop_units_are_where_the_map_cells_project() -> None:
    centre = np.array([0.05, -0.02, 0.6])
    camera = np.array([500.0, 500.0, 320.0, 240.0])
    cells = np.array([[3.25, 17.5], [28.0, 0.0]])
    uv = crop_cell_pixels(cells, centre, camera)
    z = np.array([0.55, 0.7])  # any depth along the ray projects to the same crop unit
    points = np.stack(
        [(uv[:, 0] - camera[2]) * z / camera[0], (uv[:, 1] - camera[3]) * z / camera[1], z], 1
    )
    np.testing.assert_allclose((crop_units(points, centre) + 1) / 2 * GRID - 0.5, cells, atol=1e-9)


def test_peaks_are_true_within_the_radius_of_any_visible_tip() -> None:
    tips = np.array([[0, 0, 0.5], [np.nan] * 3, [0.05, 0, 0.5], [np.nan] * 3, [np.nan] * 3])
    peaks = np.array([[0.01, 0, 0.5], [0.0, 0.0, 0.52], [0.05, 0.005, 0.5], [0.1, 0, 0.5]])
    np.testing.assert_array_equal(
        label_heat_peaks(peaks, tips, radius_m=0.015), [True, False, True, False]
    )
    assert label_heat_peaks(peaks, np.full((5, 3), np.nan), radius_m=0.015).sum() == 0


def test_config_reads_data_overrides_and_refuses_bad_values() -> None:
    config = heatmap_config_from_dict(
        {"crop_seeds": [4, 5], "width": 4, "data": {"curl_fraction": 0.3}}
    )
    assert config.crop_seeds == (4, 5)
    assert config.heatmap_data(FingertipDataConfig()).curl_fraction == 0.3
    with pytest.raises(ValueError, match="passes"):
        heatmap_config_from_dict({"passes": 3})
    with pytest.raises(ValueError, match="widht"):
        heatmap_config_from_dict({"widht": 4})
    with pytest.raises(ValueError, match="curl_fracton"):
        heatmap_config_from_dict({"data": {"curl_fracton": 0.3}})
