"""The 8-bit heatmap network (fingertips/heatmap_quantization.py).

The float network is the tiny stand-in of ``tests/data/fingertips`` (``logits = 40 *
(-crop averaged over 2 x 2 blocks) - 10``); quantizing needs the ``onnx`` package
(the ``train`` extra), running the result only onnxruntime.
"""

from pathlib import Path

import numpy as np
import pytest

from fingertips.heatmap import HeatmapNetwork
from fingertips.heatmap_quantization import is_quantized, quantize_network

TINY_ONNX = Path(__file__).resolve().parents[1] / "data" / "fingertips" / "tiny_heatmap.onnx"


def _crops(seed: int, count: int) -> np.ndarray:
    """Crops like the detector's: a hand-like blob in front of a far background,
    depth relative to the crop centre in [-1, 1], 1 where missing."""
    rng = np.random.default_rng(seed)
    crops = np.ones((count, 64, 64), np.float32)
    rows, cols = np.mgrid[0:64, 0:64]
    for crop in crops:
        centre = rng.uniform(16, 48, 2)
        radius = rng.uniform(6, 20)
        inside = (rows - centre[0]) ** 2 + (cols - centre[1]) ** 2 < radius**2
        crop[inside] = rng.uniform(-0.6, 0.2) + rng.normal(0.0, 0.05, inside.sum())
    return np.clip(crops, -1.0, 1.0)


def test_the_quantized_network_gives_the_float_networks_probabilities() -> None:
    pytest.importorskip("onnx", reason="quantizing needs the onnx package (train extra)")
    float_network = TINY_ONNX.read_bytes()
    assert not is_quantized(float_network)
    quantized = quantize_network(float_network, _crops(1, 40), passes=4)
    assert is_quantized(quantized)
    exact, eight_bit = HeatmapNetwork(float_network, 4), HeatmapNetwork(quantized, 4)
    differences = [np.abs(exact(crop) - eight_bit(crop)).max() for crop in _crops(2, 20)]
    # The logits step by about 40 / 255 per activation level: a few hundredths of
    # probability at most, where the sigmoid is steepest.
    assert max(differences) < 0.05
    hot = [(exact(crop) > 0.5) == (eight_bit(crop) > 0.5) for crop in _crops(3, 20)]
    assert np.mean(hot) > 0.99


def test_quantizing_refuses_a_quantized_network_and_no_crops() -> None:
    pytest.importorskip("onnx", reason="quantizing needs the onnx package (train extra)")
    float_network = TINY_ONNX.read_bytes()
    with pytest.raises(ValueError, match="crops"):
        quantize_network(float_network, np.zeros((0, 64, 64), np.float32), passes=4)
    quantized = quantize_network(float_network, _crops(1, 8), passes=1)
    with pytest.raises(ValueError, match="already quantized"):
        quantize_network(quantized, _crops(1, 8), passes=1)
