"""A view-build worker: what it is sent, what it does with it, and how it fails.

A worker (a process of the local pool, :mod:`campusnav_env.features.parallel_build`, or a Ray actor,
:mod:`campusnav_env.features.ray_build`) is sent the renderer factory and the encoder once, pickled by
:func:`pickle_for_workers`, and builds a :class:`BatchWorker` from them: one torch thread and one OpenCV thread (so
``n`` workers use ``n`` cores instead of oversubscribing them), the renderer built once (the 3D world is built by the
caller and copied, not rebuilt), then batch after batch rendered and encoded with the serial build's pieces
(:func:`~campusnav_env.features.feature_cache.render_nodes`,
:func:`~campusnav_env.features.feature_cache.encode_nodes`), so that a batch's encodings are those of the serial
build up to the float rounding of another thread count.

Workers never import the running script (neither the pool's nor Ray's do), so classes and functions defined in it
cannot reach them: :func:`pickle_for_workers` refuses them with a :class:`TypeError` that says so, before any worker
starts.
"""

from __future__ import annotations

import io
import os
import pickle
import types
from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

from campusnav_env.features.encoders import ViewEncoder
from campusnav_env.features.feature_cache import encode_nodes, render_nodes

__all__ = [
    "BatchWorker",
    "NodeRenderer",
    "ViewBuildError",
    "WorkerStartError",
    "default_workers",
    "encode_in_process",
    "pickle_for_workers",
    "start_process",
]

# The names under which the running script's classes and functions live
_SCRIPT_MODULES = frozenset({"__main__", "__mp_main__"})


class NodeRenderer(Protocol):
    """What a worker renders with (e.g. :class:`~campusnav_env.rendering.street_view.StreetViewRenderer`)."""

    def render_node(self, node: int) -> np.ndarray:
        """``(4, H, W, 3)`` uint8 views of ``node`` in N, E, S, W order."""


class ViewBuildError(RuntimeError):
    """
    A node's views could not be rendered or encoded in a worker, or a worker did not start or died.

    :param nodes: The node that failed (or the nodes left unbuilt, where the failure is not one node's)
    :param message: What went wrong
    """

    def __init__(self, nodes: Sequence[int], message: str) -> None:
        super().__init__(message)
        self.nodes = tuple(int(node) for node in nodes)

    def __reduce__(self) -> tuple[Any, ...]:  # RuntimeError pickles only its message; the parent needs the nodes too
        return type(self), (self.nodes, str(self))


class WorkerStartError(ViewBuildError):
    """A worker could not build its renderer or encoder (the parent names the nodes left unbuilt)."""


def default_workers() -> int:
    """The cores this process may run on (``os.sched_getaffinity``; ``os.cpu_count()`` where that is missing)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


class _NoMainPickler(pickle.Pickler):
    """A pickler that refuses classes and functions of ``__main__``: a worker does not import the running script."""

    def reducer_override(self, obj: Any) -> Any:
        # __mp_main__: the script as multiprocessing's spawn re-imports it, in a process that calls this one
        if isinstance(obj, (type, types.FunctionType)) and getattr(obj, "__module__", None) in _SCRIPT_MODULES:
            raise TypeError(
                f"{obj.__qualname__} is defined in the script being run ({obj.__module__}), which view-build workers "
                "do not import: define it in a module of its own and import it from there, or build in this process "
                "(ViewBuild(workers=1))"
            )
        return NotImplemented


def pickle_for_workers(obj: object) -> bytes:
    """
    Pickle ``obj`` as it is sent to the workers.

    :param obj: The object (e.g. ``(make_renderer, encoder)``)
    :return: Its pickle
    :raises TypeError: if it cannot be pickled, or holds a class or function defined in ``__main__``
    """
    buffer = io.BytesIO()
    try:
        _NoMainPickler(buffer, protocol=pickle.HIGHEST_PROTOCOL).dump(obj)
    except TypeError:
        raise
    except Exception as e:  # PicklingError, AttributeError (local objects), ...
        raise TypeError(f"the renderer and encoder must be picklable to build views in workers: {e}") from e
    return buffer.getvalue()


def _one_thread() -> None:
    """One torch thread and one OpenCV thread in this worker: ``n`` workers then use ``n`` cores."""
    import cv2
    import torch

    torch.set_num_threads(1)
    cv2.setNumThreads(1)


class BatchWorker:
    """
    A worker's renderer and encoder, built from the parent's payload by its first batch (so that a failure to build
    them reaches the parent as that batch's error), and the batches it renders and encodes.

    :param payload: ``pickle_for_workers((make_renderer, encoder))``
    """

    def __init__(self, payload: bytes) -> None:
        _one_thread()
        self._payload = payload
        self._built: tuple[NodeRenderer, ViewEncoder] | None = None

    def _build(self) -> tuple[NodeRenderer, ViewEncoder]:
        """The renderer and the encoder, built once; a Ray actor also moves the encoder to its GPU here."""
        make_renderer, encoder = pickle.loads(self._payload)
        return make_renderer(), encoder

    def encode(self, nodes: range) -> np.ndarray:
        """
        Render and encode one batch of nodes.

        :param nodes: The batch
        :return: ``(len(nodes), 4, *encoder.output_shape)``
        :raises WorkerStartError: if the payload cannot be unpickled or the renderer cannot be built (the cause in the
            message)
        :raises ViewBuildError: naming the node whose rendering failed, or the batch whose encoding failed
        """
        if self._built is None:
            try:
                self._built = self._build()
            except Exception as e:
                raise WorkerStartError(
                    (), f"a view-build worker could not start: pid {os.getpid()}: {type(e).__name__}: {e}"
                ) from e
        renderer, encoder = self._built
        views = []
        for node in nodes:
            try:
                views.append(render_nodes([node], renderer.render_node))
            except Exception as e:
                raise ViewBuildError([node], f"node {node}: rendering its views failed: {type(e).__name__}: {e}") from e
        try:
            return encode_nodes(np.concatenate(views), encoder)
        except Exception as e:
            raise ViewBuildError(
                nodes, f"nodes {nodes.start}-{nodes.stop - 1}: encoding their views failed: {type(e).__name__}: {e}"
            ) from e


# --- a process of the local pool: the payload arrives when the process starts ---------------------------------------

_WORKER: BatchWorker | None = None


def start_process(payload: bytes) -> None:
    """The pool's initializer: this process's worker (it builds the renderer and encoder with its first batch)."""
    global _WORKER
    _WORKER = BatchWorker(payload)


def encode_in_process(nodes: range) -> np.ndarray:
    """A pool task: :meth:`BatchWorker.encode` with this process's worker."""
    assert _WORKER is not None, "start_process was not called in this process"
    return _WORKER.encode(nodes)
