"""Fingertip detection on depth: Hough forest, 3D voting, assignment to model fingers.

Tzionas et al., "Capturing Hand Motion with an RGB-D Sensor, Fusing a Generative Model
with Salient Points" (GCPR 2014), Sec. 3.2.5, with Shotton et al.'s depth features.
"""

from tracker.fingertips.assignment import FINGER_NAMES, Assignment, assign_detections
from tracker.fingertips.detect import (
    DEFAULT_DETECTOR,
    Detection,
    DetectorConfig,
    detect_fingertips,
    fingertip_votes,
    fingertips_output,
    model_detector_config,
    name_fingers,
)
from tracker.fingertips.detector import FingertipDetector
from tracker.fingertips.forest import FingertipForest, load_forest, save_forest
from tracker.fingertips.pose_guess import PoseGuess, guess_hand_pose
from tracker.fingertips.voting import VotingConfig

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
