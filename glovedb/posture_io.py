"""Posture files: CSV with the 20 joint names as header, or ``.npy`` of shape (N, 20).

Angles are radians in both formats (docs/conventions.md order for ``.npy``; any column
order for CSV, matched by name).
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array
from glovedb.hand_model import JOINT_NAMES, N_JOINTS


def load_postures(path: str | Path) -> NDArray[np.float64]:
    """Read postures from a ``.csv`` or ``.npy`` file; returns ``(N, 20) float64`` radians.

    Raises
    ------
    ValueError
        One line naming the file and the problem (missing, wrong columns, bad numbers,
        wrong shape, no rows, an angle beyond +-pi: degrees where radians belong).
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such posture file")
    if path.suffix.lower() == ".npy":
        try:
            data = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as error:
            # numpy calls any file without its header "pickled data": not helpful here
            raise ValueError(f"{path}: not a .npy array file") from error
        postures = as_array(str(path), data, (None, N_JOINTS), np.float64, kind="fiu", finite=True)
    elif path.suffix.lower() == ".csv":
        postures = _read_csv(path)
    else:
        raise ValueError(f"{path}: posture files are .csv or .npy")
    if len(postures) == 0:
        raise ValueError(f"{path}: no postures in the file")
    beyond = np.argwhere(np.abs(postures) > np.pi)
    if len(beyond):
        row, joint = beyond[0]
        raise ValueError(
            f"{path}: posture {row}, {JOINT_NAMES[joint]} is {postures[row, joint]:g}, beyond "
            "+-pi: posture files hold radians (degrees?)"
        )
    return postures


def _read_csv(path: Path) -> NDArray[np.float64]:
    with open(path, newline="") as stream:
        rows = list(csv.reader(stream))
    if not rows:
        raise ValueError(f"{path}: empty file")
    header = [name.strip() for name in rows[0]]
    missing = [name for name in JOINT_NAMES if name not in header]
    if missing:
        raise ValueError(f"{path}: header lacks joint columns {', '.join(missing[:3])}...")
    columns = [header.index(name) for name in JOINT_NAMES]
    try:
        values = [[float(row[c]) for c in columns] for row in rows[1:] if row]
    except (ValueError, IndexError) as error:
        raise ValueError(f"{path}: a row is not 20 numbers ({error})") from error
    return as_array(str(path), np.array(values).reshape(-1, N_JOINTS), finite=True)


def save_postures_csv(path: str | Path, postures: ArrayLike) -> None:
    """Write ``(N, 20)`` postures in radians as CSV with the joint-name header."""
    array = as_array("postures", postures, (None, N_JOINTS), np.float64, finite=True)
    with open(path, "w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(JOINT_NAMES)
        writer.writerows([[repr(float(x)) for x in row] for row in array])
