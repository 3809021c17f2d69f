"""8-bit integer version of the heatmap network (:mod:`fingertips.heatmap`).

The float network's passes take 10 ms per frame on one laptop-class core, more than
the rest of the detector's second thread can hide. Quantized to 8 bits (onnxruntime's
static quantization in the QDQ format: weights signed 8-bit per output channel,
activations unsigned 8-bit with ranges taken from calibration crops) the same passes
take 3.3 ms, and onnxruntime runs the result with its integer kernels.

A first check on the shipped float network, calibrated on the crops of 200 frames
rendered like its training crops with a seed no config uses (``default.toml``, seed
777): the largest difference of a crop's fingertip probabilities from the float
network's was 0.04 (median over 200 more crops; 0.08 at the 95th percentile), and
with the float network's verifier left as it was the detections on the validation
frames did not change beyond one or two tips: ``validation.toml`` precision / recall
0.939 / 0.423 -> 0.942 / 0.422, ``validation_surface.toml`` 0.985 / 0.338 -> 0.984 /
0.338. Training calibrates on the first crop seed's frames (``quantize_crops``);
docs/fingertips.md ("An 8-bit network") has the shipped model's figures.

The weights are then stored unsigned (:func:`unsigned_weights`, the same network):
onnxruntime's kernels for signed weights saturate on x86 CPUs without VNNI.

Training time only: needs the ``onnx`` package (the ``train`` extra) besides
onnxruntime; detection runs the quantized network as any other.
"""

from __future__ import annotations

import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fingertips.heatmap import crop_views, is_quantized, onnx_bytes

__all__ = ["is_quantized", "quantize_network", "unsigned_weights"]


def quantize_network(
    network_onnx: bytes | NDArray[np.uint8], crops: ArrayLike, *, passes: int
) -> NDArray[np.uint8]:
    """The network with 8-bit weights and activations (module docstring).

    Parameters
    ----------
    network_onnx : (B,) uint8 or bytes
        The float network: input ``crops`` ``(N, 1, 64, 64)``, output ``logits``.
    crops : (C, 64, 64) float
        Calibration crops (:class:`fingertips.heatmap_data.Crops` ``.images``); each
        is given as the ``passes`` views detection gives it, so that the activation
        ranges are those of detection.
    passes : int
        Passes at detection (:func:`fingertips.heatmap.crop_views`).

    Returns
    -------
    (B',) uint8
        The quantized network as ONNX bytes, the same input and output, its weights
        stored unsigned (:func:`unsigned_weights`).

    Raises
    ------
    ValueError
        When the network is quantized already, there are no crops, or the ``onnx``
        package is missing.
    """
    content = onnx_bytes(network_onnx)
    if is_quantized(content):
        raise ValueError("heatmap network: already quantized")
    images = np.asarray(crops, dtype=np.float32)
    if images.ndim != 3 or len(images) == 0:
        raise ValueError(f"crops: expected (C, 64, 64) with C >= 1, got {images.shape}")
    try:
        from onnxruntime.quantization import (
            CalibrationDataReader,
            QuantFormat,
            QuantType,
            quantize_static,
        )
        from onnxruntime.quantization.shape_inference import quant_pre_process
    except ImportError as error:  # onnxruntime's quantization needs the onnx package
        raise ValueError(
            "quantizing the heatmap network needs the onnx package: "
            'pip install -e ".[train]" (or scripts/setup.sh --train)'
        ) from error

    class _Views(CalibrationDataReader):
        def __init__(self) -> None:
            self._views: Iterator[dict[str, NDArray[np.float32]]] = (
                {"crops": crop_views(image, passes)} for image in images
            )

        def get_next(self) -> dict[str, NDArray[np.float32]] | None:
            return next(self._views, None)

    with tempfile.TemporaryDirectory() as folder:
        source, prepared, target = (Path(folder) / name for name in ("f.onnx", "p.onnx", "q.onnx"))
        source.write_bytes(content)
        # Shape inference and graph cleanup, as onnxruntime recommends before quantizing
        # (its symbolic shape inference is not needed for a fixed-size convolutional
        # network).
        quant_pre_process(str(source), str(prepared), skip_symbolic_shape=True)
        quantize_static(
            str(prepared),
            str(target),
            _Views(),
            quant_format=QuantFormat.QDQ,
            activation_type=QuantType.QUInt8,
            weight_type=QuantType.QInt8,
            per_channel=True,
        )
        return unsigned_weights(target.read_bytes())


def unsigned_weights(network_onnx: bytes | NDArray[np.uint8]) -> NDArray[np.uint8]:
    """The same quantized network with its signed 8-bit weights stored unsigned.

    Each signed weight ``w`` and its zero point ``z`` become ``w + 128`` and ``z + 128``
    (unsigned 8-bit): every dequantized weight ``(w - z) * scale`` is the same, so the
    network computes exactly what it did. onnxruntime then multiplies unsigned
    activations by unsigned weights with kernels that widen both to 16 bits first. Its
    unsigned-times-signed kernels on x86 CPUs without VNNI add pairs of 8-bit products
    in 16 bits, which saturate and turned the shipped network's heatmaps into noise
    there (:func:`fingertips.heatmap.kernels_agree`). On a 2-core AMD EPYC (AVX2) the
    shipped network's 4 passes take 11.5 ms unsigned, 9.3 ms signed (wrong) and 14.1 ms
    in float.

    Parameters
    ----------
    network_onnx : (B,) uint8 or bytes
        A quantized (QDQ) network; weights that are unsigned already stay as they are.

    Returns
    -------
    (B',) uint8
        The network as ONNX bytes.

    Raises
    ------
    ValueError
        When the network is not quantized or the ``onnx`` package is missing.
    """
    content = onnx_bytes(network_onnx)
    if not is_quantized(content):
        raise ValueError("heatmap network: not quantized")
    onnx, numpy_helper = _onnx()
    model = onnx.load_from_string(content)
    initializers = {tensor.name: tensor for tensor in model.graph.initializer}
    signed = {  # each tensor once, though nodes may share one
        name
        for node in model.graph.node
        if node.op_type == "DequantizeLinear"
        # values and zero point, both stored (onnxruntime writes both); not an
        # activation's, not a 32-bit bias, not unsigned already
        and len(names := node.input[:3:2]) == 2
        and all(name in initializers for name in names)
        and all(initializers[name].data_type == onnx.TensorProto.INT8 for name in names)
        for name in names
    }
    for name in sorted(signed):
        tensor = initializers[name]
        shifted = numpy_helper.to_array(tensor).astype(np.int16) + 128
        tensor.CopyFrom(numpy_helper.from_array(shifted.astype(np.uint8), name))
    return np.frombuffer(model.SerializeToString(), dtype=np.uint8).copy()


def _onnx():  # -> the onnx module and its numpy_helper
    try:
        import onnx
        from onnx import numpy_helper
    except ImportError as error:
        raise ValueError(
            "editing the heatmap network needs the onnx package: "
            'pip install -e ".[train]" (or scripts/setup.sh --train)'
        ) from error
    return onnx, numpy_helper
