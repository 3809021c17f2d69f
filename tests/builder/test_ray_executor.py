"""Builds on Ray actors: the same bytes as a local build, resume, unreachable clusters."""

import sys

import pytest
from helpers import SMALL_DATABASE

from builder.build import build_database
from builder.config import config_from_dict

ray = pytest.importorskip("ray", reason="Ray builds need the ray extra (scripts/setup.sh --ray)")

pytestmark = [pytest.mark.gl, pytest.mark.slow]


class InterruptedBuildError(Exception):
    """Stands for a build killed after its first shard."""


def stop_after_first_shard(finished, remaining):
    for index in finished:
        yield index
        raise InterruptedBuildError


def test_a_ray_build_equals_a_local_build_also_when_resumed(small_database, tmp_path):
    config = config_from_dict(SMALL_DATABASE)
    straight = tmp_path / "straight.h5"
    report = build_database(config, straight, workers=2, executor="ray")
    assert (report.entries, report.rendered_postures) == (72, 2)
    assert straight.read_bytes() == small_database.read_bytes()
    assert not ray.is_initialized(), "the build shuts down the Ray instance it started"

    resumed = tmp_path / "resumed.h5"
    with pytest.raises(InterruptedBuildError):
        build_database(config, resumed, workers=2, executor="ray", progress=stop_after_first_shard)
    assert not resumed.exists()
    assert len(list((tmp_path / "resumed.h5.parts").glob("posture_*.npy"))) >= 1
    report = build_database(config, resumed, workers=2, executor="ray", resume=True)
    assert report.rendered_postures <= 1
    assert resumed.read_bytes() == small_database.read_bytes()


@pytest.mark.parametrize(
    ("address", "message"),
    [("127.0.0.1:1", "cannot be reached within"), ("no-port", "expected HOST:PORT")],
)
def test_a_bad_address_is_one_line_and_leaves_nothing(tmp_path, address, message):
    out = tmp_path / "db.h5"
    with pytest.raises(ValueError, match=message) as error:
        build_database(config_from_dict(SMALL_DATABASE), out, executor="ray", address=address)
    assert "\n" not in str(error.value)
    assert not out.with_name("db.h5.parts").exists()
    assert not ray.is_initialized()


def test_executor_and_address_are_checked():
    config = config_from_dict(SMALL_DATABASE)
    with pytest.raises(ValueError, match="executor: expected one of local, ray"):
        build_database(config, "db.h5", executor="dask")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="needs the ray executor"):
        build_database(config, "db.h5", address="127.0.0.1:6379")


def test_without_ray_the_error_names_the_extra(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "ray", None)  # makes "import ray" fail
    with pytest.raises(ValueError, match=r"install the ray extra: bash scripts/setup.sh --ray"):
        build_database(config_from_dict(SMALL_DATABASE), tmp_path / "db.h5", executor="ray")
    assert not (tmp_path / "db.h5.parts").exists()
