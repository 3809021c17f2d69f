"""The 8-bit heatmap network (fingertips/heatmap_quantization.py).

The float network is the tiny stand-in of ``tests/data/fingertips`` (``logits = 40 *
(-crop averaged over 2 x 2 blocks) - 10``); quantizing needs the ``onnx`` package
(the ``train`` extra), running the result only onnxruntime.
"""

from pathlib import Path

import numpy as np
import pytest

import fingertips.heatmap
from fingertips.heatmap import HeatmapNetwork, check_crop, crop_views, unturn_maps
from fingertips.heatmap_quantization import is_quantized, quantize_network, unsigned_weights

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


def _signed(network: np.ndarray) -> bytes:
    """The quantized network with its weights stored signed, as onnxruntime quantizes."""
    import onnx
    from onnx import numpy_helper

    model = onnx.load_from_string(network.tobytes())
    initializers = {tensor.name: tensor for tensor in model.graph.initializer}
    weights = [
        node.input[:3:2]  # values, zero point
        for node in model.graph.node
        if node.op_type == "DequantizeLinear" and node.input[0] in initializers
    ]
    for names in weights:
        tensors = [initializers[name] for name in names]
        if tensors[0].data_type != onnx.TensorProto.UINT8:
            continue  # the biases are 32-bit
        for tensor in tensors:
            shifted = numpy_helper.to_array(tensor).astype(np.int16) - 128
            tensor.CopyFrom(numpy_helper.from_array(shifted.astype(np.int8), tensor.name))
    return model.SerializeToString()


def _reference_logits(network: bytes, crop: np.ndarray) -> np.ndarray:
    from fingertips.heatmap import _network_session

    return _network_session(network, fused=False).run(None, {"crops": crop_views(crop, 4)})[0]


def test_unsigned_weights_are_the_same_network() -> None:
    onnx = pytest.importorskip("onnx", reason="quantizing needs the onnx package (train extra)")
    unsigned = quantize_network(TINY_ONNX.read_bytes(), _crops(1, 40), passes=4)
    graph = onnx.load_from_string(unsigned.tobytes()).graph
    assert onnx.TensorProto.INT8 not in {tensor.data_type for tensor in graph.initializer}
    signed = _signed(unsigned)
    assert signed != unsigned.tobytes()
    # Every dequantized weight is the same: the reference graphs agree exactly.
    for crop in [*_crops(4, 5), check_crop()]:
        np.testing.assert_array_equal(
            _reference_logits(signed, crop), _reference_logits(unsigned.tobytes(), crop)
        )
    np.testing.assert_array_equal(unsigned_weights(signed), unsigned)
    np.testing.assert_array_equal(unsigned_weights(unsigned), unsigned)  # unsigned already
    with pytest.raises(ValueError, match="not quantized"):
        unsigned_weights(TINY_ONNX.read_bytes())


def test_a_network_whose_kernels_disagree_runs_its_reference_graph(monkeypatch) -> None:
    pytest.importorskip("onnx", reason="quantizing needs the onnx package (train extra)")
    quantized = quantize_network(TINY_ONNX.read_bytes(), _crops(1, 8), passes=4)
    crop = _crops(5, 1)[0]
    assert not HeatmapNetwork(quantized, 4).reference_graph  # agrees on every CPU
    monkeypatch.setattr(fingertips.heatmap, "kernels_agree", lambda fused, reference: False)
    with pytest.warns(RuntimeWarning, match="reference graph"):
        network = HeatmapNetwork(quantized, 4)
    assert network.reference_graph
    logits = _reference_logits(quantized.tobytes(), crop).astype(np.float64)
    expected = unturn_maps((1.0 / (1.0 + np.exp(-logits))).astype(np.float32), 4)
    np.testing.assert_allclose(network(crop), expected, rtol=0, atol=1e-6)
