"""A person's hand proportions: the model hand stretched to fit a real hand.

Real hands differ from the model in overall size, in the length of each finger and in
the width of the palm. :class:`HandProportions` holds seven factors against the model:

- ``length_scale``: the whole hand, about the wrist (1.1 is a hand 10 % longer);
- ``finger_length`` (5, thumb first): the length of one finger's three segments
  (the thumb's metacarpal, proximal and distal bones);
- ``palm_width``: the palm's extent across the hand (hand-frame x), which moves the
  fingers' bases apart.

The personal hand is the model's skeleton with its offsets and bone lengths scaled,
and the model's mesh re-rested by a scale of every bone's local frame::

    v' = sum_b w_b * hand_T_bone'_b @ D_b @ inv(hand_T_bone_b) @ v

with ``hand_T_bone`` the rest transforms of the model and of the personal skeleton,
and ``D_b`` the bone's scale: ``length_scale * diag(palm_width, 1, 1)`` for the palm,
``length_scale * diag(1, finger_length, 1)`` for a finger bone (fingers grow longer,
not thicker). Skinning weights and faces are kept, so a personal mesh poses, renders
and differentiates like the model's.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from glovedb import __version__
from glovedb.hand_model import N_BONES, N_JOINTS, Skeleton, forward_kinematics
from glovedb.mesh import HandMesh, skin

FACTOR_RANGE = (0.5, 2.0)
"""Every factor must lie in this range (a hand half or twice the model's)."""

N_PROPORTIONS = 7
"""Length of :meth:`HandProportions.as_vector`: length scale, five fingers, palm width."""


@dataclass(frozen=True)
class HandProportions:
    """Factors of a personal hand against the model hand (module docstring).

    Attributes
    ----------
    length_scale : float
        Whole hand, about the wrist.
    finger_length : (5,) tuple of float
        Each finger's segment lengths, thumb first.
    palm_width : float
        The palm across the hand.
    """

    length_scale: float = 1.0
    finger_length: tuple[float, float, float, float, float] = (1.0, 1.0, 1.0, 1.0, 1.0)
    palm_width: float = 1.0

    def __post_init__(self) -> None:
        values = [self.length_scale, *self.finger_length, self.palm_width]
        if len(self.finger_length) != 5:
            raise ValueError(f"finger_length: expected 5 factors, got {len(self.finger_length)}")
        low, high = FACTOR_RANGE
        for name, value in zip(_NAMES, values, strict=True):
            if not low <= float(value) <= high:
                raise ValueError(f"{name}: expected a factor in {low}-{high}, got {value}")
        object.__setattr__(self, "finger_length", tuple(float(f) for f in self.finger_length))

    @classmethod
    def from_vector(cls, vector: NDArray[np.float64]) -> HandProportions:
        """From ``(7,)`` factors in :meth:`as_vector` order."""
        values = np.asarray(vector, dtype=np.float64).reshape(-1)
        if values.shape != (N_PROPORTIONS,):
            raise ValueError(f"vector: expected {N_PROPORTIONS} factors, got {values.shape}")
        return cls(float(values[0]), tuple(float(v) for v in values[1:6]), float(values[6]))  # type: ignore[arg-type]

    def as_vector(self) -> NDArray[np.float64]:
        """``(7,)`` length scale, finger lengths (thumb first), palm width."""
        return np.array([self.length_scale, *self.finger_length, self.palm_width])

    @property
    def is_model(self) -> bool:
        """Whether these are the model's own proportions (every factor 1)."""
        return bool(np.all(self.as_vector() == 1.0))

    def as_dict(self) -> dict[str, Any]:
        return {
            "length_scale": self.length_scale,
            "finger_length": list(self.finger_length),
            "palm_width": self.palm_width,
        }


_NAMES = ("length_scale",) + tuple(f"finger_length[{i}]" for i in range(5)) + ("palm_width",)


def bone_scales(proportions: HandProportions) -> NDArray[np.float64]:
    """``(16, 3)`` scale of every bone's local x, y, z axes (module docstring)."""
    scales = np.full((N_BONES, 3), proportions.length_scale)
    scales[0, 0] *= proportions.palm_width
    for finger, factor in enumerate(proportions.finger_length):
        scales[1 + 3 * finger : 4 + 3 * finger, 1] *= factor
    return scales


def proportioned_skeleton(skeleton: Skeleton, proportions: HandProportions) -> Skeleton:
    """The model's skeleton with the proportions of a personal hand.

    Parameters
    ----------
    skeleton : Skeleton
        The model's.
    proportions : HandProportions

    Returns
    -------
    Skeleton
        ``hand_length_m`` is the model's times ``length_scale`` (it sets the finger
        radii, which follow the overall size, not the finger lengths).
    """
    scale = proportions.length_scale
    offsets = skeleton.offsets_m * scale
    lengths = skeleton.lengths_m * scale
    for finger, factor in enumerate(proportions.finger_length):
        first = 1 + 3 * finger
        offsets[first, 0] *= proportions.palm_width
        lengths[first : first + 3] *= factor
        offsets[first + 1 : first + 3, 1] *= factor
    return Skeleton(
        skeleton.hand_length_m * scale,
        offsets,
        skeleton.rest_before.copy(),
        skeleton.rest_after.copy(),
        lengths,
    )


def proportioned_mesh(
    mesh: HandMesh, proportions: HandProportions, *, thickness: float = 1.0
) -> HandMesh:
    """The model's mesh re-rested for a personal hand (module docstring).

    Parameters
    ----------
    mesh : HandMesh
        The model's.
    proportions : HandProportions
    thickness : float
        Extra scale of every bone's local z axis (palm and finger thickness, across
        the palm plane), 0.5-2; it moves no joint, so the skeleton is unchanged by it.
        Not one of the tracked proportions: for rendering varied hands.

    Returns
    -------
    HandMesh
        Same faces and weights; the model's mesh itself when every factor is 1.
    """
    low, high = FACTOR_RANGE
    if not low <= thickness <= high:
        raise ValueError(f"thickness: expected a factor in {low}-{high}, got {thickness}")
    if proportions.is_model and thickness == 1.0:
        return mesh
    skeleton = proportioned_skeleton(mesh.skeleton, proportions)
    rest = np.zeros((2, N_JOINTS))
    model_rest, personal_rest = (
        forward_kinematics(rest[:1], s).bone_transforms[0] for s in (mesh.skeleton, skeleton)
    )
    stretch = bone_stretch(proportions, thickness=thickness)
    moves = (personal_rest @ stretch @ np.linalg.inv(model_rest))[:, :3, :]  # (16, 3, 4)
    return mesh.rerested(skeleton, skin(mesh, moves[None])[0])


def bone_stretch(proportions: HandProportions, *, thickness: float = 1.0) -> NDArray[np.float64]:
    """``(16, 4, 4)`` scaling of every bone's local axes (:func:`bone_scales`, and
    ``thickness`` along z) as homogeneous matrices."""
    stretch = np.tile(np.eye(4), (N_BONES, 1, 1))
    stretch[:, [0, 1, 2], [0, 1, 2]] = bone_scales(proportions) * [1.0, 1.0, thickness]
    return stretch


def save_proportions(
    path: str | Path, proportions: HandProportions, *, extra: dict[str, Any] | None = None
) -> Path:
    """Write proportions as JSON (``--hand FILE`` reads it back), with the project
    version and any ``extra`` fields (e.g. how they were estimated)."""
    record = {"version": __version__, **proportions.as_dict(), **(extra or {})}
    target = Path(path)
    target.write_text(json.dumps(record, indent=1) + "\n")
    return target


def load_proportions(path: str | Path) -> HandProportions:
    """Read proportions written by :func:`save_proportions`.

    Raises
    ------
    ValueError
        One line naming the file, when it is missing, not JSON or lacks a factor.
    """
    source = Path(path)
    try:
        record = json.loads(source.read_text())
        return HandProportions(
            float(record["length_scale"]),
            tuple(float(f) for f in record["finger_length"]),  # type: ignore[arg-type]
            float(record["palm_width"]),
        )
    except FileNotFoundError as error:
        raise ValueError(f"{source}: no such hand proportions file") from error
    except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError) as error:
        raise ValueError(f"{source}: not a hand proportions file ({error})") from error
