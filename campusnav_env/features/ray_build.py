"""Every node's view encodings built on a Ray cluster (``pip install "sb3-dcqn[ray]"``), for maps beyond one machine.

:func:`encode_batches_on_ray` is a :data:`~campusnav_env.features.feature_cache.BatchBuild`: it yields each batch of
nodes as it finishes, and the caller (the cache) stores it as a shard of the same cache file, under the same key, as
the local build's; the driver is the only process that touches the cache directory, so the cluster's nodes need no
shared disk. Each actor is a :class:`~campusnav_env.features.view_worker.BatchWorker`: the renderer factory and the
encoder are put in Ray's object store once, and each actor builds its renderer and encoder once and keeps them.

Actors, unless their number is given: one per GPU where the cluster has GPUs (the encoder moved to it), else one per
CPU, less one CPU on the driver's node (the driver receives the batches and writes the shards, and Ray's own tasks
must not starve there: ray-project/ray#44687). An actor that dies (killed, out of memory, its node lost) has its
batches retried on the others and is replaced; a batch that kills :data:`MAX_TRIES` actors stops the build with a
:class:`~campusnav_env.features.view_worker.ViewBuildError` naming it. A failing node stops the build at once with one
naming the node, as in the local pool.

The actors import ``campusnav_env`` (and the modules of the renderer and encoder) on their nodes: install the package
there too (or ship it with a ``runtime_env``).
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import logging
import time
from collections.abc import Callable, Iterator, Sequence
from types import ModuleType
from typing import Any

import numpy as np

from campusnav_env.features.encoders import ViewEncoder
from campusnav_env.features.feature_cache import VIEWS_PER_BATCH
from campusnav_env.features.parallel_build import DEFAULT_START_TIMEOUT, check_workers
from campusnav_env.features.view_worker import (
    BatchWorker,
    NodeRenderer,
    ViewBuildError,
    WorkerStartError,
    pickle_for_workers,
)

__all__ = ["MAX_TRIES", "RAY_EXTRA", "GpuBatchWorker", "encode_batches_on_ray", "import_ray"]

logger = logging.getLogger(__name__)

RAY_EXTRA = 'pip install "sb3-dcqn[ray]"'
# Actors a batch may see die before the build gives up on it (a node whose views kill every process that renders it)
MAX_TRIES = 3
# Batches handed to an actor ahead of its results, so that it never idles while the driver stores a shard
_BATCHES_AHEAD = 2


def import_ray() -> ModuleType:
    """
    Ray, or a one-line error naming the extra that installs it.

    :raises ImportError: if Ray is not installed
    """
    try:
        import ray
    except ImportError as e:
        raise ImportError(f'view_build backend="ray" needs Ray, which is not installed: {RAY_EXTRA}') from e
    return ray


class GpuBatchWorker(BatchWorker):
    """A :class:`BatchWorker` that moves a torch encoder to the GPU Ray gave its actor, where it has one."""

    def _build(self) -> tuple[NodeRenderer, ViewEncoder]:
        import torch

        renderer, encoder = super()._build()
        model, device = getattr(encoder, "model", None), getattr(encoder, "device", None)
        if torch.cuda.is_available() and isinstance(model, torch.nn.Module) and isinstance(device, torch.device):
            encoder.model, encoder.device = model.to("cuda"), torch.device("cuda")  # type: ignore[attr-defined]
            # A whole batch in one pass: the CPU default (2 views) would leave the GPU idle
            encoder.batch_size = max(int(getattr(encoder, "batch_size", 1)), VIEWS_PER_BATCH)  # type: ignore[attr-defined]
        return renderer, encoder


@dataclasses.dataclass
class _Actor:
    """An actor, the options it was started with (for its replacement) and the batches handed to it."""

    handle: Any
    options: dict[str, Any]
    in_flight: int = 0
    alive: bool = True


def _actor_options(ray: ModuleType, actors: int | None) -> list[dict[str, Any]]:
    """The options of each actor to start: the plan of the module docstring, or ``actors`` actors of one CPU each."""
    if actors is not None:
        return [{"num_cpus": 1}] * actors
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    nodes = [node for node in ray.nodes() if node.get("Alive")]
    gpus = sum(int(node["Resources"].get("GPU", 0)) for node in nodes)
    if gpus:
        return [{"num_cpus": 1, "num_gpus": 1}] * gpus
    driver = ray.get_runtime_context().get_node_id()
    options = []
    for node in nodes:
        cpus = int(node["Resources"].get("CPU", 0)) - (node["NodeID"] == driver)
        strategy = NodeAffinitySchedulingStrategy(node["NodeID"], soft=True)  # soft: its replacement may go elsewhere
        options += [{"num_cpus": 1, "scheduling_strategy": strategy}] * max(0, cpus)
    return options or [{"num_cpus": 1}]  # a one-CPU cluster: its CPU, rather than no build


def _task_error(ray: ModuleType, error: Exception, nodes: range, unbuilt: list[int]) -> ViewBuildError:
    """The build's error for an exception raised in an actor's task (the actor's traceback in the cause)."""
    cause = error.cause if isinstance(error, ray.exceptions.RayTaskError) else error
    if isinstance(cause, WorkerStartError):
        return ViewBuildError(unbuilt, str(cause))
    if isinstance(cause, ViewBuildError):
        return ViewBuildError(cause.nodes, str(cause))
    return ViewBuildError(list(nodes), f"nodes {nodes.start}-{nodes.stop - 1}: {type(cause).__name__}: {cause}")


def encode_batches_on_ray(
    batches: Sequence[range],
    make_renderer: Callable[[], NodeRenderer],
    encoder: ViewEncoder,
    *,
    address: str | None = None,
    actors: int | None = None,
    start_timeout: float = DEFAULT_START_TIMEOUT,
) -> Iterator[tuple[range, np.ndarray]]:
    """
    Render and encode ``batches`` of nodes on Ray actors, yielding each as it finishes.

    :param batches: The batches (of :func:`~campusnav_env.features.feature_cache.node_batches`)
    :param make_renderer: Picklable factory of the renderer, called once in each actor; not defined in ``__main__``
    :param encoder: Picklable encoder, copied to each actor; its class not defined in ``__main__``
    :param address: The cluster, where Ray is not initialised in this process yet: ``"auto"`` (the one started on this
        machine with ``ray start``), ``"ray://<head>:10001"`` (Ray Client) or ``"<head>:6379"``; None: ``$RAY_ADDRESS``
        or else a Ray instance on this machine (shut down after the build)
    :param actors: Number of actors of one CPU each; None: the plan of the module docstring
    :param start_timeout: Seconds the first batch may take to finish (actors scheduled, started, built)
    :return: ``(nodes, encodings)`` pairs, in the order they finish
    :raises ImportError: if Ray is not installed (naming the extra)
    :raises ViewBuildError: a node failed (its id in the message and in ``.nodes``), no batch finished within
        ``start_timeout`` or a batch killed :data:`MAX_TRIES` actors
    :raises ValueError: ``actors`` < 1 or ``start_timeout`` <= 0
    :raises TypeError: the renderer factory or the encoder cannot be pickled, or is defined in ``__main__``
    """
    ray = import_ray()
    check_workers(actors, allow_none=True)
    if not start_timeout > 0:
        raise ValueError(f"start_timeout must be a number of seconds > 0, got {start_timeout!r}")
    payload = pickle_for_workers((make_renderer, encoder))
    return _run_actors(ray, list(batches), payload, address, actors, start_timeout)


def _run_actors(
    ray: ModuleType,
    batches: list[range],
    payload: bytes,
    address: str | None,
    actors: int | None,
    start_timeout: float,
) -> Iterator[tuple[range, np.ndarray]]:
    if not batches:
        return
    started_ray = not ray.is_initialized()
    if started_ray:
        ray.init(address=address, include_dashboard=False, logging_level=logging.WARNING)
    remote_worker = ray.remote(GpuBatchWorker)
    pool: list[_Actor] = []
    try:
        payload_ref = ray.put(payload)  # in the object store once; each actor's node fetches it once

        def start(options: dict[str, Any]) -> _Actor:
            return _Actor(remote_worker.options(max_restarts=0, **options).remote(payload_ref), options)

        pool = [start(options) for options in _actor_options(ray, actors)[: len(batches)]]
        logger.info("building the views of %d nodes on %d Ray actors", sum(map(len, batches)), len(pool))
        todo = collections.deque(batches)
        in_flight: dict[Any, tuple[_Actor, range]] = {}
        deaths: collections.Counter[range] = collections.Counter()
        deadline: float | None = time.monotonic() + start_timeout
        while todo or in_flight:
            for actor in pool:
                while actor.alive and todo and actor.in_flight < _BATCHES_AHEAD:
                    nodes = todo.popleft()
                    in_flight[actor.handle.encode.remote(nodes)] = (actor, nodes)
                    actor.in_flight += 1
            timeout = None if deadline is None else max(0.0, deadline - time.monotonic())
            ready, _ = ray.wait(list(in_flight), num_returns=1, timeout=timeout)
            if not ready:
                raise ViewBuildError(
                    [node for nodes in batches for node in nodes],
                    f"no Ray actor finished a batch within {start_timeout:g} s: does the cluster have the resources "
                    f"asked for ({len(pool)} actors, {pool[0].options.get('num_gpus', 0)} GPU and 1 CPU each)? "
                    "`ray status` shows them",
                )
            actor, nodes = in_flight.pop(ready[0])
            actor.in_flight -= 1
            try:
                encoded = ray.get(ready[0])
            except ray.exceptions.RayActorError as e:
                deaths[nodes] += 1
                if deaths[nodes] >= MAX_TRIES:
                    raise ViewBuildError(
                        list(nodes),
                        f"nodes {nodes.start}-{nodes.stop - 1}: {MAX_TRIES} Ray actors died building them; "
                        f"the last: {e}",
                    ) from e
                todo.appendleft(nodes)
                if actor.alive:  # its other batches fail too, and come back here: replace it once
                    logger.warning(
                        "a Ray view-build actor died building nodes %d-%d; retrying them on another: %s",
                        nodes.start,
                        nodes.stop - 1,
                        e,
                    )
                    actor.alive = False
                    pool.append(start(actor.options))
                continue
            except Exception as e:
                unbuilt = [node for batch in [nodes, *todo, *(n for _, n in in_flight.values())] for node in batch]
                raise _task_error(ray, e, nodes, sorted(unbuilt)) from e
            deadline = None
            yield nodes, encoded
    finally:
        for actor in pool:
            with contextlib.suppress(Exception):  # an actor that died already, or a cluster that went away
                ray.kill(actor.handle)
        if started_ray:
            ray.shutdown()
