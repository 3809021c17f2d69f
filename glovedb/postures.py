"""Named hand postures (``configs/hand/postures.toml``) and posture lookup by name."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import tomllib
from numpy.typing import NDArray

from glovedb.hand_model import JOINT_NAMES, N_JOINTS, within_limits
from glovedb.resources import config_path

# The names docs/conventions.md requires; the file may define more.
REQUIRED_POSTURES: tuple[str, ...] = (
    "open", "fist", "pinch", "power", "tripod", "lateral", "point", "peace", "ok", "thumbs_up",
)  # fmt: skip


def load_named_postures(path: str | Path | None = None) -> dict[str, NDArray[np.float64]]:
    """All named postures of a TOML file (default: the project's), in radians.

    Returns
    -------
    dict of str to (20,) float64
        In file order.

    Raises
    ------
    ValueError
        For an unknown joint name or an angle outside the joint limits.
    """
    path = Path(path) if path is not None else config_path("hand/postures.toml")
    with open(path, "rb") as stream:
        table = tomllib.load(stream)
    postures = {}
    for name, angles_deg in table.items():
        posture = np.zeros(N_JOINTS)
        for joint, value in angles_deg.items():
            if joint not in JOINT_NAMES:
                raise ValueError(f"{path}: posture {name!r} has unknown joint {joint!r}")
            posture[JOINT_NAMES.index(joint)] = np.radians(float(value))
        if not within_limits(posture):
            raise ValueError(f"{path}: posture {name!r} is outside the joint limits")
        postures[name] = posture
    return postures


def named_posture(name: str) -> NDArray[np.float64]:
    """The ``(20,)`` posture in radians called ``name``; ``ValueError`` lists the names."""
    postures = load_named_postures()
    if name not in postures:
        raise ValueError(f"unknown posture {name!r}; known: {', '.join(postures)}")
    return postures[name]
