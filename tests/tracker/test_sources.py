"""Frame sources: RGB-D folders (good and every kind of bad), arrays, bag and camera errors."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from glovedb.camera import CameraIntrinsics, save_intrinsics
from tracker.frames import Frame
from tracker.sources import (
    frames_from_arrays,
    frames_from_bag,
    frames_from_folder,
    open_source,
    scan_folder,
)

CAMERA = CameraIntrinsics(32, 24, 30.0, 30.0, 15.5, 11.5)


def color_image(index: int) -> np.ndarray:
    """RGB with the frame number in red and a known green/blue."""
    image = np.zeros((CAMERA.height, CAMERA.width, 3), np.uint8)
    image[..., 0] = index
    image[..., 1] = 100
    image[..., 2] = 200
    return image


def depth_image(index: int) -> np.ndarray:
    return np.full((CAMERA.height, CAMERA.width), 500 + index, np.uint16)


def write_color(path: Path, rgb: np.ndarray) -> None:
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))


def make_folder(root: Path, numbers=(0, 1, 2), *, meta: dict | None = None) -> Path:
    (root / "color").mkdir(parents=True)
    (root / "depth").mkdir()
    save_intrinsics(CAMERA, root / "intrinsic.json")
    for n in numbers:
        write_color(root / "color" / f"{n:06d}.png", color_image(n))
        assert cv2.imwrite(str(root / "depth" / f"{n:06d}.png"), depth_image(n))
    if meta is not None:
        (root / "meta.json").write_text(json.dumps(meta))
    return root


def first_error(folder: Path) -> str:
    with pytest.raises(ValueError) as info:
        list(frames_from_folder(folder))
    message = str(info.value)
    assert "\n" not in message
    return message


def test_folder_frames_in_numeric_order_with_metres_and_rgb(tmp_path):
    folder = make_folder(tmp_path / "seq", numbers=(10, 2, 1), meta={"depth_scale": 500, "fps": 15})
    frames = list(frames_from_folder(folder))
    assert [f.index for f in frames] == [0, 1, 2]
    assert [int(f.color[0, 0, 0]) for f in frames] == [1, 2, 10]
    first = frames[0]
    assert isinstance(first, Frame)
    assert first.color.dtype == np.uint8 and first.depth_m.dtype == np.float32
    np.testing.assert_array_equal(first.color[0, 0], [1, 100, 200])
    np.testing.assert_allclose(first.depth_m, 501 / 500, rtol=1e-6)
    assert first.intrinsics == CAMERA
    assert frames[2].timestamp_s == pytest.approx(2 / 15)


def test_open_source_reports_fps_and_length(tmp_path):
    folder = make_folder(tmp_path / "seq", meta={"fps": 30})
    source = open_source(folder)
    assert (source.kind, source.fps, source.n_frames) == ("folder", 30.0, 3)
    assert len(list(source)) == 3
    assert scan_folder(folder).depth_scale == 1000.0


def test_jpeg_color_and_all_zero_depth_are_accepted(tmp_path):
    folder = make_folder(tmp_path / "seq", numbers=(0,))
    (folder / "color" / "000000.png").unlink()
    write_color(folder / "color" / "000000.jpg", color_image(0))
    assert cv2.imwrite(str(folder / "depth" / "000000.png"), np.zeros((24, 32), np.uint16))
    (frame,) = list(frames_from_folder(folder))
    assert not frame.depth_m.any()


def test_depth_scale_argument_overrides_meta(tmp_path):
    folder = make_folder(tmp_path / "seq", numbers=(0,), meta={"depth_scale": 500})
    (frame,) = list(frames_from_folder(folder, depth_scale=1000))
    np.testing.assert_allclose(frame.depth_m, 0.5)


@pytest.mark.parametrize(
    ("breakage", "expected"),
    [
        (lambda f: (f / "intrinsic.json").unlink(), "intrinsic.json: missing"),
        (lambda f: (f / "intrinsic.json").write_text("{"), "intrinsic.json"),
        (lambda f: (f / "meta.json").write_text('{"depth_scale": -1}'), "depth_scale"),
        (lambda f: (f / "color" / "000001.png").unlink(), "depth/000001.png: no color image"),
        (lambda f: (f / "depth" / "000002.png").unlink(), "color/000002.png: no depth image"),
        (lambda f: (f / "color" / "abc.png").write_bytes(b""), "frame numbers"),
        (lambda f: [p.unlink() for p in f.glob("*/*.png")], "no frames"),
    ],
)
def test_bad_layouts_name_the_file(tmp_path, breakage, expected):
    folder = make_folder(tmp_path / "seq")
    breakage(folder)
    assert expected in first_error(folder)


def test_missing_folder(tmp_path):
    assert "no such folder" in first_error(tmp_path / "nowhere")
    with pytest.raises(ValueError, match="no such folder or file"):
        open_source(tmp_path / "nowhere")


def test_layout_errors_are_raised_when_opening(tmp_path):
    folder = make_folder(tmp_path / "seq")
    (folder / "depth" / "000000.png").unlink()
    with pytest.raises(ValueError, match="no depth image"):
        frames_from_folder(folder)


def replace_depth(folder: Path, image: np.ndarray, name: str = "000001.png") -> Path:
    path = folder / "depth" / name
    assert cv2.imwrite(str(path), image)
    return path


def test_wrong_size(tmp_path):
    folder = make_folder(tmp_path / "seq")
    replace_depth(folder, np.zeros((10, 10), np.uint16))
    message = first_error(folder)
    assert "depth/000001.png" in message and "10x10" in message and "32x24" in message


def test_eight_bit_depth(tmp_path):
    folder = make_folder(tmp_path / "seq")
    replace_depth(folder, np.zeros((24, 32), np.uint8))
    assert "000001.png: depth must be 16-bit, got 8-bit" in first_error(folder)


def test_depth_as_jpeg(tmp_path):
    folder = make_folder(tmp_path / "seq", numbers=(0,))
    (folder / "depth" / "000000.png").rename(folder / "depth" / "000000.jpg")
    assert "depth must be a 16-bit PNG" in first_error(folder)


def test_grey_color(tmp_path):
    folder = make_folder(tmp_path / "seq")
    assert cv2.imwrite(str(folder / "color" / "000002.png"), np.zeros((24, 32), np.uint8))
    assert "color/000002.png: color must have 3 channels (RGB), got 1" in first_error(folder)


def test_rgba_color(tmp_path):
    folder = make_folder(tmp_path / "seq")
    assert cv2.imwrite(str(folder / "color" / "000000.png"), np.zeros((24, 32, 4), np.uint8))
    assert "got 4" in first_error(folder)


def test_truncated_png(tmp_path):
    folder = make_folder(tmp_path / "seq")
    path = folder / "color" / "000001.png"
    path.write_bytes(path.read_bytes()[:-30])
    assert "color/000001.png: truncated" in first_error(folder)


def test_truncated_jpeg(tmp_path):
    folder = make_folder(tmp_path / "seq", numbers=(0,))
    (folder / "color" / "000000.png").unlink()
    path = folder / "color" / "000000.jpg"
    write_color(path, color_image(0))
    path.write_bytes(path.read_bytes()[:-40])
    assert "000000.jpg: truncated" in first_error(folder)


def test_garbage_png(tmp_path):
    folder = make_folder(tmp_path / "seq")
    (folder / "depth" / "000000.png").write_bytes(b"not an image IEND\xaeB`\x82")
    assert "depth/000000.png: unreadable image" in first_error(folder)


def test_arrays_accept_uint16_and_metres():
    color = color_image(3)
    frames = list(
        frames_from_arrays(
            [
                (color, depth_image(0), CAMERA),
                (color, np.full((24, 32), np.nan, np.float32), CAMERA),
                (color, np.full((24, 32), 0.7), CAMERA),
            ],
            depth_scale=250,
        )
    )
    np.testing.assert_allclose(frames[0].depth_m, 2.0)
    assert not frames[1].depth_m.any()
    np.testing.assert_allclose(frames[2].depth_m, 0.7, rtol=1e-6)
    assert all(f.depth_m.dtype == np.float32 for f in frames)
    assert [f.index for f in frames] == [0, 1, 2]


def test_arrays_name_the_frame_at_fault():
    good = (color_image(0), depth_image(0), CAMERA)
    with pytest.raises(ValueError, match=r"frame 1 depth: expected shape \(24, 32\)"):
        list(frames_from_arrays([good, (color_image(0), np.zeros((2, 2)), CAMERA)]))
    with pytest.raises(TypeError, match="frame 0 color: expected uint8"):
        list(frames_from_arrays([(color_image(0).astype(np.uint16), depth_image(0), CAMERA)]))
    with pytest.raises(TypeError, match="frame 0: expected a"):
        list(frames_from_arrays([(1, 2)]))  # type: ignore[list-item]


def test_open_source_takes_an_iterable():
    source = open_source(iter([(color_image(0), depth_image(0), CAMERA)]))
    assert source.kind == "arrays"
    assert len(list(source)) == 1


def test_non_bag_file(tmp_path):
    path = tmp_path / "recording.bag"
    path.write_text("hello")
    with pytest.raises(ValueError, match=r"not a RealSense \.bag recording"):
        frames_from_bag(path)
    with pytest.raises(ValueError, match=r"not a RealSense \.bag recording"):
        open_source(path)


def test_unopenable_bag(tmp_path):
    pytest.importorskip("open3d")
    path = tmp_path / "broken.bag"
    path.write_bytes(b"#ROSBAG V2.0\n" + bytes(64))
    with pytest.raises(ValueError, match="Open3D cannot"):
        frames_from_bag(path)


def test_no_realsense_connected():
    o3d = pytest.importorskip("open3d")
    if hasattr(o3d.t.io, "RealSenseSensor") and o3d.t.io.RealSenseSensor.enumerate_devices():
        pytest.skip("a RealSense camera is connected")
    with pytest.raises(ValueError, match=r"^realsense: (no RealSense camera|this Open3D build)"):
        open_source("realsense", timeout_s=10)


def test_no_kinect_connected():
    pytest.importorskip("open3d")
    with pytest.raises(ValueError, match=r"^kinect: ") as info:
        open_source("kinect", timeout_s=10)
    assert "\n" not in str(info.value)
