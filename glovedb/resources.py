"""Where the project's data files live (the ``configs/`` tree).

In a source checkout (or an editable install) they are in ``configs/`` beside the
packages; a wheel carries a copy inside ``glovedb/_configs``.
"""

from __future__ import annotations

from pathlib import Path

_PACKAGED = Path(__file__).resolve().parent / "_configs"
_CHECKOUT = Path(__file__).resolve().parent.parent / "configs"


def config_path(relative: str) -> Path:
    """Absolute path of a file under ``configs/``, e.g. ``"glove/pattern.toml"``.

    Raises
    ------
    FileNotFoundError
        When neither the packaged copy nor the checkout has the file.
    """
    for root in (_PACKAGED, _CHECKOUT):
        candidate = root / relative
        if candidate.is_file():
            return candidate
    raise FileNotFoundError(f"configs/{relative} not found in {_PACKAGED} or {_CHECKOUT}")
