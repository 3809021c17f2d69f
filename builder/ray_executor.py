"""Rendering a build's shards on a Ray cluster (``glove build --executor ray``).

The driver (the process that runs the build) starts a local Ray instance or connects
to a cluster, puts the :class:`~builder.build.BuildPlan` into the object store once
and creates one actor per free CPU. Each actor holds one
:class:`~builder.build.PostureRenderer` (a software rasteriser: no OpenGL context),
made in the actor's own process, and returns a posture's tiny images through the
object store. The driver writes every shard into
its own ``DB.h5.parts/`` with :func:`~builder.build.write_shard`, so the nodes need no
shared file system, and :func:`~builder.build.build_database` then assembles the file
exactly as for a local build: the bytes do not depend on the executor.

``ray`` is imported only here, and only when this executor is used.
"""

from __future__ import annotations

import logging
import socket
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
from numpy.typing import NDArray

import glovedb
from builder.build import BuildPlan, PostureRenderer, write_shard
from glovedb._threads import single_threaded_blas

# Seconds to wait for the cluster's address to accept a connection: Ray itself
# retries an unreachable address for minutes.
CONNECT_TIMEOUT_S = 5.0
# Postures queued on each actor: one rendering while the next one waits, so an actor
# never idles for a round trip, yet few finished images wait in the object store.
_TASKS_PER_ACTOR = 2

ShardRenderer = Callable[[BuildPlan, Path, list[int]], Iterator[int]]


class _RenderActor:
    """One Ray worker: a renderer for every posture of the plan."""

    def __init__(self, plan: BuildPlan) -> None:
        single_threaded_blas()
        self._renderer = PostureRenderer(plan)

    def version(self) -> str:
        return glovedb.__version__

    def tiny_images(self, posture_index: int) -> dict[int, NDArray[np.uint8]]:
        return self._renderer.tiny_images(posture_index)


@contextmanager
def ray_shard_renderer(address: str | None, *, workers: int) -> Iterator[ShardRenderer]:
    """Connect to Ray for one build; yield the function that renders its shards.

    Parameters
    ----------
    address : str or None
        Ray cluster address (``HOST:PORT``, ``ray://HOST:PORT`` or ``"auto"`` for the
        cluster this machine belongs to); None starts a local Ray instance.
    workers : int
        CPUs of the local instance (ignored when connecting to a cluster, which
        gets one actor per free CPU).

    Yields
    ------
    callable
        ``render(plan, parts, pending)``: renders the pending postures on the
        cluster, writes their shards into ``parts`` and yields each posture index
        as its shard is written.

    Raises
    ------
    ValueError
        When ray is not installed or the address cannot be reached.

    Notes
    -----
    A Ray session that is already open in this process is used as it is and left
    open; otherwise the session opened here is closed on leaving.
    """
    ray = _import_ray()
    opened = not ray.is_initialized()
    if opened:
        _connect(ray, address, workers)
    try:
        yield lambda plan, parts, pending: _render_shards(ray, plan, parts, pending)
    finally:
        if opened:
            ray.shutdown()


def _import_ray() -> ModuleType:
    try:
        import ray
    except ImportError:
        raise ValueError(
            "the ray executor needs Ray: install the ray extra: bash scripts/setup.sh --ray"
        ) from None
    return ray


def _connect(ray: ModuleType, address: str | None, workers: int) -> None:
    quiet: dict[str, Any] = {"logging_level": logging.WARNING, "log_to_driver": False}
    if address is None:
        # "local" always starts a new instance; None would join a cluster that
        # RAY_ADDRESS or a `ray start` on this machine names.
        ray.init(address="local", num_cpus=workers, include_dashboard=False, **quiet)
        return
    if address != "auto":
        _check_reachable(address)
    try:
        ray.init(address=address, **quiet)
    except ConnectionError as error:
        raise ValueError(f"ray address {address!r}: {error}") from None


def _check_reachable(address: str) -> None:
    """Fail within ``CONNECT_TIMEOUT_S`` when nothing listens at ``address``."""
    host, separator, port = address.removeprefix("ray://").rpartition(":")
    if not separator or not host or not port.isdigit():
        raise ValueError(f"ray address {address!r}: expected HOST:PORT, ray://HOST:PORT or auto")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), CONNECT_TIMEOUT_S):
            pass
    except OSError as error:
        reason = error.strerror or type(error).__name__
        raise ValueError(
            f"ray address {address!r} cannot be reached within {CONNECT_TIMEOUT_S:g} s: {reason}"
        ) from None


def _render_shards(
    ray: ModuleType, plan: BuildPlan, parts: Path, pending: list[int]
) -> Iterator[int]:
    if not pending:
        return
    free_cpus = int(ray.available_resources().get("CPU", 0))
    actor_class = ray.remote(num_cpus=1)(_RenderActor)
    plan_ref = ray.put(plan)
    actors = [actor_class.remote(plan_ref) for _ in range(max(1, min(free_cpus, len(pending))))]
    # Waiting for every actor's version also waits until every renderer is built.
    versions = set(ray.get([actor.version.remote() for actor in actors]))
    if versions != {glovedb.__version__}:
        raise ValueError(
            f"ray workers run glove-tracker {', '.join(sorted(versions))} but this machine "
            f"{glovedb.__version__}: install the same version on every node"
        )
    queue = iter(pending)
    running: dict[Any, tuple[int, Any]] = {}

    def submit(actor: Any) -> None:
        index = next(queue, None)
        if index is not None:
            running[actor.tiny_images.remote(index)] = (index, actor)

    for _ in range(_TASKS_PER_ACTOR):
        for actor in actors:
            submit(actor)
    while running:
        [done], _ = ray.wait(list(running), num_returns=1)
        index, actor = running.pop(done)
        write_shard(parts, index, ray.get(done))
        submit(actor)
        yield index
