"""Overlay drawing, the model outline, the video writer and the timing table."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from glovedb.camera import KINECT_V1, CameraIntrinsics
from glovedb.hand_model import forward_kinematics
from glovedb.mesh import HandMesh, pose_mesh
from glovedb.postures import named_posture
from tracker import overlay
from tracker.overlay import (
    FINGER_COLORS,
    VideoWriter,
    draw_detections,
    draw_fingertips,
    draw_model_outline,
    draw_outline,
    draw_record,
    draw_skeleton,
    draw_status,
    outline_mask,
    status_text,
    timing_summary,
)

# The palm faces the camera, fingers up, 45 cm away.
ROTATION = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
TRANSLATION_M = np.array([0.0, 0.08, 0.45])
SMALL = CameraIntrinsics(64, 48, 60.0, 60.0, 31.5, 23.5)


def black(camera: CameraIntrinsics = KINECT_V1) -> np.ndarray:
    return np.zeros((camera.height, camera.width, 3), np.uint8)


def posed_vertices(mesh: HandMesh, posture: str) -> np.ndarray:
    vertices = pose_mesh(mesh, named_posture(posture)).reshape(-1, 3)
    return vertices @ ROTATION.T + TRANSLATION_M


def test_keypoints_are_drawn_where_they_project():
    keypoints = forward_kinematics(named_posture("open")).keypoints_m[0]
    pixels = KINECT_V1.project(keypoints @ ROTATION.T + TRANSLATION_M)
    image = black()
    drawn = draw_skeleton(image, pixels)
    assert drawn.dtype == np.uint8 and drawn.shape == image.shape
    assert not image.any(), "the input must not change"
    for index, (u, v) in enumerate(np.round(pixels).astype(int)):
        expected = (
            (255, 255, 255) if index == 0 else FINGER_COLORS[overlay.FINGERS[(index - 1) // 4]]
        )
        assert tuple(drawn[v, u]) == expected, index
    # Bones: the midpoint of the index finger's proximal segment is drawn too.
    u, v = np.round((pixels[5] + pixels[6]) / 2).astype(int)
    assert tuple(drawn[v, u]) == FINGER_COLORS["index"]


def test_skeleton_skips_missing_keypoints_and_checks_shape():
    pixels = np.full((21, 2), np.nan)
    pixels[0] = (10, 10)
    assert draw_skeleton(black(SMALL), pixels)[10, 10].any()
    with pytest.raises(ValueError, match="keypoints_2d_px: expected shape"):
        draw_skeleton(black(SMALL), np.zeros((20, 2)))
    with pytest.raises(TypeError, match="image: expected"):
        draw_skeleton(np.zeros((48, 64, 3), np.float32), pixels)


@pytest.mark.parametrize("posture", ["open", "fist", "pinch"])
def test_outline_mask_covers_the_projected_vertices(hand_mesh, posture):
    vertices = posed_vertices(hand_mesh, posture)
    mask = outline_mask(vertices, hand_mesh.faces, KINECT_V1)
    assert mask.dtype == np.bool_ and mask.shape == (480, 640)
    u, v = np.round(KINECT_V1.project(vertices)).astype(int).T
    # A vertex on the silhouette may sit half a pixel outside the covered centres.
    grown = cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert grown[v, u].all()
    # And no more than the projected vertices' convex hull.
    hull = cv2.convexHull(np.stack([u, v], 1).astype(np.int32))
    inside = cv2.fillConvexPoly(np.zeros((480, 640), np.uint8), hull, 1).astype(bool)
    assert not (mask & ~inside).any()


def test_overlapping_layers_stay_filled():
    # Two squares facing the camera, the near one covering the middle of the far one.
    def square(centre, half, z):
        x0, x1, y0, y1 = centre[0] - half, centre[0] + half, centre[1] - half, centre[1] + half
        return np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]])

    vertices = np.vstack([square((0, 0), 0.1, 1.0), square((0, 0), 0.05, 0.9)])
    faces = np.array([[0, 3, 2], [0, 2, 1], [4, 7, 6], [4, 6, 5]])  # facing -z: the camera
    mask = outline_mask(vertices, faces, SMALL)
    assert mask[23:25, 31:33].all(), "the overlap must be covered, not cancelled"
    assert mask.sum() == pytest.approx(13 * 13, abs=30)
    assert not outline_mask(vertices, faces[:, ::-1], SMALL).any(), "back faces are culled"


def test_outline_is_drawn_on_the_silhouette_boundary(hand_mesh):
    image = black()
    drawn = draw_model_outline(
        image, hand_mesh, named_posture("open"), ROTATION, TRANSLATION_M, KINECT_V1
    )
    mask = outline_mask(posed_vertices(hand_mesh, "open"), hand_mesh.faces, KINECT_V1)
    lit = drawn.any(axis=2)
    eroded = cv2.erode(mask.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    assert lit.sum() > 200
    assert not (lit & eroded).any(), "only the contour, not the inside"
    assert np.array_equal(draw_outline(image, np.zeros((480, 640), bool)), image)


def test_fingertips_status_and_record(hand_mesh):
    tips = [
        {"finger": "index", "u_px": 20.0, "v_px": 30.0, "confidence": 0.9},
        {"finger": None, "u_px": float("nan"), "v_px": 1.0},
    ]
    drawn = draw_fingertips(black(), tips)
    assert tuple(drawn[30, 20 + 7]) == FINGER_COLORS["index"]
    assert not drawn[30, 20].any()
    assert status_text(3, fps=29.96, confidence=0.5) == "frame 3 | 30.0 fps | confidence 0.50"
    assert status_text(4) == "frame 4 | no hand"
    assert draw_status(black(), 3)[:20, :100].any()
    keypoints = forward_kinematics(named_posture("open")).keypoints_m[0]
    record = {
        "frame": 7,
        "hand_found": True,
        "posture_rad": named_posture("open").tolist(),
        "rotation": ROTATION.tolist(),
        "translation_m": TRANSLATION_M.tolist(),
        "keypoints_2d_px": KINECT_V1.project(keypoints @ ROTATION.T + TRANSLATION_M).tolist(),
        "fingertips": tips,
        "confidence": 0.8,
    }
    full = draw_record(black(), record, KINECT_V1, mesh=hand_mesh, fps=30)
    bare = draw_record(black(), {"frame": 8, "hand_found": False}, KINECT_V1)
    assert full.any(axis=2).sum() > bare.any(axis=2).sum() > 0
    detections = [{"finger": "ring", "u_px": 600.0, "v_px": 400.0},
                  {"finger": None, "u_px": 500.0, "v_px": 420.0}]  # fmt: skip
    crossed = draw_detections(black(), detections)
    assert tuple(crossed[400, 600]) == FINGER_COLORS["ring"]
    assert crossed[420, 500].any() and not crossed[400, 610].any()
    with_detections = draw_record(black(), {**record, "fingertip_detections": detections},
                                  KINECT_V1)  # fmt: skip
    assert tuple(with_detections[400, 600]) == FINGER_COLORS["ring"]


def frames(n: int = 5) -> list[np.ndarray]:
    images = []
    for i in range(n):
        image = np.zeros((48, 64, 3), np.uint8)
        image[:, : 10 * (i + 1)] = (200, 40, 40)
        images.append(image)
    return images


def test_video_writer_writes_a_readable_mp4(tmp_path):
    path = tmp_path / "out" / "overlay.mp4"
    with VideoWriter(path, fps=10) as video:
        for image in frames():
            video.write(image)
    if video.fell_back:
        pytest.skip(f"no mp4v codec in this OpenCV: {video.note}")
    assert video.output_path == path and video.frames_written == 5
    capture = cv2.VideoCapture(str(path))
    read = []
    while True:
        ok, bgr = capture.read()
        if not ok:
            break
        read.append(bgr)
    capture.release()
    assert len(read) == 5 and read[0].shape == (48, 64, 3)
    # Red stripe widths survive compression (BGR order on read).
    assert read[2][24, 25, 2] > 120 and read[2][24, 40, 2] < 60


def test_video_writer_falls_back_to_png(tmp_path, monkeypatch):
    class ClosedWriter:
        def __init__(self, *args):
            pass

        def isOpened(self):  # noqa: N802 (OpenCV's name)
            return False

        def release(self):
            pass

    monkeypatch.setattr(overlay.cv2, "VideoWriter", ClosedWriter)
    monkeypatch.setattr(ClosedWriter, "fourcc", staticmethod(lambda *c: 0), raising=False)
    video = VideoWriter(tmp_path / "overlay.mp4", fps=10)
    with pytest.warns(RuntimeWarning, match="PNG frames"):
        video.write(frames(1)[0])
    for image in frames(3)[1:]:
        video.write(image)
    video.close()
    assert video.fell_back and video.output_path == tmp_path / "overlay_frames"
    written = sorted(video.output_path.glob("*.png"))
    assert [p.name for p in written] == ["000000.png", "000001.png", "000002.png"]
    back = cv2.cvtColor(cv2.imread(str(written[2])), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(back, frames(3)[2])
    with pytest.raises(ValueError, match="expected 64x48"):
        video.write(np.zeros((10, 10, 3), np.uint8))


def test_timing_summary():
    timings = [{"lookup": float(t), "icp": 2.0} for t in range(1, 101)] + [{"lookup": 1000.0}]
    summary = timing_summary(timings)
    assert summary.frames == 101 and list(summary.stages) == ["lookup", "icp"]
    stats = summary.as_dict()
    assert stats["lookup"]["median"] == pytest.approx(51.0)
    assert stats["lookup"]["p95"] == pytest.approx(np.percentile([*range(1, 101), 1000], 95))
    assert stats["lookup"]["p99"] == pytest.approx(np.percentile([*range(1, 101), 1000], 99))
    assert stats["icp"] == {
        "median": 2.0, "p95": 2.0, "p99": 2.0, "mean": 2.0, "max": 2.0, "frames": 100
    }  # fmt: skip
    lines = summary.table().splitlines()
    assert lines[0].split()[:3] == ["stage", "median", "ms"] and len(lines) == 4
    assert lines[2].split()[:2] == ["lookup", "51.00"]
    with pytest.raises(ValueError, match="frame 1, 'icp'"):
        timing_summary([{"icp": 1.0}, {"icp": -1.0}])
