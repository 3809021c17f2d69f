"""Write the named trajectories Tr1-Tr5 (thesis ch. 4.3) and free_fingers to
configs/trajectories/.

The thesis recorded five movements with its tracker and replayed them as synthetic
Kinect data: Tr1 and Tr2 a pinch grasp, an open hand and some movements; Tr3, Tr4 and
Tr5 a power grasp, an open hand and some movements. The recordings are not
available, so these are hand-made stand-ins with the same content: realistic wrist
motion (forearm rotation, wrist flexion, the arm swinging in the image and toward the
camera), the hand 0.4-1.0 m from the camera and mostly in view. Tr4 holds the quick
open-close changes that make the posture error peak in the thesis' Figure 4.7.

``free_fingers`` tests the tracker on postures far from every grasp database: a fist
opens into pointing and a peace sign, the hand turns from its back to its palm, the
fingers curl one after another and the thumb crosses the palm. Postures that
configs/hand/postures.toml does not name are written out in :data:`FREE_POSTURES`,
in degrees by joint, and go into the file as 20 angles in radians.

Every keyframe is written out below in words a person can check: the posture name,
four angles in degrees and where the middle of the hand is (camera frame, metres):

- ``forearm``: rotation about the forearm; 0 shows the back of the hand to the
  camera, +90 the thumb side, -90 the little-finger side, 180 the palm;
- ``flex``: wrist flexion; positive tips the fingers toward the camera;
- ``roll``: the arm's direction in the image, degrees clockwise from "fingers up";
- ``lean``: the arm turned toward (positive) or away from the camera about the
  camera's x axis;
- ``centre``: the middle of the hand (0.42 hand lengths from the wrist along the
  hand's y axis) in the camera frame; the wrist is placed accordingly.

Nothing is random, so running it again writes the same files. It prints a Markdown
table (duration, rotation range, translation range, distance range, frames in view)
for docs/synthetic_data.md.

Usage::

    python scripts/make_trajectories.py [--out configs/trajectories]
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from glovedb import __version__
from glovedb.camera import KINECT_V1
from glovedb.hand_model import DEFAULT_HAND_LENGTH_M, JOINT_NAMES, forward_kinematics
from glovedb.rotations import (
    geodesic_angle,
    matrix_to_quaternion,
    rotation_x,
    rotation_y,
    rotation_z,
)
from glovedb.trajectory import Trajectory, trajectory_from_dict
from glovedb.views import HAND_CENTRE

FPS = 30
# cam_R_hand of the back of a right hand facing the camera, fingers up in the image.
BACK_TO_CAMERA = np.diag([1.0, -1.0, -1.0])

# time_s, posture, forearm, flex, roll, lean (degrees), centre of the hand (m)
Keyframe = tuple[float, str, float, float, float, float, tuple[float, float, float]]

# Postures no grasp database holds and configs/hand/postures.toml does not name, in
# degrees by joint (docs/conventions.md names, within the joint limits; joints not listed
# are 0, the straight open hand).
FREE_POSTURES: dict[str, dict[str, float]] = {
    # One finger curled into the palm, the other four and the thumb straight.
    "index_curled": {"index_mcp_flex": 80, "index_pip_flex": 95, "index_dip_flex": 50},
    "middle_curled": {"middle_mcp_flex": 80, "middle_pip_flex": 95, "middle_dip_flex": 50},
    "ring_curled": {"ring_mcp_flex": 65, "ring_pip_flex": 85, "ring_dip_flex": 45},
    "little_curled": {"little_mcp_flex": 80, "little_pip_flex": 95, "little_dip_flex": 50},
    # The thumb laid across the palm toward the little finger's base, fingers straight.
    "thumb_across": {
        "thumb_cmc_abd": 10,
        "thumb_cmc_flex": 50,
        "thumb_mcp_flex": 45,
        "thumb_ip_flex": 30,
    },
}

TRAJECTORIES: dict[str, tuple[str, list[Keyframe]]] = {
    "tr1_pinch": (
        "Tr1: open hand turns thumb-side on, pinches twice while swinging right and back.",
        [
            (0.0, "open", 0, 0, 0, 0, (0.00, 0.00, 0.60)),
            (1.0, "open", 30, 10, -10, 5, (-0.08, 0.02, 0.55)),
            (2.0, "pinch", 60, 20, -20, 10, (-0.12, 0.03, 0.50)),
            (3.0, "pinch", 90, 10, -15, 10, (-0.05, 0.05, 0.45)),
            (4.0, "pinch", 60, -15, 5, 0, (0.05, 0.00, 0.55)),
            (5.0, "open", 20, -10, 20, -5, (0.12, -0.03, 0.65)),
            (6.0, "pinch", -20, 0, 25, -10, (0.10, -0.05, 0.72)),
            (7.0, "pinch", -40, 15, 10, 0, (0.02, 0.00, 0.62)),
            (8.0, "open", 0, 0, 0, 0, (0.00, 0.00, 0.60)),
        ],
    ),
    "tr2_pinch": (
        "Tr2: palm to the camera, pinch while the hand comes near and goes far.",
        [
            (0.0, "open", 160, 0, 10, 0, (0.02, 0.00, 0.70)),
            (1.0, "open", 180, -10, 0, 10, (0.00, -0.02, 0.60)),
            (2.0, "pinch", 200, -20, -15, 20, (-0.06, 0.00, 0.48)),
            (3.0, "pinch", 150, 0, -25, 10, (-0.10, 0.04, 0.45)),
            (4.0, "open", 120, 15, -10, 0, (-0.04, 0.06, 0.60)),
            (5.0, "pinch", 140, 10, 15, -10, (0.08, 0.02, 0.80)),
            (6.0, "pinch", 190, -5, 30, -5, (0.12, -0.04, 0.90)),
            (7.0, "open", 170, 0, 10, 0, (0.04, 0.00, 0.75)),
        ],
    ),
    "tr3_power": (
        "Tr3: back of the hand to the camera, power grasp moved in depth and rolled.",
        [
            (0.0, "open", 0, 0, 0, 0, (0.00, 0.00, 0.55)),
            (1.0, "power", 10, 20, -20, 10, (-0.05, 0.02, 0.50)),
            (2.5, "power", -20, 30, -40, 15, (-0.10, 0.06, 0.45)),
            (4.0, "power", -40, 10, 0, 0, (0.00, 0.03, 0.70)),
            (5.0, "open", -20, -10, 30, -10, (0.10, -0.02, 0.85)),
            (6.0, "power", 20, 0, 40, -5, (0.15, -0.05, 0.95)),
            (7.0, "power", 40, 15, 15, 5, (0.05, 0.00, 0.75)),
            (8.0, "open", 0, 0, 0, 0, (0.00, 0.00, 0.60)),
        ],
    ),
    "tr4_power": (
        "Tr4: quick open-close changes of a power grasp while the hand turns to the palm.",
        [
            (0.0, "open", 0, 0, 0, 0, (0.00, 0.00, 0.60)),
            (0.8, "open", 40, 10, -10, 5, (-0.08, 0.02, 0.56)),
            (1.1, "power", 50, 10, -12, 5, (-0.10, 0.03, 0.55)),
            (2.0, "power", 90, 0, -20, 10, (-0.14, 0.05, 0.50)),
            (2.3, "open", 100, 0, -20, 10, (-0.14, 0.05, 0.50)),
            (3.2, "open", 150, -15, -5, 15, (-0.02, 0.00, 0.62)),
            (3.5, "power", 160, -15, 0, 15, (0.02, 0.00, 0.64)),
            (4.5, "power", 120, 10, 20, 0, (0.12, -0.04, 0.75)),
            (4.8, "open", 110, 10, 22, 0, (0.13, -0.04, 0.76)),
            (6.0, "open", 60, 0, 5, 0, (0.03, 0.00, 0.65)),
        ],
    ),
    "tr5_power": (
        "Tr5: a wide sweep left to right and back, the power grasp turned about all axes.",
        [
            (0.0, "open", 0, 0, 0, 0, (-0.18, 0.00, 0.70)),
            (1.5, "open", 30, -20, -30, 20, (-0.12, 0.05, 0.65)),
            (2.5, "power", 70, -10, -35, 30, (-0.05, 0.06, 0.60)),
            (4.0, "power", 110, 20, -10, 20, (0.05, 0.03, 0.55)),
            (5.5, "power", 60, 30, 25, -10, (0.16, -0.03, 0.68)),
            (6.5, "open", 0, 10, 35, -25, (0.20, -0.06, 0.80)),
            (8.0, "power", -40, -10, 10, -10, (0.05, 0.00, 0.75)),
            (9.0, "open", -10, 0, 0, 0, (-0.10, 0.00, 0.70)),
        ],
    ),
    "free_fingers": (
        "Free fingers: a fist opens into pointing and a peace sign, the hand turns to its "
        "palm, the fingers curl one after another, the thumb crosses the palm.",
        [
            (0.0, "fist", 0, 0, 0, 0, (0.00, 0.02, 0.62)),
            (0.8, "fist", 15, 5, -5, 5, (-0.02, 0.02, 0.61)),
            (1.8, "point", 25, 10, -10, 5, (-0.04, 0.01, 0.60)),
            (2.6, "point", 20, 5, -15, 0, (-0.04, 0.00, 0.60)),
            (3.4, "peace", 10, 0, -5, 0, (-0.02, 0.00, 0.60)),
            (4.4, "open", 160, -5, 5, 5, (0.00, 0.00, 0.58)),
            (4.9, "index_curled", 170, -5, 5, 5, (0.01, 0.00, 0.58)),
            (5.4, "middle_curled", 175, 0, 5, 0, (0.02, 0.00, 0.58)),
            (5.9, "ring_curled", 180, 0, 8, 0, (0.02, -0.01, 0.59)),
            (6.4, "little_curled", 185, 5, 10, 0, (0.03, -0.01, 0.60)),
            (7.0, "thumb_across", 190, 5, 10, -5, (0.03, -0.01, 0.60)),
            (7.5, "open", 180, 0, 5, 0, (0.02, 0.00, 0.62)),
        ],
    ),
}


def hand_rotation(forearm: float, flex: float, roll: float, lean: float) -> NDArray[np.float64]:
    """``cam_R_hand`` from the four angles of the module docstring, in degrees."""
    arm = rotation_z(np.radians(roll)) @ rotation_x(np.radians(lean)) @ BACK_TO_CAMERA
    return arm @ rotation_y(np.radians(forearm)) @ rotation_x(np.radians(flex))


def posture_json(name: str) -> str | list[float]:
    """A posture as the trajectory file holds it: a name of configs/hand/postures.toml
    as it is, a :data:`FREE_POSTURES` name as its 20 angles in radians."""
    if name not in FREE_POSTURES:
        return name
    angles = FREE_POSTURES[name]
    unknown = sorted(set(angles) - set(JOINT_NAMES))
    if unknown:
        raise ValueError(f"FREE_POSTURES[{name!r}]: unknown joint {unknown[0]!r}")
    return [round(math.radians(angles.get(joint, 0.0)), 6) for joint in JOINT_NAMES]


def keyframe_json(keyframe: Keyframe) -> dict:
    """One keyframe in the docs/conventions.md trajectory format."""
    time_s, posture, forearm, flex, roll, lean, centre = keyframe
    rotation = hand_rotation(forearm, flex, roll, lean)
    middle_of_hand = np.array(HAND_CENTRE) * DEFAULT_HAND_LENGTH_M
    wrist = np.array(centre) - rotation @ middle_of_hand
    quaternion = matrix_to_quaternion(rotation)
    return {
        "time_s": time_s,
        "posture": posture_json(posture),
        "rotation_quat_wxyz": np.round(quaternion, 6).tolist(),
        "translation_m": np.round(wrist, 5).tolist(),
    }


def trajectory_json(name: str) -> dict:
    """The file content of a named trajectory."""
    description, keyframes = TRAJECTORIES[name]
    return {
        "name": name,
        "description": description,
        "generator": "scripts/make_trajectories.py",
        "version": __version__,
        "fps": FPS,
        "keyframes": [keyframe_json(keyframe) for keyframe in keyframes],
    }


def file_text(content: dict) -> str:
    """JSON text with one line per keyframe, easy to read and to compare."""
    header = json.dumps({key: value for key, value in content.items() if key != "keyframes"})
    keyframes = ",\n  ".join(json.dumps(keyframe) for keyframe in content["keyframes"])
    return f'{header[:-1]},\n "keyframes": [\n  {keyframes}\n ]\n}}\n'


def statistics(trajectory: Trajectory) -> dict[str, float]:
    """Ranges a reader wants to know about a trajectory, over its frames at its fps.

    rotation range: the largest angle between the hand's orientations in any two
    frames; translation: the extent of the wrist's path along x, y and z and its
    length; distance: the wrist's depth z; in view: the share of frames whose 21
    keypoints all project into a Kinect v1 image.
    """
    postures, rotations, translations = trajectory.sample(trajectory.frame_times())
    angles = geodesic_angle(rotations[:, None], rotations[None, :])
    keypoints = forward_kinematics(postures).keypoints_m
    camera_points = np.einsum("tij,tkj->tki", rotations, keypoints) + translations[:, None]
    pixels = KINECT_V1.project(camera_points)
    inside = (
        (pixels[..., 0] >= 0)
        & (pixels[..., 0] <= KINECT_V1.width - 1)
        & (pixels[..., 1] >= 0)
        & (pixels[..., 1] <= KINECT_V1.height - 1)
    )
    extent = translations.max(axis=0) - translations.min(axis=0)
    return {
        "duration_s": trajectory.duration_s,
        "frames": len(postures),
        "rotation_range_deg": float(np.degrees(angles.max())),
        "extent_x_cm": 100 * extent[0],
        "extent_y_cm": 100 * extent[1],
        "extent_z_cm": 100 * extent[2],
        "path_cm": 100 * float(np.linalg.norm(np.diff(translations, axis=0), axis=1).sum()),
        "depth_min_m": float(translations[:, 2].min()),
        "depth_max_m": float(translations[:, 2].max()),
        "in_view_percent": 100 * float(inside.all(axis=1).mean()),
    }


def markdown_table(rows: dict[str, dict[str, float]]) -> str:
    """The statistics of every trajectory as a Markdown table."""
    lines = [
        "| trajectory | duration | frames | rotation range | wrist extent x / y / z | "
        "wrist path | wrist depth | fully in view |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, s in rows.items():
        lines.append(
            f"| `{name}` | {s['duration_s']:.1f} s | {s['frames']:.0f} | "
            f"{s['rotation_range_deg']:.0f}° | {s['extent_x_cm']:.0f} / {s['extent_y_cm']:.0f} / "
            f"{s['extent_z_cm']:.0f} cm | {s['path_cm']:.0f} cm | "
            f"{s['depth_min_m']:.2f}-{s['depth_max_m']:.2f} m | {s['in_view_percent']:.0f} % |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    default_out = Path(__file__).resolve().parents[1] / "configs" / "trajectories"
    parser.add_argument("--out", type=Path, default=default_out, help="output folder")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    rows = {}
    for name in TRAJECTORIES:
        content = trajectory_json(name)
        (args.out / f"{name}.json").write_text(file_text(content))
        rows[name] = statistics(trajectory_from_dict(content, source=name))
    print(markdown_table(rows))


if __name__ == "__main__":
    main()
