"""Shared fixtures. Expensive objects (mesh, renderer) are built once per session."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest
from helpers import SMALL_DATABASE

from glovedb.hand_model import make_skeleton
from glovedb.mesh import HandMesh, make_hand_mesh


@pytest.fixture(scope="session", autouse=True)
def cache_folder(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """The tests' own cache folder (meshes), not the user's; subprocesses inherit it."""
    folder = tmp_path_factory.mktemp("glove_cache")
    before = os.environ.get("GLOVE_CACHE")
    os.environ["GLOVE_CACHE"] = str(folder)
    yield folder
    if before is None:
        del os.environ["GLOVE_CACHE"]
    else:
        os.environ["GLOVE_CACHE"] = before


@pytest.fixture(scope="session")
def hand_mesh() -> HandMesh:
    """The default glove mesh (about two seconds to build)."""
    return make_hand_mesh(make_skeleton())


@pytest.fixture(scope="session")
def renderer(hand_mesh: HandMesh) -> Iterator[object]:
    """One VGA renderer shared by the GL tests."""
    from builder.render import GloveRenderer
    from glovedb.camera import KINECT_V1

    with GloveRenderer(KINECT_V1, mesh=hand_mesh) as instance:
        yield instance


@pytest.fixture(scope="session")
def small_database(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 72-entry database: open and pinch, 12 camera positions x 3 rolls, 8/16/32."""
    from builder.build import build_database
    from builder.config import config_from_dict

    path = tmp_path_factory.mktemp("db") / "small.h5"
    build_database(config_from_dict(SMALL_DATABASE), path)
    return path


@pytest.fixture(scope="session")
def open_pinch_power_database(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The thesis' DB_open+pinch+power (2,268 entries), built once per session."""
    from builder.build import build_database
    from builder.config import load_config
    from glovedb.resources import config_path

    path = tmp_path_factory.mktemp("db") / "open_pinch_power.h5"
    build_database(load_config(config_path("db/open_pinch_power.toml")), path)
    return path
