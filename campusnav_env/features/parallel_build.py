"""Every node's view encodings built by worker processes, for maps too big to render and encode in one process.

:func:`encode_views_in_workers` splits the nodes into the batches of the serial build
(:func:`~campusnav_env.features.feature_cache.node_batches`, 8 nodes = 32 views) and hands them to ``workers``
processes. Each worker is started with the ``spawn`` method (safe wherever torch, OpenCV or threads are loaded), runs
one torch thread and one OpenCV thread (so ``workers`` processes use ``workers`` cores instead of oversubscribing
them), and receives the renderer factory and the encoder pickled once by the parent: the 3D world is built once, by
the caller, and each worker builds its own renderer from it. Workers render and encode with the serial build's
pieces (:func:`~campusnav_env.features.feature_cache.render_nodes`,
:func:`~campusnav_env.features.feature_cache.encode_nodes`), so on one thread a batch's encodings are those of the
serial build (up to the float rounding of a different thread count). The parent fills the array and the progress bar
as batches finish; storing the array is the caller's (the cache's) job.

A failing node stops the build with a :class:`ViewBuildError` that names it (the worker's traceback attached), and a
worker that dies (killed, out of memory) with a :class:`ViewBuildError` naming the nodes it was building.
"""

from __future__ import annotations

import os
import pickle
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_EXCEPTION, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import get_context
from typing import Any, Protocol

import numpy as np
from tqdm import tqdm

from campusnav_env.features.encoders import ViewEncoder
from campusnav_env.features.feature_cache import (
    VIEWS_PER_NODE,
    encode_nodes,
    node_batches,
    progress_label,
    render_nodes,
)

__all__ = ["NodeRenderer", "ViewBuildError", "default_workers", "encode_views_in_workers"]


class NodeRenderer(Protocol):
    """What a worker renders with (e.g. :class:`~campusnav_env.rendering.street_view.StreetViewRenderer`)."""

    def render_node(self, node: int) -> np.ndarray:
        """``(4, H, W, 3)`` uint8 views of ``node`` in N, E, S, W order."""


class ViewBuildError(RuntimeError):
    """
    A node's views could not be rendered or encoded in a worker.

    :param nodes: The node that failed (or the batch of nodes, where the failure is not one node's)
    :param message: What went wrong
    """

    def __init__(self, nodes: Sequence[int], message: str) -> None:
        super().__init__(message)
        self.nodes = tuple(int(node) for node in nodes)

    def __reduce__(self) -> tuple[Any, ...]:  # RuntimeError pickles only its message; the parent needs the nodes too
        return type(self), (self.nodes, str(self))


def default_workers() -> int:
    """The cores this process may run on (``os.sched_getaffinity``; ``os.cpu_count()`` where that is missing)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


# The worker's renderer and encoder, set once by _start_worker
_WORKER: tuple[NodeRenderer, ViewEncoder] | None = None


def _start_worker(payload: bytes) -> None:
    """Worker initializer: one thread for torch and OpenCV, then the renderer and the encoder from the parent."""
    import cv2
    import torch

    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    global _WORKER
    make_renderer, encoder = pickle.loads(payload)
    _WORKER = (make_renderer(), encoder)


def _encode_batch(nodes: range) -> tuple[range, np.ndarray]:
    """Worker task: render and encode one batch of nodes; failures name the node (or the batch, for the encoder)."""
    assert _WORKER is not None, "worker not started"
    renderer, encoder = _WORKER
    views = []
    for node in nodes:
        try:
            views.append(render_nodes([node], renderer.render_node))
        except Exception as e:
            raise ViewBuildError([node], f"node {node}: rendering its views failed: {type(e).__name__}: {e}") from e
    try:
        return nodes, encode_nodes(np.concatenate(views), encoder)
    except Exception as e:
        raise ViewBuildError(
            nodes, f"nodes {nodes.start}-{nodes.stop - 1}: encoding their views failed: {type(e).__name__}: {e}"
        ) from e


def encode_views_in_workers(
    n_nodes: int,
    make_renderer: Callable[[], NodeRenderer],
    encoder: ViewEncoder,
    *,
    workers: int,
    progress: bool = True,
) -> np.ndarray:
    """
    Render and encode the four views of nodes ``0 .. n_nodes - 1`` in ``workers`` processes.

    :param n_nodes: Number of nodes
    :param make_renderer: Picklable factory of the renderer, called once in each worker (e.g.
        ``functools.partial(StreetViewRenderer, world, settings)``: the world is pickled once, not rebuilt)
    :param encoder: Picklable encoder, copied to each worker
    :param workers: Number of worker processes (at most one per batch of nodes is started)
    :param progress: Show a tqdm progress bar
    :return: ``(n_nodes, 4, *encoder.output_shape)`` array of dtype ``encoder.dtype``
    :raises ViewBuildError: a node failed (its id in the message and in ``.nodes``), or a worker died
    :raises ValueError: ``workers`` < 1
    :raises TypeError: the renderer factory or the encoder cannot be pickled
    """
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be an int >= 1, got {workers!r}")
    try:
        payload = pickle.dumps((make_renderer, encoder), protocol=pickle.HIGHEST_PROTOCOL)
    except Exception as e:
        raise TypeError(f"the renderer and encoder must be picklable to build views in workers: {e}") from e
    batches = node_batches(n_nodes)
    features = np.empty((n_nodes, VIEWS_PER_NODE, *encoder.output_shape), dtype=encoder.dtype)
    with (
        ProcessPoolExecutor(
            max_workers=min(workers, len(batches)),
            mp_context=get_context("spawn"),
            initializer=_start_worker,
            initargs=(payload,),
        ) as pool,
        tqdm(total=n_nodes, desc=progress_label(encoder), unit="node", disable=not progress) as bar,
    ):
        batch_of: dict[Future[tuple[range, np.ndarray]], range] = {
            pool.submit(_encode_batch, nodes): nodes for nodes in batches
        }
        pending, received = set(batch_of), set()
        try:
            while pending:
                done, pending = wait(pending, return_when=FIRST_EXCEPTION)
                for future in done:
                    nodes, encoded = future.result()  # re-raises a worker's ViewBuildError
                    features[nodes.start : nodes.stop] = encoded
                    bar.update(len(nodes))
                    received.add(future)
        except BrokenProcessPool as e:
            unfinished = [nodes for future, nodes in batch_of.items() if future not in received]
            first = min(nodes.start for nodes in unfinished)
            raise ViewBuildError(
                [node for nodes in unfinished for node in nodes],
                f"a view-build worker died (killed or out of memory) while nodes from {first} on were being built: "
                f"{len(unfinished)} batches of {len(batches)} unfinished",
            ) from e
        finally:
            for future in pending:
                future.cancel()
    return features
