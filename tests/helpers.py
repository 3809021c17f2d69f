"""Constants and small helpers shared by the tests (fixtures live in conftest.py)."""

from pathlib import Path

# ../shared/data beside the repository: present for developers and CI, absent for users.
SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"

# A 72-entry database: open and pinch, 12 camera positions x 3 rolls, sizes 8/16/32.
SMALL_DATABASE = {
    "name": "small",
    "postures": {"named": ["open", "pinch"]},
    "views": {"subdivisions": 0, "rolls": 3},
    "images": {"sizes": [8, 16, 32], "render_size": 96},
}
