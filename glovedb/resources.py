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


def config_files(folder: str, suffix: str) -> list[Path]:
    """Files ending in ``suffix`` under ``configs/<folder>``, packaged copy first,
    one per name, sorted by name."""
    found: dict[str, Path] = {}
    for root in (_PACKAGED, _CHECKOUT):
        directory = root / folder
        if directory.is_dir():
            for path in sorted(directory.glob(f"*{suffix}")):
                found.setdefault(path.name, path)
    return [found[name] for name in sorted(found)]
