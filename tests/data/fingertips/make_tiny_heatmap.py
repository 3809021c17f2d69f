"""Write ``tiny_heatmap.onnx``: a fixed-weight stand-in for the fingertip heatmap network.

``logits = 40 * (-crop averaged over 2 x 2 blocks) - 10``: one stride-2 convolution
with every weight -10 and bias -10. A cell is hot (sigmoid above 0.5) where the crop
averages below -0.25, i.e. where the depth lies more than 3.75 cm in front of the crop
centre, and cold elsewhere (sigmoid(-10) at the centre's depth, about 0 where depth is
missing). Turning or mirroring the crop turns or mirrors the map in the same way.

Input ``crops`` ``(N, 1, 64, 64)`` float32, output ``logits`` ``(N, 32, 32)`` float32,
batch axis dynamic. Used by ``tests/fingertips/test_heatmap.py``, which needs
only onnxruntime. Regenerate (needs torch and onnx, as in the project's venv) with::

    .venv/bin/python tests/data/fingertips/make_tiny_heatmap.py
"""

from pathlib import Path

import onnx
import torch

OUTPUT = Path(__file__).with_name("tiny_heatmap.onnx")


class TinyHeatmap(torch.nn.Module):
    """Minus the 2 x 2 block mean, scaled by 40, minus 10."""

    def __init__(self) -> None:
        super().__init__()
        self.pool = torch.nn.Conv2d(1, 1, kernel_size=2, stride=2)
        with torch.no_grad():
            self.pool.weight.fill_(-10.0)
            self.pool.bias.fill_(-10.0)

    def forward(self, crops: torch.Tensor) -> torch.Tensor:
        return self.pool(crops)[:, 0]


def main() -> None:
    model = TinyHeatmap().eval()
    torch.onnx.export(
        model,
        (torch.zeros(2, 1, 64, 64),),
        str(OUTPUT),
        input_names=["crops"],
        output_names=["logits"],
        dynamic_axes={"crops": {0: "n"}, "logits": {0: "n"}},
        opset_version=17,
        dynamo=False,
    )
    onnx.checker.check_model(onnx.load(str(OUTPUT)))
    print(f"{OUTPUT}: {OUTPUT.stat().st_size} bytes")


if __name__ == "__main__":
    main()
