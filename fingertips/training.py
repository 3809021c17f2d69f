"""Training of the fingertip Hough forest from depth images with known fingertips.

Training takes plain arrays so any renderer (or real annotated data) can feed it:
depth images in metres, the camera intrinsics and, per image, the 3D fingertips in the
camera frame (NaN for a fingertip that is not visible). Pixels within
``tip_radius_m`` (3D) of a visible fingertip are positives; each positive also carries
its 3D offset to that fingertip. A scikit-learn forest learns the fingertip
probability; every leaf then stores the mean offset of the positive training pixels
that reach it (found with ``forest.apply``).

With ``forest_kind = "hough_extra_trees"`` the splits also care about the offsets, as
in a Hough forest (Gall and Lempitsky, CVPR 2009): an extremely randomised regression
forest fits the target ``(is_tip, w * is_tip * offset)`` with the summed squared error,
which for the 0/1 label is proportional to the Gini impurity of a classifier. Splits
then separate fingertip pixels whose tips lie in different directions, so the leaf
offsets are consistent and the votes gather; the leaf's mean label is the fingertip
probability. The result is exported to the plain-array
:class:`fingertips.forest.FingertipForest`, so inference needs neither
scikit-learn nor pickle.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Literal, TypeAlias

import numpy as np
import sklearn
from numpy.typing import ArrayLike, NDArray
from sklearn.ensemble import ExtraTreesClassifier, ExtraTreesRegressor, RandomForestClassifier

from fingertips.calibration_training import (
    CalibrationConfig,
    calibrate_from_config,
    calibration_config_from_dict,
    without_calibration,
)
from fingertips.data import (
    FingertipDataConfig,
    FingertipExample,
    data_config_from_dict,
    read_config_tables,
)
from fingertips.detect import DetectorConfig, detector_config_from_dict, model_detector_config
from fingertips.features import (
    backproject,
    foreground_pixels,
    intrinsics_array,
    mask_depth_range,
    nearest_band,
    pixel_features,
    random_offsets,
)
from fingertips.forest import FingertipForest
from fingertips.heatmap_data import (
    HeatmapTrainingConfig,
    heatmap_config_from_dict,
    require_training_extra,
)
from fingertips.tree_export import SklearnForest, pack_tree_table
from fingertips.verifier_training import (
    VerifierTrainingConfig,
    train_verifier,
    verifier_config_from_dict,
)
from glovedb import __version__
from glovedb._validate import as_array, check_choice, dataclass_from_table
from glovedb.hand_model import FINGERTIP_KEYPOINTS

ForestKind = Literal["extra_trees", "random_forest", "hough_extra_trees"]
FOREST_KINDS: tuple[ForestKind, ...] = ("extra_trees", "random_forest", "hough_extra_trees")

N_TIPS = 5


@dataclass(frozen=True)
class FingertipTrainingConfig:
    """Settings of feature generation, pixel sampling and the forest.

    Attributes
    ----------
    n_features : int
        Number of random probe-offset pairs ``F``.
    max_offset_m : float
        Largest lateral probe distance, metres.
    unary_fraction : float
        Fraction of features comparing one probe with the reference pixel.
    tip_radius_m : float
        A pixel is a fingertip pixel within this 3D distance of a visible tip, metres.
    depth_range_m : tuple of float
        Working range (near, far) in metres; depth outside it is background.
    depth_band_m : float
        Only depth within this many metres behind the nearest surface is kept
        (:func:`fingertips.features.nearest_band`); use the detector's value.
    pixels_per_image : int
        Pixels sampled per training image.
    positive_fraction : float
        Largest share of fingertip pixels among the sampled ones (they are rare, so
        they are over-sampled; leaf probabilities refer to this balance).
    hard_negative_fraction : float
        Share of the non-fingertip samples drawn from pixels within
        ``hard_negative_radius_m`` of a visible tip (finger sides, knuckles), where
        mistakes are likely; the rest are uniform over the image.
    hard_negative_radius_m : float
    ignore_hidden_tips : bool
        Sample no pixel within ``tip_radius_m`` of a hidden fingertip (when the images
        give them): the end of a finger pointing away from the camera looks like a
        fingertip while its tip keypoint lies behind the finger's own surface, so it
        is neither a fingertip nor clearly not one.
    forest_kind : {"extra_trees", "random_forest", "hough_extra_trees"}
        Classification forests, or the Hough regression forest of the module
        docstring.
    offset_weight : float
        Weight ``w`` of the offsets (per metre) in the ``hough_extra_trees`` objective:
        at 50, an offset spread of 1 cm weighs like a label spread of 0.5.
    n_trees : int
    max_depth : int
    min_samples_leaf : int
    max_features : int
        Features tried per split.
    seed : int
        Seeds the offsets, the pixel sampling and the forest.
    n_jobs : int
        Worker processes for fitting (scikit-learn ``n_jobs``).
    """

    n_features: int = 400
    max_offset_m: float = 0.08
    unary_fraction: float = 0.5
    tip_radius_m: float = 0.015
    depth_range_m: tuple[float, float] = (0.1, 1.0)
    depth_band_m: float = math.inf
    pixels_per_image: int = 2000
    positive_fraction: float = 0.4
    hard_negative_fraction: float = 0.0
    hard_negative_radius_m: float = 0.06
    ignore_hidden_tips: bool = False
    forest_kind: ForestKind = "extra_trees"
    offset_weight: float = 50.0
    n_trees: int = 8
    max_depth: int = 18
    min_samples_leaf: int = 5
    max_features: int = 40
    seed: int = 0
    n_jobs: int = 1

    def __post_init__(self) -> None:
        for name in (
            "n_features",
            "pixels_per_image",
            "n_trees",
            "max_depth",
            "min_samples_leaf",
            "max_features",
            "n_jobs",
        ):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}: expected at least 1, got {getattr(self, name)}")
        for name in ("max_offset_m", "tip_radius_m", "depth_band_m", "hard_negative_radius_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: expected a positive distance, got {getattr(self, name)}")
        for name in ("unary_fraction", "positive_fraction", "hard_negative_fraction"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"{name}: expected a share in [0, 1], got {getattr(self, name)}")
        near, far = self.depth_range_m
        if not 0 <= near < far:
            raise ValueError(f"depth_range_m: expected 0 <= near < far, got {(near, far)}")
        check_choice("forest_kind", self.forest_kind, FOREST_KINDS)


@dataclass(frozen=True)
class TrainingSamples:
    """Sampled training pixels.

    Attributes
    ----------
    features : (N, F) float32
        Feature values, metres.
    is_tip : (N,) bool
        Whether the pixel lies within the tip radius of a visible fingertip.
    offset_m : (N, 3) float32
        Offset from the pixel's 3D point to its nearest visible fingertip, metres
        (NaN when the image has no visible fingertip).
    """

    features: NDArray[np.float32]
    is_tip: NDArray[np.bool_]
    offset_m: NDArray[np.float32]


def label_points(
    points_m: ArrayLike, tips_m: ArrayLike, *, tip_radius_m: float
) -> tuple[NDArray[np.bool_], NDArray[np.float32]]:
    """Fingertip label and offset to the nearest visible fingertip of 3D points.

    Parameters
    ----------
    points_m : (N, 3) float
        Camera-frame points, metres.
    tips_m : (5, 3) float
        Fingertips in the camera frame, metres; NaN rows are not visible.
    tip_radius_m : float

    Returns
    -------
    is_tip : (N,) bool
    offset_m : (N, 3) float32
        ``tip - point`` for the nearest visible tip; NaN if no tip is visible.
    """
    points = as_array("points_m", points_m, (None, 3), np.float64, kind="fiu", finite=True)
    tips = as_array("tips_m", tips_m, (N_TIPS, 3), np.float64, kind="fiu")
    visible = tips[np.all(np.isfinite(tips), axis=1)]
    if visible.shape[0] == 0:
        return np.zeros(points.shape[0], bool), np.full(points.shape, np.nan, np.float32)
    delta = visible[None, :, :] - points[:, None, :]
    distance = np.linalg.norm(delta, axis=2)
    nearest = np.argmin(distance, axis=1)
    rows = np.arange(points.shape[0])
    is_tip = distance[rows, nearest] <= tip_radius_m
    return is_tip, delta[rows, nearest].astype(np.float32)


def sample_image(
    depth_m: NDArray[np.float32],
    intrinsics: NDArray[np.float64],
    tips_m: NDArray[np.float64],
    offsets_m: NDArray[np.float32],
    config: FingertipTrainingConfig,
    rng: np.random.Generator,
    hidden_tips_m: NDArray[np.float64] | None = None,
) -> TrainingSamples:
    """Sample, label and featurise the pixels of one training image.

    ``hidden_tips_m`` (K, 3), metres: fingertips that are not visible; with
    ``config.ignore_hidden_tips`` no non-fingertip pixel within ``tip_radius_m`` of
    them is sampled.
    """
    near, far = config.depth_range_m
    masked = mask_depth_range(depth_m, near_m=near, far_m=far)
    masked = nearest_band(masked, band_m=config.depth_band_m)
    pixels = foreground_pixels(masked)
    points = backproject(pixels, masked[pixels[:, 1], pixels[:, 0]], intrinsics)
    is_tip, offset = label_points(points, tips_m, tip_radius_m=config.tip_radius_m)
    negative = ~is_tip
    if config.ignore_hidden_tips and hidden_tips_m is not None and len(hidden_tips_m):
        gap = np.linalg.norm(points[:, None, :] - hidden_tips_m[None, :, :], axis=2)
        negative &= gap.min(axis=1) > config.tip_radius_m
    positives = np.flatnonzero(is_tip)
    near = np.linalg.norm(offset, axis=1) <= config.hard_negative_radius_m
    n_pos = min(positives.size, int(config.positive_fraction * config.pixels_per_image))
    n_neg = config.pixels_per_image - n_pos
    hard = np.flatnonzero(negative & near)
    hard = rng.choice(hard, min(hard.size, int(config.hard_negative_fraction * n_neg)), False)
    rest = np.setdiff1d(np.flatnonzero(negative), hard, assume_unique=True)
    chosen = np.concatenate(
        [
            rng.choice(positives, n_pos, replace=False),
            hard,
            rng.choice(rest, min(rest.size, n_neg - hard.size), replace=False),
        ]
    )
    features = pixel_features(masked, pixels[chosen], offsets_m, intrinsics)
    return TrainingSamples(features, is_tip[chosen], offset[chosen])


TrainingImage: TypeAlias = (
    tuple[ArrayLike, ArrayLike, ArrayLike] | tuple[ArrayLike, ArrayLike, ArrayLike, ArrayLike]
)
"""One training image: depth ``(H, W)`` metres, intrinsics ``(4,)``, fingertips ``(5, 3)``
and optionally the hidden fingertips ``(K, 3)`` (see ``ignore_hidden_tips``)."""


def collect_samples(
    images: Iterable[TrainingImage],
    offsets_m: ArrayLike,
    *,
    config: FingertipTrainingConfig = FingertipTrainingConfig(),
) -> TrainingSamples:
    """Sample training pixels from a stream of images, holding only the samples.

    Parameters
    ----------
    images : iterable of (depth_m, intrinsics, tips_m[, hidden_tips_m])
        ``depth_m`` (H, W) float32 metres, 0 where missing; ``intrinsics`` (4,) float
        ``(fx, fy, cx, cy)`` pixels; ``tips_m`` (5, 3) float, camera frame, metres,
        NaN for a fingertip that is not visible; optionally ``hidden_tips_m`` (K, 3)
        float, the positions of the hidden ones. Image sizes may differ.
    offsets_m : (F, 2, 2) float32
        Feature probe offsets (:func:`fingertips.features.random_offsets`).
    config : FingertipTrainingConfig

    Returns
    -------
    TrainingSamples
    """
    offsets = as_array("offsets_m", offsets_m, (None, 2, 2), np.float32, kind="f", finite=True)
    rng = np.random.default_rng(config.seed)
    parts = []
    for depth_m, intrinsics, tips_m, *hidden_tips_m in images:
        depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
        tips = as_array("tips_m", tips_m, (N_TIPS, 3), np.float64, kind="fiu")
        camera = intrinsics_array(intrinsics)
        hidden = None
        if hidden_tips_m:
            hidden = as_array("hidden_tips_m", hidden_tips_m[0], (None, 3), np.float64)
        parts.append(sample_image(depth, camera, tips, offsets, config, rng, hidden))
    if not parts:
        raise ValueError("images: expected at least one training image")
    return TrainingSamples(
        features=np.concatenate([p.features for p in parts]),
        is_tip=np.concatenate([p.is_tip for p in parts]),
        offset_m=np.concatenate([p.offset_m for p in parts]),
    )


def _image_stack(
    depth_images_m: ArrayLike, intrinsics: ArrayLike, tips_m: ArrayLike
) -> list[TrainingImage]:
    """Check stacked training arrays and split them into per-image tuples."""
    depth = as_array("depth_images_m", depth_images_m, (None, None, None), np.float32, kind="fiu")
    n_images = depth.shape[0]
    tips = as_array("tips_m", tips_m, (n_images, N_TIPS, 3), np.float64, kind="fiu")
    cameras = np.asarray(intrinsics, dtype=np.float64)
    cameras = np.broadcast_to(cameras, (n_images, 4)) if cameras.ndim == 1 else cameras
    cameras = as_array("intrinsics", cameras, (n_images, 4), np.float64, finite=True)
    return list(zip(depth, cameras, tips, strict=True))


def sample_training_set(
    depth_images_m: ArrayLike,
    intrinsics: ArrayLike,
    tips_m: ArrayLike,
    offsets_m: ArrayLike,
    *,
    config: FingertipTrainingConfig = FingertipTrainingConfig(),
) -> TrainingSamples:
    """Sample training pixels from a stack of depth images.

    Parameters
    ----------
    depth_images_m : (N, H, W) float32
        Depth in metres, 0 where missing.
    intrinsics : (4,) or (N, 4) float
        ``(fx, fy, cx, cy)`` in pixels, shared or per image.
    tips_m : (N, 5, 3) float
        Fingertips (thumb, index, middle, ring, little) in the camera frame, metres;
        NaN for a fingertip that is not visible.
    offsets_m : (F, 2, 2) float32
        Feature probe offsets (:func:`fingertips.features.random_offsets`).
    config : FingertipTrainingConfig

    Returns
    -------
    TrainingSamples
    """
    images = _image_stack(depth_images_m, intrinsics, tips_m)
    return collect_samples(images, offsets_m, config=config)


def hough_targets(samples: TrainingSamples, offset_weight: float) -> NDArray[np.float32]:
    """Regression targets ``(N, 4)`` of the Hough objective: label, weighted offset.

    Non-fingertip pixels get a zero offset, so that only the offsets of fingertip
    pixels shape the splits.
    """
    offset = np.where(samples.is_tip[:, None], samples.offset_m, np.float32(0.0))
    label = samples.is_tip[:, None].astype(np.float32)
    return np.concatenate([label, np.float32(offset_weight) * offset], axis=1).astype(np.float32)


def fit_classifier(
    samples: TrainingSamples, *, config: FingertipTrainingConfig = FingertipTrainingConfig()
) -> SklearnForest:
    """Fit the scikit-learn forest of ``config.forest_kind`` on the training samples."""
    kind = check_choice("forest_kind", config.forest_kind, FOREST_KINDS)
    if samples.is_tip.all() or not samples.is_tip.any():
        raise ValueError("samples: need both fingertip and non-fingertip pixels to train")
    settings = {
        "n_estimators": config.n_trees,
        "max_depth": config.max_depth,
        "min_samples_leaf": config.min_samples_leaf,
        "max_features": min(config.max_features, samples.features.shape[1]),
        "random_state": config.seed,
        "n_jobs": config.n_jobs,
    }
    forest: SklearnForest
    if kind == "hough_extra_trees":
        forest = ExtraTreesRegressor(**settings)
        forest.fit(samples.features, hough_targets(samples, config.offset_weight))
    else:
        classes = {"extra_trees": ExtraTreesClassifier, "random_forest": RandomForestClassifier}
        forest = classes[kind](**settings)
        forest.fit(samples.features, samples.is_tip)
    return forest


def leaf_offsets(classifier: SklearnForest, samples: TrainingSamples) -> list[NDArray[np.float32]]:
    """Per tree, the mean offset ``(n_nodes, 3)`` of the positive pixels reaching each node.

    Nodes that no positive training pixel reaches get a zero offset.
    """
    positive = samples.is_tip & np.all(np.isfinite(samples.offset_m), axis=1)
    leaves = classifier.apply(samples.features[positive])
    offsets = samples.offset_m[positive].astype(np.float64)
    result = []
    for t, estimator in enumerate(classifier.estimators_):
        n_nodes = estimator.tree_.node_count
        count = np.bincount(leaves[:, t], minlength=n_nodes)
        total = np.stack(
            [np.bincount(leaves[:, t], offsets[:, k], minlength=n_nodes) for k in range(3)], 1
        )
        mean = np.divide(total, count[:, None], out=np.zeros_like(total), where=count[:, None] > 0)
        result.append(mean.astype(np.float32))
    return result


def _json_number(value: object) -> object:
    """``value`` with an infinite float replaced by None (JSON has no infinity)."""
    return None if isinstance(value, float) and not math.isfinite(value) else value


def export_forest(
    classifier: SklearnForest,
    samples: TrainingSamples,
    offsets_m: NDArray[np.float32],
    *,
    config: FingertipTrainingConfig,
    extra_settings: dict[str, object] | None = None,
) -> FingertipForest:
    """Pack a fitted scikit-learn forest and its leaf offsets into plain arrays."""
    settings = {
        **{k: _json_number(v) for k, v in asdict(config).items()},
        "sklearn_version": sklearn.__version__,
        "n_training_pixels": int(samples.is_tip.size),
        "n_positive_pixels": int(samples.is_tip.sum()),
        **(extra_settings or {}),
    }
    return FingertipForest(
        offsets_m=offsets_m.astype(np.float32),
        depth_range_m=(float(config.depth_range_m[0]), float(config.depth_range_m[1])),
        node_offset_m=np.concatenate(leaf_offsets(classifier, samples)).astype(np.float32),
        settings_json=json.dumps(settings, sort_keys=True),
        version=__version__,
        **pack_tree_table(classifier),
    )


def train_on_images(
    images: Iterable[TrainingImage],
    *,
    config: FingertipTrainingConfig = FingertipTrainingConfig(),
    extra_settings: Mapping[str, Any] | None = None,
) -> FingertipForest:
    """Train the fingertip Hough forest from a stream of images with known fingertips.

    Parameters
    ----------
    images : iterable of (depth_m, intrinsics, tips_m)
        As for :func:`collect_samples`; consumed once, only the samples are kept.
    config : FingertipTrainingConfig
    extra_settings : mapping, optional
        More settings to record in the model (e.g. the data and detector settings).

    Returns
    -------
    FingertipForest
        Save it with :func:`fingertips.forest.save_forest`.
    """
    offsets = random_offsets(
        config.n_features,
        max_offset_m=config.max_offset_m,
        unary_fraction=config.unary_fraction,
        seed=config.seed,
    )
    counted = _Counted(images)
    samples = collect_samples(counted, offsets, config=config)
    classifier = fit_classifier(samples, config=config)
    settings = {"n_images": counted.count, **(extra_settings or {})}
    return export_forest(classifier, samples, offsets, config=config, extra_settings=settings)


class _Counted:
    """An iterable that counts the items it has handed out."""

    def __init__(self, items: Iterable[TrainingImage]) -> None:
        self._items = items
        self.count = 0

    def __iter__(self) -> Iterator[TrainingImage]:
        for item in self._items:
            self.count += 1
            yield item


def train_fingertip_forest(
    depth_images_m: ArrayLike,
    intrinsics: ArrayLike,
    tips_m: ArrayLike,
    *,
    config: FingertipTrainingConfig = FingertipTrainingConfig(),
) -> FingertipForest:
    """Train the fingertip Hough forest from depth images with known fingertips.

    Parameters
    ----------
    depth_images_m : (N, H, W) float32
        Depth in metres, 0 where missing.
    intrinsics : (4,) or (N, 4) float
        ``(fx, fy, cx, cy)`` in pixels, shared or per image.
    tips_m : (N, 5, 3) float
        Fingertips (thumb, index, middle, ring, little) in the camera frame, metres;
        NaN for a fingertip that is not visible.
    config : FingertipTrainingConfig

    Returns
    -------
    FingertipForest
        Save it with :func:`fingertips.forest.save_forest`.
    """
    return train_on_images(_image_stack(depth_images_m, intrinsics, tips_m), config=config)


def training_config_from_dict(table: Mapping[str, Any]) -> FingertipTrainingConfig:
    """Build a :class:`FingertipTrainingConfig` from a TOML table; unknown keys are errors."""
    return dataclass_from_table(FingertipTrainingConfig, table, "training")


@dataclass(frozen=True)
class FingertipRecipe:
    """Everything that makes a shipped model: data, training and detector settings.

    Attributes
    ----------
    data : FingertipDataConfig
        How training images are rendered (:mod:`fingertips.data`).
    training : FingertipTrainingConfig
    detector : DetectorConfig
        Detection settings recorded in the model; its ``depth_band_m`` is the
        training one.
    verifier : VerifierTrainingConfig or None
        How the peak verifier is trained (:mod:`fingertips.verifier_training`); None:
        no verifier.
    heatmap : HeatmapTrainingConfig or None
        How the heatmap stage is trained (:mod:`fingertips.heatmap_data`; training it
        needs PyTorch); None: no heatmap stage.
    calibration : CalibrationConfig or None
        On which frames the confidence maps are fitted
        (:mod:`fingertips.calibration_training`; its ``frames`` resolved against the
        config's folder); None: uncalibrated confidences.
    """

    data: FingertipDataConfig
    training: FingertipTrainingConfig
    detector: DetectorConfig
    verifier: VerifierTrainingConfig | None = None
    heatmap: HeatmapTrainingConfig | None = None
    calibration: CalibrationConfig | None = None


def load_recipe(path: str | os.PathLike[str], **data_overrides: Any) -> FingertipRecipe:
    """Read a ``configs/fingertips/*.toml`` file.

    Tables: ``data``, ``training``, ``detector`` and the optional ``verifier``,
    ``heatmap`` and ``calibration`` (both need ``verifier``).

    Parameters
    ----------
    path : path
    **data_overrides
        Replace settings of the ``data`` table (e.g. ``n_images``, ``noise``).

    Raises
    ------
    ValueError
        For an unreadable file, an unknown table or setting, or a detector table that
        sets ``depth_band_m``.
    """
    content = read_config_tables(path)
    data = replace(data_config_from_dict(content.get("data", {})), **data_overrides)
    training = training_config_from_dict(content.get("training", {}))
    detector_table = content.get("detector", {})
    if "depth_band_m" in detector_table:
        raise ValueError("detector: depth_band_m comes from [training], do not set it here")
    detector = detector_config_from_dict(
        {**detector_table, "depth_band_m": _json_number(training.depth_band_m)}
    )
    verifier = verifier_config_from_dict(content["verifier"]) if "verifier" in content else None
    table = content.get("heatmap")
    heatmap = heatmap_config_from_dict(table) if table is not None else None
    if heatmap is not None and verifier is None:
        raise ValueError(f"{os.fspath(path)}: a [heatmap] table needs a [verifier] table")
    if detector.heatmap_min_probability > 0 and heatmap is None:
        raise ValueError(
            f"{os.fspath(path)}: detector: heatmap_min_probability needs a [heatmap] table"
        )
    calibration = None
    if "calibration" in content:
        if verifier is None:
            raise ValueError(f"{os.fspath(path)}: a [calibration] table needs a [verifier] table")
        calibration = calibration_config_from_dict(content["calibration"])
        frames = Path(path).parent / calibration.frames
        calibration = replace(calibration, frames=frames.as_posix())
    return FingertipRecipe(data, training, detector, verifier, heatmap, calibration)


def _hidden_tips(example: FingertipExample) -> NDArray[np.float64]:
    """Positions ``(K, 3)`` of the fingertips of ``example`` that are not visible."""
    tips = example.keypoints_m[list(FINGERTIP_KEYPOINTS)]
    return tips[np.isnan(example.tips_m).any(axis=1)]


def train_from_recipe(
    recipe: FingertipRecipe,
    *,
    progress: bool = False,
    forest: FingertipForest | None = None,
    keep_verifier: bool = False,
    heatmap_network: NDArray[np.uint8] | None = None,
) -> FingertipForest:
    """Render the recipe's training images and train the forest, verifier and heatmap.

    Parameters
    ----------
    recipe : FingertipRecipe
    progress : bool
        Show a progress bar (on a terminal).
    forest : FingertipForest, optional
        Keep this trained forest and only train the recipe's verifier (and heatmap
        stage) for it (the recipe's detector settings replace the recorded ones).
    keep_verifier : bool
        Also keep ``forest``'s peak verifier: train only the heatmap stage.
    heatmap_network : (B,) uint8, optional
        An ONNX heatmap network to use instead of training one (only the heatmap's
        verifier is fitted; see :func:`fingertips.heatmap_training.train_heatmap`).

    Returns
    -------
    FingertipForest
        With the data, detector, training, verifier and heatmap settings recorded,
        and the confidence maps when the recipe has a ``[calibration]`` table
        (:func:`fingertips.calibration_training.calibrate_from_config`, the same as
        ``glove fingertips calibrate``). Maps of a given ``forest`` are dropped.

    Raises
    ------
    ValueError
        When there is nothing to train, or the recipe has a ``[heatmap]`` table and
        PyTorch is not installed.
    """
    heatmap = recipe.heatmap
    if heatmap is not None:
        require_training_extra()  # before any rendering
    if heatmap is None and (keep_verifier or heatmap_network is not None):
        raise ValueError("the config has no [heatmap] table: nothing to train")
    if forest is not None:
        forest = without_calibration(forest)  # its scores change
    trained = _train_stages(recipe, progress, forest, keep_verifier, heatmap_network)
    if recipe.calibration is None:
        return trained
    return calibrate_from_config(trained, recipe.calibration)


def _train_stages(
    recipe: FingertipRecipe,
    progress: bool,
    forest: FingertipForest | None,
    keep_verifier: bool,
    heatmap_network: NDArray[np.uint8] | None,
) -> FingertipForest:
    """:func:`train_from_recipe` without the confidence maps."""
    heatmap = recipe.heatmap
    if keep_verifier:
        assert heatmap is not None  # checked above
        if forest is None or forest.verifier is None:
            raise ValueError("keep_verifier: needs a given forest that has a peak verifier")
        return _train_heatmap(forest, recipe, heatmap, heatmap_network, progress)
    from tqdm import tqdm

    from fingertips.data import generate_examples

    if forest is None:
        examples = generate_examples(recipe.data)
        images = (
            (example.depth_m, example.intrinsics, example.tips_m, _hidden_tips(example))
            for example in tqdm(
                examples,
                total=recipe.data.n_images,
                desc="render",
                unit="img",
                disable=not progress,
            )
        )
        settings = {
            "data": asdict(recipe.data),
            "detector": recipe.detector.as_dict(),
        }
        forest = train_on_images(images, config=recipe.training, extra_settings=settings)
    elif recipe.verifier is None:
        raise ValueError("the config has no [verifier] table: nothing to train for the forest")
    if recipe.verifier is None:
        return forest
    forest = train_verifier(
        replace(forest, verifier=None, heatmap=None),
        recipe.data,
        recipe.detector,
        recipe.verifier,
        progress=progress,
    )
    if heatmap is None:
        return forest
    return _train_heatmap(forest, recipe, heatmap, heatmap_network, progress)


def _train_heatmap(
    forest: FingertipForest,
    recipe: FingertipRecipe,
    heatmap: HeatmapTrainingConfig,
    network: NDArray[np.uint8] | None,
    progress: bool,
) -> FingertipForest:
    from fingertips.heatmap_training import train_heatmap

    # The candidates the forest's verifier was trained on (its [verifier] table's).
    detector = replace(recipe.detector, candidates=model_detector_config(forest).candidates)
    return train_heatmap(
        forest, recipe.data, detector, heatmap, network_onnx=network, progress=progress
    )
