"""Fingertip detection on depth: Hough forest, 3D voting, assignment to model fingers.

Tzionas et al., "Capturing Hand Motion with an RGB-D Sensor, Fusing a Generative Model
with Salient Points" (GCPR 2014), Sec. 3.2.5, with Shotton et al.'s depth features,
and a whole-hand heatmap network for the tips the forest cannot see.

The whole detector lives here (docs/fingertips.md):

- inference, which imports neither ``builder``, pyrender, scikit-learn nor PyTorch
  (the tracker uses it): :mod:`~fingertips.features`, :mod:`~fingertips.forest` (the
  model file), :mod:`~fingertips.trees`, :mod:`~fingertips.voting`,
  :mod:`~fingertips.verify`, :mod:`~fingertips.heatmap`, :mod:`~fingertips.detect`,
  :mod:`~fingertips.assignment`, :mod:`~fingertips.pose_guess`,
  :mod:`~fingertips.segmentation`, :mod:`~fingertips.detector`, :mod:`~fingertips.depth_input`,
  :mod:`~fingertips.evaluation`, :mod:`~fingertips.miss_causes`,
  :mod:`~fingertips.heatmap_evaluation`, :mod:`~fingertips.geodesic` (candidates
  without learning) with :mod:`~fingertips.geodesic_evaluation`,
  :mod:`~fingertips.calibration` (calibrated confidences) and
  :mod:`~fingertips.pictures`;
- training, which renders with ``builder`` and fits with scikit-learn (and PyTorch for
  the network): :mod:`~fingertips.data`, :mod:`~fingertips.training`,
  :mod:`~fingertips.verifier_training`, :mod:`~fingertips.heatmap_data`,
  :mod:`~fingertips.heatmap_training`, :mod:`~fingertips.calibration_training` and
  :mod:`~fingertips.tree_export`. Importing
  this package imports none of them.
"""

from fingertips.assignment import FINGER_NAMES, Assignment, assign_detections
from fingertips.detect import (
    DEFAULT_DETECTOR,
    Detection,
    DetectorConfig,
    detect_fingertips,
    fingertip_votes,
    fingertips_output,
    model_detector_config,
    name_fingers,
)
from fingertips.detector import FingertipDetector
from fingertips.forest import FingertipForest, load_forest, save_forest
from fingertips.pose_guess import PoseGuess, guess_hand_pose
from fingertips.voting import VotingConfig

__all__ = [
    "DEFAULT_DETECTOR",
    "FINGER_NAMES",
    "Assignment",
    "Detection",
    "DetectorConfig",
    "FingertipDetector",
    "FingertipForest",
    "PoseGuess",
    "VotingConfig",
    "assign_detections",
    "detect_fingertips",
    "fingertip_votes",
    "fingertips_output",
    "guess_hand_pose",
    "load_forest",
    "model_detector_config",
    "name_fingers",
    "save_forest",
]
