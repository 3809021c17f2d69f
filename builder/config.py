"""Database build configuration: TOML files under ``configs/db/`` as frozen dataclasses.

Example (``configs/db/open_pinch_power.toml``)::

    name = "open_pinch_power"
    [postures]
    named = ["open", "pinch", "power"]
    [views]
    subdivisions = 1   # 42 camera positions on the icosahedron
    rolls = 18         # rotations about the optical axis: 756 views per posture
    [images]
    sizes = [8, 16, 32, 64]

Postures come from any mix of ``named`` postures, posture ``files`` (CSV or .npy),
``trajectories`` (JSON, sampled at ``trajectory_fps``) and ``[postures.random]``
(synergy sampling); ``select = K`` then keeps a low-dispersion subset of K of them.
Relative file names are relative to the TOML file. Unknown keys are errors.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import tomllib

from glovedb._validate import dataclass_from_table
from glovedb.tiny_images import DEFAULT_SIZES, check_sizes


@dataclass(frozen=True)
class RandomPostures:
    """``[postures.random]``: random natural postures (see ``builder.sampling``)."""

    count: int
    seed: int = 0
    synergies: int = 4
    spread: float = 1.0
    noise_deg: float = 5.0


MAX_POSTURES = 1_000_000
"""Most postures a build may draw or sample from one source (their arrays and the
names are held in memory; a million postures already make a database of billions of
entries)."""


@dataclass(frozen=True)
class PostureSources:
    """``[postures]``: where the database's postures come from."""

    named: tuple[str, ...] = ()
    files: tuple[str, ...] = ()
    trajectories: tuple[str, ...] = ()
    trajectory_fps: float = 10.0
    random: RandomPostures | None = None
    select: int | None = None


@dataclass(frozen=True)
class ViewSettings:
    """``[views]``: icosphere camera positions times rolls about the optical axis."""

    subdivisions: int = 1
    rolls: int = 18
    distance_m: float = 0.5


@dataclass(frozen=True)
class ImageSettings:
    """``[images]``: tiny image sizes, the square render they are made from, and the
    glove mesh's resolution for these renders (3 mm is ample for 64 x 64 images and
    renders twice as fast as the 2 mm mesh)."""

    sizes: tuple[int, ...] = DEFAULT_SIZES
    render_size: int = 192
    mesh_spacing_m: float = 0.003


@dataclass(frozen=True)
class DatabaseConfig:
    """A whole build configuration."""

    name: str
    postures: PostureSources
    views: ViewSettings = field(default_factory=ViewSettings)
    images: ImageSettings = field(default_factory=ImageSettings)
    hand_length_m: float = 0.19
    base_dir: str = "."

    def as_dict(self) -> dict[str, Any]:
        """Plain dictionary (JSON-ready) of every setting."""
        return asdict(self)


def config_from_dict(
    data: dict[str, Any], *, source: str = "config", base_dir: str = "."
) -> DatabaseConfig:
    """Check and convert parsed TOML into a :class:`DatabaseConfig`."""
    data = dict(data)
    postures = dict(data.pop("postures", {}))
    random = postures.pop("random", None)
    sources = dataclass_from_table(PostureSources, postures, f"{source} [postures]")
    if random is not None:
        sources = PostureSources(
            **{
                **asdict(sources),
                "random": dataclass_from_table(
                    RandomPostures, random, f"{source} [postures.random]"
                ),
            }
        )
    views = dataclass_from_table(ViewSettings, data.pop("views", {}), f"{source} [views]")
    images = dataclass_from_table(ImageSettings, data.pop("images", {}), f"{source} [images]")
    if "name" not in data:
        data["name"] = Path(source).stem
    config = dataclass_from_table(
        DatabaseConfig,
        {**data, "postures": sources, "views": views, "images": images, "base_dir": base_dir},
        source,
    )
    check_config(config, source)
    return config


def check_config(config: DatabaseConfig, source: str) -> None:
    """Raise a one-line ``ValueError`` for settings that cannot build a database."""
    p = config.postures
    if not (p.named or p.files or p.trajectories or p.random):
        raise ValueError(
            f"{source}: [postures] names no source (named, files, trajectories, random)"
        )
    if p.select is not None and p.select < 1:
        raise ValueError(f"{source}: [postures] select must be positive")
    if not 0 < p.trajectory_fps <= 1000:
        raise ValueError(f"{source}: [postures] trajectory_fps must be in (0, 1000]")
    if p.random is not None:
        r = p.random
        if not 1 <= r.count <= MAX_POSTURES:
            raise ValueError(f"{source}: [postures.random] count must be 1..{MAX_POSTURES}")
        if r.seed < 0:
            raise ValueError(f"{source}: [postures.random] seed must be 0 or more")
        if not (0 <= r.spread <= 10 and 0 <= r.noise_deg <= 90):
            raise ValueError(
                f"{source}: [postures.random] spread must be 0..10 and noise_deg 0..90"
            )
    if not config.name or not config.name.isprintable():
        raise ValueError(f"{source}: name must be non-empty printable text, got {config.name!r}")
    if not 0.05 <= config.hand_length_m <= 0.5:
        raise ValueError(f"{source}: hand_length_m must be 0.05..0.5 m")
    if not 0 <= config.views.subdivisions <= 4:
        raise ValueError(f"{source}: [views] subdivisions must be 0..4")
    if not 1 <= config.views.rolls <= 360:
        raise ValueError(f"{source}: [views] rolls must be 1..360")
    if not 0.1 <= config.views.distance_m <= 5:
        raise ValueError(f"{source}: [views] distance_m must be 0.1..5")
    if not 0.001 <= config.images.mesh_spacing_m <= 0.006:
        raise ValueError(f"{source}: [images] mesh_spacing_m must be 0.001..0.006")
    sizes = check_sizes(config.images.sizes)
    if not 2 * sizes[-1] <= config.images.render_size <= 1024:
        raise ValueError(f"{source}: [images] render_size must be 2x the largest size..1024")


def load_config(path: str | Path) -> DatabaseConfig:
    """Read a database build TOML file."""
    path = Path(path)
    try:
        with open(path, "rb") as stream:
            data = tomllib.load(stream)
    except OSError as error:
        raise ValueError(f"{path}: cannot read the config ({error.strerror})") from error
    except tomllib.TOMLDecodeError as error:
        raise ValueError(f"{path}: not valid TOML ({error})") from error
    return config_from_dict(data, source=str(path), base_dir=str(path.resolve().parent))
