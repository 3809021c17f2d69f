"""Training of the peak verifier (:mod:`fingertips.verify`) on rendered frames.

The trained Hough forest runs on frames rendered like its training data but from
another seed; every candidate (a vote peak with a vote weight of at least the
detector's ``c_thr`` and, with ``candidates = "union"``, a geodesic finger candidate;
:mod:`fingertips.candidates`) is described by
:func:`fingertips.candidates.candidate_features` and labelled true when a
one-to-one matching within ``match_radius_m`` pairs it with a visible fingertip (the
rule by which ``glove fingertips eval`` counts a detection as correct). A
scikit-learn random forest learns the label; it is exported to the plain arrays of
:class:`fingertips.verify.PeakVerifier` and stored in the model file.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from sklearn.ensemble import RandomForestClassifier

from fingertips.candidates import CANDIDATE_SOURCES, CandidateSource
from fingertips.data import FingertipDataConfig
from fingertips.detect import DetectorConfig, candidate_peaks
from fingertips.evaluation import match_within
from fingertips.forest import FingertipForest
from fingertips.tree_export import pack_tree_table
from fingertips.verify import PEAK_FEATURES, UNION_FEATURES, PeakVerifier
from glovedb._validate import as_array, check_choice, dataclass_from_table


@dataclass(frozen=True)
class VerifierTrainingConfig:
    """Settings of the verifier's training frames and forest.

    Attributes
    ----------
    n_images : int
        Frames rendered with the recipe's ``[data]`` settings.
    seed_offset : int
        Their data seed is the recipe's plus this, so they are not the forest's
        training frames.
    match_radius_m : float
        A peak is a fingertip when matched to a visible tip within this distance.
    n_trees, max_depth, min_samples_leaf : int
        Random forest settings.
    seed : int
        Seeds the forest.
    n_jobs : int
        Worker processes for fitting.
    candidates : {"forest", "union"}
        The candidates the verifier is trained on and will score: the vote peaks
        (over :data:`~fingertips.verify.PEAK_FEATURES`), or those and the geodesic
        finger candidates (over :data:`~fingertips.verify.UNION_FEATURES`). The model
        records it as the detector's ``candidates``.
    """

    n_images: int = 1500
    seed_offset: int = 1000
    match_radius_m: float = 0.015
    n_trees: int = 100
    max_depth: int = 16
    min_samples_leaf: int = 5
    seed: int = 0
    n_jobs: int = 2
    candidates: CandidateSource = "union"

    def __post_init__(self) -> None:
        check_choice("candidates", self.candidates, CANDIDATE_SOURCES)
        for name in ("n_images", "n_trees", "max_depth", "min_samples_leaf", "n_jobs"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}: expected at least 1, got {getattr(self, name)}")
        if not self.match_radius_m > 0:
            raise ValueError(
                f"match_radius_m: expected a positive distance, got {self.match_radius_m}"
            )


def verifier_config_from_dict(table: Mapping[str, Any]) -> VerifierTrainingConfig:
    """Build a :class:`VerifierTrainingConfig` from a TOML table; unknown keys are errors."""
    return dataclass_from_table(VerifierTrainingConfig, table, "verifier")


def label_peaks(positions_m: ArrayLike, tips_m: ArrayLike, *, radius_m: float) -> NDArray[np.bool_]:
    """Which peaks a one-to-one matching within ``radius_m`` pairs with a visible tip.

    Parameters
    ----------
    positions_m : (K, 3) float
        Peak positions, metres.
    tips_m : (5, 3) float
        Fingertips, metres; NaN rows are hidden tips (never matched).
    radius_m : float

    Returns
    -------
    (K,) bool
    """
    peaks = as_array("positions_m", positions_m, (None, 3), np.float64)
    tips = as_array("tips_m", tips_m, (None, 3), np.float64)
    visible = tips[np.all(np.isfinite(tips), axis=1)]
    distance = np.linalg.norm(peaks[:, None] - visible[None], axis=2)
    labels = np.zeros(peaks.shape[0], dtype=bool)
    labels[match_within(distance, radius_m)[0]] = True
    return labels


def collect_peak_samples(
    images: Iterable[tuple[NDArray[np.float32], NDArray[np.float64], NDArray[np.float64]]],
    forest: FingertipForest,
    *,
    detector: DetectorConfig,
    radius_m: float = 0.015,
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Candidate peaks of the forest on annotated frames, with their features and labels.

    Parameters
    ----------
    images : iterable of (depth_m, intrinsics, tips_m)
        ``(H, W)`` float32 depth in metres, ``(4,)`` intrinsics, ``(5, 3)`` fingertips
        in metres with NaN rows for hidden tips.
    forest : FingertipForest
    detector : DetectorConfig
        Its ``c_thr`` and voting settings make the candidates.
    radius_m : float
        See :func:`label_peaks`.

    Returns
    -------
    features : (N, len(UNION_FEATURES)) float32
    labels : (N,) bool
    """
    features, labels = [], []
    for depth_m, intrinsics, tips_m in images:
        candidates, frame_features = candidate_peaks(depth_m, intrinsics, forest, config=detector)
        features.append(frame_features)
        labels.append(label_peaks(candidates.positions_m, tips_m, radius_m=radius_m))
    if not features:
        return np.zeros((0, len(UNION_FEATURES)), np.float32), np.zeros(0, bool)
    return np.concatenate(features), np.concatenate(labels)


def fit_verifier(
    features: ArrayLike, labels: ArrayLike, *, config: VerifierTrainingConfig
) -> PeakVerifier:
    """Fit the random forest on labelled peaks and export it as a :class:`PeakVerifier`.

    Parameters
    ----------
    features : (N, len(UNION_FEATURES)) or (N, len(PEAK_FEATURES)) float32
        From :func:`collect_peak_samples`; a ``"forest"`` verifier uses only the
        leading :data:`~fingertips.verify.PEAK_FEATURES` columns, a ``"union"``
        verifier needs all.
    labels : (N,) bool
    config : VerifierTrainingConfig

    Raises
    ------
    ValueError
        Unless there are both true and false peaks.
    """
    values = as_array("features", features, (None, None), np.float32, kind="fiu")
    names = verifier_features(config.candidates)
    if values.shape[1] not in (len(names), len(UNION_FEATURES)):
        raise ValueError(
            f"features: expected (N, {len(names)}) or (N, {len(UNION_FEATURES)}), "
            f"got {values.shape}"
        )
    values = values[:, : len(names)]
    truth = as_array("labels", labels, (values.shape[0],), bool)
    if truth.all() or not truth.any():
        raise ValueError("labels: need both true and false fingertip peaks to train a verifier")
    classifier = RandomForestClassifier(
        n_estimators=config.n_trees,
        max_depth=config.max_depth,
        min_samples_leaf=config.min_samples_leaf,
        max_features="sqrt",
        random_state=config.seed,
        n_jobs=config.n_jobs,
    )
    classifier.fit(values, truth)
    return export_verifier(classifier, names)


def verifier_features(candidates: CandidateSource) -> tuple[str, ...]:
    """The feature names of a verifier of ``candidates`` (see :class:`VerifierTrainingConfig`)."""
    return UNION_FEATURES if candidates == "union" else PEAK_FEATURES


def export_verifier(
    classifier: RandomForestClassifier, feature_names: tuple[str, ...] = PEAK_FEATURES
) -> PeakVerifier:
    """A fitted binary scikit-learn classifier over ``feature_names`` as plain arrays."""
    if classifier.n_features_in_ != len(feature_names):
        raise ValueError(
            f"classifier: expected {len(feature_names)} peak features, "
            f"got {classifier.n_features_in_}"
        )
    return PeakVerifier(**pack_tree_table(classifier), feature_names=feature_names)


def train_verifier(
    forest: FingertipForest,
    data: FingertipDataConfig,
    detector: DetectorConfig,
    config: VerifierTrainingConfig,
    *,
    progress: bool = False,
) -> FingertipForest:
    """Render verifier frames, collect the forest's candidate peaks and fit the verifier.

    Parameters
    ----------
    forest : FingertipForest
        The trained Hough forest (an existing verifier is replaced).
    data : FingertipDataConfig
        The forest's training data settings; seed and number of frames come from
        ``config``.
    detector : DetectorConfig
        Detection settings; its ``c_thr`` and voting make the candidate peaks (its
        ``candidates`` is replaced by ``config.candidates``).
    config : VerifierTrainingConfig
    progress : bool
        Show a progress bar (on a terminal).

    Returns
    -------
    FingertipForest
        ``forest`` with the verifier and its settings recorded.
    """
    from tqdm import tqdm

    from fingertips.data import generate_examples

    detector = replace(detector, candidates=config.candidates)
    frames = replace(data, seed=data.seed + config.seed_offset, n_images=config.n_images)
    images = (
        (example.depth_m, example.intrinsics, example.tips_m)
        for example in tqdm(
            generate_examples(frames),
            total=frames.n_images,
            desc="verifier",
            unit="img",
            disable=not progress,
        )
    )
    features, labels = collect_peak_samples(
        images, forest, detector=detector, radius_m=config.match_radius_m
    )
    verifier = fit_verifier(features, labels, config=config)
    settings = {
        **forest.settings,
        "verifier": {
            **asdict(config),
            "data_seed": frames.seed,
            "n_peaks": int(labels.size),
            "n_true_peaks": int(labels.sum()),
        },
        "detector": detector.as_dict(),
    }
    return replace(forest, verifier=verifier, settings_json=json.dumps(settings, sort_keys=True))
