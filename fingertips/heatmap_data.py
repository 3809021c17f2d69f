"""Training data of the whole-hand heatmap network: its settings and the hand crops.

The ``[heatmap]`` table of a fingertip config (:class:`HeatmapTrainingConfig`) says
how the heatmap stage is trained. Its crops (:func:`render_crops`) are frames rendered
with the recipe's ``[data]`` settings overridden by ``[heatmap.data]``, one run of
``crops_per_seed`` frames per seed of ``crop_seeds``; each gives the hand crop
(:func:`fingertips.heatmap.hand_crop`) and its visible fingertips (the data's
visibility rule; with ``surface_tip_depth_m`` a tip hidden by a few centimetres is the
surface point in front of it) in the crop's [-1, 1] units. Crop files
(:func:`save_crops`, :func:`load_crops`) let the rendering run apart from the
network's training (``glove fingertips crops``, ``glove fingertips train-heatmap``).
Needs no PyTorch; the network is trained by :mod:`fingertips.heatmap_training`.
"""

from __future__ import annotations

import json
import os
import zipfile
import zlib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fingertips.data import FingertipDataConfig, data_config_from_dict, generate_examples
from fingertips.heatmap import (
    CROP_CENTRES,
    CROP_HALF_M,
    PASSES,
    CropCentre,
    crop_units,
    frame_crop_centre,
    hand_crop,
)
from glovedb import __version__
from glovedb._files import write_atomically
from glovedb._validate import check_choice, dataclass_from_table

CROPS_FORMAT = "glove-fingertip-crops"
"""The ``format`` entry of a crop file."""

_WHOLE_HAND_XY_M = 0.14
"""A crop holds the whole hand when every keypoint lies this close to its centre (x, y)."""


@dataclass(frozen=True)
class HeatmapTrainingConfig:
    """Settings of the heatmap stage's training (the ``[heatmap]`` table).

    Attributes
    ----------
    data : dict
        Settings of the recipe's ``[data]`` table replaced for the heatmap's frames
        (the ``[heatmap.data]`` table).
    crop_seeds : tuple of int
        One run of ``crops_per_seed`` rendered frames per seed gives the network's
        training crops.
    crops_per_seed : int
    width : int
        Channels of the network's stem (:class:`HeatNet`).
    whole_hand_epochs, all_epochs : int
        Epochs on the crops holding the whole hand, then on all crops.
    whole_hand_learning_rate, all_learning_rate : float
        Peak of each stage's one-cycle schedule.
    batch_size : int
    positive_weight : float
        Weight of the fingertip cells in the binary cross-entropy.
    sigma_cells : float
        Width of the target Gaussians, heatmap cells.
    passes : int
        Averaged passes at detection (:func:`fingertips.heatmap.crop_views`).
    min_value : float
        Smallest mean heat of a peak given to the verifier.
    verifier_seeds : tuple of int
        One run of ``verifier_images`` frames (at full resolution) per seed gives the
        verifier's peaks.
    verifier_images : int
    match_radius_m : float
        A peak within this distance of a visible fingertip is a true one.
    verifier_iterations, verifier_leaf_nodes : int
        Boosting iterations and leaves per tree.
    verifier_learning_rate : float
    quantize : bool
        Store the network with 8-bit weights and activations
        (:mod:`fingertips.heatmap_quantization`; 3 times faster at detection), before
        its verifier is fitted on what it gives. Needs the ``onnx`` package.
    quantize_crops : int
        Frames of the first crop seed whose crops calibrate the quantization.
    crop_centre : {"density", "fingers"}
        The crop centre's rule of the network's training crops
        (:func:`fingertips.heatmap.frame_crop_centre`). The detector's own rule is
        ``[detector] heatmap_centre``, which the heatmap's verifier is fitted with; the
        shipped network was trained on ``"density"`` crops and is used with
        ``"fingers"`` (docs/fingertips.md, "The crop centre").
    judge_candidates : bool
        Fit the candidate judge (:mod:`fingertips.judge`) on the verifier's frames;
        without it the detector keeps candidates by the peak verifier alone.
    judge_iterations, judge_leaf_nodes : int
        The judge's boosting iterations and leaves per tree.
    judge_learning_rate : float
    seed : int
        Seeds PyTorch, the crop order and the boosting.
    """

    data: Mapping[str, Any] | None = None
    crop_seeds: tuple[int, ...] = (101, 102, 103, 104, 105)
    crops_per_seed: int = 7000
    width: int = 8
    whole_hand_epochs: int = 18
    all_epochs: int = 5
    whole_hand_learning_rate: float = 2e-3
    all_learning_rate: float = 1e-3
    batch_size: int = 64
    positive_weight: float = 20.0
    sigma_cells: float = 1.2
    passes: int = 8
    min_value: float = 0.3
    verifier_seeds: tuple[int, ...] = (11, 12)
    verifier_images: int = 5000
    match_radius_m: float = 0.015
    verifier_iterations: int = 300
    verifier_leaf_nodes: int = 31
    verifier_learning_rate: float = 0.05
    quantize: bool = False
    quantize_crops: int = 200
    crop_centre: CropCentre = "density"
    judge_candidates: bool = True
    judge_iterations: int = 300
    judge_leaf_nodes: int = 31
    judge_learning_rate: float = 0.05
    seed: int = 0

    def __post_init__(self) -> None:
        for name in (
            "crops_per_seed",
            "width",
            "batch_size",
            "verifier_images",
            "quantize_crops",
            "judge_iterations",
        ):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}: expected at least 1, got {getattr(self, name)}")
        if not self.crop_seeds or not self.verifier_seeds:
            raise ValueError("crop_seeds, verifier_seeds: expected at least one seed")
        if self.whole_hand_epochs < 0 or self.all_epochs < 0:
            raise ValueError("whole_hand_epochs, all_epochs: expected 0 or more")
        if self.whole_hand_epochs + self.all_epochs < 1:
            raise ValueError("whole_hand_epochs + all_epochs: expected at least one epoch")
        for name in ("verifier_leaf_nodes", "judge_leaf_nodes"):
            if getattr(self, name) < 2:
                raise ValueError(f"{name}: expected at least 2, got {getattr(self, name)}")
        for name in (
            "whole_hand_learning_rate",
            "all_learning_rate",
            "verifier_learning_rate",
            "judge_learning_rate",
        ):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: expected a positive rate, got {getattr(self, name)}")
        check_choice("crop_centre", self.crop_centre, CROP_CENTRES)
        if self.passes not in PASSES:
            raise ValueError(f"passes: expected one of {PASSES}, got {self.passes}")
        if not 0 <= self.min_value < 1:
            raise ValueError(f"min_value: expected a probability below 1, got {self.min_value}")
        for name in ("match_radius_m", "sigma_cells", "positive_weight"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: expected a positive value, got {getattr(self, name)}")

    def heatmap_data(self, data: FingertipDataConfig) -> FingertipDataConfig:
        """The recipe's data settings with ``[heatmap.data]`` applied."""
        table = {**asdict(data), **(self.data or {})}
        return data_config_from_dict(table)


def heatmap_config_from_dict(table: Mapping[str, Any]) -> HeatmapTrainingConfig:
    """Build a :class:`HeatmapTrainingConfig` from a TOML table; unknown keys are errors."""
    values = dict(table)
    data = values.pop("data", None)
    if data is not None:
        data_config_from_dict(data)  # unknown or invalid data keys fail here, by name
    return replace(dataclass_from_table(HeatmapTrainingConfig, values, "heatmap"), data=data)


# --- crops --------------------------------------------------------------------------


@dataclass(frozen=True)
class Crops:
    """Hand crops and their fingertips.

    Attributes
    ----------
    images : (N, CROP_PX, CROP_PX) float16
        :func:`fingertips.heatmap.hand_crop` of each frame.
    tips : (N, 5, 2) float32
        Visible fingertips in the crop's [-1, 1] units (x right, y down); NaN if hidden.
    whole_hand : (N,) bool
        Every keypoint of the hand lies inside the crop's cube.
    """

    images: NDArray[np.float16]
    tips: NDArray[np.float32]
    whole_hand: NDArray[np.bool_]


def render_crops(
    data: FingertipDataConfig,
    seeds: Iterable[int],
    per_seed: int,
    *,
    centre: CropCentre = "density",
    progress: bool = False,
) -> Crops:
    """Render ``per_seed`` frames for each seed and crop the hand of each.

    ``centre`` is the crop centre's rule (:func:`fingertips.heatmap.frame_crop_centre`),
    the config's ``crop_centre``. Frames without an object in view are skipped.
    """
    from tqdm import tqdm

    images, tips, whole = [], [], []
    for seed in seeds:
        frames = generate_examples(replace(data, seed=seed, n_images=per_seed))
        for example in tqdm(
            frames, total=per_seed, desc=f"crops (seed {seed})", unit="img", disable=not progress
        ):
            camera = np.asarray(example.intrinsics, dtype=np.float64)
            middle = frame_crop_centre(example.depth_m, camera, centre)
            if middle is None:
                continue
            images.append(hand_crop(example.depth_m, camera, middle).astype(np.float16))
            tips.append(crop_units(example.tips_m, middle))
            local = (example.keypoints_m - middle).astype(np.float32)
            whole.append(
                bool(
                    (np.abs(local[:, :2]) < _WHOLE_HAND_XY_M).all()
                    and (np.abs(local[:, 2]) < CROP_HALF_M).all()
                )
            )
    if not images:
        raise ValueError("heatmap: no rendered frame had a hand in view")
    return Crops(np.stack(images), np.array(tips, np.float32), np.array(whole, bool))


def crop_settings(data: FingertipDataConfig) -> dict[str, Any]:
    """The rendering settings that crops of ``data`` share, whatever their seed and count."""
    settings = asdict(data)
    del settings["seed"], settings["n_images"]
    return settings


def save_crops(
    crops: Crops,
    path: str | os.PathLike[str],
    *,
    data: FingertipDataConfig,
    seeds: Sequence[int],
    centre: CropCentre = "density",
) -> None:
    """Write ``crops`` to an ``.npz`` file, with the settings, seeds and crop centre rule
    that rendered them.

    Written under a temporary name and renamed, so an interrupted run leaves no
    damaged file.
    """
    settings = {"data": crop_settings(data), "seeds": [int(s) for s in seeds], "centre": centre}
    arrays: dict[str, Any] = {
        "format": np.array(CROPS_FORMAT),
        "version": np.array(__version__),
        "settings_json": np.array(json.dumps(settings, sort_keys=True)),
        "images": crops.images.astype(np.float16),
        "tips": crops.tips.astype(np.float32),
        "whole_hand": crops.whole_hand.astype(bool),
    }
    write_atomically(path, lambda file: np.savez(file, **arrays))


def load_crops(
    paths: Sequence[str | os.PathLike[str]],
    *,
    data: FingertipDataConfig | None = None,
    centre: CropCentre | None = None,
) -> Crops:
    """Read crop files written by :func:`save_crops` and join them in the given order.

    Parameters
    ----------
    paths : sequence of path
    data : FingertipDataConfig, optional
        When given, every file must have been rendered with these settings (apart from
        the seed and the number of frames).
    centre : {"density", "fingers"}, optional
        When given, every file's crops must be centred by this rule (files written
        before the rule was recorded are ``"density"``).

    Raises
    ------
    ValueError
        For a missing or foreign file, or crops rendered with other settings.
    """
    if not paths:
        raise ValueError("crops: expected at least one crop file")
    # Compared as stored: through JSON, where tuples are lists.
    expected = None if data is None else json.loads(json.dumps(crop_settings(data)))
    parts = []
    for path in paths:
        name = os.fspath(path)
        part, settings = _read_crop_file(name)
        if expected is not None and settings["data"] != expected:
            changed = sorted(
                key
                for key in expected.keys() | settings["data"].keys()
                if expected.get(key) != settings["data"].get(key)
            )
            raise ValueError(
                f"{name}: crops rendered with other [heatmap.data] settings ({', '.join(changed)})"
            )
        rule = settings.get("centre", "density")
        if centre is not None and rule != centre:
            raise ValueError(f"{name}: crops centred by the {rule!r} rule, expected {centre!r}")
        parts.append(part)
    return Crops(
        np.concatenate([p.images for p in parts]),
        np.concatenate([p.tips for p in parts]),
        np.concatenate([p.whole_hand for p in parts]),
    )


def _read_crop_file(name: str) -> tuple[Crops, dict[str, Any]]:
    """The crops of one file and the settings recorded with them."""
    try:
        archive = np.load(name, allow_pickle=False)
    except (OSError, EOFError, ValueError, zipfile.BadZipFile) as error:
        raise ValueError(f"{name}: cannot read crops ({error})") from error
    if not isinstance(archive, np.lib.npyio.NpzFile):
        raise ValueError(f"{name}: not a crop file (glove fingertips crops)")
    with archive as data:
        if "format" not in data or str(data["format"]) != CROPS_FORMAT:
            raise ValueError(f"{name}: not a crop file (glove fingertips crops)")
        try:
            settings = json.loads(str(data["settings_json"]))
            crops = Crops(data["images"], data["tips"], data["whole_hand"])
        except (KeyError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as error:
            raise ValueError(f"{name}: damaged crop file ({error})") from error
    return crops, settings


def require_training_extra() -> None:
    """Raise ValueError, with the way to install them, when PyTorch or onnx (the
    ``train`` extra: training and quantizing the network) is missing."""
    try:
        import onnx  # noqa: F401
        import torch  # noqa: F401
    except ImportError as error:
        raise ValueError(
            f"[heatmap]: training the heatmap stage needs PyTorch and onnx ({error}); "
            "install the train extra: bash scripts/setup.sh --train"
        ) from error
