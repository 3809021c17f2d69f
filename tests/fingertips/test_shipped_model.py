"""The shipped model: loads without scikit-learn or PyTorch, finds a rendered hand's tips."""

import subprocess
import sys
import warnings

import numpy as np
import pytest

from fingertips import detect_fingertips, load_forest, model_detector_config
from fingertips.forest import DEFAULT_MODEL_PATH
from fingertips.heatmap import HeatmapNetwork
from fingertips.heatmap_quantization import is_quantized


def test_shipped_model_loads_and_is_small() -> None:
    assert DEFAULT_MODEL_PATH.is_file()
    assert DEFAULT_MODEL_PATH.stat().st_size < 13e6
    model = load_forest()
    config = model_detector_config(model)
    assert model.n_trees >= 1 and config.c_thr > 0 and np.isfinite(config.depth_band_m)
    assert "data" in model.settings and model.version
    assert model.verifier is not None and config.min_tip_probability > 0
    assert model.heatmap is not None and config.heatmap_min_probability > 0
    assert is_quantized(model.heatmap.network_onnx)  # the 8-bit network (3x faster)


def test_shipped_network_runs_its_fused_kernels_on_this_cpu() -> None:
    # Its weights are stored unsigned: signed 8-bit weights saturate onnxruntime's
    # kernels on CPUs without VNNI, where the network then warns and runs its
    # (3 times slower) reference graph. Before, it gave noise there.
    network = load_forest().heatmap.network_onnx
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert not HeatmapNetwork(network, 4).reference_graph


def test_shipped_network_holds_no_signed_weights() -> None:
    onnx = pytest.importorskip("onnx", reason="reading the graph needs the onnx package")
    graph = onnx.load_from_string(load_forest().heatmap.network_onnx.tobytes()).graph
    types = {tensor.data_type for tensor in graph.initializer}
    assert onnx.TensorProto.UINT8 in types and onnx.TensorProto.INT8 not in types


def test_shipped_model_needs_no_scikit_learn_or_torch() -> None:
    code = (
        "import sys, numpy as np\n"
        "sys.modules['sklearn'] = sys.modules['torch'] = None\n"  # importing them now fails
        "from fingertips import detect_fingertips, load_forest, model_detector_config\n"
        "model = load_forest()\n"
        "depth = np.zeros((48, 64), np.float32); depth[10:40, 20:40] = 0.5\n"
        "config = model_detector_config(model)\n"
        "detect_fingertips(depth, (60.0, 60.0, 31.5, 23.5), model, config=config)\n"
        "assert 'pyrender' not in sys.modules and 'builder' not in sys.modules\n"
        "assert 'onnxruntime' in sys.modules\n"  # the heatmap stage ran
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr


@pytest.mark.gl
def test_shipped_model_finds_the_tips_of_a_rendered_open_hand(renderer) -> None:
    from glovedb.camera import KINECT_V1
    from glovedb.hand_model import FINGERTIP_KEYPOINTS, forward_kinematics
    from glovedb.postures import named_posture
    from glovedb.views import named_view

    posture = named_posture("open")
    skeleton = renderer.mesh.skeleton
    rotation, translation = named_view("palm", 0.45, skeleton.hand_length_m)
    depth = renderer.render_labels(posture, rotation, translation).depth_m
    keypoints = forward_kinematics(posture, skeleton).keypoints_m[0] @ rotation.T + translation
    tips = keypoints[list(FINGERTIP_KEYPOINTS)]
    camera = KINECT_V1.pinhole
    model = load_forest()
    detections = detect_fingertips(depth, camera, model, config=model_detector_config(model))
    found = [np.linalg.norm(tips - (d.x_m, d.y_m, d.z_m), axis=1).min() for d in detections]
    assert sum(distance < 0.015 for distance in found) >= 3


@pytest.mark.gl
@pytest.mark.parametrize("view", ["palm", "back"])
def test_pose_guess_from_detections_on_a_rendered_open_hand(renderer, view: str) -> None:
    from fingertips import FINGER_NAMES
    from fingertips.detector import FingertipDetector
    from glovedb.camera import KINECT_V1
    from glovedb.hand_model import FINGERTIP_KEYPOINTS, forward_kinematics
    from glovedb.postures import named_posture
    from glovedb.views import named_view

    posture = named_posture("open")
    rotation, translation = named_view(view, 0.45, renderer.mesh.skeleton.hand_length_m)
    depth = renderer.render_labels(posture, rotation, translation).depth_m
    camera = KINECT_V1.pinhole
    detector = FingertipDetector()
    record = detector.record(0, depth, camera, pose_guess=True)
    guess = record["pose_guess"]
    assert guess is not None
    cos = (np.trace(np.asarray(guess["rotation"]).T @ rotation) - 1) / 2
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))) < 10
    assert np.linalg.norm(np.asarray(guess["translation_m"]) - translation) < 0.02
    keypoints = forward_kinematics(posture).keypoints_m[0] @ rotation.T + translation
    true_tips = dict(zip(FINGER_NAMES, keypoints[list(FINGERTIP_KEYPOINTS)], strict=True))
    named = [tip for tip in record["fingertips"] if tip["finger"]]
    assert len(named) >= 3 and len({tip["finger"] for tip in named}) == len(named)
    for tip in named:
        position = np.array([tip["x_m"], tip["y_m"], tip["z_m"]])
        assert np.linalg.norm(position - true_tips[tip["finger"]]) < 0.015
