"""Toy fingertip scenes and a hand-made forest, shared by the fingertip tests."""

import numpy as np

from fingertips import DetectorConfig, FingertipForest
from fingertips.verify import PeakVerifier

STRIDE_1 = DetectorConfig(stride=1)

INTRINSICS = (200.0, 200.0, 40.0, 40.0)
Z_M = 0.4
PROBE_M = 0.008


def bar_scene() -> tuple[np.ndarray, np.ndarray]:
    """A vertical bar ("finger") at 0.4 m whose upper end is the planted tip."""
    depth = np.zeros((80, 80), np.float32)
    depth[30:, 37:43] = Z_M
    fx, _, cx, cy = INTRINSICS
    tip_m = np.array([(39.5 - cx) * Z_M / fx, (29.5 - cy) * Z_M / fx, Z_M])
    return depth, tip_m


def toy_forest() -> FingertipForest:
    """One split: a probe PROBE_M above the pixel off the bar means "near the tip".

    Pixels within PROBE_M of the upper end vote PROBE_M / 2 upwards, so their votes
    centre on the end.
    """
    offsets = np.zeros((1, 2, 2), np.float32)
    offsets[0, 0] = (0.0, -PROBE_M)
    return FingertipForest(
        offsets_m=offsets,
        depth_range_m=(0.1, 1.0),
        tree_roots=np.array([0], np.int32),
        node_feature=np.array([0, -1, -1], np.int32),
        node_threshold=np.array([1.0, 0.0, 0.0], np.float32),
        node_left=np.array([1, -1, -1], np.int32),
        node_right=np.array([2, -1, -1], np.int32),
        node_probability=np.array([0.1, 0.0, 1.0], np.float32),
        node_offset_m=np.array([[0, 0, 0], [0, 0, 0], [0, -PROBE_M / 2, 0]], np.float32),
    )


def constant_verifier(probability: float) -> PeakVerifier:
    """One tree, one leaf: every peak gets ``probability``."""
    return PeakVerifier(
        tree_roots=np.array([0], np.int32),
        node_feature=np.array([-1], np.int32),
        node_threshold=np.zeros(1, np.float32),
        node_left=np.array([-1], np.int32),
        node_right=np.array([-1], np.int32),
        node_probability=np.array([probability], np.float32),
    )


def render_named_hand(
    renderer, posture: str, side: str, distance_m: float, noise: str = "none"
):  # -> fingertips.data.FingertipExample (imported lazily: it needs the renderer)
    """A rendered example of a named posture seen from the palm or the back, its middle
    ``distance_m`` in front of the camera on the optical axis, fingers up."""
    from fingertips.data import FingertipDataConfig, Scene, render_scene
    from glovedb.postures import named_posture
    from glovedb.views import HAND_CENTRE, pose_for_view

    length = renderer.mesh.skeleton.hand_length_m
    direction = np.array([0.0, 0.0, -1.0 if side == "palm" else 1.0])
    rotation, translation = pose_for_view(
        direction, distance_m, target_m=np.array(HAND_CENTRE) * length
    )
    scene = Scene(
        named_posture(posture), rotation, translation, length, None, None, False, noise, False
    )
    return render_scene(renderer, scene, FingertipDataConfig(), np.random.default_rng(0))
