"""The user's cache folder: what is slow to make and the same every time.

``$GLOVE_CACHE``, else ``$XDG_CACHE_HOME/glove``, else ``~/.cache/glove``. It holds
the demo's database, the generated hand meshes (:func:`glovedb.mesh.
cached_hand_mesh`) and the search stages of large databases (:mod:`glovedb.
stage_cache`). Every entry's name carries a hash of what decides its contents,
the code that makes it included, so a changed input or a new version makes a new
entry instead of reusing a stale one. Deleting the folder is always safe.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent


def cache_folder() -> Path:
    """``$GLOVE_CACHE``, else ``$XDG_CACHE_HOME/glove``, else ``~/.cache/glove`` (not
    created here)."""
    if os.environ.get("GLOVE_CACHE"):
        return Path(os.environ["GLOVE_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "glove"


def source_digest(*modules: str) -> hashlib._Hash:
    """A SHA-256 over the source of ``glovedb`` modules (file stems, e.g. ``"mesh"``),
    to be updated with the entry's other inputs."""
    digest = hashlib.sha256()
    for stem in modules:
        digest.update((PACKAGE / f"{stem}.py").read_bytes())
    return digest
