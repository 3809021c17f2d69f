"""Prototype: a whole-hand fingertip heatmap network next to the Hough forest (issue 7).

The stage now ships in the package (``tracker/fingertips/heatmap.py``, trained by
``builder/fingertip_heatmap.py``, whose network, targets, augmentation and crops this
script uses); the script stays as the record of the ninth session's experiments, whose
figures in ``docs/fingertips_experiments.md`` it made, and its ``crops`` and ``train``
steps made the shipped network (``hm4.pt``, exported with
``builder.fingertip_heatmap.export_onnx``). Imported neither by the package nor by the
tests; it needs the ``train`` extra. Run from the repository root, with the project's
environment:

    # 35,000 hand crops rendered like configs/fingertips/curled.toml (curl_fraction 0.3)
    for s in 101 102 103 104 105; do
      python experiments/tip_heatmap.py crops --seed $s --frames 7000 --out d$s.npz
    done
    # 18 epochs on the crops that hold the whole hand, then 5 more on all of them
    python experiments/tip_heatmap.py train d10?.npz --out hm1.pt --epochs 18 --whole-hands
    python experiments/tip_heatmap.py train d10?.npz --out hm4.pt --epochs 5 --init hm1.pt \
        --lr 1e-3
    # the shipped network (docs/fingertips.md, "Model file", gives the step after it)
    python experiments/tip_heatmap.py export hm4.pt --out hm4.onnx
    # the network alone on annotated folders
    python experiments/tip_heatmap.py eval hm4.pt /tmp/fingertips_validation
    # test frames whose curled tips follow the real annotations' rule ("surface"), and
    # 600 validation frames of their own seed
    tip='s/^occlusion_tolerance_m = 0.015/&\nsurface_tip_depth_m = 0.04/'
    more='s/^n_images = 200/n_images = 600/; s/^seed = 2/seed = 3/'
    sed "$tip" configs/fingertips/heldout.toml > heldout_surface.toml
    sed "$tip" configs/fingertips/validation.toml > validation_surface.toml
    sed "$tip; $more" configs/fingertips/validation.toml > validation600_surface.toml
    for c in heldout_surface validation_surface validation600_surface; do
      glove fingertips synth $c.toml --out /tmp/fingertips_$c
    done
    # peaks with verifier features (training frames, validation, held-out, real), then
    # a verifier, the union with the shipped forest's detections and the validation rule
    python experiments/tip_heatmap.py peaks hm4.pt --frames 1500 --seed 11 --surface 0.04 \
        --validation /tmp/fingertips_validation_surface \
        --heldout /tmp/fingertips_heldout_surface --out v4s.npz
    python experiments/tip_heatmap.py peaks hm4.pt --frames 3500 --seed 12 --surface 0.04 \
        --validation /tmp/fingertips_validation_surface \
        --heldout /tmp/fingertips_heldout_surface --out v4s_b.npz
    python experiments/tip_heatmap.py union v4s.npz v4s_b.npz
    python experiments/tip_heatmap.py peaks hm4.pt --frames 0 \
        --validation /tmp/fingertips_validation600_surface \
        --heldout /tmp/fingertips_heldout_surface --out v600s.npz
    python experiments/tip_heatmap.py union v600s.npz v4s.npz v4s_b.npz

The same without ``--surface`` and with the shipped folders (and 600 validation frames
without ``$tip``) gives the figures for the held-out frames' own rule.

What it does (details and figures in the experiment log):

- **crop**: the mean of the nearest object's points (``hand_points_from_depth``),
  moved three times to the mean of the points within 12 cm, is the centre of a 30 cm
  cube; the crop is a 64 x 64 image of the depth relative to that centre over 15 cm,
  clipped to [-1, 1] (1 where depth is missing).
- **network**: a small U-Net (stride-2 stem, encoder to 4 x 4, decoder with skips back
  to 32 x 32) whose one output channel is the logit that a visible fingertip lies in
  each 9.4 mm cell. Targets are Gaussians (sigma 1.2 cells) at the visible tips of the
  rendered frames (the data config's visibility rule); loss: binary cross-entropy with
  positive weight 20; augmentation: in-plane rotations and left-right flips.
- **peaks**: local 3 x 3 maxima of the mean of 8 flipped and rotated passes, moved by
  the centroid of their 3 x 3 neighbourhood (sub-cell), lifted to 3D at the 10th
  percentile of the depth within 6 mm (and within 15 cm of the crop centre) plus 8 mm.
- **verifier and union**: 22 features per peak (heatmap value and its spread over the
  8 passes, neighbourhood, depth context, the shipped forest's nearest candidate peak
  and its verifier probability), a gradient-boosting classifier trained on peaks of
  rendered frames; accepted peaks farther than 15 mm from every detection of the
  shipped forest are added to those detections.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import tomllib
import torch
from scipy.ndimage import maximum_filter
from sklearn.ensemble import HistGradientBoostingClassifier
from torch import nn
from tqdm import tqdm

from builder.fingertip_data import data_config_from_dict, generate_examples
from builder.fingertip_heatmap import HeatNet, augment, crop_units, export_onnx, heat_targets
from tracker.fingertips import Detection, detect_fingertips, load_forest, model_detector_config
from tracker.fingertips.detect import candidate_peaks, detection_points
from tracker.fingertips.evaluation import fingertip_metrics, read_annotated_depth
from tracker.fingertips.heatmap import CROP_HALF_M as HALF_M
from tracker.fingertips.heatmap import GRID, HEAT_PEAK_FEATURES, hand_centre, hand_crop
from tracker.fingertips.verify import verify_peaks

SIGMA_CELLS = 1.2
"""Width of the training targets' Gaussians, heatmap cells."""
REAL = "../shared/data/real_depth/hmodel_andrii"


def crop(depth_m: np.ndarray, intrinsics: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """The package's hand crop, stored as float16."""
    return hand_crop(depth_m, np.asarray(intrinsics, float), centre).astype(np.float16)


def load_net(path: str) -> HeatNet:
    state = torch.load(path, weights_only=True)
    net = HeatNet(width=state["stem.0.weight"].shape[0])
    net.load_state_dict(state)
    return net.eval()


def tta_heat(net: HeatNet, crop_image: np.ndarray, passes: int = 8) -> np.ndarray:
    """(passes, GRID, GRID) probabilities of turned and mirrored crops, turned back.

    ``passes`` 8: the 4 quarter turns of the crop and of its mirror image; 2: the crop
    and its mirror image; 1: the crop alone.
    """
    x = torch.from_numpy(crop_image.astype(np.float32))[None, None]
    mirrors = (x,) if passes == 1 else (x, x.flip(-1))
    turns = max(passes // 2, 1)
    views = [torch.rot90(v, k, (-2, -1)) for v in mirrors for k in range(turns)]
    with torch.no_grad():
        maps = torch.sigmoid(net(torch.cat(views)))
    back = [torch.rot90(maps[i], -(i % turns), (-2, -1)) for i in range(len(views))]
    back = [m if i < turns else m.flip(-1) for i, m in enumerate(back)]
    return torch.stack(back).numpy()


# --- peaks -------------------------------------------------------------------------


def heat_peaks(
    heat: np.ndarray,
    centre: np.ndarray,
    depth_m: np.ndarray,
    intrinsics: np.ndarray,
    threshold: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Local maxima above ``threshold``: cells (K, 2), pixels (K, 2), 3D (K, 3), values (K,)."""
    cells = np.argwhere((heat == maximum_filter(heat, 3)) & (heat > threshold))[:, ::-1]
    values = heat[cells[:, 1], cells[:, 0]]
    padded = np.pad(heat, 1)
    gy, gx = np.mgrid[-1:2, -1:2]
    refined = cells.astype(float)
    for n, (a, b) in enumerate(cells):
        w = padded[b : b + 3, a : a + 3]
        w = np.maximum(w - w.min(), 0)
        if w.sum() > 0:  # a flat neighbourhood keeps the cell centre
            refined[n] += [(w * gx).sum() / w.sum(), (w * gy).sum() / w.sum()]
    fx, fy, cx, cy = intrinsics
    offset = ((refined + 0.5) / GRID * 2 - 1) * HALF_M
    u = fx * (centre[0] + offset[:, 0]) / centre[2] + cx
    v = fy * (centre[1] + offset[:, 1]) / centre[2] + cy
    h, w = depth_m.shape
    radius = max(2, round(0.006 * fx / centre[2]))
    xyz = []
    for a, b in zip(u, v, strict=True):
        i, j = int(np.clip(round(b), 0, h - 1)), int(np.clip(round(a), 0, w - 1))
        window = depth_m[max(i - radius, 0) : i + radius + 1, max(j - radius, 0) : j + radius + 1]
        window = window[(window > 0) & (np.abs(window - centre[2]) < HALF_M)]
        z = np.percentile(window, 10) + 0.008 if len(window) else centre[2]
        xyz.append([(a - cx) * z / fx, (b - cy) * z / fy, z])
    return cells, np.stack([u, v], 1), np.array(xyz).reshape(-1, 3), values


def as_detections(uv: np.ndarray, xyz: np.ndarray, values: np.ndarray) -> tuple[Detection, ...]:
    """Peaks at pixels ``uv`` (K, 2) and points ``xyz`` (K, 3) with ``values`` as detections."""
    return tuple(
        Detection(*map(float, (*uv[k], *xyz[k])), confidence=float(values[k]))
        for k in range(len(uv))
    )


def report(detections: list[tuple[Detection, ...]], data) -> str:
    """The package's fingertip metrics of per-frame detections, on one line."""
    m = fingertip_metrics(detections, data.tips_m, data.tips_px)
    precision_2d = m.recall_10px * m.annotated_tips / max(m.detections, 1)
    return (
        f"{m.detections} detections, P {m.precision_15mm:.3f} R {m.recall_15mm:.3f} "
        f"({m.error_3d_mm:.1f} mm); 2D P {precision_2d:.3f} R@10px {m.recall_10px:.3f} "
        f"({m.error_2d_px:.1f} px)"
    )


FEATURES = HEAT_PEAK_FEATURES
"""The package's names of the 22 features (the prototype computes them in this order)."""


def peak_rows(
    net: HeatNet, forest, depth_m: np.ndarray, intrinsics: np.ndarray, passes: int = 8
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Features (K, len(FEATURES)), pixels (K, 2) and 3D (K, 3) of a frame's heatmap peaks."""
    empty = np.zeros((0, len(FEATURES))), np.zeros((0, 2)), np.zeros((0, 3))
    centre = hand_centre(depth_m, intrinsics)
    if centre is None:
        return empty
    maps = tta_heat(net, crop(depth_m, intrinsics, centre), passes)
    heat, spread = maps.mean(0), maps.std(0)
    cells, uv, xyz, values = heat_peaks(heat, centre, depth_m, intrinsics, 0.3)
    if not len(uv):
        return empty
    base = model_detector_config(forest)
    config = replace(base, c_thr=0.5, voting=replace(base.voting, min_probability=0.3))
    candidates, features = candidate_peaks(depth_m, intrinsics, forest, config=config)
    probability = verify_peaks(forest.verifier, features) if len(features) else np.zeros(0)
    positions = candidates.positions_m.astype(float)
    rank = np.empty(len(values))
    rank[np.argsort(-values)] = np.arange(len(values))
    h, w = depth_m.shape
    radius = max(2, round(0.006 * intrinsics[0] / centre[2]))
    rows = []
    for k, (a, b) in enumerate(cells):
        i, j = int(np.clip(round(uv[k, 1]), 0, h - 1)), int(np.clip(round(uv[k, 0]), 0, w - 1))
        window = depth_m[max(i - radius, 0) : i + radius + 1, max(j - radius, 0) : j + radius + 1]
        valid = (window > 0) & (np.abs(window - centre[2]) < HALF_M)
        seen = window[valid]
        front = np.percentile(seen, 25) if len(seen) else centre[2]
        extent = np.percentile(seen, 90) - np.percentile(seen, 10) if len(seen) else 0.0
        if len(positions):
            distance = np.linalg.norm(positions - xyz[k], axis=1)
            n = distance.argmin()
            near = distance < 0.02
            best = probability[near].max() if near.any() else 0.0
            forest_part = [
                distance[n],
                candidates.confidences[n],
                probability[n],
                best,
                candidates.confidences[near].sum(),
            ]
        else:
            forest_part = [1.0, 0.0, 0.0, 0.0, 0.0]
        rows.append(
            [
                values[k],
                spread[b, a],
                heat[max(b - 1, 0) : b + 2, max(a - 1, 0) : a + 2].mean(),
                heat[max(b - 2, 0) : b + 3, max(a - 2, 0) : a + 3].mean(),
                (values > 0.5).sum(),
                rank[k],
                np.hypot(a - 15.5, b - 15.5),
                xyz[k, 2] - centre[2],
                centre[2],
                valid.mean(),
                extent,
                front - np.median(seen) if len(seen) else 0.0,
                xyz[k, 2],
                len(positions),
                (probability >= 0.75).sum(),
            ]
            + forest_part
            + [maps[:, b, a].min(), (maps[:, b, a] > 0.5).mean()]
        )
    return np.array(rows), uv, xyz


# --- commands ----------------------------------------------------------------------


def curled_data(seed: int, frames: int, surface_m: float, half_resolution: float):
    table = tomllib.loads(Path("configs/fingertips/curled.toml").read_text())["data"]
    return replace(
        data_config_from_dict(table),
        seed=seed,
        n_images=frames,
        curl_fraction=0.3,
        surface_tip_depth_m=surface_m,
        half_resolution_fraction=half_resolution,
    )


def cmd_crops(args: argparse.Namespace) -> None:
    data = curled_data(args.seed, args.frames, 0.04, 0.5)
    crops, keypoints, centres, tips = [], [], [], []
    for example in tqdm(generate_examples(data), total=args.frames, mininterval=30):
        centre = hand_centre(example.depth_m, example.intrinsics)
        if centre is None:
            continue
        crops.append(crop(example.depth_m, example.intrinsics, centre))
        keypoints.append(example.keypoints_m - centre)
        centres.append(centre)
        tips.append(example.tips_m)
    np.savez(
        args.out,
        X=np.array(crops),
        K=np.array(keypoints, np.float32),
        C=np.array(centres),
        T=np.array(tips),
    )
    print(f"{len(crops)} crops")


def cmd_train(args: argparse.Namespace) -> None:
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    crops, tips = [], []
    for path in args.crops:
        z = np.load(path)
        keep = np.ones(len(z["X"]), bool)
        if args.whole_hands:  # every keypoint inside the crop's cube
            k = z["K"]
            keep = (np.abs(k[..., :2]) < 0.14).all((1, 2)) & (np.abs(k[..., 2]) < HALF_M).all(1)
        crops.append(z["X"][keep])
        tips.append(crop_units(z["T"][keep], z["C"][keep]))
    x = torch.from_numpy(np.concatenate(crops).astype(np.float32))[:, None]
    p = torch.from_numpy(np.concatenate(tips).astype(np.float32))
    order = rng.permutation(len(x))
    check, train = order[: min(500, len(x) // 5)], order[min(500, len(x) // 5) :]
    net = HeatNet(args.width)
    if args.init:
        net.load_state_dict(torch.load(args.init, weights_only=True))
    optimiser = torch.optim.AdamW(net.parameters(), 1e-3, weight_decay=1e-4)
    schedule = torch.optim.lr_scheduler.OneCycleLR(
        optimiser, args.lr, total_steps=args.epochs * (len(train) // 64 + 1)
    )
    for epoch in range(args.epochs):
        net.train()
        start, total = time.time(), 0.0
        shuffled = torch.from_numpy(rng.permutation(train))
        for b in range(0, len(train), 64):
            batch = shuffled[b : b + 64]
            xb, pb = augment(x[batch].clone(), p[batch].clone())
            loss = nn.functional.binary_cross_entropy_with_logits(
                net(xb), heat_targets(pb, SIGMA_CELLS), pos_weight=torch.tensor(20.0)
            )
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            schedule.step()
            total += loss.item() * len(batch)
        net.eval()
        with torch.no_grad():
            prob, target = torch.sigmoid(net(x[check])), heat_targets(p[check], SIGMA_CELLS)
        found = (prob[target > 0.6] > 0.5).float().mean()
        false = (prob[target < 0.05] > 0.5).float().mean()
        print(
            f"epoch {epoch} loss {total / len(train):.4f} tip cells found {found:.3f} "
            f"background cells above 0.5 {false:.4f} ({time.time() - start:.0f} s)",
            flush=True,
        )
    torch.save(net.state_dict(), args.out)


def cmd_eval(args: argparse.Namespace) -> None:
    net = load_net(args.net)
    for folder in args.folders:
        data = read_annotated_depth(folder)
        camera = np.asarray(data.intrinsics, float)
        maps = []
        for depth in data.depth_m:
            centre = hand_centre(depth, camera)
            # the plain pass of the 8: the network's own peaks, without averaging
            maps.append(
                None if centre is None else (tta_heat(net, crop(depth, camera, centre))[0], centre)
            )
        for threshold in (0.5, 0.9, 0.97):
            found = [
                ()
                if item is None
                else as_detections(*heat_peaks(*item, depth, camera, threshold)[1:])
                for item, depth in zip(maps, data.depth_m, strict=True)
            ]
            print(f"{folder} threshold {threshold}: {report(found, data)}")


def _labels(uv, xyz, data, k, real: bool) -> np.ndarray:
    """Peaks near any tip (10 px on real frames, else 15 mm), not one-to-one.

    Unlike ``builder.fingertip_verifier.label_peaks``, two peaks near one tip are both
    positive; the verifiers in the experiment log were fitted on these labels.
    """
    seen = np.isfinite(data.tips_px[k]).all(1)
    if not len(uv) or not seen.any():
        return np.zeros(len(uv), bool)
    if real:
        return np.linalg.norm(uv[:, None] - data.tips_px[k][seen][None], axis=2).min(1) <= 10
    return np.linalg.norm(xyz[:, None] - data.tips_m[k][seen][None], axis=2).min(1) <= 0.015


def cmd_peaks(args: argparse.Namespace) -> None:
    net, forest = load_net(args.net), load_forest()
    out: dict[str, np.ndarray] = {}
    rows, labels = [], []
    examples = generate_examples(curled_data(args.seed, max(args.frames, 1), args.surface, 0.0))
    for example in tqdm(examples if args.frames else (), total=args.frames, mininterval=30):
        camera = np.asarray(example.intrinsics, float)
        f, _, xyz = peak_rows(net, forest, example.depth_m, camera, args.passes)
        seen = np.isfinite(example.tips_m).all(1)
        hit = np.zeros(len(xyz), bool)
        if len(xyz) and seen.any():
            hit = np.linalg.norm(xyz[:, None] - example.tips_m[seen][None], axis=2).min(1) <= 0.015
        rows.append(f)
        labels.append(hit)
    out.update(
        Ftrain=np.concatenate(rows) if rows else np.zeros((0, len(FEATURES))),
        ytrain=np.concatenate(labels) if labels else np.zeros(0, bool),
    )
    for name, folder in (("val", args.validation), ("held", args.heldout), ("real", REAL)):
        data = read_annotated_depth(folder)
        camera = np.asarray(data.intrinsics, float)
        parts: dict[str, list] = {"F": [], "y": [], "frame": [], "uv": [], "xyz": []}
        for k, depth in enumerate(data.depth_m):
            f, uv, xyz = peak_rows(net, forest, depth, camera, args.passes)
            hits = _labels(uv, xyz, data, k, name == "real")
            for key, value in zip(parts, (f, hits, np.full(len(f), k), uv, xyz), strict=True):
                parts[key].append(value)
        out.update({f"{key}{name}": np.concatenate(v) for key, v in parts.items()})
        out[f"folder{name}"] = np.array(folder)
    np.savez(args.out, **out)


def cmd_union(args: argparse.Namespace) -> None:
    z = dict(np.load(args.caches[0]))
    for path in args.caches[1:]:  # more training frames for the verifier
        extra = np.load(path)
        z["Ftrain"] = np.concatenate([z["Ftrain"], extra["Ftrain"]])
        z["ytrain"] = np.concatenate([z["ytrain"], extra["ytrain"]])
    forest = load_forest()
    config = model_detector_config(forest)
    classifier = HistGradientBoostingClassifier(
        max_iter=300, learning_rate=0.05, max_leaf_nodes=31, random_state=0
    ).fit(z["Ftrain"], z["ytrain"])
    sets = {}
    for name in ("val", "held", "real"):
        data = read_annotated_depth(str(z[f"folder{name}"]))
        camera = np.asarray(data.intrinsics, float)
        forest_detections = [
            detect_fingertips(depth, camera, forest, config=config) for depth in data.depth_m
        ]
        sets[name] = (data, forest_detections, classifier.predict_proba(z[f"F{name}"])[:, 1])

    def union(name: str, threshold: float) -> list[tuple[Detection, ...]]:
        """Per frame: the forest's detections and the accepted peaks apart from them."""
        _, forest_detections, probability = sets[name]
        frames = []
        for k, forest_found in enumerate(forest_detections):
            keep = (z[f"frame{name}"] == k) & (probability >= threshold)
            uv, xyz, p = z[f"uv{name}"][keep], z[f"xyz{name}"][keep], probability[keep]
            forest_xyz = detection_points(forest_found)
            if len(forest_xyz) and len(xyz):
                apart = np.linalg.norm(xyz[:, None] - forest_xyz[None], axis=2).min(1) > 0.015
                uv, xyz, p = uv[apart], xyz[apart], p[apart]
            frames.append(forest_found + as_detections(uv, xyz, p))
        return frames

    def precision(name: str, threshold: float) -> float:
        return fingertip_metrics(
            union(name, threshold), sets[name][0].tips_m, sets[name][0].tips_px
        ).precision_15mm

    def line(threshold: float) -> str:
        return " | ".join(
            f"{name} {report(union(name, threshold), sets[name][0])}" for name in sets
        )

    for threshold in np.arange(0.5, 1.0, 0.05):
        print(f"threshold {threshold:.2f}: {line(threshold)}")
    passing = [t for t in np.arange(0.3, 1.0, 0.01) if precision("val", t) >= 0.95]
    if passing:
        print(f"validation rule {passing[0]:.2f}: {line(passing[0])}")
    else:
        print("validation rule: no threshold keeps 0.95 precision on the validation frames")


def cmd_export(args: argparse.Namespace) -> None:
    """Write a network's ONNX file, for ``glove fingertips train --heatmap-network``."""
    Path(args.out).write_bytes(export_onnx(load_net(args.net)).tobytes())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("crops", help="render frames and crop the hand")
    p.add_argument("--seed", type=int, required=True)
    p.add_argument("--frames", type=int, default=7000)
    p.add_argument("--out", required=True)
    p = sub.add_parser("train", help="train the heatmap network on crop files")
    p.add_argument("crops", nargs="+")
    p.add_argument("--out", required=True)
    p.add_argument("--epochs", type=int, default=18)
    p.add_argument("--lr", type=float, default=2e-3, help="peak of the one-cycle schedule")
    p.add_argument("--init", help="start from these weights")
    p.add_argument("--width", type=int, default=16, help="channels of the stem")
    p.add_argument("--whole-hands", action="store_true", help="only crops holding every keypoint")
    p = sub.add_parser("eval", help="the network alone (one pass) on annotated folders")
    p.add_argument("net")
    p.add_argument("folders", nargs="+")
    p = sub.add_parser("peaks", help="heatmap peaks with verifier features and labels")
    p.add_argument("net")
    p.add_argument("--frames", type=int, default=1500, help="training frames (0: none)")
    p.add_argument("--seed", type=int, default=11)
    p.add_argument("--surface", type=float, default=0.0, help="surface_tip_depth_m of the labels")
    p.add_argument("--passes", type=int, choices=(1, 2, 8), default=8, help="averaged passes")
    p.add_argument("--validation", default="/tmp/fingertips_validation")
    p.add_argument("--heldout", default="/tmp/fingertips_heldout")
    p.add_argument("--out", required=True)
    p = sub.add_parser("export", help="write a network as ONNX")
    p.add_argument("net")
    p.add_argument("--out", required=True)
    p = sub.add_parser("union", help="verifier, union with the forest, validation rule")
    p.add_argument("caches", nargs="+", help="peaks files; the training rows of all are used")
    args = parser.parse_args()
    torch.set_num_threads(2)
    {
        "crops": cmd_crops,
        "train": cmd_train,
        "eval": cmd_eval,
        "peaks": cmd_peaks,
        "union": cmd_union,
        "export": cmd_export,
    }[args.command](args)


if __name__ == "__main__":
    main()
