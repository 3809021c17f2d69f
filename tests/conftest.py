"""Shared fixtures. Expensive objects (mesh, renderer) are built once per session."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from glovedb.hand_model import make_skeleton
from glovedb.mesh import HandMesh, make_hand_mesh

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


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
