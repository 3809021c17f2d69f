"""The fingertip Hough forest as plain arrays: file format, loading and fast inference.

All trees are packed into one node table. On depth images every (pixel, tree) pair
walks down to its leaf in a compiled loop that computes each split's feature on the
way (:mod:`fingertips._tree_kernels`), and likewise on precomputed features
(:func:`fingertips.trees.descend_matrix`).

File format (``.npz``, read with ``allow_pickle=False``):

======================  ==================  ===============================================
key                     shape, dtype        meaning
======================  ==================  ===============================================
``format``              () str              ``"glove-fingertip-forest"``
``format_version``      () int64            :data:`FORMAT_VERSION`
``version``             () str              project version that wrote the file
``settings_json``       () str              training settings (JSON object)
``offsets_m``           (F, 2, 2) float32   feature probe offsets in metres
``depth_range_m``       (2,) float32        working depth range (near, far) in metres
``tree_roots``          (T,) int32          node index of each tree's root; tree ``t`` owns
                                            nodes ``tree_roots[t]:tree_roots[t + 1]``
``node_feature``        (n,) int32          feature index tested at a split, -1 at a leaf
``node_threshold``      (n,) float32        go left when feature value <= threshold
``node_left``           (n,) int32          left child (global node index), -1 at a leaf
``node_right``          (n,) int32          right child (global node index), -1 at a leaf
``node_probability``    (n,) float32        fingertip probability of the training pixels
                                            reaching the node (their share of fingertip
                                            pixels, for classification and Hough forests)
``node_offset_m``       (n, 3) float32      mean 3D offset (camera axes, metres) from the
                                            pixel to its nearest fingertip, over the
                                            positive training pixels reaching the node
                                            (0 where there are none)
``verifier_*``          see below           optional (format 2): the peak verifier
``heatmap_*``           see below           optional (format 3): the heatmap stage
``calibration_*``       see below           optional (format 4): the confidence maps
======================  ==================  ===============================================

The peak verifier (:class:`fingertips.verify.PeakVerifier`) is stored as
``verifier_tree_roots``, ``verifier_node_feature``, ``verifier_node_threshold``,
``verifier_node_left``, ``verifier_node_right``, ``verifier_node_probability`` (the
same node table layout) and ``verifier_features`` ``(F',) str``, the names of the peak
features it was trained on: :data:`fingertips.verify.PEAK_FEATURES` (a verifier
of the vote peaks) or :data:`fingertips.verify.UNION_FEATURES` (of the vote peaks and
geodesic candidates, :mod:`fingertips.candidates`); a model with other names is
refused. Format 1 files (no verifier) are still read.

The heatmap stage (:class:`fingertips.heatmap.HeatmapStage`) is stored as
``heatmap_network_onnx`` ``(B,) uint8`` (the ONNX network), its verifier's node table
``heatmap_tree_roots``, ``heatmap_node_feature``, ``heatmap_node_threshold``,
``heatmap_node_left``, ``heatmap_node_right``, ``heatmap_node_value``, the scalars
``heatmap_baseline``, ``heatmap_passes`` and ``heatmap_min_value``, and
``heatmap_features`` ``(F'',) str``, checked against
:data:`fingertips.heatmap.HEAT_PEAK_FEATURES`. Its candidate judge
(:class:`fingertips.judge.CandidateJudge`, format 5) is the node table
``heatmap_judge_tree_roots``, ..., ``heatmap_judge_node_value`` with the scalar
``heatmap_judge_baseline`` and ``heatmap_judge_features`` ``(J,) str``, checked
against :data:`fingertips.judge.JUDGE_FEATURES`; format 4 files hold the logistic
fusion that preceded it, ``heatmap_fusion`` ``(3,) float64``, instead.

The confidence maps (:class:`fingertips.calibration.Calibration`) are stored as
``calibration_KIND_scores`` and ``calibration_KIND_probabilities`` ``(B,) float64``,
the breakpoints of the map of each kind of score (``verifier``, and ``heatmap`` for a
model with a heatmap stage). A model without them gives uncalibrated confidences.
"""

from __future__ import annotations

import json
import os
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fingertips._tree_kernels import descend_depth_forest, leaf_votes
from fingertips.calibration import SCORE_KINDS, Calibration, ConfidenceMap
from fingertips.features import (
    intrinsics_array,
    probe_image,
    read_probes,
)
from fingertips.heatmap import HEAT_PEAK_FEATURES, HeatmapNetwork, HeatmapStage
from fingertips.judge import JUDGE_FEATURES, CandidateJudge
from fingertips.trees import (
    FeatureLookup,
    PackedNodes,
    check_tree_table,
    descend,
    descend_matrix,
)
from fingertips.verify import VERIFIER_FEATURE_SETS, PeakVerifier
from glovedb._files import write_atomically
from glovedb._validate import as_array

FORMAT_NAME = "glove-fingertip-forest"
FORMAT_VERSION = 5
READABLE_VERSIONS = (1, 2, 3, 4, 5)
_VERIFIER_ARRAYS = (
    "tree_roots",
    "node_feature",
    "node_threshold",
    "node_left",
    "node_right",
    "node_probability",
)

DEFAULT_MODEL_PATH = Path(__file__).resolve().parent / "models" / "default.npz"
"""The pretrained forest shipped with the package (see ``docs/fingertips.md``)."""

__all__ = [
    "DEFAULT_MODEL_PATH",
    "FeatureLookup",
    "FingertipForest",
    "ForestPrediction",
    "apply_depth",
    "apply_features",
    "apply_probe_image",
    "descend",
    "load_forest",
    "predict_leaves",
    "save_forest",
]


@dataclass(frozen=True)
class FingertipForest(PackedNodes):
    """A trained fingertip forest; see the module docstring for the meaning of each array.

    ``verifier`` is the optional peak verifier trained with it (None: detection keeps
    peaks by their vote weight alone); ``heatmap`` the optional second stage
    (:mod:`fingertips.heatmap`), which needs the verifier; ``calibration`` the optional
    confidence maps (:mod:`fingertips.calibration`), which need the verifier (and a
    heatmap map for the heatmap stage).
    """

    offsets_m: NDArray[np.float32]
    depth_range_m: tuple[float, float]
    tree_roots: NDArray[np.int32]
    node_feature: NDArray[np.int32]
    node_threshold: NDArray[np.float32]
    node_left: NDArray[np.int32]
    node_right: NDArray[np.int32]
    node_probability: NDArray[np.float32]
    node_offset_m: NDArray[np.float32]
    settings_json: str = "{}"
    version: str = ""
    verifier: PeakVerifier | None = None
    heatmap: HeatmapStage | None = None
    calibration: Calibration | None = None

    def __post_init__(self) -> None:
        _check_forest(self)

    @property
    def n_trees(self) -> int:
        """Number of trees ``T``."""
        return int(self.tree_roots.size)

    @property
    def n_features(self) -> int:
        """Number of features ``F`` the split tests index into."""
        return int(self.offsets_m.shape[0])

    @property
    def settings(self) -> dict[str, Any]:
        """The training settings recorded with the forest."""
        loaded: dict[str, Any] = json.loads(self.settings_json)
        return loaded


@dataclass(frozen=True)
class ForestPrediction:
    """Per-pixel output of the forest.

    Attributes
    ----------
    probability : (N,) float32
        Fingertip probability, mean over the trees.
    offset_m : (N, 3) float32
        Vote offset in metres from the pixel's 3D point to the fingertip: the mean of
        the trees' leaf offsets weighted by their leaf probabilities.
    """

    probability: NDArray[np.float32]
    offset_m: NDArray[np.float32]


def _check_forest(forest: FingertipForest) -> None:
    n = forest.node_feature.shape[0]
    as_array("node_probability", forest.node_probability, (n,), finite=True)
    as_array("node_offset_m", forest.node_offset_m, (n, 3), finite=True)
    as_array("node_threshold", forest.node_threshold, (n,), finite=True)
    as_array("offsets_m", forest.offsets_m, (None, 2, 2), finite=True)
    check_tree_table(forest, forest.offsets_m.shape[0])
    if forest.heatmap is not None and forest.verifier is None:
        raise ValueError("heatmap: the heatmap stage needs the forest's peak verifier")
    if forest.calibration is not None:
        if forest.verifier is None:
            raise ValueError("calibration: calibrated confidences need the peak verifier")
        if forest.heatmap is not None and "heatmap" not in forest.calibration.maps:
            raise ValueError("calibration: the heatmap stage needs a 'heatmap' map")
    try:
        json.loads(forest.settings_json)
    except ValueError as error:
        raise ValueError(f"settings_json: not JSON ({error})") from error


def save_forest(forest: FingertipForest, path: str | os.PathLike[str]) -> None:
    """Write ``forest`` to an ``.npz`` file in the format of the module docstring.

    The file is written under a temporary name beside ``path`` and then renamed, so an
    interrupted save never leaves a damaged model at ``path``; ``path`` is used as
    given (no ``.npz`` is appended).
    """
    arrays: dict[str, Any] = dict(
        format=np.array(FORMAT_NAME),
        format_version=np.array(FORMAT_VERSION, dtype=np.int64),
        version=np.array(forest.version),
        settings_json=np.array(forest.settings_json),
        offsets_m=forest.offsets_m.astype(np.float32),
        depth_range_m=np.asarray(forest.depth_range_m, dtype=np.float32),
        tree_roots=forest.tree_roots.astype(np.int32),
        node_feature=forest.node_feature.astype(np.int32),
        node_threshold=forest.node_threshold.astype(np.float32),
        node_left=forest.node_left.astype(np.int32),
        node_right=forest.node_right.astype(np.int32),
        node_probability=forest.node_probability.astype(np.float32),
        node_offset_m=forest.node_offset_m.astype(np.float32),
        **_verifier_arrays(forest.verifier),
        **_heatmap_arrays(forest.heatmap),
        **_calibration_arrays(forest.calibration),
    )
    write_atomically(path, lambda file: np.savez_compressed(file, **arrays))


def _verifier_arrays(verifier: PeakVerifier | None) -> dict[str, NDArray]:
    if verifier is None:
        return {}
    arrays = {f"verifier_{name}": getattr(verifier, name) for name in _VERIFIER_ARRAYS}
    return {**arrays, "verifier_features": np.array(verifier.feature_names)}


_HEATMAP_TABLE = (
    "tree_roots",
    "node_feature",
    "node_threshold",
    "node_left",
    "node_right",
    "node_value",
)


def _heatmap_arrays(stage: HeatmapStage | None) -> dict[str, NDArray]:
    if stage is None:
        return {}
    arrays = {f"heatmap_{name}": getattr(stage, name) for name in _HEATMAP_TABLE}
    return {
        **arrays,
        "heatmap_network_onnx": stage.network_onnx.astype(np.uint8),
        "heatmap_baseline": np.array(stage.baseline, dtype=np.float64),
        "heatmap_passes": np.array(stage.passes, dtype=np.int64),
        "heatmap_min_value": np.array(stage.min_value, dtype=np.float64),
        "heatmap_features": np.array(HEAT_PEAK_FEATURES),
        **(
            {}
            if stage.fusion is None
            else {"heatmap_fusion": np.asarray(stage.fusion, dtype=np.float64)}
        ),
        **_judge_arrays(stage.judge),
    }


def _judge_arrays(judge: CandidateJudge | None) -> dict[str, NDArray]:
    if judge is None:
        return {}
    arrays = {f"heatmap_judge_{name}": getattr(judge, name) for name in _HEATMAP_TABLE}
    return {
        **arrays,
        "heatmap_judge_baseline": np.array(judge.baseline, dtype=np.float64),
        "heatmap_judge_features": np.array(JUDGE_FEATURES),
    }


def _read_judge(data: Any, path: str) -> CandidateJudge | None:
    if "heatmap_judge_features" not in data:
        return None
    if tuple(str(name) for name in data["heatmap_judge_features"]) != JUDGE_FEATURES:
        raise ValueError(
            f"{path}: its candidate judge uses other features than this code; "
            "retrain the model (docs/fingertips.md)"
        )
    return CandidateJudge(
        **_boosted_table(data, "heatmap_judge_"), baseline=float(data["heatmap_judge_baseline"])
    )


def _boosted_table(data: Any, prefix: str) -> dict[str, NDArray]:
    """The node table of boosted trees stored under ``prefix`` (``_HEATMAP_TABLE``)."""
    kinds = {"node_threshold": np.float32, "node_value": np.float32}
    return {
        name: data[f"{prefix}{name}"].astype(kinds.get(name, np.int32)) for name in _HEATMAP_TABLE
    }


def _read_heatmap(data: Any, path: str) -> HeatmapStage | None:
    if "heatmap_network_onnx" not in data:
        return None
    names = tuple(str(name) for name in data["heatmap_features"])
    if names != HEAT_PEAK_FEATURES:
        raise ValueError(
            f"{path}: its heatmap verifier uses other peak features than this code; "
            "retrain the model (docs/fingertips.md)"
        )
    return HeatmapStage(
        network_onnx=data["heatmap_network_onnx"].astype(np.uint8),
        **_boosted_table(data, "heatmap_"),
        baseline=float(data["heatmap_baseline"]),
        passes=int(data["heatmap_passes"]),
        min_value=float(data["heatmap_min_value"]),
        fusion=data["heatmap_fusion"].astype(np.float64) if "heatmap_fusion" in data else None,
        judge=_read_judge(data, path),
    )


def _calibration_arrays(calibration: Calibration | None) -> dict[str, NDArray]:
    if calibration is None:
        return {}
    arrays = {}
    for kind, mapping in calibration.maps.items():
        arrays[f"calibration_{kind}_scores"] = mapping.scores.astype(np.float64)
        arrays[f"calibration_{kind}_probabilities"] = mapping.probabilities.astype(np.float64)
    return arrays


def _read_calibration(data: Any) -> Calibration | None:
    maps: dict[str, ConfidenceMap] = {
        kind: ConfidenceMap(
            data[f"calibration_{kind}_scores"], data[f"calibration_{kind}_probabilities"]
        )
        for kind in SCORE_KINDS
        if f"calibration_{kind}_scores" in data
    }
    return Calibration(maps) if maps else None


def _read_verifier(data: Any, path: str) -> PeakVerifier | None:
    if "verifier_tree_roots" not in data:
        return None
    names = tuple(str(name) for name in data["verifier_features"])
    if names not in VERIFIER_FEATURE_SETS:
        raise ValueError(
            f"{path}: its peak verifier uses other peak features than this code; "
            "retrain the model (docs/fingertips.md)"
        )
    kinds = {"node_threshold": np.float32, "node_probability": np.float32}
    return PeakVerifier(
        **{
            name: data[f"verifier_{name}"].astype(kinds.get(name, np.int32))
            for name in _VERIFIER_ARRAYS
        },
        feature_names=names,
    )


def load_forest(path: str | os.PathLike[str] = DEFAULT_MODEL_PATH) -> FingertipForest:
    """Read a forest written by :func:`save_forest` (default: the shipped one).

    Never unpickles anything.

    Raises
    ------
    ValueError
        If the file is missing, damaged (not a readable ``.npz`` archive, a member
        missing or truncated) or not a fingertip forest of a supported format version.
    """
    name = os.fspath(path)
    if not Path(path).is_file():
        raise ValueError(f"{name}: no such model file")
    try:
        archive = np.load(path, allow_pickle=False)
    except (OSError, EOFError, ValueError, zipfile.BadZipFile) as error:
        raise ValueError(f"{name}: not a {FORMAT_NAME} file (no readable .npz archive)") from error
    if not isinstance(archive, np.lib.npyio.NpzFile):
        raise ValueError(f"{name}: not a {FORMAT_NAME} file (a single array, not an archive)")
    with archive as data:
        try:
            return _forest_from_archive(data, name)
        except (KeyError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as error:
            raise ValueError(f"{name}: damaged {FORMAT_NAME} file ({error})") from error


def read_heatmap_network(path: str | os.PathLike[str]) -> NDArray[np.uint8]:
    """The ONNX bytes ``(B,)`` of a heatmap network: an ``.onnx`` file or a model's network.

    Raises
    ------
    ValueError
        If the file cannot be read, a model has no heatmap stage, or onnxruntime
        cannot load the network (checked here, before any work that needs it).
    """
    name = os.fspath(path)
    if not name.endswith(".onnx"):
        stage = load_forest(path).heatmap
        if stage is None:
            raise ValueError(f"{name}: the model has no heatmap stage")
        return stage.network_onnx
    try:
        network = np.frombuffer(Path(path).read_bytes(), dtype=np.uint8)
    except OSError as error:
        raise ValueError(f"{name}: cannot read ({error.strerror})") from error
    HeatmapNetwork(network, 1)
    return network


def _forest_from_archive(data: Any, path: str) -> FingertipForest:
    """The forest in an opened ``.npz`` archive (see :func:`load_forest`)."""
    if "format" not in data or str(data["format"]) != FORMAT_NAME:
        raise ValueError(f"{path}: not a {FORMAT_NAME} file")
    if int(data["format_version"]) not in READABLE_VERSIONS:
        raise ValueError(
            f"{path}: format version {int(data['format_version'])}, "
            f"this code reads {', '.join(map(str, READABLE_VERSIONS))}"
        )
    near, far = (float(x) for x in data["depth_range_m"])
    verifier = _read_verifier(data, path)
    heatmap = _read_heatmap(data, path)
    try:
        calibration = _read_calibration(data)
        return FingertipForest(
            offsets_m=data["offsets_m"].astype(np.float32),
            depth_range_m=(near, far),
            tree_roots=data["tree_roots"].astype(np.int32),
            node_feature=data["node_feature"].astype(np.int32),
            node_threshold=data["node_threshold"].astype(np.float32),
            node_left=data["node_left"].astype(np.int32),
            node_right=data["node_right"].astype(np.int32),
            node_probability=data["node_probability"].astype(np.float32),
            node_offset_m=data["node_offset_m"].astype(np.float32),
            settings_json=str(data["settings_json"]),
            version=str(data["version"]),
            verifier=verifier,
            heatmap=heatmap,
            calibration=calibration,
        )
    except ValueError as error:
        raise ValueError(f"{path}: damaged {FORMAT_NAME} file ({error})") from error


def apply_features(forest: FingertipForest, features: ArrayLike) -> NDArray[np.int32]:
    """Leaves reached by samples whose feature vectors are given.

    Parameters
    ----------
    forest : FingertipForest
    features : (N, F) float32
        Feature values, as from :func:`fingertips.features.pixel_features`.

    Returns
    -------
    leaves : (N, T) int32
        Global node index per tree; subtract ``forest.tree_roots`` for the index within
        each tree (what scikit-learn's ``apply`` returns).
    """
    values = as_array("features", features, (None, forest.n_features), np.float32, kind="fiu")
    return descend_matrix(forest, values)


def apply_depth(
    forest: FingertipForest,
    depth_m: ArrayLike,
    pixels_uv: ArrayLike,
    intrinsics: ArrayLike,
) -> NDArray[np.int32]:
    """Leaves reached by pixels of a depth image, computing only the features tested.

    Parameters
    ----------
    forest : FingertipForest
    depth_m : (H, W) float32
        Depth in metres, 0 where missing, already restricted to the working range.
    pixels_uv : (N, 2) int32
        Pixels ``(u, v)`` with a depth measurement.
    intrinsics : (4,) float
        ``(fx, fy, cx, cy)`` in pixels.

    Returns
    -------
    leaves : (N, T) int32
    """
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
    return apply_probe_image(forest, probe_image(depth), pixels_uv, intrinsics)


def apply_probe_image(
    forest: FingertipForest,
    probes_m: NDArray[np.float32],
    pixels_uv: ArrayLike,
    intrinsics: ArrayLike,
) -> NDArray[np.int32]:
    """:func:`apply_depth` on the depth's :func:`~fingertips.features.probe_image`.

    For callers that probe the same image again (the peak verifier), so that it is
    made once per frame. The descent is compiled
    (:func:`fingertips._tree_kernels.descend_depth_forest`); it gives the
    leaves of the level-by-level NumPy descent over
    :func:`~fingertips.features.paired_feature_values`, bit for bit.
    """
    pixels = as_array("pixels_uv", pixels_uv, (None, 2), np.int32, kind="iu")
    fx, fy, _, _ = intrinsics_array(intrinsics)
    reference = read_probes(probes_m, pixels[:, 0], pixels[:, 1])
    return descend_depth_forest(
        np.ascontiguousarray(probes_m, dtype=np.float32),
        np.ascontiguousarray(pixels),
        reference.astype(np.float32),
        np.ascontiguousarray(forest.offsets_m, dtype=np.float32),
        (float(fx), float(fy)),
        forest.tree_roots,
        forest.packed_nodes,
    )


def predict_leaves(forest: FingertipForest, leaves: ArrayLike) -> ForestPrediction:
    """Combine the leaves ``(N, T)`` reached in each tree into one prediction per sample
    (compiled: :func:`fingertips._tree_kernels.leaf_votes`, a tenth of the time of
    NumPy's gathers and ``einsum`` on a frame's 1,500 pixels, the same values)."""
    given = as_array("leaves", leaves, (None, forest.n_trees), kind="iu")
    if given.size and (given.min() < 0 or given.max() >= len(forest.node_probability)):
        raise ValueError(f"leaves: node ids must lie in 0..{len(forest.node_probability) - 1}")
    nodes = given.astype(np.int32, copy=False)
    probability = np.empty(len(nodes), np.float32)
    offset = np.empty((len(nodes), 3), np.float32)
    leaf_votes(
        np.ascontiguousarray(nodes), forest.node_probability, forest.node_offset_m,
        probability, offset,
    )  # fmt: skip
    return ForestPrediction(probability=probability, offset_m=offset)
