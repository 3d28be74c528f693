"""What the scale benchmarks share: the plan of a run, the generated maps, the two feature builds, and measuring the
time and peak memory of a block of code.

``scale.py`` runs the stages of :mod:`benchmarks.scale_stages` (replay, world build, feature transform, vector envs,
training; each in a fresh process) and writes ``results/scale.md``; ``scale_<stage>.py`` runs one of them alone.
"""

from __future__ import annotations

import gc
import math
import resource
import runpy
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

GOAL = "Dreese Lab"
WORLD_SEED = 0
EFFNET = "efficientnet-lite0"
PIXELS = "pixels"
FULL_VIEW = (640, 480)  # the default street views (RenderSettings())
SMALL_VIEW = (64, 48)  # the smoke runs' views (campusnav_runs.quick_env_kwargs)
EFFNET_DIM = 1280
VIEW_DIM = 64  # the shipped env_kwargs of CampusNav-v0
BUFFER_SIZE = 50_000  # the shipped buffer_size of CampusNav-v0
GAMMA = 0.95  # the shipped gamma of CampusNav-v0
MB = 1e6


@dataclass(frozen=True)
class Plan:
    """
    What one benchmark run measures.

    :param sizes: Intersections of the generated maps
    :param budgets: Training-time budget per size (seconds, evaluations excluded)
    :param eval_freq: Route evaluation every this many env steps, per size
    :param max_steps: Env-step cap per size
    :param extent: ``"scaled"`` (street density of the built-in campus) or ``"fixed"`` (2.5 km x 1.7 km)
    :param effnet_max_nodes: Largest map encoded in full with EfficientNet-Lite0 (larger: sampled, extrapolated)
    :param effnet_sample: Nodes rendered and encoded with EfficientNet-Lite0 to extrapolate a larger map
    :param vec_counts: Numbers of envs in the vector-env comparison
    :param vec_seconds: Seconds of stepping per vector-env configuration
    :param env_steps: Random env steps timed per size
    :param quick: A smoke run (pixel features everywhere, tiny budgets)
    :param cache_dir: The benchmark's own feature cache folder (its cold builds delete their files there)
    :param seed: Seed of the agents and of the random actions
    """

    sizes: tuple[int, ...]
    budgets: dict[int, float]
    eval_freq: dict[int, int]
    max_steps: dict[int, int]
    extent: str = "scaled"
    effnet_max_nodes: int = 1000
    effnet_sample: int = 32
    vec_counts: tuple[int, ...] = (1, 2, 4)
    vec_seconds: float = 4.0
    env_steps: int = 5_000
    quick: bool = False
    cache_dir: str = ""
    seed: int = 0

    def train_encoder(self, n_nodes: int) -> str:
        """The features the training at ``n_nodes`` uses: the full EfficientNet build if there is one."""
        return EFFNET if n_nodes <= self.effnet_max_nodes and not self.quick else PIXELS


def env_kwargs_for(encoder: str) -> dict[str, Any]:
    """The env arguments that select one of the two feature builds (EfficientNet on full views, pixels on small)."""
    from campusnav_env.features.view_build import ViewBuild
    from campusnav_env.rendering.street_view import RenderSettings

    if encoder == EFFNET:
        return {"encoder": EFFNET, "view_build": ViewBuild(render_settings=RenderSettings(*FULL_VIEW))}
    return {"encoder": PIXELS, "view_build": ViewBuild(render_settings=RenderSettings(*SMALL_VIEW))}


def make_graph(n_nodes: int, extent: str) -> Any:
    """
    The generated campus of ``n_nodes`` intersections (seed 0). ``extent="scaled"``: the street density of the
    built-in campus at every size (:func:`campusnav_env.maps.campus.generate_city`; 101 nodes: exactly the built-in
    campus); ``"fixed"``: 2.5 km x 1.7 km at every size (10,000 intersections then lie about 20 m apart, less than
    the 21 m a road, its verges and sidewalks take).
    """
    from campusnav_env.maps.campus import generate_campus, generate_city

    return generate_city(n_nodes, seed=0) if extent == "scaled" else generate_campus(n_nodes, seed=0)


def buffer_arrays(buffer: Any) -> dict[str, int]:
    """
    Bytes of every per-transition array of a replay buffer (dicts of arrays by key), by attribute name; a lean
    buffer's observation table counts its row indices (its distinct rows are not per transition).
    """
    from sb3_dcqn.observation_table import ObservationTable

    arrays: dict[str, int] = {}
    for name, value in vars(buffer).items():
        items = value.items() if isinstance(value, dict) else [(None, value)]
        for key, array in items:
            label = name if key is None else f"{name}[{key}]"
            if isinstance(array, ObservationTable):
                arrays[label] = array.index_nbytes
            elif isinstance(array, np.ndarray) and array.ndim and array.shape[0] == buffer.buffer_size:
                arrays[label] = int(array.nbytes)
    return arrays


# ------------------------------------------------------------------------------------------------ time and memory
def _status_kb(field_name: str) -> float | None:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(field_name + ":"):
                return float(line.split()[1])
    except OSError:
        pass
    return None


def rss_mb() -> float:
    """Resident memory now (MB); the process's peak where /proc is missing."""
    kb = _status_kb("VmRSS")
    return (kb if kb is not None else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024 / MB


@dataclass
class Peak:
    """Peak resident memory of a block of code: ``start_mb`` when it began, ``peak_mb`` its highest (MB)."""

    start_mb: float = 0.0
    peak_mb: float = 0.0
    method: str = "VmHWM"

    @property
    def extra_mb(self) -> float:
        return max(self.peak_mb - self.start_mb, 0.0)


@contextmanager
def peak_memory() -> Iterator[Peak]:
    """
    Measure a block's peak RSS: Linux resets the process's high-water mark (``VmHWM``) on writing 5 to
    ``/proc/self/clear_refs``; elsewhere the process's lifetime peak (``ru_maxrss``) is all there is.
    """
    gc.collect()
    peak = Peak()
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        peak.method = "ru_maxrss (process lifetime)"
    peak.start_mb = rss_mb()
    try:
        yield peak
    finally:
        hwm = _status_kb("VmHWM") if peak.method == "VmHWM" else None
        kb = hwm if hwm is not None else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        peak.peak_mb = kb * 1024 / MB


def seconds_per_call(function: Callable[[], Any], repeats: int) -> float:
    """Seconds per call, after one warm-up call."""
    function()
    start = time.perf_counter()
    for _ in range(repeats):
        function()
    return (time.perf_counter() - start) / repeats


# ------------------------------------------------------------------------------------------------------ the report
def fmt(value: float | None, digits: int = 1) -> str:
    """A table cell: the number with thousands separators, ``-`` where there is none."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:,.{digits}f}"


def records_by_size(runs: list[dict[str, Any]], stage: str) -> dict[int, dict[str, Any]]:
    """One stage's records, by map size."""
    return {run["size"]: run for run in runs if run["stage"] == stage}


def run_scale(argv: list[str]) -> None:
    """
    Run ``scale.py``'s command line with ``argv``: how a stage script (``scale_replay.py``, ...) runs its stage alone.
    By module name, not by import: no benchmark script imports another.

    :param argv: The arguments after the script's name (``["--stages", STAGE, ...]``)
    """
    saved = sys.argv
    sys.argv = ["benchmarks/scale.py", *argv]
    try:
        runpy.run_module("benchmarks.scale", run_name="__main__", alter_sys=True)
    finally:
        sys.argv = saved
