"""The inference modules import neither builder, pyrender, scikit-learn nor PyTorch."""

import subprocess
import sys

INFERENCE_MODULES = (
    "fingertips",
    "fingertips.assignment",
    "fingertips.calibration",
    "fingertips.depth_input",
    "fingertips.detect",
    "fingertips.detector",
    "fingertips.evaluation",
    "fingertips.features",
    "fingertips.forest",
    "fingertips.geodesic",
    "fingertips.geodesic_evaluation",
    "fingertips.heatmap",
    "fingertips.heatmap_evaluation",
    "fingertips.miss_causes",
    "fingertips.pictures",
    "fingertips.pose_guess",
    "fingertips.segmentation",
    "fingertips.trees",
    "fingertips.verify",
    "fingertips.voting",
)


def test_inference_modules_need_no_training_packages() -> None:
    code = (
        "import importlib, sys\n"
        "sys.modules['sklearn'] = sys.modules['torch'] = None\n"  # importing them now fails
        f"for name in {INFERENCE_MODULES!r}:\n"
        "    importlib.import_module(name)\n"
        "bad = [m for m in ('builder', 'pyrender', 'sklearn', 'torch') if sys.modules.get(m)]\n"
        "assert not bad, bad\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
