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

Training time only: needs the ``onnx`` package (the ``train`` extra) besides
onnxruntime; detection runs the quantized network as any other.
"""

from __future__ import annotations

import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fingertips.heatmap import crop_views, onnx_bytes

QUANTIZED_OP = b"QuantizeLinear"
"""An operator that only a quantized (QDQ) network holds: its name appears in the
ONNX bytes."""


def is_quantized(network_onnx: bytes | NDArray[np.uint8]) -> bool:
    """Whether an ONNX heatmap network is already quantized (holds QDQ operators)."""
    return QUANTIZED_OP in onnx_bytes(network_onnx)


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
        The quantized network as ONNX bytes, the same input and output.

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
        return np.frombuffer(target.read_bytes(), dtype=np.uint8).copy()
