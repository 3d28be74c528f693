"""Every node's view encodings built by worker processes, for maps too big to render and encode in one process.

:func:`encode_views_in_workers` splits the nodes into the batches of the serial build
(:func:`~campusnav_env.features.feature_cache.node_batches`, 8 nodes = 32 views) and hands them to ``workers``
processes. Each worker is a fresh interpreter running ``python -m campusnav_env.features.view_worker`` (started by
:mod:`subprocess`, safe wherever torch, OpenCV or threads are loaded), which talks to the parent over its stdin and
stdout. Unlike :mod:`multiprocessing`'s ``spawn`` and ``forkserver`` methods, it never imports the parent's
``__main__``: a script without an ``if __name__ == "__main__":`` guard is not run again in every worker (which there
built the env again and waited for the feature cache its parent was building). Objects defined in the running script
cannot reach the workers for the same reason, and are refused with a :class:`TypeError` that says so.

Each worker runs one torch thread and one OpenCV thread (so ``workers`` processes use ``workers`` cores instead of
oversubscribing them) and receives the renderer factory and the encoder pickled once by the parent: the 3D world is
built once, by the caller, and each worker builds its own renderer from it. Workers render and encode with the serial
build's pieces (:func:`~campusnav_env.features.feature_cache.render_nodes`,
:func:`~campusnav_env.features.feature_cache.encode_nodes`), so on one thread a batch's encodings are those of the
serial build (up to the float rounding of a different thread count). The parent fills the array and advances the
progress bar as each batch finishes; storing the array is the caller's (the cache's) job.

A failing node stops the build at once with a :class:`ViewBuildError` that names it (the worker's traceback
attached); a worker that dies (killed, out of memory) with one naming the nodes it was building and its exit status;
a worker that cannot start (an import error, an object it cannot unpickle) or does not start within
``start_timeout`` seconds with one giving the cause and the end of the worker's stderr.
"""

from __future__ import annotations

import collections
import collections.abc
import contextlib
import dataclasses
import logging
import os
import pickle
import queue
import struct
import subprocess
import sys
import threading
import time
import traceback
import types
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import IO, Any, Protocol

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

__all__ = [
    "DEFAULT_START_TIMEOUT",
    "WORKER_MODULE",
    "NodeRenderer",
    "ViewBuildError",
    "default_workers",
    "encode_views_in_workers",
    "pickle_for_workers",
]

logger = logging.getLogger(__name__)

WORKER_MODULE = "campusnav_env.features.view_worker"
# Seconds a worker may take from its start to taking its first batch: importing torch and unpickling a large city's
# world take seconds, tens of them on a loaded machine; beyond this it hangs or waits for something that never comes.
DEFAULT_START_TIMEOUT = 300.0
# Batches handed to a worker ahead of its results, so that it never idles while the parent answers
_BATCHES_AHEAD = 2
# Lines of a worker's stderr kept for the error message when it fails to start or dies
_STDERR_TAIL = 20
# The names under which the running script's classes and functions live
_SCRIPT_MODULES = frozenset({"__main__", "__mp_main__"})
# Frames on the pipes: an 8-byte little-endian length, then a pickle
_LENGTH = struct.Struct("<Q")


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


class _WorkerTraceback(Exception):
    """The traceback of an exception raised in a worker, attached as the ``__cause__`` of the parent's error."""

    def __str__(self) -> str:
        return "\n\n" + str(self.args[0])


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
                f"{obj.__qualname__} is defined in the script being run ({obj.__module__}), which view-build worker "
                "processes do not import: define it in a module of its own and import it from there, or build in "
                "this process (build_workers=1 / workers=1)"
            )
        return NotImplemented


def pickle_for_workers(obj: object) -> bytes:
    """
    Pickle ``obj`` as it is sent to the workers.

    :param obj: The object (e.g. ``(make_renderer, encoder)``)
    :return: Its pickle
    :raises TypeError: if it cannot be pickled, or holds a class or function defined in ``__main__``
    """
    import io

    buffer = io.BytesIO()
    try:
        _NoMainPickler(buffer, protocol=pickle.HIGHEST_PROTOCOL).dump(obj)
    except TypeError:
        raise
    except Exception as e:  # PicklingError, AttributeError (local objects), ...
        raise TypeError(f"the renderer and encoder must be picklable to build views in workers: {e}") from e
    return buffer.getvalue()


# --- the pipe protocol ---------------------------------------------------------------------------------------------


def _write_frame(stream: IO[bytes], message: object) -> None:
    data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(_LENGTH.pack(len(data)))
    stream.write(data)
    stream.flush()


def _read_frame(stream: IO[bytes]) -> Any:
    """Read one message; raise EOFError at the end of the stream (the other side exited or closed it)."""
    header = stream.read(_LENGTH.size)
    if len(header) < _LENGTH.size:
        raise EOFError("pipe closed")
    (length,) = _LENGTH.unpack(header)
    data = stream.read(length)
    if len(data) < length:
        raise EOFError("pipe closed mid-message")
    return pickle.loads(data)


# --- the worker's side ---------------------------------------------------------------------------------------------

# The worker's renderer and encoder, set once by _start_worker
_WORKER: tuple[NodeRenderer, ViewEncoder] | None = None


def _start_worker(payload: bytes) -> None:
    """One thread for torch and OpenCV, then the renderer and the encoder from the parent."""
    import cv2
    import torch

    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    global _WORKER
    make_renderer, encoder = pickle.loads(payload)
    _WORKER = (make_renderer(), encoder)


def _encode_batch(nodes: range) -> np.ndarray:
    """Render and encode one batch of nodes; failures name the node (or the batch, for the encoder)."""
    assert _WORKER is not None, "worker not started"
    renderer, encoder = _WORKER
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


def _portable(error: BaseException) -> BaseException | None:
    """The exception itself if the parent can unpickle it, else None (the parent then reports its text)."""
    try:
        pickle.loads(pickle.dumps(error))
    except Exception:
        return None
    return error


def serve_worker() -> int:
    """
    The worker process's main loop (``python -m campusnav_env.features.view_worker``): read ``("start", sys.path,
    payload)`` from stdin, answer ``("ready", pid)``, then answer each ``("batch", start, stop)`` with ``("done",
    start, stop, encodings)``; any failure is answered with ``("failed", (start, stop) or None, exception or None,
    text, traceback)`` and ends the worker. The end of stdin (the parent closed it, or died) ends it too.

    :return: The exit status: 0 after the end of stdin, 1 after a failure
    """
    channel_in = sys.stdin.buffer
    # The protocol owns the real stdout; print() in a renderer or an encoder goes to stderr instead of into it
    channel_out = os.fdopen(os.dup(sys.stdout.fileno()), "wb")
    sys.stdout.flush()
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    sys.stdin = open(os.devnull)  # noqa: SIM115 (lives as long as the process)

    def fail(nodes: range | None, error: BaseException) -> int:
        text = f"{type(error).__name__}: {error}"
        _write_frame(channel_out, ("failed", nodes, _portable(error), text, traceback.format_exc()))
        return 1

    try:
        kind, sys_path, payload = _read_frame(channel_in)
    except EOFError:
        return 0
    assert kind == "start", kind
    try:
        sys.path[:] = sys_path  # import what the parent imports, from where it imports it (but not its __main__)
        _start_worker(payload)
    except Exception as e:
        return fail(None, e)
    _write_frame(channel_out, ("ready", os.getpid()))
    while True:
        try:
            kind, start, stop = _read_frame(channel_in)
        except EOFError:
            return 0
        nodes = range(start, stop)
        try:
            encoded = _encode_batch(nodes)
        except Exception as e:
            return fail(nodes, e)
        _write_frame(channel_out, ("done", start, stop, encoded))


# --- the parent's side ---------------------------------------------------------------------------------------------


@dataclasses.dataclass
class _Worker:
    """A worker process and the threads that feed and read its pipes."""

    process: subprocess.Popen[bytes]
    ready: bool = False
    batches: list[range] = dataclasses.field(default_factory=list)  # handed to it, not finished
    stderr_tail: collections.deque[str] = dataclasses.field(
        default_factory=lambda: collections.deque(maxlen=_STDERR_TAIL)
    )
    threads: list[threading.Thread] = dataclasses.field(default_factory=list)

    @property
    def pid(self) -> int:
        return self.process.pid

    def stderr_text(self) -> str:
        """The end of the worker's stderr, for error messages."""
        for thread in self.threads[2:]:  # the stderr reader: wait briefly for the last lines of a worker that exited
            thread.join(timeout=2)
        tail = "".join(self.stderr_tail).strip()
        return (
            f"; the stderr of pid {self.pid} ended with:\n{tail}"
            if tail
            else f"; pid {self.pid} wrote nothing to stderr"
        )

    def send_batch(self, nodes: range) -> None:
        assert self.process.stdin is not None
        self.batches.append(nodes)
        # A worker that died meanwhile is reported by its reader thread, with its exit status and stderr
        with contextlib.suppress(OSError):
            _write_frame(self.process.stdin, ("batch", nodes.start, nodes.stop))


def _worker_environment() -> dict[str, str]:
    """The worker's environment: this package importable first, one thread for the libraries that read it at import."""
    env = dict(os.environ)
    package_root = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = os.pathsep.join([package_root, *filter(None, [env.get("PYTHONPATH")])])
    for variable in ("OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env[variable] = "1"
    return env


def _start_process(index: int, start_message: bytes, events: queue.Queue[tuple[_Worker, Any]]) -> _Worker:
    """Start one worker; its threads send it the start message and post its messages (None: it exited) to events."""
    process = subprocess.Popen(
        [sys.executable, "-m", WORKER_MODULE],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=_worker_environment(),
    )
    worker = _Worker(process)
    stdin, stdout, stderr = process.stdin, process.stdout, process.stderr
    assert stdin is not None and stdout is not None and stderr is not None

    def feed() -> None:  # in a thread: a worker that never reads must not block the parent (it is timed out instead)
        with contextlib.suppress(OSError, ValueError):  # the worker died or was killed meanwhile
            stdin.write(start_message)
            stdin.flush()

    def read_messages() -> None:
        try:
            while True:
                events.put((worker, _read_frame(stdout)))
        except Exception:  # EOFError, or a garbled pipe: either way nothing more comes from this worker
            events.put((worker, None))

    def read_stderr() -> None:
        for line in iter(stderr.readline, b""):
            text = line.decode(errors="replace")
            worker.stderr_tail.append(text)
            with contextlib.suppress(Exception):  # the parent's stderr may be closed; the tail is kept regardless
                sys.stderr.write(text)

    for target in (feed, read_messages, read_stderr):
        thread = threading.Thread(target=target, name=f"view-worker-{index}-{target.__name__}", daemon=True)
        thread.start()
        worker.threads.append(thread)
    return worker


def _stop(workers: Sequence[_Worker], *, kill: bool) -> None:
    """End the workers: close their stdin (they exit), or kill them; reap them either way."""
    for worker in workers:
        if kill:
            with contextlib.suppress(OSError):
                worker.process.kill()
        with contextlib.suppress(OSError, ValueError):
            assert worker.process.stdin is not None
            worker.process.stdin.close()
    for worker in workers:
        try:
            worker.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            worker.process.kill()
            worker.process.wait()
        for thread in worker.threads:
            thread.join(timeout=2)
        for stream in (worker.process.stdout, worker.process.stderr):
            with contextlib.suppress(OSError):
                assert stream is not None
                stream.close()


def _unbuilt(batches: collections.abc.Iterable[range]) -> list[int]:
    return [node for nodes in batches for node in nodes]


def _exited_error(worker: _Worker, todo: Sequence[range]) -> ViewBuildError:
    """The error for a worker whose pipe closed before the build finished: it exited or was killed."""
    try:
        returncode: int | None = worker.process.wait(timeout=10)
    except subprocess.TimeoutExpired:
        returncode = None
    if returncode is None:
        status = "closed its pipe"
    elif returncode < 0:
        status = f"was killed by signal {-returncode}"
    else:
        status = f"exited with status {returncode}"
    if not worker.ready:
        return ViewBuildError(
            _unbuilt(todo), f"a view-build worker could not start: pid {worker.pid} {status}{worker.stderr_text()}"
        )
    building = f" while building nodes from {worker.batches[0].start} on" if worker.batches else ""
    return ViewBuildError(
        _unbuilt([*worker.batches, *todo]),
        f"a view-build worker died{building} (killed or out of memory?): pid {worker.pid} {status}"
        f"{worker.stderr_text()}",
    )


def encode_views_in_workers(
    n_nodes: int,
    make_renderer: Callable[[], NodeRenderer],
    encoder: ViewEncoder,
    *,
    workers: int,
    progress: bool = True,
    start_timeout: float = DEFAULT_START_TIMEOUT,
) -> np.ndarray:
    """
    Render and encode the four views of nodes ``0 .. n_nodes - 1`` in ``workers`` processes.

    :param n_nodes: Number of nodes
    :param make_renderer: Picklable factory of the renderer, called once in each worker (e.g.
        ``functools.partial(StreetViewRenderer, world, settings)``: the world is pickled once, not rebuilt); not
        defined in ``__main__``
    :param encoder: Picklable encoder, copied to each worker; its class not defined in ``__main__``
    :param workers: Number of worker processes (at most one per batch of nodes is started)
    :param progress: Show a tqdm progress bar, advanced as each batch finishes
    :param start_timeout: Seconds each worker may take to start (import, unpickle, build its renderer)
    :return: ``(n_nodes, 4, *encoder.output_shape)`` array of dtype ``encoder.dtype``
    :raises ViewBuildError: a node failed (its id in the message and in ``.nodes``), or a worker did not start or
        died (the unbuilt nodes in ``.nodes``)
    :raises ValueError: ``workers`` < 1 or ``start_timeout`` <= 0
    :raises TypeError: the renderer factory or the encoder cannot be pickled, or is defined in ``__main__``
    """
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be an int >= 1, got {workers!r}")
    if not start_timeout > 0:
        raise ValueError(f"start_timeout must be a number of seconds > 0, got {start_timeout!r}")
    payload = pickle_for_workers((make_renderer, encoder))
    start_data = pickle.dumps(("start", list(sys.path), payload), protocol=pickle.HIGHEST_PROTOCOL)
    start_message = _LENGTH.pack(len(start_data)) + start_data
    batches = node_batches(n_nodes)
    todo = collections.deque(batches)
    features = np.empty((n_nodes, VIEWS_PER_NODE, *encoder.output_shape), dtype=encoder.dtype)
    events: queue.Queue[tuple[_Worker, Any]] = queue.Queue()
    pool: list[_Worker] = []
    finished = 0
    failed = True
    try:
        for index in range(min(workers, len(batches))):
            pool.append(_start_process(index, start_message, events))
        logger.info(
            "building the views of %d nodes in %d worker processes (pids %s)",
            n_nodes,
            len(pool),
            ", ".join(str(worker.pid) for worker in pool),
        )
        start_deadline = time.monotonic() + start_timeout
        with tqdm(total=n_nodes, desc=progress_label(encoder), unit="node", disable=not progress) as bar:
            while finished < len(batches):
                waiting = [worker for worker in pool if not worker.ready]
                try:
                    worker, message = events.get(
                        timeout=max(0.0, start_deadline - time.monotonic()) if waiting else None
                    )
                except queue.Empty:
                    worker = waiting[0]
                    raise ViewBuildError(
                        _unbuilt(todo),
                        f"{len(waiting)} of {len(pool)} view-build workers did not start within {start_timeout:g} s "
                        f"(pids {', '.join(str(w.pid) for w in waiting)}){worker.stderr_text()}",
                    ) from None
                if message is None:
                    raise _exited_error(worker, todo)
                kind = message[0]
                if kind == "failed":
                    _, nodes, error, text, remote_traceback = message
                    cause = _WorkerTraceback(remote_traceback)
                    if isinstance(error, ViewBuildError):
                        raise error from cause
                    if nodes is None:
                        raise ViewBuildError(
                            _unbuilt(todo),
                            f"a view-build worker could not start: pid {worker.pid}: {text}",
                        ) from cause
                    raise ViewBuildError(nodes, f"nodes {nodes.start}-{nodes.stop - 1}: {text}") from cause
                if kind == "ready":
                    worker.ready = True
                elif kind == "done":
                    _, start, stop, encoded = message
                    worker.batches.remove(range(start, stop))
                    features[start:stop] = encoded
                    finished += 1
                    bar.update(stop - start)
                while worker.ready and todo and len(worker.batches) < _BATCHES_AHEAD:
                    worker.send_batch(todo.popleft())
        failed = False
    finally:
        _stop(pool, kill=failed)
    return features
