"""Benchmark runs in parallel worker processes, one torch thread each.

Seeds, goals and agents are independent runs: :func:`run_in_workers` hands them to ``workers`` processes and yields
each result as it finishes (in completion order), so a benchmark can append it to its runs file at once and an
interrupted benchmark keeps what it finished. Every worker sets ``torch.set_num_threads(1)`` before its first run:
on a small machine two processes of one thread each beat one process of two threads by far (two threads under load
were measured 40x slower per Adam step here). ``workers=1`` runs everything in this process, one run after another.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any, TypeVar

Job = TypeVar("Job")
Result = TypeVar("Result")


def _init_worker() -> None:
    # The jobs' functions unpickle from the benchmarks package by name: a spawned child has its parent's sys.path,
    # so it finds the package where the parent did (benchmarks/benchmarks.py for a script run as a file)
    import torch

    torch.set_num_threads(1)


def default_workers() -> int:
    """One worker per core this process may run on (at least one)."""
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)


def run_in_workers(function: Callable[[Job], Result], jobs: Sequence[Job], workers: int = 1) -> Iterator[Result]:
    """
    Run ``function(job)`` for every job, in ``workers`` processes, and yield the results as they finish.

    :param function: A module-level function (it is pickled to the workers by name)
    :param jobs: The jobs' arguments (picklable)
    :param workers: Worker processes; 1 runs the jobs here, one after another, in order
    :return: the results, in completion order (each result should say which job it belongs to)
    :raises ValueError: if ``workers`` is below 1
    """
    if workers < 1:
        raise ValueError(f"workers must be at least 1, got {workers}")
    if workers == 1 or len(jobs) <= 1:
        _init_worker()
        for job in jobs:
            yield function(job)
        return
    # spawn: a fresh interpreter per worker (fork would copy this process's torch thread pool and open files)
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=context, initializer=_init_worker) as pool:
        futures = [pool.submit(function, job) for job in jobs]
        for future in as_completed(futures):
            yield future.result()


def run_in_fresh_process(function: Callable[..., Result], *args: Any) -> Result:
    """
    Run ``function(*args)`` in a fresh spawned process of one torch thread and return its result: what it allocates
    (its peak memory included) is its own, and nothing of it stays in this process.
    """
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(1, mp_context=context, initializer=_init_worker) as pool:
        return pool.submit(function, *args).result()


def workers_argument(parser: Any, default: int | None = 1) -> None:
    """Add ``--workers`` to a benchmark's argument parser (``default=None``: one worker per core)."""
    parser.add_argument(
        "--workers",
        type=int,
        default=default_workers() if default is None else default,
        help=f"worker processes, one torch thread each (this machine has {default_workers()} cores); 1: in process",
    )
