"""Color calibration from tracked frames of a glove whose dyes differ from nominal."""

import dataclasses

import numpy as np
import pytest

from glovedb.camera import KINECT_V1
from glovedb.pattern import load_pattern
from glovedb.postures import named_posture
from glovedb.rotations import axis_angle_to_matrix
from tracker.calibrate import calibrate, model_label_image
from tracker.classify import nominal_table
from tracker.frames import Frame
from tracker.pipeline import Tracker

pytestmark = pytest.mark.gl


def glove_frames(renderer_pattern, count, seed):
    from builder.render import GloveRenderer

    rng = np.random.default_rng(seed)
    frames, truth = [], []
    with GloveRenderer(
        KINECT_V1, pattern=renderer_pattern, background_rgb=(70, 60, 50)
    ) as renderer:
        for index in range(count):
            rotation = axis_angle_to_matrix(rng.normal(size=3), rng.uniform(0, np.pi))
            translation = np.array([rng.uniform(-0.08, 0.08), rng.uniform(-0.05, 0.05), 0.6])
            posture = named_posture(("open", "pinch", "power")[index % 3])
            rendering = renderer.render(posture, rotation, translation)
            frames.append(Frame(index, rendering.color, rendering.depth_m, KINECT_V1))
            truth.append((rendering.labels, posture, rotation, translation))
    return frames, truth


def glove_accuracy(table, frames, truth):
    hits = [
        np.mean(table.classify(frame.color)[labels > 0] == labels[labels > 0])
        for frame, (labels, *_) in zip(frames, truth, strict=True)
    ]
    return float(np.mean(hits))


def test_model_label_image_matches_the_renderer(open_pinch_power_database):
    pattern = load_pattern()
    _, truth = glove_frames(pattern, 2, seed=4)
    with Tracker(open_pinch_power_database) as tracker:
        for labels, posture, rotation, translation in truth:
            model, depth = model_label_image(
                tracker.mesh, tracker.split, posture, rotation, translation, KINECT_V1
            )
            glove = (labels > 0) | (model > 0)
            # A 3 mm tracking mesh against the 2 mm render mesh: borders differ slightly.
            assert np.mean(model[glove] == labels[glove]) > 0.9
            assert np.all(depth[model > 0] > 0.4)


def test_calibration_learns_a_glove_with_shifted_dyes(open_pinch_power_database):
    pattern = load_pattern()
    dyed = np.clip((pattern.colors_rgb * 0.8 + 20) * np.array([1.1, 0.98, 0.85]), 0, 255)
    glove = dataclasses.replace(pattern, colors_rgb=dyed.astype(np.uint8))
    frames, truth = glove_frames(glove, 10, seed=5)
    nominal = glove_accuracy(nominal_table(pattern), frames[6:], truth[6:])
    with Tracker(open_pinch_power_database) as tracker:
        result = calibrate(frames[:6], tracker)
    calibrated = glove_accuracy(result.table, frames[6:], truth[6:])
    assert result.frames_used >= 1 and result.glove_samples > 1000
    assert calibrated > 0.97 and calibrated > nominal + 0.1
    background = [
        np.mean(result.table.classify(frame.color)[labels == 0] == 0)
        for frame, (labels, *_) in zip(frames, truth, strict=True)
    ]
    assert np.mean(background) > 0.995
