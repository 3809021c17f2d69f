"""Database builds: round trip, determinism, resume after a kill, tiny-image equivalences."""

import json
import os
import signal
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest
from helpers import SMALL_DATABASE

from builder.build import (
    PostureRenderer,
    build_database,
    make_plan,
    read_shard,
    read_shard_lengths,
    shard_path,
    stored_settings,
    write_shard,
)
from builder.config import config_from_dict, load_config
from glovedb._row_codec import encode_rows
from glovedb.chamfer import symmetric_distance
from glovedb.database import FORMAT_VERSION, GloveDatabase
from glovedb.postures import named_posture
from glovedb.resources import config_path
from glovedb.tiny_images import tiny_images
from glovedb.views import HAND_CENTRE, pose_for_view

pytestmark = pytest.mark.gl

SMALL = SMALL_DATABASE


def small_config(**postures):
    return config_from_dict({**SMALL, "postures": {**SMALL["postures"], **postures}})


def test_round_trip(small_database):
    plan = make_plan(small_config())
    with GloveDatabase(small_database) as database:
        info = database.info()
        assert (info.entries, info.postures, info.views_per_posture) == (72, 2, 36)
        assert info.resolutions == (8, 16, 32) and info.camera_positions == 12
        np.testing.assert_allclose(database.postures[1], named_posture("pinch"), atol=1e-6)
        assert database.posture_names == ("open", "pinch")
        np.testing.assert_array_equal(database.entry_posture_ids, np.repeat([0, 1], 36))
        np.testing.assert_array_equal(database.entry_view_ids, np.tile(np.arange(36), 2))
        np.testing.assert_allclose(
            database.entry_rotations[36:], plan.view_rotations.astype(np.float32)
        )
        expected = PostureRenderer(plan).tiny_images(1)
        for size in (8, 16, 32):
            images = database.images(size)
            assert images.dtype == np.uint8 and images.shape == (72, size, size)
            np.testing.assert_array_equal(images[36:], expected[size])
            assert set(np.unique(images)) <= set(range(11))
            assert np.all(images.reshape(72, -1).any(axis=1)), "every entry shows the glove"
        ids = np.array([40, 3, 40])
        np.testing.assert_array_equal(database.image_rows(32, ids), database.images(32)[ids])
        assert (
            json.loads(h5py.File(small_database)["/"].attrs["settings_json"])["config"]["name"]
            == "small"
        )


def test_two_builds_give_the_same_bytes(small_database, tmp_path):
    again = tmp_path / "again.h5"
    build_database(small_config(), again)
    assert again.read_bytes() == small_database.read_bytes()


def test_workers_do_not_change_the_result(small_database, tmp_path):
    parallel = tmp_path / "parallel.h5"
    report = build_database(small_config(), parallel, workers=2)
    assert report.entries == 72
    assert parallel.read_bytes() == small_database.read_bytes()


def test_resume_after_a_killed_build_equals_an_uninterrupted_build(tmp_path):
    # Enough postures that the build is still running when the test sees two shards:
    # a posture of this small database renders in milliseconds.
    random = {"count": 60, "seed": 7, "synergies": 3, "spread": 1.0, "noise_deg": 5.0}
    named = ["open", "fist", "pinch", "power", "ok", "point"]
    config = dict(SMALL, postures={"named": named, "random": random})
    config_file = tmp_path / "six.toml"
    config_file.write_text(_toml(config))
    out = tmp_path / "six.h5"
    command = [sys.executable, "-m", "glove_cli", "build", str(config_file), "--out", str(out),
               "--workers", "1"]  # fmt: skip
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    parts = tmp_path / "six.h5.parts"
    deadline = time.time() + 120
    while len(list(parts.glob("posture_*.npy"))) < 2 and time.time() < deadline:
        time.sleep(0.05)
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    assert not out.exists(), "an interrupted build must not leave a database behind"
    assert 2 <= len(list(parts.glob("posture_*.npy"))) < 66

    again = subprocess.run(command, capture_output=True, text=True)
    assert again.returncode == 2 and "--resume" in again.stderr
    resumed = subprocess.run(command + ["--resume", "--json"], capture_output=True, text=True)
    assert resumed.returncode == 0, resumed.stderr
    figures = json.loads(resumed.stdout)
    assert figures["entries"] == 66 * 36 and figures["rendered_postures"] < 66
    assert not parts.exists()

    uninterrupted = tmp_path / "straight.h5"
    build_database(load_config(config_file), uninterrupted)
    assert out.read_bytes() == uninterrupted.read_bytes()


def test_shards_hold_the_encoded_rows_and_old_shards_are_not_resumed(tmp_path):
    images = {8: np.zeros((3, 8, 8), np.uint8), 16: np.ones((3, 16, 16), np.uint8)}
    images[16][1, 4:9, 2:7] = 7
    write_shard(tmp_path, 4, images)
    for size, (lengths, rows) in read_shard(tmp_path, 4, (8, 16), 3).items():
        expected_rows, expected_lengths = encode_rows(images[size])
        np.testing.assert_array_equal(lengths, expected_lengths)
        np.testing.assert_array_equal(rows, expected_rows)
    np.testing.assert_array_equal(
        read_shard_lengths(tmp_path, 4, (8, 16), 3),
        [encode_rows(images[8])[1], encode_rows(images[16])[1]],
    )
    # A shard cut short (an interrupted copy) is refused by both readers ...
    whole = shard_path(tmp_path, 4).read_bytes()
    shard_path(tmp_path, 4).write_bytes(whole[:-1])
    for read in (read_shard, read_shard_lengths):
        with pytest.raises(ValueError, match="not a shard of this build"):
            read(tmp_path, 4, (8, 16), 3)
    # ... a shard of format 1 (raw images) is refused, not misread ...
    np.save(shard_path(tmp_path, 5), np.zeros(3 * (64 + 256), np.uint8))
    with pytest.raises(ValueError, match="not a shard of this build"):
        read_shard(tmp_path, 5, (8, 16), 3)
    # ... and --resume does not continue a build of another format version.
    settings = stored_settings(small_config())
    assert settings["format_version"] == FORMAT_VERSION
    parts = tmp_path / "old.h5.parts"
    parts.mkdir()
    (parts / "settings.json").write_text(json.dumps({**settings, "format_version": 1}))
    with pytest.raises(ValueError, match="other settings"):
        build_database(small_config(), tmp_path / "old.h5", resume=True)


def test_an_unfinished_file_is_not_a_database(small_database, tmp_path):
    copy = tmp_path / "copy.h5"
    copy.write_bytes(small_database.read_bytes())
    with h5py.File(copy, "r+") as file:
        file.attrs["complete"] = False
    with pytest.raises(ValueError, match="unfinished"):
        GloveDatabase(copy)
    truncated = tmp_path / "truncated.h5"
    truncated.write_bytes(small_database.read_bytes()[:5000])
    with pytest.raises(ValueError, match="not a readable HDF5"):
        GloveDatabase(truncated)
    with pytest.raises(ValueError, match="a folder, not a database file"):
        GloveDatabase(tmp_path)
    settings = tmp_path / "settings.h5"
    settings.write_bytes(small_database.read_bytes())
    with h5py.File(settings, "r+") as file:
        file.attrs["settings_json"] = "{not json"
    with pytest.raises(ValueError, match="damaged database, settings_json"):
        GloveDatabase(settings)
    # Damage that the shapes do not show: an entry pointing past the postures (an
    # IndexError in the middle of tracking) and zeroed rotations (a 173-degree error).
    damages = [
        ("entries/posture_id", "posture_id outside 0..1"),
        ("entries/rotation", "entry rotations are not its views'"),
    ]
    for dataset, message in damages:
        damaged = tmp_path / f"{dataset.replace('/', '_')}.h5"
        damaged.write_bytes(small_database.read_bytes())
        with h5py.File(damaged, "r+") as file:
            values = file[dataset][()]
            values[-1] = 2 if dataset.endswith("id") else 0
            file[dataset][...] = values
        with pytest.raises(ValueError, match=message):
            GloveDatabase(damaged)


def test_rolling_pixels_equals_rendering_a_rolled_camera():
    """In-plane rotations are made from one render: equivalent up to aliasing."""
    plan = make_plan(load_config(config_path("db/open_pinch_power.toml")))
    renderer = PostureRenderer(plan)
    rolled = renderer.tiny_images(2)  # views: position-major, 18 rolls each
    posture = plan.postures_rad[2]
    for view in (1, 9, 16, 18 * 7 + 5, 18 * 30 + 11):
        rendered = renderer.label_images(
            posture,
            plan.view_rotations[view : view + 1],
            plan.view_translations_m[view : view + 1],
        )[0]
        direct = tiny_images(rendered)
        for size in (8, 16, 32, 64):
            # Aliasing moves silhouettes and patch borders by under a pixel: the
            # mean distance to the same color in the other image stays below one.
            distance = float(symmetric_distance(direct[size], rolled[size][view]))
            assert distance < 0.75, f"view {view} size {size}: {distance:.2f} px apart"
            assert np.mean(direct[size] != rolled[size][view]) < 0.1


def test_tiny_images_do_not_depend_on_distance_or_image_position(renderer):
    """The same view of the hand, near and centred or far and off-centre."""
    posture = named_posture("peace")
    direction = np.array([0.2, 0.3, 1.0])
    target = np.array(HAND_CENTRE) * 0.19
    near_rotation, near_translation = pose_for_view(direction, 0.45, target_m=target)
    near = tiny_images(renderer.render_labels(posture, near_rotation, near_translation).labels)
    # Farther away and shifted sideways, the camera turned so the view direction is kept.
    far_translation = near_translation * 0 + near_rotation @ -target + [0.12, -0.06, 0.8]
    far = tiny_images(renderer.render_labels(posture, near_rotation, far_translation).labels)
    for size in (8, 16, 32):
        assert np.mean(near[size] != far[size]) < 0.06


def test_config_errors_are_one_line(tmp_path):
    with pytest.raises(ValueError, match="unknown key 'subdivision'"):
        config_from_dict({**SMALL, "views": {"subdivision": 1}})
    with pytest.raises(ValueError, match="names no source"):
        config_from_dict({**SMALL, "postures": {}})
    with pytest.raises(ValueError, match="render_size"):
        config_from_dict({**SMALL, "images": {"sizes": [64], "render_size": 96}})
    with pytest.raises(ValueError, match="not valid TOML"):
        bad = tmp_path / "bad.toml"
        bad.write_text("name = ")
        load_config(bad)
    with pytest.raises(ValueError, match=r"\.h5"):
        build_database(small_config(), tmp_path / "db.hdf")
    postures = SMALL["postures"]
    refused = [
        ({"postures": {**postures, "trajectory_fps": 0.0}}, "trajectory_fps must be in"),
        ({"postures": {**postures, "random": {"count": 0}}}, r"count must be 1\.\."),
        ({"postures": {**postures, "random": {"count": 5, "spread": -1.0}}}, "spread must"),
        ({"name": "x\u0000"}, "name must be non-empty printable"),  # HDF5 refuses NUL, at the end
        ({"hand_length_m": float("nan")}, "hand_length_m must be"),
    ]
    for change, message in refused:
        with pytest.raises(ValueError, match=message):
            config_from_dict({**SMALL, **change})


def test_postures_from_files_random_and_selection(tmp_path):
    from glovedb.posture_io import load_postures, save_postures_csv

    save_postures_csv(
        tmp_path / "extra.csv", np.stack([named_posture("ok"), named_posture("fist")])
    )
    config = config_from_dict(
        {**SMALL, "postures": {"named": ["open"], "files": ["extra.csv"],
                               "random": {"count": 30, "seed": 3}, "select": 5}},
        base_dir=str(tmp_path),
    )  # fmt: skip
    plan = make_plan(config)
    assert plan.postures_rad.shape == (5, 20)
    assert plan.posture_names[0] == "open"  # farthest-point selection starts at the first
    assert make_plan(config).posture_names == plan.posture_names  # deterministic
    # Degrees where radians belong would build a database of impossible hands.
    save_postures_csv(tmp_path / "degrees.csv", np.degrees([named_posture("fist")]))
    with pytest.raises(ValueError, match=r"degrees\.csv: posture 0, .* beyond \+-pi"):
        load_postures(tmp_path / "degrees.csv")
    np.save(tmp_path / "complex.npy", np.ones((1, 20), complex))
    with pytest.raises(TypeError, match="complex"):
        load_postures(tmp_path / "complex.npy")
    (tmp_path / "text.npy").write_text("open\n")
    with pytest.raises(ValueError, match=r"text\.npy: not a \.npy array file"):
        load_postures(tmp_path / "text.npy")


def _toml(config: dict) -> str:
    lines = [f'name = "{config["name"]}"']
    for table in ("postures", "views", "images"):
        lines.append(f"[{table}]")
        subtables = {key: value for key, value in config[table].items() if isinstance(value, dict)}
        for key, value in config[table].items():
            if key not in subtables:
                lines.append(f"{key} = {json.dumps(value)}")
        for name, subtable in subtables.items():
            lines.append(f"[{table}.{name}]")
            lines += [f"{key} = {json.dumps(value)}" for key, value in subtable.items()]
    return "\n".join(lines) + "\n"
