"""The rerun logger: frames written to an .rrd file and read back with rerun's reader."""

from __future__ import annotations

import sys
from collections import defaultdict
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from glovedb.camera import CameraIntrinsics
from glovedb.hand_model import N_JOINTS, N_KEYPOINTS, forward_kinematics, make_skeleton
from glovedb.mesh import make_hand_mesh, pose_mesh
from glovedb.pattern import load_pattern, split_by_label
from tracker.classify import nominal_table
from tracker.frames import Frame
from tracker.outputs import rerun_view
from tracker.outputs.rerun_view import MISSING_EXTRA, RerunLogger, labeled_depth_cloud
from tracker.overlay import FINGER_BONES, PALM_BONES

SMALL = CameraIntrinsics(64, 48, 60.0, 60.0, 31.5, 23.5)
TRANSLATION_M = np.array([0.0, 0.0, 0.5])  # the wrist half a metre ahead
HAND_ENTITIES = ("/world/hand/mesh", "/world/hand/keypoints", "/world/hand/bones")


@pytest.fixture
def rr() -> Any:
    """rerun, in strict mode: a malformed log call raises instead of warning."""
    module = pytest.importorskip("rerun", reason="rerun-sdk (the 'view' extra) is not installed")
    strict = module.strict_mode()
    module.set_strict_mode(True)
    yield module
    module.set_strict_mode(strict)


@pytest.fixture(scope="module")
def fake_tracker() -> SimpleNamespace:
    """What the logger reads from a tracker: a coarse glove mesh and the nominal colors."""
    mesh = make_hand_mesh(make_skeleton(), spacing_m=0.006)
    return SimpleNamespace(mesh=mesh, color_table=nominal_table(load_pattern()))


def make_frame(index: int, timestamp_s: float | None = None) -> Frame:
    """A grey wall 0.6 m away with two patches of glove colors 3 and 7, and a column
    of pixels without depth."""
    colors = load_pattern().colors_rgb
    color = np.full((SMALL.height, SMALL.width, 3), 128, np.uint8)
    color[10:20, 10:30] = colors[2]
    color[30:40, 40:60] = colors[6]
    depth = np.full((SMALL.height, SMALL.width), 0.6, np.float32)
    depth[:, 5] = 0.0
    return Frame(index, color, depth, SMALL, timestamp_s)


def found_record(frame: int, mesh_skeleton: Any) -> dict[str, Any]:
    """A poses.jsonl record: rest posture, identity rotation, wrist 0.5 m ahead."""
    posture = np.zeros(N_JOINTS)
    keypoints = forward_kinematics(posture, mesh_skeleton).keypoints_m[0] + TRANSLATION_M
    return {
        "frame": frame,
        "hand_found": True,
        "posture_rad": posture.tolist(),
        "rotation": np.eye(3).tolist(),
        "translation_m": TRANSLATION_M.tolist(),
        "keypoints_3d_m": np.round(keypoints, 5).tolist(),
        "keypoints_2d_px": np.round(SMALL.project(keypoints), 2).tolist(),
        "fingertips": [],
        "confidence": 0.8 + 0.1 * frame,
        "keypoint_visibility": ["seen"] * N_KEYPOINTS,
        "timing_ms": {},
    }


def read_rrd(path: Path) -> dict[str, list[dict[str, Any]]]:
    """The rows of every entity of the file's recording (rerun's own reader).

    Each row maps column names (``frame``, ``capture_time``, ``Points3D:positions``,
    ...) to Python values, times (``log_time``, ``capture_time``) as integer nanoseconds
    (``datetime`` cannot hold them); temporal rows are in frame order, static rows first.
    """
    import pyarrow as pa
    from rerun.chunk import RrdReader

    rows: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        columns = {
            name: column.cast(pa.int64()) if pa.types.is_temporal(column.type) else column
            for name, column in zip(batch.schema.names, batch.columns, strict=True)
        }
        rows[chunk.entity_path].extend(pa.table(columns).to_pylist())
    for entity_rows in rows.values():
        entity_rows.sort(key=lambda row: row.get("frame", -1))
    return dict(rows)


def test_two_frames_round_trip(rr, fake_tracker, tmp_path):
    from rerun.chunk import RrdReader

    path = tmp_path / "run.rrd"
    mesh = fake_tracker.mesh
    frames = [make_frame(0, 0.0), make_frame(1, 1 / 30)]
    records = [found_record(frame.index, mesh.skeleton) for frame in frames]
    with RerunLogger(fake_tracker, path=path) as view:
        for frame, record in zip(frames, records, strict=True):
            view.write(frame, record)
    entities = read_rrd(path)
    assert RrdReader(path).blueprints(), "the default layout is saved too"

    for entity in (
        "/world/camera/color",
        "/world/camera/depth",
        "/world/points",
        "/confidence",
        *HAND_ENTITIES,
    ):
        assert [row["frame"] for row in entities[entity]] == [0, 1], entity
    capture_ns = [row["capture_time"] for row in entities["/world/points"]]
    assert capture_ns == [0, round(1e9 / 30)]
    assert len(entities["/world/camera"]) == 1, "the pinhole is logged when it changes"
    assert entities["/world/camera"][0]["Pinhole:resolution"] == [[64.0, 48.0]]
    static = {key: value for row in entities["/world"] for key, value in row.items() if value}
    assert "ViewCoordinates:xyz" in static
    classes = static["AnnotationContext:context"][0]
    pattern = load_pattern()
    assert [c["class_description"]["info"]["label"] for c in classes] == [
        "unlabeled",
        *pattern.color_names,
    ]
    red, green, blue = pattern.colors_rgb[2]
    assert classes[3]["class_description"]["info"]["color"] == (
        (int(red) << 24) | (int(green) << 16) | (int(blue) << 8) | 0xFF
    ), "class 3 in the pattern's color (RGBA packed in a u32)"
    confidence = [row["Scalars:scalars"] for row in entities["/confidence"]]
    np.testing.assert_allclose(confidence, [[0.8], [0.9]])

    for row, record in zip(entities["/world/hand/keypoints"], records, strict=True):
        np.testing.assert_allclose(row["Points3D:positions"], record["keypoints_3d_m"], atol=1e-6)
        assert row["Points3D:labels"][0] == "wrist (seen)"
    bones = np.array(entities["/world/hand/bones"][0]["LineStrips3D:strips"])
    assert bones.shape == (len(FINGER_BONES) + len(PALM_BONES), 2, 3)

    split = split_by_label(mesh, load_pattern())
    expected_vertices = pose_mesh(mesh, np.zeros(N_JOINTS))[split.source_vertex] + TRANSLATION_M
    mesh_row = entities["/world/hand/mesh"][1]
    vertices = np.array(mesh_row["Mesh3D:vertex_positions"])
    assert len(vertices) == len(split.source_vertex), "the mesh's vertices, split by color"
    assert len(mesh_row["Mesh3D:triangle_indices"]) == len(mesh.faces)
    np.testing.assert_allclose(vertices, expected_vertices, atol=1e-6)  # float32 storage
    assert set(mesh_row["Mesh3D:class_ids"]) <= set(range(1, 11))

    points_row = entities["/world/points"][0]
    assert len(points_row["Points3D:positions"]) == SMALL.height * (SMALL.width - 1)
    class_ids = np.array(points_row["Points3D:class_ids"])
    assert np.count_nonzero(class_ids == 3) == 10 * 20
    assert np.count_nonzero(class_ids == 7) == 10 * 20
    assert np.count_nonzero(class_ids == 0) == SMALL.height * (SMALL.width - 1) - 400


def test_a_frame_without_the_hand_clears_it(rr, fake_tracker, tmp_path):
    path = tmp_path / "lost.rrd"
    with RerunLogger(fake_tracker, path=path) as view:
        view.write(make_frame(0), found_record(0, fake_tracker.mesh.skeleton))
        view.write(make_frame(1), {"frame": 1, "hand_found": False, "timing_ms": {}})
    entities = read_rrd(path)

    clears = entities["/world/hand"]
    assert [(row["frame"], row["Clear:is_recursive"]) for row in clears] == [(1, [True])]
    for entity in HAND_ENTITIES:
        assert [row["frame"] for row in entities[entity]] == [0], entity
    assert [row["Scalars:scalars"] for row in entities["/confidence"]] == [[0.8], [0.0]]
    assert all(row.get("capture_time") is None for row in entities["/world/points"])


def test_loggers_keep_their_recordings_apart(rr, fake_tracker, tmp_path):
    first, second = tmp_path / "first.rrd", tmp_path / "second.rrd"
    with (
        RerunLogger(fake_tracker, path=first) as one,
        RerunLogger(fake_tracker, path=second) as two,
    ):
        one.write(make_frame(0), {"frame": 0, "hand_found": False})
        two.write(make_frame(5), {"frame": 5, "hand_found": False})
        two.write(make_frame(6), {"frame": 6, "hand_found": False})
        assert one.recording.get_recording_id() != two.recording.get_recording_id()
    assert [row["frame"] for row in read_rrd(first)["/world/points"]] == [0]
    assert [row["frame"] for row in read_rrd(second)["/world/points"]] == [5, 6]


def test_labeled_depth_cloud_back_projects_labeled_pixels(fake_tracker):
    frame = make_frame(0)
    cloud = labeled_depth_cloud(frame.color, frame.depth_m, SMALL, fake_tracker.color_table)
    assert cloud.points_m.dtype == np.float32 and cloud.labels.dtype == np.uint8
    assert len(cloud) == SMALL.height * (SMALL.width - 1), "pixels without depth are left out"
    rows, cols = np.mgrid[30:40, 40:60].reshape(2, -1)
    expected = SMALL.back_project(np.stack([cols, rows], axis=1), np.full(len(rows), 0.6))
    np.testing.assert_allclose(cloud.points_m[cloud.labels == 7], expected, atol=1e-6)


def test_labeled_depth_cloud_keeps_at_most_max_points(fake_tracker):
    camera = CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
    color = np.random.default_rng(0).integers(0, 256, (480, 640, 3), dtype=np.uint8)
    depth = np.full((480, 640), 1.0, np.float32)
    table = fake_tracker.color_table
    cloud = labeled_depth_cloud(color, depth, camera, table)
    assert 15_000 < len(cloud) <= 20_000
    # Every 4th row and column: the labels are those of the sampled pixels.
    np.testing.assert_array_equal(cloud.labels, table.classify(color[::4, ::4]).ravel())
    assert len(labeled_depth_cloud(color, depth, camera, table, max_points=7)) <= 7
    with pytest.raises(ValueError, match="depth_m"):
        labeled_depth_cloud(color, depth[:10], camera, table)


def test_without_rerun_the_error_names_the_extra(fake_tracker, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "rerun", None)  # import rerun raises ImportError
    with pytest.raises(ValueError) as error:
        RerunLogger(fake_tracker, path=tmp_path / "x.rrd")
    assert str(error.value) == MISSING_EXTRA


def test_needs_a_viewer_or_a_file(fake_tracker):
    with pytest.raises(ValueError, match="spawn=True"):
        RerunLogger(fake_tracker)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the display check is Linux's")
def test_spawn_without_a_display_is_a_one_line_error(rr, fake_tracker, monkeypatch):
    for name in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"):
        monkeypatch.delenv(name, raising=False)
    with pytest.raises(ValueError, match="needs a display") as error:
        RerunLogger(fake_tracker, spawn=True)
    assert "\n" not in str(error.value)


def test_spawn_without_the_viewer_executable_is_a_one_line_error(rr, fake_tracker, monkeypatch):
    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setattr(rerun_view, "_viewer_executable", lambda: None)
    with pytest.raises(ValueError, match="viewer executable was not found") as error:
        RerunLogger(fake_tracker, spawn=True)
    assert "\n" not in str(error.value)


@pytest.mark.parametrize("where", ["missing/run.rrd", "."], ids=["no folder", "a folder"])
def test_an_unwritable_path_is_a_one_line_error(rr, fake_tracker, tmp_path, where):
    with pytest.raises(ValueError, match="cannot write the rerun recording") as error:
        RerunLogger(fake_tracker, path=tmp_path / where)
    assert "\n" not in str(error.value)
