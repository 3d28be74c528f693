"""Every node's view encodings built by a local pool of worker processes, for maps too big to build in one process.

The pool is loky's reusable executor (:func:`loky.get_reusable_executor`, the one joblib runs on): its workers are
fresh interpreters started by fork + exec (safe wherever torch, OpenCV or threads are loaded) that do not import the
parent's ``__main__``, so a script without an ``if __name__ == "__main__":`` guard is not run again in every worker.
What is CampusNav's is only what the workers do (:mod:`campusnav_env.features.view_worker`: one torch thread each, the
renderer and the encoder built once per worker, the serial build's batches) and how failures read:

- a failing node stops the build at once (the other workers are killed) with a :class:`ViewBuildError` that names it,
  the worker's traceback attached as its ``__cause__``;
- a worker that dies (killed, out of memory) with one naming the first node left unbuilt and its exit status;
- a worker that cannot start (an import error, an object it cannot unpickle) with one giving the cause, and a build
  whose first batch does not finish within ``start_timeout`` seconds with one saying so (the workers' stderr is the
  parent's, so what they printed is on screen).

:func:`encode_batches_in_workers` yields each batch as it finishes (a
:data:`~campusnav_env.features.feature_cache.BatchBuild`), which the cache stores as a shard, so a build killed half
way resumes there; :func:`encode_views_in_workers` returns the whole array.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, wait

import numpy as np
from loky import get_reusable_executor
from loky.process_executor import BrokenProcessPool

from campusnav_env.features.encoders import ViewEncoder
from campusnav_env.features.feature_cache import collect_batches, node_batches
from campusnav_env.features.view_worker import (
    NodeRenderer,
    ViewBuildError,
    WorkerStartError,
    default_workers,
    encode_in_process,
    pickle_for_workers,
    start_process,
)

__all__ = [
    "DEFAULT_START_TIMEOUT",
    "NodeRenderer",
    "ViewBuildError",
    "check_workers",
    "default_workers",
    "encode_batches_in_workers",
    "encode_views_in_workers",
    "pickle_for_workers",
    "stop_workers",
]

logger = logging.getLogger(__name__)

# Seconds from the start of a build to its first finished batch: importing torch and unpickling a large city's world
# take seconds, tens of them on a loaded machine; beyond this a worker hangs or waits for something that never comes.
DEFAULT_START_TIMEOUT = 300.0
# Seconds idle workers wait for another build with the same renderer and encoder before they exit (and free the world)
_IDLE_TIMEOUT = 30  # (said in stop_workers' docstring)
# For the libraries that read them at import, before the worker sets its thread counts
_ONE_THREAD_ENV = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
# loky's report of a dead worker ends with its exit code, e.g. "{EXIT(3)}" or "{SIGKILL(-9)}"
_EXIT_CODE = re.compile(r"\{(\w+)\((-?\d+)\)")


def check_workers(workers: object, *, allow_none: bool = False) -> None:
    """
    Refuse a worker count that is not an int >= 1 (or None where ``allow_none``).

    :raises ValueError: saying what was given
    """
    if workers is None and allow_none:
        return
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be an int >= 1{' or None' if allow_none else ''}, got {workers!r}")


def _died(error: BrokenProcessPool, unbuilt: Sequence[range]) -> ViewBuildError:
    """The error for a worker that died: the first node left unbuilt, and how it ended."""
    match = _EXIT_CODE.search(str(error))
    if match is None:
        status = f"ended ({error})"
    elif int(match[2]) < 0:
        status = f"was killed by signal {-int(match[2])} ({match[1]})"
    else:
        status = f"exited with status {match[2]}"
    first = f" while building nodes from {unbuilt[0].start} on" if unbuilt else ""
    return ViewBuildError(
        [node for nodes in unbuilt for node in nodes],
        f"a view-build worker died{first} (killed or out of memory?): it {status}",
    )


def encode_batches_in_workers(
    batches: Sequence[range],
    make_renderer: Callable[[], NodeRenderer],
    encoder: ViewEncoder,
    *,
    workers: int,
    start_timeout: float = DEFAULT_START_TIMEOUT,
) -> Iterator[tuple[range, np.ndarray]]:
    """
    Render and encode ``batches`` of nodes in ``workers`` processes, yielding each as it finishes.

    :param batches: The batches (of :func:`~campusnav_env.features.feature_cache.node_batches`)
    :param make_renderer: Picklable factory of the renderer, called once in each worker (e.g.
        ``functools.partial(StreetViewRenderer, world, settings)``: the world is pickled once, not rebuilt); not
        defined in ``__main__``
    :param encoder: Picklable encoder, copied to each worker; its class not defined in ``__main__``
    :param workers: Number of worker processes (at most one per batch is started)
    :param start_timeout: Seconds the first batch may take to finish (workers import, unpickle, build the renderer)
    :return: ``(nodes, encodings)`` pairs, in the order they finish
    :raises ViewBuildError: a node failed (its id in the message and in ``.nodes``), or a worker did not start or
        died (the unbuilt nodes in ``.nodes``)
    :raises ValueError: ``workers`` < 1 or ``start_timeout`` <= 0
    :raises TypeError: the renderer factory or the encoder cannot be pickled, or is defined in ``__main__``
    """
    check_workers(workers)
    if not start_timeout > 0:
        raise ValueError(f"start_timeout must be a number of seconds > 0, got {start_timeout!r}")
    payload = pickle_for_workers((make_renderer, encoder))  # before any worker starts: a TypeError is the caller's
    return _run_pool(list(batches), payload, workers, start_timeout)


def _run_pool(
    batches: list[range], payload: bytes, workers: int, start_timeout: float
) -> Iterator[tuple[range, np.ndarray]]:
    if not batches:
        return
    executor = get_reusable_executor(
        max_workers=min(workers, len(batches)),
        timeout=_IDLE_TIMEOUT,
        initializer=start_process,
        initargs=(payload,),
        env=_ONE_THREAD_ENV,
    )
    logger.info(
        "building the views of %d nodes in %d worker processes (loky)",
        sum(map(len, batches)),
        min(workers, len(batches)),
    )
    futures: dict[Future[np.ndarray], range] = {executor.submit(encode_in_process, nodes): nodes for nodes in batches}
    pending = set(futures)
    yielded: set[range] = set()
    finished = False
    try:
        first = True
        while pending:
            done, pending = wait(pending, timeout=start_timeout if first else None, return_when=FIRST_COMPLETED)
            if not done:
                raise ViewBuildError(
                    [node for nodes in batches for node in nodes],
                    f"the view-build workers did not start within {start_timeout:g} s (no batch finished; "
                    "what they printed is on stderr)",
                )
            first = False
            for future in sorted(done, key=lambda f: futures[f].start):
                nodes = futures[future]
                try:
                    encoded = future.result()
                except WorkerStartError as e:
                    unbuilt = [node for nodes in batches for node in nodes]
                    raise ViewBuildError(unbuilt, str(e)) from e.__cause__
                except BrokenProcessPool as e:  # TerminatedWorkerError: a worker died
                    raise _died(e, [nodes for nodes in batches if nodes not in yielded]) from e
                yielded.add(nodes)
                yield nodes, encoded
        finished = True
    finally:
        if not finished:  # a failure, or the consumer stopped: stop the other workers at once
            executor.shutdown(wait=True, kill_workers=True)


def stop_workers() -> None:
    """Stop the pool's idle workers now, freeing their worlds (else they exit after 30 idle seconds by themselves)."""
    # A new executor replaces the reusable one, which is shut down; the new one starts no process until used
    get_reusable_executor(max_workers=1, reuse=False).shutdown(wait=True)


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
    Render and encode the four views of nodes ``0 .. n_nodes - 1`` in ``workers`` processes (not cached, not
    resumable: :func:`~campusnav_env.features.feature_cache.cached_batched_features` with
    :func:`encode_batches_in_workers` is).

    :param n_nodes: Number of nodes
    :param make_renderer: As for :func:`encode_batches_in_workers`
    :param encoder: As for :func:`encode_batches_in_workers`
    :param workers: As for :func:`encode_batches_in_workers`
    :param progress: Show a tqdm progress bar, advanced as each batch finishes
    :param start_timeout: As for :func:`encode_batches_in_workers`
    :return: ``(n_nodes, 4, *encoder.output_shape)`` array of dtype ``encoder.dtype``
    :raises ViewBuildError: As for :func:`encode_batches_in_workers`
    """
    batches = encode_batches_in_workers(
        node_batches(n_nodes), make_renderer, encoder, workers=workers, start_timeout=start_timeout
    )
    return collect_batches(n_nodes, encoder, batches, progress)
