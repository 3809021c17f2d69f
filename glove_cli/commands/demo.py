"""``glove demo``: the main job on embedded defaults.

Until the tracker exists this renders every named posture from the back and the palm
side and writes a contact sheet plus the glove pattern, then says what it made.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "demo",
        help="run the main job on embedded defaults",
        description="Render every named posture of the glove hand and the glove pattern "
        "into a folder, and print what was made.",
    )
    parser.add_argument("--out", default="glove_demo", help="output folder (default: %(default)s)")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np
    from tqdm import tqdm

    from builder.figures import caption, grid, pattern_sheet, save_rgb
    from builder.render import GloveRenderer
    from glovedb.camera import KINECT_V1
    from glovedb.postures import load_named_postures
    from glovedb.views import named_view

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    postures = load_named_postures()
    tiles = []
    with GloveRenderer(KINECT_V1) as renderer:
        hand_length = renderer.mesh.skeleton.hand_length_m
        for name, posture in tqdm(postures.items(), desc="rendering postures", unit="posture"):
            for view in ("back", "palm", "thumb"):
                rotation, translation = named_view(view, 0.4, hand_length)
                rendering = renderer.render(posture, rotation, translation)
                tiles.append(caption(rendering.color, f"{name} ({view})"))
                labels = renderer.pattern.colorize(rendering.labels)
                tiles.append(caption(labels, "labels"))
        sheet = grid([tile[60:420, 140:500] for tile in tiles], columns=6)
        save_rgb(out / "postures.png", sheet)
        save_rgb(out / "pattern.png", pattern_sheet(renderer))
    elapsed = time.perf_counter() - started
    print(f"rendered {len(postures)} named postures x 3 views in {elapsed:.1f} s")
    print(f"  {out / 'postures.png'}: color and label images ({sheet.shape[1]}x{sheet.shape[0]})")
    print(f"  {out / 'pattern.png'}: the glove pattern, back and palm, with its legend")
    print(f"  postures: {', '.join(postures)}")
    print(
        f"  mean glove pixels per view: {np.mean([t.any(axis=2).sum() for t in tiles[1::2]]):.0f}"
    )
    return 0
