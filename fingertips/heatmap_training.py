"""Training of the whole-hand heatmap stage (:mod:`fingertips.heatmap`).

Needs PyTorch (the optional ``train`` extra: ``pip install -e ".[train]"``); nothing
at run time does. Four steps, all deterministic on a CPU:

1. **Crops** (:func:`fingertips.heatmap_data.render_crops`, no PyTorch): hand crops
   of rendered frames and their visible fingertips in the crop's units.
2. **Network** (:func:`train_network`): a small U-Net (:class:`HeatNet`) learns the
   per-cell logit that a fingertip lies there. Targets are Gaussians (``sigma_cells``)
   at the visible tips; the loss is binary cross-entropy with positive weight
   ``positive_weight``; each batch is turned by a random angle and mirrored half of
   the time. First ``whole_hand_epochs`` on the crops whose cube holds every keypoint,
   then ``all_epochs`` on all of them, each with a one-cycle learning rate schedule.
3. **Export** (:func:`export_onnx`): ONNX bytes that onnxruntime runs at detection;
   with ``quantize`` they are quantized to 8 bits
   (:mod:`fingertips.heatmap_quantization`), calibrated on the crops of
   ``quantize_crops`` frames of the first crop seed (a given float network too), their
   weights stored unsigned (a given quantized network's too).
4. **Verifier** (:func:`collect_heat_samples`, :func:`fit_heat_verifier`): on
   ``verifier_images`` more frames per seed of ``verifier_seeds`` the exported
   network's peaks are described by
   :func:`fingertips.heatmap.heat_peak_features` and labelled true when within
   ``match_radius_m`` of a visible fingertip; scikit-learn's histogram gradient boosting
   learns the label and is exported to a node table.
5. **Judge** (:func:`fingertips.judge.fit_candidate_judge`, with
   ``judge_candidates``): on the same frames every candidate of the forest and the
   geodesic stage, labelled the same way, gives its peak verifier probability, the
   heat of its map cell and its verifier features; histogram gradient boosting of the
   label on them (:func:`fingertips.judge.judge_inputs`) decides at detection which
   candidates are kept (:func:`fingertips.judge.judged_probability`).
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
import warnings
from collections.abc import Iterable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from sklearn.ensemble import HistGradientBoostingClassifier
from torch import nn

from fingertips.data import FingertipDataConfig, generate_examples
from fingertips.detect import DetectorConfig, verified_candidates
from fingertips.forest import FingertipForest
from fingertips.heat_fusion import candidate_heat
from fingertips.heatmap import (
    GRID,
    HEAT_PEAK_FEATURES,
    HeatmapNetwork,
    HeatmapStage,
    frame_heat_peaks,
    hand_heatmaps,
)
from fingertips.heatmap_data import Crops, HeatmapTrainingConfig, render_crops
from fingertips.heatmap_quantization import is_quantized, quantize_network, unsigned_weights
from fingertips.judge import JUDGE_FEATURES, fit_candidate_judge, judge_inputs
from fingertips.tree_export import pack_boosted_table

# --- network ------------------------------------------------------------------------


def _block(n_in: int, n_out: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(n_in, n_out, 3, padding=1),
        nn.BatchNorm2d(n_out),
        nn.ReLU(),
        nn.Conv2d(n_out, n_out, 3, padding=1),
        nn.BatchNorm2d(n_out),
        nn.ReLU(),
    )


class HeatNet(nn.Module):
    """``(N, 1, 64, 64)`` hand crops to ``(N, 32, 32)`` logits of "a fingertip is here".

    A U-Net: a stride-2 stem of ``width`` channels, an encoder down to 4 x 4 (2, 4, 8
    and 8 times ``width`` channels), a decoder with skips back to 32 x 32 (6, 4 and 2
    times ``width``) and a 1 x 1 output.
    """

    def __init__(self, width: int = 8) -> None:
        super().__init__()
        c = width
        self.stem = nn.Sequential(
            nn.Conv2d(1, c, 5, stride=2, padding=2), nn.BatchNorm2d(c), nn.ReLU()
        )
        self.e1, self.e2 = _block(c, 2 * c), _block(2 * c, 4 * c)
        self.e3, self.e4 = _block(4 * c, 8 * c), _block(8 * c, 8 * c)
        self.d3 = _block(16 * c, 6 * c)
        self.d2, self.d1 = _block(10 * c, 4 * c), _block(6 * c, 2 * c)
        self.out = nn.Conv2d(2 * c, 1, 1)
        self.pool = nn.MaxPool2d(2)
        self.up = nn.Upsample(scale_factor=2, mode="nearest")

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.stem(x)
        a = self.e1(x)
        b = self.e2(self.pool(a))
        c = self.e3(self.pool(b))
        d = self.e4(self.pool(c))
        y = self.d3(torch.cat([self.up(d), c], 1))
        y = self.d2(torch.cat([self.up(y), b], 1))
        y = self.d1(torch.cat([self.up(y), a], 1))
        return self.out(y)[:, 0]


def heat_targets(tips: torch.Tensor, sigma_cells: float) -> torch.Tensor:
    """Tips ``(N, 5, 2)`` in crop units (NaN: hidden) to targets ``(N, GRID, GRID)``.

    Each cell holds the largest of the Gaussians centred on the visible tips.
    """
    u = (tips[..., 0] + 1) / 2 * GRID - 0.5
    v = (tips[..., 1] + 1) / 2 * GRID - 0.5
    cells = torch.arange(GRID).float()
    d2 = (cells[None, None, None, :] - u[..., None, None]) ** 2
    d2 = d2 + (cells[None, None, :, None] - v[..., None, None]) ** 2
    return torch.nan_to_num(torch.exp(-d2 / (2 * sigma_cells**2)), nan=0.0).max(1).values


def augment(x: torch.Tensor, tips: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Turn crops ``(N, 1, 64, 64)`` and their tips ``(N, 5, 2)`` by random angles and
    mirror half of them left to right (in place on copies the caller owns)."""
    n = len(x)
    angle = torch.rand(n) * 2 * np.pi - np.pi
    c, s = torch.cos(angle), torch.sin(angle)
    theta = torch.zeros(n, 2, 3)
    theta[:, 0, 0], theta[:, 0, 1], theta[:, 1, 0], theta[:, 1, 1] = c, -s, s, c
    grid = nn.functional.affine_grid(theta, list(x.shape), align_corners=False)
    # Missing depth is 1: shift so that samples from outside the crop are missing too.
    x = nn.functional.grid_sample(x - 1, grid, mode="nearest", align_corners=False) + 1
    px = c[:, None] * tips[..., 0] + s[:, None] * tips[..., 1]
    py = -s[:, None] * tips[..., 0] + c[:, None] * tips[..., 1]
    tips = torch.stack([px, py], -1)
    flip = torch.rand(n) < 0.5
    x[flip] = x[flip].flip(-1)
    tips[flip, :, 0] = -tips[flip, :, 0]
    return x, tips


def _log(message: str, progress: bool) -> None:
    if progress:
        print(message, file=sys.stderr, flush=True)


def train_stage(
    initial: dict[str, torch.Tensor] | None,
    images: NDArray[np.float16],
    tips: NDArray[np.float32],
    *,
    epochs: int,
    learning_rate: float,
    config: HeatmapTrainingConfig,
    progress: bool = False,
) -> HeatNet:
    """Train a :class:`HeatNet` for ``epochs`` on crops, with a one-cycle schedule.

    Torch and the crop order are seeded with ``config.seed`` first, then a network is
    initialised and, when ``initial`` (a state dict) is given, set to it: a stage is
    reproducible on its own, from a fresh process or not. Up to 500 crops (a fifth at
    most) are kept out of training to report the share of tip cells found and of
    background cells above 0.5.
    """
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    net = HeatNet(config.width)
    if initial is not None:
        net.load_state_dict(initial)
    if epochs == 0:
        return net.eval()
    x = torch.from_numpy(images.astype(np.float32))[:, None]
    p = torch.from_numpy(tips.astype(np.float32))
    order = rng.permutation(len(x))
    n_check = min(500, len(x) // 5)
    check, train = order[:n_check], order[n_check:]
    if len(train) == 0:
        raise ValueError("heatmap: too few crops to train on")
    optimiser = torch.optim.AdamW(net.parameters(), 1e-3, weight_decay=1e-4)
    batch = config.batch_size
    schedule = torch.optim.lr_scheduler.OneCycleLR(
        optimiser, learning_rate, total_steps=epochs * (len(train) // batch + 1)
    )
    weight = torch.tensor(config.positive_weight)
    for epoch in range(epochs):
        net.train()
        start, total = time.perf_counter(), 0.0
        shuffled = torch.from_numpy(rng.permutation(train))
        for b in range(0, len(train), batch):
            index = shuffled[b : b + batch]
            xb, pb = augment(x[index].clone(), p[index].clone())
            loss = nn.functional.binary_cross_entropy_with_logits(
                net(xb), heat_targets(pb, config.sigma_cells), pos_weight=weight
            )
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            schedule.step()
            total += loss.item() * len(index)
        net.eval()
        if n_check:
            with torch.no_grad():
                probability = torch.sigmoid(net(x[check]))
                target = heat_targets(p[check], config.sigma_cells)
            found = (probability[target > 0.6] > 0.5).float().mean()
            false = (probability[target < 0.05] > 0.5).float().mean()
            _log(
                f"heatmap epoch {epoch + 1}/{epochs}: loss {total / len(train):.4f}, "
                f"tip cells found {found:.3f}, background cells above 0.5 {false:.4f} "
                f"({time.perf_counter() - start:.0f} s)",
                progress,
            )
    return net.eval()


def train_network(
    crops: Crops, config: HeatmapTrainingConfig, *, progress: bool = False
) -> HeatNet:
    """Both training stages of :class:`HeatNet` on ``crops`` (see the module docstring)."""
    whole = crops.whole_hand
    net = train_stage(
        None,
        crops.images[whole],
        crops.tips[whole],
        epochs=config.whole_hand_epochs,
        learning_rate=config.whole_hand_learning_rate,
        config=config,
        progress=progress,
    )
    return train_stage(
        net.state_dict(),
        crops.images,
        crops.tips,
        epochs=config.all_epochs,
        learning_rate=config.all_learning_rate,
        config=config,
        progress=progress,
    )


def export_onnx(net: HeatNet) -> NDArray[np.uint8]:
    """The network as ONNX bytes: input ``crops`` (N, 1, 64, 64), output ``logits``."""
    net.eval()
    with tempfile.TemporaryDirectory() as folder, warnings.catch_warnings():
        # The TorchScript exporter is deprecated in favour of one that needs onnxscript
        # (one more dependency); it exports this plain convolutional network fine, which
        # tests/fingertips/test_heatmap_training.py checks against torch.
        warnings.simplefilter("ignore", DeprecationWarning)
        path = Path(folder) / "heatmap.onnx"
        torch.onnx.export(
            net,
            (torch.zeros(1, 1, 64, 64),),
            path,
            input_names=["crops"],
            output_names=["logits"],
            dynamic_axes={"crops": {0: "n"}, "logits": {0: "n"}},
            opset_version=17,
            dynamo=False,
        )
        return np.frombuffer(path.read_bytes(), dtype=np.uint8).copy()


def train_heatmap_network(
    crops: Crops, config: HeatmapTrainingConfig, *, progress: bool = False
) -> NDArray[np.uint8]:
    """Train :class:`HeatNet` on ``crops`` (:func:`train_network`) and export it as ONNX.

    The network the model file stores (``glove fingertips train-heatmap``).
    """
    return export_onnx(train_network(crops, config, progress=progress))


# --- verifier -----------------------------------------------------------------------


def label_heat_peaks(
    xyz_m: NDArray[np.float64], tips_m: NDArray[np.float64], *, radius_m: float
) -> NDArray[np.bool_]:
    """Which peaks ``(K, 3)`` lie within ``radius_m`` of a visible tip (NaN rows: hidden).

    Not one-to-one: two peaks near one tip are both true (the verifier judges each peak
    on its own; the separation from the forest's detections removes doubles).
    """
    visible = tips_m[np.isfinite(tips_m).all(axis=1)]
    if not len(xyz_m) or not len(visible):
        return np.zeros(len(xyz_m), dtype=bool)
    return np.linalg.norm(xyz_m[:, None] - visible[None], axis=2).min(axis=1) <= radius_m


@dataclass(frozen=True)
class HeatSamples:
    """Labelled samples of the heatmap stage's two fits on annotated frames.

    Attributes
    ----------
    features : (N, len(HEAT_PEAK_FEATURES)) float32
        The heat peaks' verifier features.
    labels : (N,) bool
        Which peaks lie within ``match_radius_m`` of a visible fingertip.
    candidate_inputs : (M, len(JUDGE_FEATURES)) float32
        Every candidate's peak verifier probability, the heat of its map cell
        (:func:`fingertips.heat_fusion.candidate_heat`) and its verifier features:
        the judge's inputs (:func:`fingertips.judge.judge_inputs`).
    candidate_labels : (M,) bool
        Which candidates lie within ``match_radius_m`` of a visible fingertip.
    """

    features: NDArray[np.float32]
    labels: NDArray[np.bool_]
    candidate_inputs: NDArray[np.float32]
    candidate_labels: NDArray[np.bool_]


def collect_heat_samples(
    images: Iterable[tuple[NDArray[np.float32], NDArray[np.float64], NDArray[np.float64]]],
    forest: FingertipForest,
    network: HeatmapNetwork,
    *,
    detector: DetectorConfig,
    config: HeatmapTrainingConfig,
) -> HeatSamples:
    """The heatmap's peaks and the candidates on annotated frames, with their labels.

    Parameters
    ----------
    images : iterable of (depth_m, intrinsics, tips_m)
        As in :func:`fingertips.verifier_training.collect_peak_samples`.
    forest : FingertipForest
        With its peak verifier (the features use its candidates and probabilities).
    network : HeatmapNetwork
    detector : DetectorConfig
        Its ``c_thr``, voting, ``min_tip_probability`` and ``heatmap_centre`` make the
        forest's part and the crop.
    config : HeatmapTrainingConfig
    """
    if forest.verifier is None:
        raise ValueError("heatmap: the forest needs its peak verifier (a [verifier] table)")
    features, labels = [], []
    candidate_inputs, candidate_labels = [], []
    for depth_m, intrinsics, tips_m in images:
        candidates, probability, candidate_features, hand, geodesic = verified_candidates(
            depth_m, intrinsics, forest, config=detector
        )
        heatmaps = hand_heatmaps(
            depth_m,
            intrinsics,
            network,
            hand_depth_m=hand,
            geodesic=geodesic if detector.heatmap_centre == "fingers" else None,
        )
        peaks, frame_features = frame_heat_peaks(
            depth_m,
            intrinsics,
            network,
            candidates.positions_m,
            candidates.confidences,
            probability,
            min_value=config.min_value,
            min_tip_probability=detector.min_tip_probability,
            heatmaps=heatmaps,
        )
        features.append(frame_features)
        labels.append(label_heat_peaks(peaks.xyz_m, tips_m, radius_m=config.match_radius_m))
        points = candidates.positions_m.astype(np.float64)
        heat = candidate_heat(heatmaps, points)
        candidate_inputs.append(judge_inputs(probability, heat, candidate_features))
        candidate_labels.append(label_heat_peaks(points, tips_m, radius_m=config.match_radius_m))
    if not features:
        return HeatSamples(
            np.zeros((0, len(HEAT_PEAK_FEATURES)), np.float32),
            np.zeros(0, bool),
            np.zeros((0, len(JUDGE_FEATURES)), np.float32),
            np.zeros(0, bool),
        )
    return HeatSamples(
        np.concatenate(features),
        np.concatenate(labels),
        np.concatenate(candidate_inputs),
        np.concatenate(candidate_labels),
    )


def fit_heat_verifier(
    features: NDArray[np.float32], labels: NDArray[np.bool_], config: HeatmapTrainingConfig
) -> HistGradientBoostingClassifier:
    """Histogram gradient boosting on labelled heat peaks (no early stopping).

    Raises
    ------
    ValueError
        Unless there are both true and false peaks.
    """
    if labels.all() or not labels.any():
        raise ValueError("heatmap: need both true and false peaks to train its verifier")
    return HistGradientBoostingClassifier(
        max_iter=config.verifier_iterations,
        learning_rate=config.verifier_learning_rate,
        max_leaf_nodes=config.verifier_leaf_nodes,
        early_stopping=False,
        random_state=config.seed,
    ).fit(features, labels)


def train_heatmap(
    forest: FingertipForest,
    data: FingertipDataConfig,
    detector: DetectorConfig,
    config: HeatmapTrainingConfig,
    *,
    network_onnx: NDArray[np.uint8] | None = None,
    progress: bool = False,
) -> FingertipForest:
    """Render crops, train and export the network, then fit the heatmap's verifier.

    Parameters
    ----------
    forest : FingertipForest
        The trained forest with its peak verifier (an existing heatmap is replaced).
    data : FingertipDataConfig
        The recipe's data settings; ``config.data`` replaces some.
    detector : DetectorConfig
        Detection settings (recorded in the model).
    config : HeatmapTrainingConfig
    network_onnx : (B,) uint8, optional
        Use this network (e.g. another model's ``heatmap.network_onnx``) and fit only
        the verifier: no crops, no network training.
    progress : bool
        Progress bars and per-epoch lines on standard error.

    Returns
    -------
    FingertipForest
        ``forest`` with the heatmap stage and its settings recorded.
    """
    from tqdm import tqdm

    frames = config.heatmap_data(data)
    crop_counts: dict[str, Any] = {"network": "given"}
    if network_onnx is None:
        crops = render_crops(
            frames,
            config.crop_seeds,
            config.crops_per_seed,
            centre=config.crop_centre,
            progress=progress,
        )
        network_onnx = train_heatmap_network(crops, config, progress=progress)
        crop_counts = {
            "n_crops": len(crops.images),
            "n_whole_hand_crops": int(crops.whole_hand.sum()),
        }
    if config.quantize and not is_quantized(network_onnx):
        first_seed = config.crop_seeds[:1]
        calibration = render_crops(
            frames,
            first_seed,
            config.quantize_crops,
            centre=config.crop_centre,
            progress=progress,
        )
        network_onnx = quantize_network(network_onnx, calibration.images, passes=config.passes)
    elif is_quantized(network_onnx):  # a given network, quantized before weights were unsigned
        network_onnx = unsigned_weights(network_onnx)
    network = HeatmapNetwork(network_onnx, config.passes)
    parts = []
    for seed in config.verifier_seeds:
        verifier_frames = replace(
            frames, seed=seed, n_images=config.verifier_images, half_resolution_fraction=0.0
        )
        images = (
            (example.depth_m, example.intrinsics, example.tips_m)
            for example in tqdm(
                generate_examples(verifier_frames),
                total=verifier_frames.n_images,
                desc=f"heatmap verifier (seed {seed})",
                unit="img",
                disable=not progress,
            )
        )
        parts.append(
            collect_heat_samples(images, forest, network, detector=detector, config=config)
        )
    features = np.concatenate([part.features for part in parts])
    labels = np.concatenate([part.labels for part in parts])
    table = pack_boosted_table(fit_heat_verifier(features, labels, config))
    judge = None
    if config.judge_candidates:
        judge = fit_candidate_judge(
            np.concatenate([part.candidate_inputs for part in parts]),
            np.concatenate([part.candidate_labels for part in parts]),
            iterations=config.judge_iterations,
            leaf_nodes=config.judge_leaf_nodes,
            learning_rate=config.judge_learning_rate,
            seed=config.seed,
        )
    stage = HeatmapStage(
        network_onnx=network_onnx,
        passes=config.passes,
        min_value=config.min_value,
        judge=judge,
        **table,
    )
    settings = {
        **forest.settings,
        "heatmap": {
            **asdict(config),
            **crop_counts,
            "n_peaks": int(labels.size),
            "n_true_peaks": int(labels.sum()),
            "n_candidates": int(sum(part.candidate_labels.size for part in parts)),
            "n_true_candidates": int(sum(part.candidate_labels.sum() for part in parts)),
        },
        "detector": detector.as_dict(),
    }
    return replace(forest, heatmap=stage, settings_json=json.dumps(settings, sort_keys=True))
