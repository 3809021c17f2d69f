"""Building a posture database: plan, render in worker processes, assemble the file.

How a build stays safe when it is interrupted:

1. Every posture's tiny images are written to their own shard file in a work folder
   ``DB.h5.parts/`` beside the output, already in the database's row code, by
   writing a temporary name and renaming it, so a shard is either complete or
   absent. The folder also holds the plan's settings; ``--resume`` checks them and
   renders only the missing shards.
2. When every shard exists, the database is assembled into ``DB.h5.partial``, marked
   complete last, and renamed to ``DB.h5``; then the work folder is removed. A
   reader refuses a file that is not marked complete.

Workers are separate processes started with ``spawn`` (never ``fork``: the calling
process may hold an OpenGL context, which must not cross a fork) while the plan is
made, each with its own renderer, a software rasteriser (``glovedb.rasterize``) that
needs no context; with ``executor="ray"`` they are Ray actors on a cluster
(``builder.ray_executor``). Shards are assembled in posture order, so the output
depends neither on the number of workers nor on the executor, and two builds of one
config give the same bytes.
"""

from __future__ import annotations

import json
import math
import multiprocessing
import os
import shutil
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from multiprocessing.queues import SimpleQueue
from pathlib import Path
from typing import Any, BinaryIO, Literal

import h5py
import numpy as np
from numpy.typing import ArrayLike, NDArray

import glovedb
from builder.config import MAX_POSTURES, DatabaseConfig
from builder.sampling import farthest_point_selection, synergy_postures
from glovedb._row_codec import HEADER_BYTES, encode_rows
from glovedb._threads import single_threaded_blas
from glovedb.camera import CameraIntrinsics
from glovedb.database import FORMAT_NAME, FORMAT_VERSION
from glovedb.hand_model import forward_kinematics, make_skeleton
from glovedb.mesh import cached_hand_mesh, pose_mesh
from glovedb.posture_io import load_postures
from glovedb.postures import load_named_postures
from glovedb.rasterize import rasterize_labels
from glovedb.resources import config_path
from glovedb.tiny_images import tiny_images_of_label_images
from glovedb.trajectory import load_trajectory
from glovedb.views import HAND_CENTRE, database_views, icosphere

# Reach of the wrist cuff from the middle of the hand, in hand lengths.
_CUFF_RADIUS = 0.66

Executor = Literal["local", "ray"]
EXECUTORS: tuple[Executor, ...] = ("local", "ray")


@dataclass(frozen=True)
class BuildPlan:
    """Everything a worker needs to render any posture of the database.

    Attributes
    ----------
    config : DatabaseConfig
    postures_rad : (P, 20) float64
    posture_names : tuple of str
    view_rotations : (V * R, 3, 3) float64
        ``cam_R_hand`` of every view, camera-position-major (view ``p * R + r``).
    view_translations_m : (V * R, 3) float64
    roll_rad : (R,) float64
    camera : CameraIntrinsics
        The square render camera.
    """

    config: DatabaseConfig
    postures_rad: NDArray[np.float64]
    posture_names: tuple[str, ...]
    view_rotations: NDArray[np.float64]
    view_translations_m: NDArray[np.float64]
    roll_rad: NDArray[np.float64]
    camera: CameraIntrinsics

    @property
    def camera_positions(self) -> int:
        return len(self.view_rotations) // len(self.roll_rad)

    @property
    def views_per_posture(self) -> int:
        return len(self.view_rotations)

    @property
    def entries(self) -> int:
        return len(self.postures_rad) * self.views_per_posture


def collect_postures(config: DatabaseConfig) -> tuple[NDArray[np.float64], tuple[str, ...]]:
    """The configured postures in order (named, files, trajectories, random), then the
    low-dispersion selection if one is asked for."""
    sources = config.postures
    base = Path(config.base_dir)
    postures: list[NDArray[np.float64]] = []
    names: list[str] = []
    named = load_named_postures()
    for name in sources.named:
        if name not in named:
            raise ValueError(f"unknown posture {name!r}; known: {', '.join(named)}")
        postures.append(named[name][None])
        names.append(name)
    for file in sources.files:
        loaded = load_postures(base / file)
        postures.append(loaded)
        names += [f"{Path(file).name}:{i}" for i in range(len(loaded))]
    for file in sources.trajectories:
        trajectory = load_trajectory(base / file)
        count = int(np.floor(trajectory.duration_s * sources.trajectory_fps)) + 1
        if count > MAX_POSTURES:
            raise ValueError(f"{file}: {count} postures at trajectory_fps, over {MAX_POSTURES}")
        sampled, _, _ = trajectory.sample(np.arange(count) / sources.trajectory_fps)
        postures.append(sampled)
        names += [f"{Path(file).name}@{i / sources.trajectory_fps:g}s" for i in range(count)]
    if sources.random is not None:
        settings = sources.random
        drawn = synergy_postures(
            settings.count,
            np.array(list(named.values())),
            synergies=settings.synergies,
            spread=settings.spread,
            noise_deg=settings.noise_deg,
            seed=settings.seed,
        )
        postures.append(drawn)
        names += [f"random:{i}" for i in range(settings.count)]
    all_postures = np.concatenate(postures)
    if sources.select is not None:
        if sources.select > len(all_postures):
            raise ValueError(f"select = {sources.select} but only {len(all_postures)} postures")
        picks = farthest_point_selection(all_postures, sources.select)
        return all_postures[picks], tuple(names[i] for i in picks)
    return all_postures, tuple(names)


def render_camera(config: DatabaseConfig, postures_rad: NDArray[np.float64]) -> CameraIntrinsics:
    """A square camera in which the whole hand fits from any direction at the distance.

    The hand must stay inside a sphere about the middle of the hand: the wrist cuff's
    reach, or the farthest keypoint of any posture plus a fingertip's thickness.
    """
    size = config.images.render_size
    length = config.hand_length_m
    centre = np.array(HAND_CENTRE) * length
    keypoints = forward_kinematics(postures_rad, make_skeleton(length)).keypoints_m
    reach = float(np.linalg.norm(keypoints - centre, axis=-1).max()) + 0.1 * length
    radius = max(_CUFF_RADIUS * length, reach)
    distance = config.views.distance_m
    if radius >= 0.9 * distance:
        raise ValueError(f"[views] distance_m = {distance} is too close for the hand")
    # The widest a sphere of this radius can look: tan = r / sqrt(d^2 - r^2).
    focal = (size / 2 - 2) * math.sqrt(distance**2 - radius**2) / radius
    middle = (size - 1) / 2
    return CameraIntrinsics(size, size, focal, focal, middle, middle)


def make_plan(config: DatabaseConfig) -> BuildPlan:
    """Postures, views and render camera of a configuration."""
    postures, names = collect_postures(config)
    rotations, translations, roll_rad = database_views(
        config.views.subdivisions,
        config.views.rolls,
        distance_m=config.views.distance_m,
        hand_length_m=config.hand_length_m,
    )
    return BuildPlan(
        config=config,
        postures_rad=postures,
        posture_names=names,
        view_rotations=rotations,
        view_translations_m=translations,
        roll_rad=roll_rad,
        camera=render_camera(config, postures),
    )


def stored_settings(config: DatabaseConfig) -> dict[str, Any]:
    """The settings recorded in the database (and compared on ``--resume``: shards of
    another format version are not resumed)."""
    settings = config.as_dict()
    settings.pop("base_dir")
    return {
        "project_version": glovedb.__version__,
        "format_version": FORMAT_VERSION,
        "config": settings,
    }


# Rendering one posture -------------------------------------------------------------


class PostureRenderer:
    """Renders the tiny images of every view of any posture of a plan.

    Labels come from the software rasteriser (:mod:`glovedb.rasterize`): no OpenGL
    context, so a renderer is cheap to make in any process.

    Parameters
    ----------
    plan : BuildPlan
    """

    def __init__(self, plan: BuildPlan) -> None:
        from glovedb.pattern import face_labels, load_pattern

        self.plan = plan
        self.mesh = cached_hand_mesh(
            make_skeleton(plan.config.hand_length_m), spacing_m=plan.config.images.mesh_spacing_m
        )
        self._faces = self.mesh.faces.astype(np.int32)
        self._face_labels = face_labels(self.mesh, load_pattern())

    def label_images(
        self, posture_rad: ArrayLike, rotations: ArrayLike, translations_m: ArrayLike
    ) -> NDArray[np.uint8]:
        """Label images ``(V, H, W) uint8`` of one posture in many global poses.

        Parameters
        ----------
        posture_rad : (20,) float
        rotations : (V, 3, 3) float
            ``cam_R_hand``.
        translations_m : (V, 3) float
            Wrist in the camera frame.
        """
        return rasterize_labels(
            pose_mesh(self.mesh, posture_rad),
            self._faces,
            self._face_labels,
            rotations,
            translations_m,
            self.plan.camera,
        )

    def tiny_images(self, posture_index: int) -> dict[int, NDArray[np.uint8]]:
        """``{size: (V, s, s) uint8}`` for every view of the posture, view-major order
        (camera position, then roll)."""
        plan = self.plan
        rolls = len(plan.roll_rad)
        # Render roll 0 of every camera position; the other rolls rotate its pixels.
        label_images = self.label_images(
            plan.postures_rad[posture_index],
            plan.view_rotations[::rolls],
            plan.view_translations_m[::rolls],
        )
        if label_images[:, [0, -1], :].any() or label_images[:, :, [0, -1]].any():
            raise RuntimeError("the hand left the render; the render camera is too narrow")
        return tiny_images_of_label_images(
            label_images, plan.config.images.sizes, rolls_rad=plan.roll_rad
        )


# Shards ----------------------------------------------------------------------------


def shard_path(parts: Path, posture_index: int) -> Path:
    return parts / f"posture_{posture_index:07d}.npy"


def write_shard(parts: Path, posture_index: int, images: dict[int, NDArray[np.uint8]]) -> None:
    """Write one posture's images atomically (temporary name, then rename), encoded.

    A shard is one flat uint8 ``.npy``: the ``(V,) int64`` row lengths of every size,
    smallest size first, then the rows of every size in the same order, in the
    database's run-length code (:mod:`glovedb._row_codec`): encoding here spreads it
    over the workers, shrinks the shards to the finished database's size, and leaves
    the assembly only bytes to copy. No zip, so a shard is read back as a memory map.
    """
    final = shard_path(parts, posture_index)
    temporary = final.with_suffix(".tmp.npy")
    encoded = [encode_rows(images[size]) for size in sorted(images)]
    blocks = [lengths.view(np.uint8) for _, lengths in encoded] + [rows for rows, _ in encoded]
    header = {
        "descr": np.lib.format.dtype_to_descr(np.dtype(np.uint8)),
        "fortran_order": False,
        "shape": (sum(block.size for block in blocks),),
    }
    with open(temporary, "wb") as file:
        np.lib.format.write_array_header_1_0(file, header)
        for block in blocks:
            file.write(block.data)
    os.replace(temporary, final)


def read_shard(
    parts: Path, posture_index: int, sizes: tuple[int, ...], views: int
) -> dict[int, tuple[NDArray[np.int64], NDArray[np.uint8]]]:
    """``{size: (lengths, rows)}`` of one shard: ``(views,) int64`` row lengths and the
    rows' bytes, read into memory (no memory map to set up and page in)."""
    lengths = read_shard_lengths(parts, posture_index, sizes, views)
    rows = {size: np.empty(int(lengths[k].sum()), np.uint8) for k, size in enumerate(sorted(sizes))}
    read_shard_into(parts, posture_index, views, rows)
    return {size: (lengths[k], rows[size]) for k, size in enumerate(sorted(sizes))}


def read_shard_into(
    parts: Path, posture_index: int, views: int, rows: dict[int, NDArray[np.uint8]]
) -> NDArray[np.int64]:
    """Read one shard's rows of each size into the front of ``rows[size]`` (a buffer
    at least as long, which :func:`_write_rows` reuses: filling fresh memory for every
    batch cost a third of writing natural1000's file); return the ``(len(rows),
    views)`` row lengths, sizes ascending. ``ValueError`` for a file that is not a
    shard of this build."""
    path = shard_path(parts, posture_index)
    with open(path, "rb") as file:
        lengths, size_bytes = _shard_head(file, path, len(rows), views)
        for k, size in enumerate(sorted(rows)):
            count = int(size_bytes[k])
            if len(rows[size]) < count or file.readinto(rows[size][:count].data) != count:
                raise ValueError(f"{path}: not a shard of this build")
    return lengths


def read_shard_lengths(
    parts: Path, posture_index: int, sizes: tuple[int, ...], views: int
) -> NDArray[np.int64]:
    """The ``(len(sizes), views)`` row lengths of one shard, its rows left unread."""
    path = shard_path(parts, posture_index)
    with open(path, "rb") as file:
        return _shard_head(file, path, len(sizes), views)[0]


def _shard_head(
    file: BinaryIO, path: Path, n_sizes: int, views: int
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Read a shard's ``.npy`` header and row lengths from ``file``; return the lengths
    ``(n_sizes, views)`` and the bytes of each size's rows ``(n_sizes,)``, which follow.
    ``ValueError`` for a file that is not a shard of this build."""
    refused = ValueError(f"{path}: not a shard of this build")
    try:
        if np.lib.format.read_magic(file) != (1, 0):
            raise refused
        shape, _, dtype = np.lib.format.read_array_header_1_0(file)
    except ValueError:
        raise refused from None
    head = 8 * views * n_sizes
    if dtype != np.uint8 or len(shape) != 1 or shape[0] < head:
        raise refused
    if os.fstat(file.fileno()).st_size != file.tell() + shape[0]:  # cut short
        raise refused
    raw = file.read(head)
    if len(raw) != head:
        raise refused
    lengths = np.frombuffer(raw, np.int64).reshape(n_sizes, views)
    size_bytes = lengths.sum(axis=1)
    if lengths.min() <= HEADER_BYTES or head + size_bytes.sum() != shape[0]:
        raise refused
    return lengths, size_bytes


# State of a worker process (its renderer), set once by the pool's initializer: the
# only way a ProcessPoolExecutor task can reach per-process state. Never used in the
# main process.
_WORKER: dict[str, Any] = {}


def _worker_start(plans: SimpleQueue) -> None:
    """Wait for ``(plan, parts)`` (None: nothing to render) and make the renderer.

    Workers start while the main process plans, so their imports take no time of the
    build; the plan then travels to them: planning again (e.g. a farthest-point
    selection of 1,000 out of 20,000 postures) would take seconds in every worker.
    """
    single_threaded_blas()
    message = plans.get()
    if message is not None:
        plan, parts = message
        _WORKER["renderer"] = PostureRenderer(plan)
        _WORKER["parts"] = Path(parts)


def _worker_render(posture_index: int) -> int:
    images = _WORKER["renderer"].tiny_images(posture_index)
    write_shard(_WORKER["parts"], posture_index, images)
    return posture_index


# The build -------------------------------------------------------------------------


@dataclass(frozen=True)
class BuildReport:
    """What a build did.

    Attributes
    ----------
    path : str
    entries, postures : int
        Of the database.
    rendered_postures : int
        Rendered by this run (a resumed build renders only the missing ones).
    seconds : float
        The whole build: planning, starting the workers, rendering, writing the file.
    render_seconds : float
        Rendering alone (workers started, shards written).
    plan_seconds, write_seconds : float
        Sampling the postures and views; assembling the database file.
    """

    path: str
    entries: int
    postures: int
    rendered_postures: int
    seconds: float
    render_seconds: float
    plan_seconds: float = 0.0
    write_seconds: float = 0.0

    @property
    def rendered_entries(self) -> int:
        return self.rendered_postures * (self.entries // max(self.postures, 1))

    @property
    def entries_per_second(self) -> float:
        """Entries rendered per second of the whole build (resumed postures not counted)."""
        return self.rendered_entries / max(self.seconds, 1e-9)

    @property
    def render_entries_per_second(self) -> float:
        """Entries rendered per second of rendering alone."""
        return self.rendered_entries / max(self.render_seconds, 1e-9)


def build_database(
    config: DatabaseConfig,
    out: str | Path,
    *,
    workers: int = 1,
    resume: bool = False,
    progress: Callable[[Iterator[int], int], Iterator[int]] | None = None,
    executor: Executor = "local",
    address: str | None = None,
) -> BuildReport:
    """Build the database of ``config`` into ``out`` (see the module docstring).

    Parameters
    ----------
    config : DatabaseConfig
    out : str or Path
        ``.h5`` file; replaced only when the new one is complete.
    workers : int
        Worker processes; 1 renders in this process. With ``executor="ray"`` and no
        ``address``: the CPUs of the local Ray instance.
    resume : bool
        Continue an interrupted build of the same settings.
    progress : callable, optional
        Wraps the iterator of finished posture indices (e.g. a tqdm bar); receives
        the iterator and the number of postures still to render.
    executor : {"local", "ray"}
        Render in local processes, or on Ray actors (``builder.ray_executor``).
    address : str, optional
        Ray cluster address (``HOST:PORT``, ``ray://HOST:PORT`` or ``"auto"``); None
        starts a local Ray instance. Only with ``executor="ray"``.

    Returns
    -------
    BuildReport
    """
    out = Path(out)
    if out.suffix != ".h5":
        raise ValueError(f"{out}: the database file name must end in .h5")
    if not out.parent.is_dir():
        raise ValueError(f"{out.parent}: folder does not exist")
    if workers < 1:
        raise ValueError(f"workers: expected at least 1, got {workers}")
    if executor not in EXECUTORS:
        raise ValueError(f"executor: expected one of {', '.join(EXECUTORS)}, got {executor!r}")
    if address is not None and executor != "ray":
        raise ValueError("address: a Ray cluster address needs the ray executor")
    started = time.perf_counter()
    parts = out.with_name(out.name + ".parts")
    settings = stored_settings(config)
    _check_parts(parts, settings, resume)
    # Connect before touching the parts folder, so a bad address leaves nothing behind;
    # local workers start now and import while the plan is made.
    with _shard_renderer(executor, address, workers) as render_shards:
        plan = make_plan(config)
        plan_seconds = time.perf_counter() - started
        _prepare_parts(parts, settings)
        pending = [p for p in range(len(plan.postures_rad)) if not shard_path(parts, p).exists()]

        render_started = time.perf_counter()
        finished = render_shards(plan, parts, pending)
        if progress is not None:
            finished = progress(finished, len(pending))
        for _ in finished:
            pass
        render_seconds = time.perf_counter() - render_started

    write_started = time.perf_counter()
    partial = out.with_name(out.name + ".partial")
    _assemble(plan, parts, partial, settings)
    os.replace(partial, out)
    shutil.rmtree(parts)
    return BuildReport(
        path=str(out),
        entries=plan.entries,
        postures=len(plan.postures_rad),
        rendered_postures=len(pending),
        seconds=time.perf_counter() - started,
        render_seconds=render_seconds,
        plan_seconds=plan_seconds,
        write_seconds=time.perf_counter() - write_started,
    )


def _check_parts(parts: Path, settings: dict[str, Any], resume: bool) -> None:
    """An existing parts folder is an error, unless resuming a build of the settings."""
    if not parts.exists():
        return
    if not resume:
        raise ValueError(
            f"{parts} holds an interrupted build: add --resume to continue it, or delete it"
        )
    try:
        previous = json.loads((parts / "settings.json").read_text())
    except (OSError, json.JSONDecodeError):
        previous = None
    if previous != json.loads(json.dumps(settings)):
        raise ValueError(f"{parts}: the interrupted build has other settings; delete it")


def _prepare_parts(parts: Path, settings: dict[str, Any]) -> None:
    """Make the parts folder, or clean the one being resumed (checked before)."""
    if parts.exists():
        for leftover in parts.glob("*.tmp.npy"):
            leftover.unlink()
        return
    parts.mkdir()
    (parts / "settings.json").write_text(json.dumps(settings, indent=1, sort_keys=True))


@contextmanager
def _shard_renderer(
    executor: Executor, address: str | None, workers: int
) -> Iterator[Callable[[BuildPlan, Path, list[int]], Iterator[int]]]:
    """The executor's ``render(plan, parts, pending)`` function, while it is open."""
    if executor == "local":
        if workers == 1:
            yield _render_here
        else:
            with _worker_pool(workers) as render:
                yield render
        return
    from builder.ray_executor import ray_shard_renderer

    with ray_shard_renderer(address, workers=workers) as render:
        yield render


def _render_here(plan: BuildPlan, parts: Path, pending: list[int]) -> Iterator[int]:
    if not pending:
        return
    renderer = PostureRenderer(plan)
    for index in pending:
        with single_threaded_blas():
            images = renderer.tiny_images(index)
        write_shard(parts, index, images)
        yield index


@contextmanager
def _worker_pool(workers: int) -> Iterator[Callable[[BuildPlan, Path, list[int]], Iterator[int]]]:
    """``render(plan, parts, pending)`` on worker processes started at once (see
    :func:`_worker_start`); call it at most once."""
    context = multiprocessing.get_context("spawn")
    plans = context.SimpleQueue()
    sent = False

    def render(plan: BuildPlan, parts: Path, pending: list[int]) -> Iterator[int]:
        nonlocal sent
        if pending:
            for _ in range(workers):
                plans.put((plan, str(parts)))
            sent = True
            yield from pool.map(_worker_render, pending)

    with ProcessPoolExecutor(
        max_workers=workers, mp_context=context, initializer=_worker_start, initargs=(plans,)
    ) as pool:
        # The pool starts a worker per task submitted while none is idle.
        for _ in range(workers):
            pool.submit(int)
        try:
            yield render
        finally:
            if not sent:
                for _ in range(workers):
                    plans.put(None)


def _write_rows(
    file: h5py.File, parts: Path, sizes: tuple[int, ...], views: int, postures: int
) -> None:
    """``/tiny/<s>/rows`` and ``offsets`` of every size, copied from the shards."""
    lengths = {size: np.empty((postures, views), np.int64) for size in sizes}
    for posture in range(postures):  # the row lengths first: the datasets' sizes
        shard_lengths = read_shard_lengths(parts, posture, sizes, views)
        for k, size in enumerate(sorted(sizes)):
            lengths[size][posture] = shard_lengths[k]
    datasets = {}
    for size in sizes:
        offsets = np.concatenate([[0], np.cumsum(lengths[size])])
        file[f"tiny/{size}/offsets"] = offsets
        datasets[size] = file.create_dataset(f"tiny/{size}/rows", (offsets[-1],), np.uint8)
    # Postures in batches of about 64 MB of rows, each size's written in one piece
    # from a buffer that every batch reuses.
    per_posture = sum(int(length.sum()) for length in lengths.values()) // postures
    batch = max(1, (1 << 26) // max(per_posture, 1))
    starts = range(0, postures, batch)
    batch_bytes = {
        size: np.add.reduceat(length.sum(axis=1), list(starts)) for size, length in lengths.items()
    }
    buffers = {size: np.empty(int(batch_bytes[size].max()), np.uint8) for size in sizes}
    written = dict.fromkeys(sizes, 0)
    for index, start in enumerate(starts):
        filled = dict.fromkeys(sizes, 0)
        for posture in range(start, min(postures, start + batch)):
            free = {size: buffer[filled[size] :] for size, buffer in buffers.items()}
            shard_lengths = read_shard_into(parts, posture, views, free)
            for k, size in enumerate(sorted(sizes)):
                filled[size] += int(shard_lengths[k].sum())
        for size in sizes:
            if filled[size] != batch_bytes[size][index]:
                raise ValueError(f"{parts}: a shard changed while the file was written")
            datasets[size][written[size] : written[size] + filled[size]] = buffers[size][
                : filled[size]
            ]
            written[size] += filled[size]


def _assemble(plan: BuildPlan, parts: Path, partial: Path, settings: dict[str, Any]) -> None:
    """Write the whole database into ``partial`` from the shards; mark it complete last."""
    config = plan.config
    sizes = tuple(config.images.sizes)
    views = plan.views_per_posture
    postures = len(plan.postures_rad)
    entries = plan.entries
    view_rotations = plan.view_rotations.astype(np.float32)
    with h5py.File(partial, "w", libver=("earliest", "v110"), track_order=False) as file:
        attrs = file.attrs
        attrs["format"] = FORMAT_NAME
        attrs["format_version"] = FORMAT_VERSION
        attrs["complete"] = False
        attrs["name"] = config.name
        attrs["project_version"] = glovedb.__version__
        attrs["settings_json"] = json.dumps(settings, sort_keys=True)
        attrs["camera_positions"] = plan.camera_positions
        attrs["rolls"] = len(plan.roll_rad)
        attrs["hand_length_m"] = config.hand_length_m
        attrs["render_camera_json"] = json.dumps(plan.camera.to_open3d_json())
        attrs["pattern_toml"] = config_path("glove/pattern.toml").read_text()
        file["postures"] = plan.postures_rad.astype(np.float32)
        file["posture_names"] = np.array(plan.posture_names, dtype=h5py.string_dtype())
        file["views/rotation"] = view_rotations
        file["views/translation_m"] = plan.view_translations_m.astype(np.float32)
        file["views/camera_direction"] = icosphere(config.views.subdivisions)
        file["views/roll_rad"] = plan.roll_rad
        file["entries/posture_id"] = np.repeat(np.arange(postures, dtype=np.int32), views)
        file["entries/view_id"] = np.tile(np.arange(views, dtype=np.int32), postures)
        file.create_dataset(
            "entries/rotation", data=np.tile(view_rotations, (postures, 1, 1)),
            chunks=(min(entries, 1 << 16), 3, 3), compression="gzip", compression_opts=4,
        )  # fmt: skip
        _write_rows(file, parts, sizes, views, postures)
        attrs["complete"] = True
