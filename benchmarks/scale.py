"""Scale: how the world build, the time to a solved map and memory grow with 101, 1,000 and 10,000 intersections.

Generated campuses (:func:`campusnav_env.maps.campus.generate_campus`, seed 0, goal Dreese Lab). By default the
extent grows with the map (``--extent scaled``: 2.5 km x 1.7 km times ``sqrt(n / 101)``), so that every size has the
street density of the built-in campus (101 nodes: exactly the built-in campus); at a fixed extent (``--extent fixed``,
as ``campusnav_runs.Task``) 10,000 intersections lie about 20 m apart, less than the 21 m that a road, its verges and
sidewalks take, and the street views no longer show a town.

Stages, each in a fresh process (spawned; 1 torch thread and 1 BLAS thread) so that its peak RSS is its own, each
finished stage appended to a JSON-lines runs file (an interrupted benchmark keeps them, a rerun skips them):

1. ``buffer``: replay-buffer bytes per transition of the Dict observation (the arrays of ``DCQNDictReplayBuffer``,
   ``nbytes / buffer_size``) at ``view_dim`` 64 and at full 1280-d features, and what storing (node, heading, goal)
   indices with a feature table looked up at sample time would take instead (computed and timed, not implemented).
2. ``build`` per size: map, 3D world, render + encode of every view into a cold feature cache, cache size on disk, env
   construction from the warm cache, peak RSS. EfficientNet-Lite0 (640x480 views, the default) up to
   ``--effnet-max-nodes``; above, its cost is measured on ``--effnet-sample`` nodes and extrapolated, and the map is
   built with the cheap ``"pixels"`` encoder on 64x48 views (every size gets a pixel build, for a like-for-like line).
3. ``fit`` per size: the env's feature transform (standardise, PCA to 64 per view) on 1280-d features of the size's
   view count (synthetic, CNN-like spectrum) with the code before and after the fix found here (see the results).
4. ``vecenv``: env steps/s on the 101-node campus with ``DummyVecEnv`` and ``SubprocVecEnv`` of 1, 2 and 4 envs
   (random actions), and the cost of one env step by part.
5. ``train`` per size: DCQN with the shipped ``CampusNav-v0`` settings until success >= 0.99 and SPL >= 0.98 from
   every (start, heading) (``campusnav_runs.train_until_solved``; time: training seconds, evaluations excluded) or the
   ``--budget``; env step and reset costs, evaluation time, peak RSS, replay-buffer bytes, a profile of one route
   evaluation. Features: those of the size's full EfficientNet build, else the pixel build.

Writes ``results/scale.md`` and ``results/scale.png`` (time and memory against intersections, log x).

Usage::

    python benchmarks/scale.py                                  # 101, 1000, 10000 intersections (about 20 minutes)
    python benchmarks/scale.py --budget 1000=600 10000=300      # more training time for the large maps
    python benchmarks/scale.py --quick --out /tmp/scale.md --runs-file /tmp/scale_runs.jsonl   # smoke run, ~1 min
"""

from __future__ import annotations

import argparse
import cProfile
import gc
import math
import os
import pstats
import resource
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from report import append_run, publish, read_runs
from workers import run_in_fresh_process

RESULTS_DIR = Path(__file__).resolve().parent / "results"
GOAL = "Dreese Lab"
WORLD_SEED = 0
CAMPUS_EXTENT = (2500.0, 1700.0)  # metres, the built-in campus (generate_campus's defaults)
EFFNET = "efficientnet-lite0"
PIXELS = "pixels"
FULL_VIEW = (640, 480)  # the default street views (RenderSettings())
SMALL_VIEW = (64, 48)  # the smoke runs' views (campusnav_runs.quick_env_kwargs)
EFFNET_DIM = 1280
VIEW_DIM = 64  # the shipped env_kwargs of CampusNav-v0
BUFFER_SIZE = 50_000  # the shipped buffer_size of CampusNav-v0
GAMMA = 0.95  # the shipped gamma of CampusNav-v0
MB = 1e6


# ------------------------------------------------------------------------------------------------------- the plan
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


def default_budget(n_nodes: int) -> float:
    """Training seconds per size: DCQN solved 500 nodes in a median 127 s (learning_speed.md)."""
    return 60.0 if n_nodes <= 200 else 420.0 if n_nodes <= 2_000 else 150.0


def default_eval_freq(n_nodes: int) -> int:
    """
    Env steps between route evaluations: one evaluation runs the greedy policy from all 4N (start, heading) pairs, so
    its cost grows with the map (measured: about 0.3 s at 1,000 nodes, several seconds at 10,000); sparser
    evaluations keep it a minor part of the wall time (at the price of a coarser time to threshold).
    """
    return 1_000 if n_nodes <= 200 else 5_000 if n_nodes <= 2_000 else 20_000


def env_kwargs_for(encoder: str) -> dict[str, Any]:
    """The env arguments that select one of this benchmark's feature builds."""
    from campusnav_env.rendering.street_view import RenderSettings

    if encoder == EFFNET:
        return {"encoder": EFFNET, "render_settings": RenderSettings(*FULL_VIEW)}
    return {"encoder": PIXELS, "render_settings": RenderSettings(*SMALL_VIEW)}


def make_graph(n_nodes: int, extent: str) -> Any:
    """The generated campus of ``n_nodes`` intersections (see the module docstring for ``extent``)."""
    from campusnav_env.maps.campus import generate_campus

    factor = math.sqrt(n_nodes / 101) if extent == "scaled" else 1.0
    width, height = CAMPUS_EXTENT
    return generate_campus(n_nodes, width=width * factor, height=height * factor, seed=0)


# -------------------------------------------------------------------------------------------------- measuring helpers
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


def _per_call(function: Callable[[], Any], repeats: int) -> float:
    """Seconds per call, after one warm-up call."""
    function()
    start = time.perf_counter()
    for _ in range(repeats):
        function()
    return (time.perf_counter() - start) / repeats


# ------------------------------------------------------------------------------------------------- 1. replay buffer
def _index_sample_seconds(table: np.ndarray, fill: int, rng: np.random.Generator) -> float:
    """Seconds to sample a batch of 64 from (node, heading, goal) index arrays and a feature table, as tensors."""
    import torch as th

    nodes, goals = rng.integers(0, table.shape[0], (2, fill)).astype(np.int32)
    headings = rng.integers(0, 4, fill).astype(np.int8)
    eye = np.eye(4, dtype=np.float32)

    def gather() -> None:
        picks = np.random.randint(0, fill, 64)
        for _ in range(2):  # the observation and the next one
            batch = {"views": table[nodes[picks]], "goal_views": table[goals[picks]], "heading": eye[headings[picks]]}
            {key: th.as_tensor(value) for key, value in batch.items()}

    return _per_call(gather, 300)


def buffer_arrays(buffer: Any) -> dict[str, int]:
    """Bytes of every per-transition array of a replay buffer (dicts of arrays by key), by attribute name."""
    arrays: dict[str, int] = {}
    for name, value in vars(buffer).items():
        items = value.items() if isinstance(value, dict) else [(None, value)]
        for key, array in items:
            if isinstance(array, np.ndarray) and array.ndim and array.shape[0] == buffer.buffer_size:
                arrays[name if key is None else f"{name}[{key}]"] = int(array.nbytes)
    return arrays


def measure_buffer(plan: Plan) -> dict[str, Any]:
    """
    Bytes per transition of the replay buffers at view_dim 64 and 1280: SB3's ``DictReplayBuffer`` (what DCQN uses
    as shipped) and ``DCQNDictReplayBuffer`` (experience revision or prioritised replay on), from their arrays; and
    what an index buffer would take instead.
    """
    from gymnasium import spaces
    from stable_baselines3.common.buffers import DictReplayBuffer

    from sb3_dcqn.buffers import DCQNDictReplayBuffer

    rows = []
    rng = np.random.default_rng(0)
    for cls, label in (
        (DictReplayBuffer, "DictReplayBuffer (shipped)"),
        (DCQNDictReplayBuffer, "DCQNDictReplayBuffer"),
    ):
        for dim in (VIEW_DIM, EFFNET_DIM):
            view = spaces.Box(-10.0, 10.0, shape=(4 * dim,), dtype=np.float32)
            heading = spaces.Box(0.0, 1.0, (4,), np.float32)
            space = spaces.Dict({"views": view, "goal_views": view, "heading": heading})
            # np.zeros reserves the arrays without touching their pages: nothing is allocated here
            buffer = cls(BUFFER_SIZE, space, spaces.Discrete(4), device="cpu", n_envs=1)
            per_transition = {name: nbytes / BUFFER_SIZE for name, nbytes in buffer_arrays(buffer).items()}
            # Instead: node and goal int32 and heading int8, for the observation and the next one, plus the same
            # action/reward/done/timeout (and priority) arrays; features from a (nodes, 4 * dim) table when sampled
            scalars = sum(b for name, b in per_transition.items() if "observations" not in name)
            row = {
                "buffer": label,
                "view_dim": dim,
                "per_transition": per_transition,
                "bytes_per_transition": sum(per_transition.values()),
                "index_bytes_per_transition": 2 * (4 + 1 + 4) + scalars,
                "table_bytes_per_node": 4 * dim * 4,
            }
            if cls is DictReplayBuffer:
                # Sample cost, batch 64: SB3's sample vs a gather from index arrays and a table (1,000 nodes)
                fill = 5_000
                small = cls(fill, space, spaces.Discrete(4), device="cpu", n_envs=1)
                for key in ("views", "goal_views"):
                    for store in (small.observations, small.next_observations):
                        store[key][:] = rng.standard_normal(store[key].shape, dtype=np.float32)
                small.full = True
                table = rng.standard_normal((1_000, 4 * dim), dtype=np.float32)
                row["sample_us"] = 1e6 * _per_call(lambda small=small: small.sample(64), 300)
                row["index_sample_us"] = 1e6 * _index_sample_seconds(table, fill, rng)
            rows.append(row)
    return {"stage": "buffer", "size": 0, "buffer_size": BUFFER_SIZE, "rows": rows}


# ------------------------------------------------------------------------------------------------------ 2. build
class _TimedEncoder:
    """Wraps a view encoder (same name, so the same cache entry) and counts the seconds spent encoding."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.name, self.output_shape, self.dtype = inner.name, inner.output_shape, inner.dtype
        self.seconds = 0.0

    def encode(self, images: np.ndarray) -> np.ndarray:
        start = time.perf_counter()
        out = self.inner.encode(images)
        self.seconds += time.perf_counter() - start
        return out


def _build_views(graph: Any, world: Any, encoder: str, full: bool, plan: Plan) -> dict[str, Any]:
    """Render and encode every view into a cold cache (``full``), or a sample of nodes to extrapolate from."""
    from campusnav_env.env import CampusNavEnv
    from campusnav_env.features.feature_cache import _VIEWS_PER_BATCH, cache_path, cached_view_features
    from campusnav_env.features.view_source import ViewSource
    from campusnav_env.rendering.street_view import StreetViewRenderer

    settings = env_kwargs_for(encoder)["render_settings"]
    n_nodes = graph.n_nodes
    start = time.perf_counter()
    source = ViewSource(graph, "features", encoder, None, settings, WORLD_SEED, plan.cache_dir, False)
    load_seconds = time.perf_counter() - start
    renderer = StreetViewRenderer(world, settings)
    timed = _TimedEncoder(source.encoder)
    render_seconds = 0.0

    def render(node: int) -> np.ndarray:
        nonlocal render_seconds
        begin = time.perf_counter()
        views = renderer.render_node(node)
        render_seconds += time.perf_counter() - begin
        return views

    record: dict[str, Any] = {"encoder": encoder, "view": f"{settings.width}x{settings.height}", "full": full}
    record["encoder_load_seconds"] = load_seconds
    features_bytes = 4 * n_nodes * int(np.prod(source.encoder.output_shape)) * np.dtype(source.encoder.dtype).itemsize
    with peak_memory() as peak:
        if full:
            path = cache_path(source.key_parts, n_nodes, source.encoder, cache_dir=plan.cache_dir)
            path.unlink(missing_ok=True)  # this benchmark's own cache folder: measure a cold build
            begin = time.perf_counter()
            cached_view_features(source.key_parts, n_nodes, render, timed, cache_dir=plan.cache_dir, progress=False)
            total = time.perf_counter() - begin
            nodes = n_nodes
            record["cache_bytes"] = path.stat().st_size
        else:
            # Spread over the map; encoded in the batches the cache uses (8 nodes, 32 views)
            sample = np.unique(np.linspace(0, n_nodes - 1, plan.effnet_sample).astype(int))
            per_batch = _VIEWS_PER_BATCH // 4
            source.encoder.encode(renderer.render_node(0))  # warm-up (first CNN call, first ground textures)
            for begin_index in range(0, sample.size, per_batch):
                batch = [render(int(node)) for node in sample[begin_index : begin_index + per_batch]]
                timed.encode(np.concatenate(batch))
            nodes = int(sample.size)
            total = None
            record["cache_bytes"] = features_bytes  # an uncompressed .npz: the array and a small header
    record |= {
        "nodes_measured": nodes,
        "render_s_per_node": render_seconds / nodes,
        "encode_s_per_view": timed.seconds / (4 * nodes),
        "peak_mb": peak.peak_mb,
        "extra_mb": peak.extra_mb,
    }
    # Measured for a full build (rendering, encoding, checks and the write), else rendering and encoding extrapolated
    record["build_seconds"] = (
        total if total is not None else n_nodes * (record["render_s_per_node"] + 4 * record["encode_s_per_view"])
    )
    if full:
        del renderer, timed
        gc.collect()
        with peak_memory() as env_peak:
            begin = time.perf_counter()
            env = CampusNavEnv(
                world=graph,
                goals=GOAL,
                view_dim=VIEW_DIM,
                cache_dir=plan.cache_dir,
                progress=False,
                **env_kwargs_for(encoder),
            )
            record["env_seconds"] = time.perf_counter() - begin
        record["env_extra_mb"], record["env_peak_mb"] = env_peak.extra_mb, env_peak.peak_mb
        del env
    return record


def measure_build(n_nodes: int, plan: Plan) -> dict[str, Any]:
    """Map, 3D world and every view rendered and encoded into a cold cache, for each encoder of this size."""
    from campusnav_env.maps.navigation import NavigationGraph
    from campusnav_env.rendering.world import build_world

    record: dict[str, Any] = {"stage": "build", "size": n_nodes, "extent": plan.extent, "import_rss_mb": rss_mb()}
    begin = time.perf_counter()
    graph = make_graph(n_nodes, plan.extent)
    record["map_seconds"] = time.perf_counter() - begin
    hops = NavigationGraph(graph).hops_to(graph.landmarks[GOAL])
    record |= {"states": int(graph.n_states), "roads": int(graph.n_roads), "longest_route": int(hops.max())}
    with peak_memory() as peak:
        begin = time.perf_counter()
        world = build_world(graph, seed=WORLD_SEED)
        record["world_seconds"] = time.perf_counter() - begin
    record |= {"world_extra_mb": peak.extra_mb, "world_peak_mb": peak.peak_mb, "buildings": len(world.buildings)}
    builds = [(PIXELS, True)]
    if not plan.quick and n_nodes <= plan.effnet_max_nodes:
        builds.append((EFFNET, True))
    else:
        builds.append((EFFNET, False))
    record["encoders"] = [_build_views(graph, world, encoder, full, plan) for encoder, full in builds]
    return record


def build_peak_mb(build: dict[str, Any]) -> tuple[float, bool]:
    """
    The build's peak RSS: the highest of its phases (each measured from a reset high-water mark, so the process's
    ``ru_maxrss`` only covers the last one). Returns the peak and whether it is exact: records without the world's
    absolute peak add its rise to the RSS after the imports (the map before it takes a few MB: a slight underestimate).
    """
    phases = [peak for enc in build["encoders"] for peak in (enc["peak_mb"], enc.get("env_peak_mb", 0.0))]
    if "world_peak_mb" in build:
        return max(build["world_peak_mb"], *phases), True
    return max(build["import_rss_mb"] + build["world_extra_mb"], *phases), False


# ------------------------------------------------------------------------------------------------ 3. feature fit
def _fit_transform_before(node_views: np.ndarray, view_dim: int) -> np.ndarray:
    """
    The env's feature transform as it was before this benchmark's fix (``FeatureTransform.fit`` and ``transform``
    at commit 7faab86): standardise with full-size temporaries, then a thin SVD of all views in float64.
    """
    views = node_views.astype(np.float32)
    flat = views.reshape(-1, views.shape[-1])
    mean, scale = flat.mean(axis=0), flat.std(axis=0) + 1e-6
    views = (views - mean) / scale
    flat64 = np.asarray(views, dtype=np.float64).reshape(-1, views.shape[-1])
    centre = flat64.mean(axis=0)
    _, s, vt = np.linalg.svd(flat64 - centre, full_matrices=False)
    axes = vt[:view_dim]
    axes = axes * np.sign(axes[np.arange(view_dim), np.abs(axes).argmax(axis=1)])[:, None]
    spread = np.maximum(s[:view_dim] / np.sqrt(max(flat64.shape[0] - 1, 1)), 1e-12)
    # transform(): the same views again, through float64 copies of the whole array
    views = (node_views.astype(np.float32) - mean) / scale
    flat64 = np.asarray(views, dtype=np.float64).reshape(-1, views.shape[-1])
    projected = ((flat64 - centre) @ axes.T) / spread
    return projected.reshape(node_views.shape[0], -1).astype(np.float32)


def synthetic_cnn_features(n_nodes: int, dim: int = EFFNET_DIM, seed: int = 0) -> np.ndarray:
    """``(n, 4, dim)`` float32 features with a CNN-like decaying spectrum (well separated leading axes)."""
    rng = np.random.default_rng(seed)
    rank = 96
    latent = rng.standard_normal((4 * n_nodes, rank), dtype=np.float32) * (0.93 ** np.arange(rank, dtype=np.float32))
    mixing = rng.standard_normal((rank, dim), dtype=np.float32)
    features = latent @ mixing
    features += 0.05 * rng.standard_normal(features.shape, dtype=np.float32)
    return np.maximum(features, 0.0).reshape(n_nodes, 4, dim)  # non-negative, like pooled activations


def measure_fit(n_nodes: int, plan: Plan) -> dict[str, Any]:
    """The env's feature transform on 1280-d features of ``n_nodes`` intersections, after and before the fix."""
    from campusnav_env.features.projection import FeatureTransform

    features = synthetic_cnn_features(n_nodes)
    record: dict[str, Any] = {"stage": "fit", "size": n_nodes, "views": 4 * n_nodes, "features": EFFNET_DIM}
    with peak_memory() as peak:
        begin = time.perf_counter()
        after = FeatureTransform.fit(features, "features", True, VIEW_DIM).transform(features)
        record["after_seconds"] = time.perf_counter() - begin
    record["after_extra_mb"] = peak.extra_mb
    with peak_memory() as peak:
        begin = time.perf_counter()
        before = _fit_transform_before(features, VIEW_DIM)
        record["before_seconds"] = time.perf_counter() - begin
    record |= {"before_extra_mb": peak.extra_mb, "input_mb": features.nbytes / MB, "memory_method": peak.method}
    record["max_difference"] = float(np.abs(after - before).max())
    record["identical"] = bool(np.array_equal(after, before))
    return record


# ------------------------------------------------------------------------------------------------- 4. vector envs
def _campus_env_factory(graph: Any, encoder: str, cache_dir: str) -> Callable[[], Any]:
    def make() -> Any:
        import torch

        from campusnav_env.env import CampusNavEnv

        torch.set_num_threads(1)
        return CampusNavEnv(
            world=graph, goals=GOAL, view_dim=VIEW_DIM, cache_dir=cache_dir, progress=False, **env_kwargs_for(encoder)
        )

    return make


def measure_vecenv(plan: Plan) -> dict[str, Any]:
    """Env steps/s with DummyVecEnv and SubprocVecEnv (random actions), and one env step's parts."""
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    n_nodes = plan.sizes[0]
    encoder = plan.train_encoder(n_nodes)
    make = _campus_env_factory(make_graph(n_nodes, plan.extent), encoder, plan.cache_dir)
    rng = np.random.default_rng(0)
    rows = []
    for kind, cls in (("DummyVecEnv", DummyVecEnv), ("SubprocVecEnv", SubprocVecEnv)):
        for count in plan.vec_counts:
            vec_env = cls([make] * count)
            vec_env.reset()
            for _ in range(50):  # warm up
                vec_env.step(rng.integers(0, 4, count))
            steps = 0
            begin = time.perf_counter()
            while time.perf_counter() - begin < plan.vec_seconds:
                vec_env.step(rng.integers(0, 4, count))
                steps += 1
            seconds = time.perf_counter() - begin
            vec_env.close()
            rows.append({"vec_env": kind, "envs": count, "steps_per_second": steps * count / seconds})
    # One env step by part (random actions; the episode restarts when it ends)
    env = make()
    env.reset(seed=0)
    state = {"done": False}

    def step() -> None:
        if state["done"]:
            env.reset()
        _, _, terminated, truncated, _ = env.step(int(rng.integers(4)))
        state["done"] = terminated or truncated

    repeats = 3_000 if not plan.quick else 500
    parts = {
        "env.step (whole)": _per_call(step, repeats),
        "graph.move": _per_call(lambda: env.graph.move(env._state_index(env.node, env.heading), 0), repeats),
        "observation (views, goal views, heading)": _per_call(env._observation, repeats),
        "info (incl. shortest_distance, action_mask)": _per_call(lambda: env._info(collision=False), repeats),
        "reset": _per_call(env.reset, repeats // 10),
    }
    dummy = DummyVecEnv([lambda: env])
    dummy.reset()
    parts["DummyVecEnv(1).step"] = _per_call(lambda: dummy.step(rng.integers(0, 4, 1)), repeats)
    subproc = SubprocVecEnv([make])
    subproc.reset()
    parts["SubprocVecEnv(1).step"] = _per_call(lambda: subproc.step(rng.integers(0, 4, 1)), repeats)
    subproc.close()
    return {
        "stage": "vecenv",
        "size": n_nodes,
        "encoder": encoder,
        "rows": rows,
        "parts_us": {k: 1e6 * v for k, v in parts.items()},
    }


# -------------------------------------------------------------------------------------------------------- 5. train
def _top_functions(profile: cProfile.Profile, count: int = 6) -> list[dict[str, Any]]:
    """The functions with the most own time in a profile, with their share of the total."""
    stats = pstats.Stats(profile)
    total = stats.total_tt or 1.0
    rows = []
    for (filename, line, name), (_, calls, own, cumulative, _) in stats.stats.items():  # type: ignore[attr-defined]
        where = name if filename == "~" else f"{Path(filename).name}:{line} {name}"
        rows.append({"function": where, "calls": calls, "own_share": own / total, "cumulative": cumulative})
    return sorted(rows, key=lambda row: -row["own_share"])[:count]


def measure_training(n_nodes: int, plan: Plan) -> dict[str, Any]:
    """DCQN as shipped until the map is solved (or the budget is spent): time, steps, memory, evaluation cost."""
    from campusnav_runs import TASKS, VARIANTS, train_until_solved

    from campusnav_env.env import CampusNavEnv
    from campusnav_env.route_evaluation import evaluate_routes

    record: dict[str, Any] = {"stage": "train", "size": n_nodes, "import_rss_mb": rss_mb()}
    budget, eval_freq, max_steps = plan.budgets[n_nodes], plan.eval_freq[n_nodes], plan.max_steps[n_nodes]
    task = replace(TASKS["campus"], name=f"scale{n_nodes}", n_nodes=n_nodes, env_id=None, max_steps=max_steps)
    variant = VARIANTS["DCQN"]
    entry = variant.entry(task)
    encoder = plan.train_encoder(n_nodes)
    graph = make_graph(n_nodes, plan.extent)
    with peak_memory() as peak:
        begin = time.perf_counter()
        env_kwargs = {**entry.env_kwargs, **env_kwargs_for(encoder), "cache_dir": plan.cache_dir, "progress": False}
        env = CampusNavEnv(world=graph, goals=GOAL, **env_kwargs)
        record["env_seconds"] = time.perf_counter() - begin
    settings = env_kwargs["render_settings"]
    record |= {"env_peak_mb": peak.peak_mb, "encoder": encoder, "view": f"{settings.width}x{settings.height}"}

    # Env step and reset costs at this size (random actions)
    rng = np.random.default_rng(plan.seed)
    env.reset(seed=plan.seed)
    begin, resets = time.perf_counter(), 0
    for _ in range(plan.env_steps):
        _, _, terminated, truncated, _ = env.step(int(rng.integers(4)))
        if terminated or truncated:
            env.reset()
            resets += 1
    record["env_step_us"] = 1e6 * (time.perf_counter() - begin) / plan.env_steps
    record["reset_us"] = 1e6 * _per_call(env.reset, 200)

    model = variant.make_model(env, entry, plan.seed)
    with peak_memory() as peak:
        result = train_until_solved(model, max_steps, budget, eval_freq)
    last, solved = result.evaluations[-1], result.solved_at
    at = solved or last
    buffer = model.replay_buffer
    record |= {
        "solved": solved is not None,
        "seconds": at.train_seconds,
        "steps": at.step,
        "episodes": at.episode,
        "final_steps": last.step,
        "final_train_seconds": last.train_seconds,
        "final_success": last.success_rate,
        "final_spl": last.spl,
        "budget_seconds": budget,
        "eval_freq": eval_freq,
        "max_steps": max_steps,
        "evaluations": len(result.evaluations),
        "evaluation_seconds": result.evaluation_seconds,
        "routes": len(last.report.routes),
        "wall_seconds": result.wall_seconds,
        "train_peak_mb": peak.peak_mb,
        "buffer_class": type(buffer).__name__,
        "buffer_allocated_bytes": sum(buffer_arrays(buffer).values()),
        "buffer_transitions": int(buffer.buffer_size if buffer.full else buffer.pos),
        "buffer_size": int(buffer.buffer_size),
        "curve": result.curve(),
    }

    # Where one route evaluation's time goes (the final policy)
    profile = cProfile.Profile()
    with peak_memory() as peak:
        begin = time.perf_counter()
        report = profile.runcall(
            evaluate_routes, env, lambda observations: model.predict(observations, deterministic=True)[0]
        )
        record["profiled_evaluation_seconds"] = time.perf_counter() - begin
    record["evaluation_extra_mb"] = peak.extra_mb  # all 4N starts go through the policy as one batch
    record["profiled_evaluation_mean_steps"] = report.mean_steps
    record["evaluation_profile"] = _top_functions(profile)
    return record


# ------------------------------------------------------------------------------------------------------- the report
def _fmt(value: float | None, digits: int = 1) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:,.{digits}f}"


def _by(runs: list[dict[str, Any]], stage: str) -> dict[int, dict[str, Any]]:
    return {run["size"]: run for run in runs if run["stage"] == stage}


def build_table(builds: dict[int, dict[str, Any]]) -> list[str]:
    """World build cost per size and encoder."""
    lines = [
        "| intersections | states | encoder, views | map (s) | 3D world (s) | render (ms/node) | encode (ms/view) | "
        "render + encode, cold cache (s) | feature cache (MB) | env from warm cache (s) | peak RSS of the build (MB) | "
        "longest route to the goal (hops) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for size in sorted(builds):
        build = builds[size]
        peak, exact = build_peak_mb(build)
        for enc in build["encoders"]:
            how = "measured" if enc["full"] else f"extrapolated from {enc['nodes_measured']} nodes"
            lines.append(
                f"| {size:,} | {build['states']:,} | {enc['encoder']}, {enc['view']} | {build['map_seconds']:.2f} | "
                f"{build['world_seconds']:.1f} | {1e3 * enc['render_s_per_node']:.1f} | "
                f"{1e3 * enc['encode_s_per_view']:.2f} | {_fmt(enc['build_seconds'])} ({how}) | "
                f"{enc['cache_bytes'] / MB:,.1f}{'' if enc['full'] else ' (computed)'} | "
                f"{_fmt(enc.get('env_seconds'), 2)} | {'' if exact else '~'}{peak:,.0f} | {build['longest_route']} |"
            )
    return lines


def train_table(trains: dict[int, dict[str, Any]]) -> list[str]:
    """Time to the threshold and memory during training, per size."""
    lines = [
        "| intersections | features | budget (s) | solved | training time to threshold (s) | env steps | episodes | "
        "final success / SPL | training ms per env step | evaluations (every N steps) | s per evaluation (routes) | "
        "wall (s) | peak RSS: env / training (MB) | replay buffer: allocated / used (MB) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for size in sorted(trains):
        run = trains[size]
        time_cell = f"{run['seconds']:.0f}" if run["solved"] else f"not reached in {run['final_train_seconds']:.0f} s"
        per_step = 1e3 * run["final_train_seconds"] / max(run["final_steps"], 1)
        used = run["buffer_allocated_bytes"] * run["buffer_transitions"] / run["buffer_size"]
        encoder = f"{run['encoder']}, {run['view']}, view_dim {VIEW_DIM}"
        solved = "yes" if run["solved"] else "no"
        lines.append(
            f"| {size:,} | {encoder} | {run['budget_seconds']:.0f} | {solved} | {time_cell} | "
            f"{run['steps']:,} | {run['episodes']:,} | {run['final_success']:.3f} / {run['final_spl']:.3f} | "
            f"{per_step:.2f} | {run['evaluations']} (every {run['eval_freq']:,}) | "
            f"{run['evaluation_seconds'] / max(run['evaluations'], 1):.2f} ({run['routes']:,}) | "
            f"{run['wall_seconds']:.0f} | {run['env_peak_mb']:,.0f} / {run['train_peak_mb']:,.0f} | "
            f"{run['buffer_allocated_bytes'] / MB:,.0f} / {used / MB:,.0f} |"
        )
    return lines


def buffer_tables(buffer: dict[str, Any], sizes: list[int]) -> list[str]:
    """Bytes per transition, by array, and the index alternative."""
    rows = buffer["rows"]
    names = list(dict.fromkeys(name for row in rows for name in row["per_transition"]))
    lines = [
        "| array (B per transition) | "
        + " | ".join(f"{row['buffer']}, view_dim {row['view_dim']}" for row in rows)
        + " |",
        "|---|" + "---|" * len(rows),
    ]
    for name in names:
        cells = [f"{row['per_transition'].get(name, 0):,.0f}" for row in rows]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines.append("| **total** | " + " | ".join(f"**{row['bytes_per_transition']:,.0f}**" for row in rows) + " |")
    n = buffer["buffer_size"]
    lines += [
        "",
        f"| view_dim | features: B/transition | {n:,} transitions (MB) | indices: B/transition | "
        + " | ".join(f"indices + feature table at {s:,} nodes (MB)" for s in sizes)
        + " | saving at the largest map | sample a batch of 64: features / indices + lookup (us) |",
        "|---|---|---|---|" + "---|" * len(sizes) + "---|---|",
    ]
    for row in (r for r in rows if "sample_us" in r):
        features = row["bytes_per_transition"] * n
        with_table = [row["index_bytes_per_transition"] * n + row["table_bytes_per_node"] * s for s in sizes]
        lines.append(
            f"| {row['view_dim']} | {row['bytes_per_transition']:,.0f} | {features / MB:,.1f} | "
            f"{row['index_bytes_per_transition']:,.0f} | "
            + " | ".join(f"{b / MB:,.1f}" for b in with_table)
            + f" | {features / with_table[-1]:,.0f}x ({(features - with_table[-1]) / MB:,.0f} MB) | "
            f"{row['sample_us']:.0f} / {row['index_sample_us']:.0f} |"
        )
    return lines


def vecenv_tables(vec: dict[str, Any]) -> list[str]:
    """Steps/s per vector env, and one env step's parts."""
    base = next(r["steps_per_second"] for r in vec["rows"] if r["vec_env"] == "DummyVecEnv" and r["envs"] == 1)
    lines = ["| vector env | envs | env steps/s (all envs) | vs DummyVecEnv, 1 env |", "|---|---|---|---|"]
    for row in vec["rows"]:
        lines.append(
            f"| {row['vec_env']} | {row['envs']} | {row['steps_per_second']:,.0f} | "
            f"{row['steps_per_second'] / base:.2f}x |"
        )
    lines += ["", "| part of one env step | us per call |", "|---|---|"]
    lines += [f"| {name} | {us:,.1f} |" for name, us in vec["parts_us"].items()]
    return lines


def fit_table(fits: dict[int, dict[str, Any]]) -> list[str]:
    """The env's feature transform at 1280-d, before and after the fix."""
    lines = [
        "| intersections (views x features) | before: fit + transform (s) | before: peak memory (MB) | "
        "after: fit + transform (s) | after: peak memory (MB) | features before vs after |",
        "|---|---|---|---|---|---|",
    ]
    for size in sorted(fits):
        fit = fits[size]
        same = "identical" if fit["identical"] else f"max difference {fit['max_difference']:.1e}"
        lines.append(
            f"| {size:,} ({fit['views']:,} x {fit['features']}) | {fit['before_seconds']:.2f} | "
            f"{fit['before_extra_mb']:,.0f} | {fit['after_seconds']:.2f} | {fit['after_extra_mb']:,.0f} | {same} |"
        )
    return lines


def cost_table(builds: dict[int, dict[str, Any]], trains: dict[int, dict[str, Any]]) -> list[str]:
    """Where the time goes at each size: the one-off build against the recurring costs of training."""
    lines = [
        "| intersections | cold build, EfficientNet (s) | of which render / encode / 3D world | env.step (us) | "
        "reset (us) | training ms per env step | one route evaluation (s) | its top functions (own time) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for size in sorted(set(builds) | set(trains)):
        build, run = builds.get(size), trains.get(size)
        cells = ["-", "-"]
        if build is not None:
            enc = next((e for e in build["encoders"] if e["encoder"] == EFFNET), build["encoders"][0])
            total = enc["build_seconds"] + build["world_seconds"]
            render = enc["render_s_per_node"] * size
            encode = 4 * enc["encode_s_per_view"] * size
            how = "" if enc["full"] else " (extrapolated)"
            shares = (100 * render / total, 100 * encode / total, 100 * build["world_seconds"] / total)
            cells = [f"{total:,.0f}{how}", " / ".join(f"{share:.0f}%" for share in shares)]
        if run is not None:
            top = "; ".join(f"{f['function']} {100 * f['own_share']:.0f}%" for f in run["evaluation_profile"][:3])
            cells += [
                f"{run['env_step_us']:.0f}",
                f"{run['reset_us']:.0f}",
                f"{1e3 * run['final_train_seconds'] / max(run['final_steps'], 1):.2f}",
                f"{run['profiled_evaluation_seconds']:.2f} ({run['routes']:,} routes, "
                f"success {run['final_success']:.3f})",
                top,
            ]
        else:
            cells += ["-"] * 5
        lines.append(f"| {size:,} | " + " | ".join(cells) + " |")
    return lines


def findings(
    builds: dict[int, dict[str, Any]], trains: dict[int, dict[str, Any]], fits: dict[int, dict[str, Any]]
) -> list[str]:
    """What the measurements say, smallest against largest map (bullets, figures filled in from the records)."""
    lines = []
    if len(builds) >= 2:
        small, large = builds[min(builds)], builds[max(builds)]
        ratio = large["size"] / small["size"]
        world_growth = large["world_seconds"] / small["world_seconds"]
        effnet = next(e for e in large["encoders"] if e["encoder"] == EFFNET)
        total = effnet["build_seconds"] + large["world_seconds"]
        encode = 4 * effnet["encode_s_per_view"] * large["size"]
        lines.append(
            f"- **Cold build, one-off, O(N):** with EfficientNet-Lite0 at {large['size']:,} intersections "
            f"{total:,.0f} s ({'measured' if effnet['full'] else 'extrapolated'}), {100 * encode / total:.0f}% of it "
            f"CNN forward passes ({1e3 * effnet['encode_s_per_view']:.0f} ms per view on one thread), the rest "
            "rendering and the 3D world. The CNN is the largest single cost of a large map; it is paid once per map "
            "and settings (the feature cache), and it is not ours to make cheaper short of a smaller encoder or a "
            f"GPU. The 3D world: {small['world_seconds']:.1f} s at {small['size']:,}, {large['world_seconds']:.1f} s "
            f"at {large['size']:,} ({world_growth:.0f}x for {ratio:.0f}x the intersections), "
            f"{large['world_extra_mb']:,.0f} MB while it is built."
        )
    if len(trains) >= 2:
        small, large = trains[min(trains)], trains[max(trains)]

        def per_step(run: dict[str, Any]) -> float:
            return 1e3 * run["final_train_seconds"] / max(run["final_steps"], 1)

        def per_evaluation(run: dict[str, Any]) -> float:
            return run["evaluation_seconds"] / max(run["evaluations"], 1)

        lines.append(
            f"- **Per step, nothing grows with the map:** env.step {small['env_step_us']:.0f} us at "
            f"{small['size']:,} and {large['env_step_us']:.0f} us at {large['size']:,} (hop distances for "
            "`info['shortest_distance']` are cached per goal, observations are row gathers), a training env step "
            f"{per_step(small):.2f} and {per_step(large):.2f} ms (the network and batch do not depend on N)."
        )
        lines.append(
            f"- **Route evaluation grows with 4N starts x route length:** {per_evaluation(small):.2f} s at "
            f"{small['size']:,} ({small['routes']:,} routes), {per_evaluation(large):.2f} s at {large['size']:,} "
            f"({large['routes']:,} routes; an untrained policy loops early and is stopped, so a trained one costs "
            "more). It is excluded from the training time; `eval_freq` grows with the map to keep it a small part of "
            "the wall time."
            + (
                f" Its memory grows too: all 4N starts go through the policy as one batch, "
                f"{large['evaluation_extra_mb']:,.0f} MB above the training process's RSS at {large['size']:,}."
                if "evaluation_extra_mb" in large
                else ""
            )
        )
        solved = [f"{size:,}: {run['seconds']:.0f} s" for size, run in sorted(trains.items()) if run["solved"]]
        missed = [
            f"{size:,}: not reached in {run['final_train_seconds']:.0f} s (success {run['final_success']:.3f}, "
            f"SPL {run['final_spl']:.3f})"
            for size, run in sorted(trains.items())
            if not run["solved"]
        ]
        lines.append(
            "- **Time to threshold grows with the number of states to learn** (samples, not per-step cost): "
            + "; ".join(solved + missed)
            + f". Replay buffer arrays: {large['buffer_allocated_bytes'] / MB:,.0f} MB whatever the map (50,000 "
            "transitions of 4,148 B at view_dim 64)."
        )
        longest = {size: build["longest_route"] for size, build in builds.items() if size in trains}
        if longest:
            size = max(longest)
            lines.append(
                "- **Long routes, same discount:** the longest route to the goal is "
                + ", ".join(f"{hops} hops at {n:,}" for n, hops in sorted(longest.items()))
                + f". With the shipped gamma {GAMMA} the goal's reward is worth {GAMMA ** longest[size]:.4f} from the "
                f"farthest start at {size:,}, so the value gap between the best action and one a hop longer is tiny "
                "there; SPL >= 0.98 from every start needs the critics to resolve it everywhere, a likely reason why "
                "SPL, not success, is the last to reach the threshold on large maps (not changed here: the settings "
                "are the shipped ones)."
            )
    if fits:
        large = fits[max(fits)]
        lines.append(
            f"- **Ours, and growing with the map in every process that builds an env: the feature transform's PCA** "
            f"on 1280-d views: {large['before_seconds']:.1f} s and {large['before_extra_mb']:,.0f} MB above its "
            f"input at {large['size']:,} intersections before the fix, {large['after_seconds']:.1f} s and "
            f"{large['after_extra_mb']:,.0f} MB after (table below)."
        )
    return lines


def plot(
    builds: dict[int, dict[str, Any]], trains: dict[int, dict[str, Any]], fits: dict[int, dict[str, Any]], path: Path
) -> None:
    """Time (left) and memory (right) against intersections, log x."""
    from matplotlib.figure import Figure

    from campusnav_env.figures import figure_image, write_figure

    figure = Figure(figsize=(11, 5.6), dpi=100, layout="constrained")
    left, right = figure.subplots(1, 2)

    def line(axis: Any, points: list[tuple[int, float, bool]], label: str, style: str, bound: bool = False) -> None:
        """Points (x, y, exact): hollow where extrapolated; a lower bound (``bound``) is not joined to the line."""
        points = sorted(points)
        if not points:
            return
        joined = [p for p in points if p[2] or not bound]
        colour = None
        if joined:
            (handle,) = axis.plot([p[0] for p in joined], [p[1] for p in joined], style, label=label)
            colour = handle.get_color()
        hollow = [p for p in points if not p[2]]
        if hollow:
            marker = "^" if bound else "o"
            axis.plot([p[0] for p in hollow], [p[1] for p in hollow], marker, mfc="white", color=colour,
                      label=None if joined else label)  # fmt: skip

    for encoder, style in ((EFFNET, "o-"), (PIXELS, "s-")):
        points = [
            (size, e["build_seconds"] + b["world_seconds"], e["full"])
            for size, b in builds.items()
            for e in b["encoders"]
            if e["encoder"] == encoder
        ]
        line(left, points, f"cold build, {encoder}", style)
    reached = [(s, r["seconds"] if r["solved"] else r["final_train_seconds"], r["solved"]) for s, r in trains.items()]
    line(left, reached, "training time to threshold (hollow: budget spent)", "^-", bound=True)
    evaluation = [(s, r["evaluation_seconds"] / max(r["evaluations"], 1), True) for s, r in trains.items()]
    line(left, evaluation, "one route evaluation", "v-")
    line(
        left,
        [(s, r["env_seconds"], True) for s, r in trains.items()],
        "env from warm cache (training's features)",
        "d-",
    )
    for when, style in (("before", "x--"), ("after", "x-")):
        points = [(s, f[f"{when}_seconds"], True) for s, f in fits.items()]
        line(left, points, f"feature transform, 1280-d, {when} the fix", style)
        line(right, [(s, f[f"{when}_extra_mb"], True) for s, f in fits.items()], f"feature transform, {when} the fix",
             style)  # fmt: skip
    left.set_ylabel("seconds (hollow: extrapolated, or budget spent)")
    right_lines = [
        ("peak RSS, build (world + views)", [(s, build_peak_mb(b)[0], True) for s, b in builds.items()], "o-"),
        ("peak RSS, training", [(s, r["train_peak_mb"], True) for s, r in trains.items()], "^-"),
        ("replay buffer arrays", [(s, r["buffer_allocated_bytes"] / MB, True) for s, r in trains.items()], "s-"),
        (
            "feature cache, EfficientNet",
            [
                (s, e["cache_bytes"] / MB, e["full"])
                for s, b in builds.items()
                for e in b["encoders"]
                if e["encoder"] == EFFNET
            ],
            "d-",
        ),
    ]
    for label, points, style in right_lines:
        line(right, points, label, style)
    right.set_ylabel("MB (feature transform: peak above its input)")
    for axis in (left, right):
        axis.set_xscale("log")
        axis.set_yscale("log")
        axis.set_xlabel("intersections")
        axis.grid(True, which="both", alpha=0.3)
        axis.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2)  # below: no line hidden
    left.set_title("time")
    right.set_title("memory")
    write_figure(path, figure_image(figure))


def machine_line_here(runs: str) -> str:
    """campusnav_runs.machine_line, imported lazily (it imports SB3 and the package)."""
    from campusnav_runs import machine_line

    return machine_line(runs)


def write_report(plan: Plan, runs: list[dict[str, Any]], out: Path, argv: list[str] | None) -> None:
    builds, trains, fits = _by(runs, "build"), _by(runs, "train"), _by(runs, "fit")
    buffer = next((r for r in runs if r["stage"] == "buffer"), None)
    vec = next((r for r in runs if r["stage"] == "vecenv"), None)
    picture = out.with_suffix(".png")
    plot(builds, trains, fits, picture)
    sizes = sorted(set(builds) | set(trains)) or list(plan.sizes)
    lines = [
        "# Scale: 101 to 10,000 intersections",
        "",
        f"Generated campuses (seed 0, goal Dreese Lab), extent {plan.extent}"
        + (
            " (2.5 km x 1.7 km times sqrt(n / 101): the street density of the built-in campus at every size; 101 is "
            "the built-in campus)"
            if plan.extent == "scaled"
            else " (2.5 km x 1.7 km at every size)"
        )
        + ". Each stage ran in a fresh process (its own peak RSS; a process that imports the package and torch starts "
        f"at about {_fmt(next((r['import_rss_mb'] for r in runs if 'import_rss_mb' in r), None), 0)} MB). "
        "EfficientNet-Lite0 on 640x480 views (the default) is used where a full encode is affordable; above "
        f"{plan.effnet_max_nodes:,} intersections its cost is measured on a sample and extrapolated, and the map is "
        "built and trained with the cheap `pixels` encoder on 64x48 views (stated in every row).",
        "",
        machine_line_here(
            "stages one after another, each in a fresh process, 1 BLAS thread; other engineers' jobs (another "
            "benchmark) used the other core throughout this run, so CPU-bound figures are slower and noisier than on "
            "a quiet machine"
        ),
        "",
        "## World build per size",
        "",
        "Cold cache: the feature file is removed first. Render + encode counts rendering, encoding, checks and the "
        "cache write (measured) or rendering and encoding (extrapolated). Env from warm cache: `CampusNavEnv(...)` "
        "reading that file (map, navigation graph, feature transform). Peak RSS: the highest of the build's phases "
        "(3D world, each encoder's views, env construction); ~: estimated as the world's rise above the RSS after the "
        "imports (records made before the world's absolute peak was kept).",
        "",
        *build_table(builds),
        "",
        "## Time to the threshold (DCQN, shipped CampusNav-v0 settings)",
        "",
        "Success >= 0.99 and SPL >= 0.98 from every (start, heading), evaluated every N env steps inside one "
        "`learn()` call (`campusnav_runs.train_until_solved`); time: training seconds, evaluations excluded; a run "
        "that spends its budget is reported with its last evaluation. Replay buffer: the arrays SB3 reserves "
        "(`np.zeros`, touched as they fill) and the share filled.",
        "",
        *train_table(trains),
    ]
    if buffer is not None:
        lines += [
            "",
            f"## Replay buffer bytes per transition ({buffer['buffer_size']:,} transitions, the shipped buffer_size)",
            "",
            "From the buffers' own arrays (`nbytes / buffer_size`). DCQN as shipped uses SB3's `DictReplayBuffer`; "
            "with experience revision or prioritised replay on, `DCQNDictReplayBuffer` (plus, with revision, a "
            "Python index of two 16-byte digests per transition, not counted). SB3 keeps `next_observations` apart "
            "from `observations`, so every feature vector is stored twice per transition, and `goal_views` repeats "
            "the goal's features in every transition. Indices instead (second table): node and goal int32, heading "
            "int8, for the observation and the next one (18 B), the same action/reward/done/timeout arrays, and one "
            "float32 table of 4 x view_dim features per node, gathered at sample time (computed and timed here, not "
            "implemented).",
            "",
            *buffer_tables(buffer, sizes),
        ]
    if vec is not None:
        lines += [
            "",
            f"## Env steps/s: DummyVecEnv vs SubprocVecEnv ({vec['size']} intersections, {vec['encoder']} features, "
            "random actions)",
            "",
            *vecenv_tables(vec),
        ]
    lines += [
        "",
        "## Where the cost goes as the map grows",
        "",
        *findings(builds, trains, fits),
        "",
        *cost_table(builds, trains),
    ]
    if fits:
        lines += [
            "",
            "### Fixed: the feature transform's PCA fit (campusnav_env/features/projection.py)",
            "",
            "Every env construction fits the feature transform on all 4N views (standardise, then PCA to 64 per "
            "view, the shipped `view_dim`): a thin SVD of the (4N x 1280) matrix in float64, with full-size float64 "
            "and float32 temporaries in the fit and again in the transform. Its time and memory grew with the map, "
            "in every process that builds an env (each SubprocVecEnv worker, each evaluation env). Now "
            "`ViewProjection.fit` takes large fits (from 4M values and 2 views per feature: 820+ intersections of "
            "1280-d views) from the 1280 x 1280 scatter matrix, accumulated a chunk of rows at a time; "
            "`ViewProjection.transform` works a chunk of 4,096 rows at a time; `FeatureTransform.fit/transform` "
            "standardise in place on their own copy. Smaller maps keep the exact SVD (the built-in campus's features "
            "are bit for bit unchanged). Synthetic 1280-d features with a CNN-like spectrum; peak memory: above the "
            "input, per process (`VmHWM`).",
            "",
            *fit_table(fits),
        ]
    lines += ["", f"![time and memory against intersections]({picture.name})"]
    publish(out, lines, "scale.py", argv)


# ------------------------------------------------------------------------------------------------------------ main
def _size_values(pairs: list[str] | None, sizes: tuple[int, ...], default: Callable[[int], float]) -> dict[int, float]:
    """``["1000=600", "300"]``: per-size values (a bare number applies to every size)."""
    values = {size: default(size) for size in sizes}
    for pair in pairs or []:
        if "=" in pair:
            size, value = pair.split("=", 1)
            values[int(size)] = float(value)
        else:
            values = dict.fromkeys(sizes, float(pair))
    return values


def make_plan(args: argparse.Namespace) -> Plan:
    from campusnav_env.features.feature_cache import default_cache_dir

    quick = args.quick
    sizes = tuple(args.sizes or ((101, 300) if quick else (101, 1_000, 10_000)))
    if quick:
        budgets = _size_values(args.budget, sizes, lambda _: 4.0)
        eval_freq = {size: int(v) for size, v in _size_values(args.eval_freq, sizes, lambda _: 500).items()}
        max_steps = dict.fromkeys(sizes, 2_000)  # learning starts at 1,000
    else:
        budgets = _size_values(args.budget, sizes, default_budget)
        eval_freq = {size: int(v) for size, v in _size_values(args.eval_freq, sizes, default_eval_freq).items()}
        max_steps = {size: 60_000 if size <= 200 else 3_000_000 for size in sizes}
    return Plan(
        sizes=sizes,
        budgets=budgets,
        eval_freq=eval_freq,
        max_steps=max_steps,
        extent=args.extent,
        effnet_max_nodes=args.effnet_max_nodes,
        effnet_sample=2 if quick else args.effnet_sample,
        vec_counts=(1, 2) if quick else (1, 2, 4),
        vec_seconds=0.5 if quick else 4.0,
        env_steps=500 if quick else 5_000,
        quick=quick,
        cache_dir=str(args.cache_dir or default_cache_dir() / "scale"),
    )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", nargs="+", type=int, help="intersections (default 101 1000 10000; quick: 101 300)")
    parser.add_argument("--budget", nargs="+", help="training seconds: SIZE=SECONDS per size, or one number for all")
    parser.add_argument("--eval-freq", nargs="+", help="env steps between route evaluations: SIZE=STEPS, or one number")
    parser.add_argument("--extent", choices=("scaled", "fixed"), default="scaled")
    parser.add_argument("--effnet-max-nodes", type=int, default=1_000, help="largest map encoded with EfficientNet")
    parser.add_argument("--effnet-sample", type=int, default=32, help="nodes encoded to extrapolate larger maps")
    parser.add_argument("--cache-dir", type=Path, help="feature cache (default: $CAMPUSNAV_CACHE/scale)")
    parser.add_argument("--quick", action="store_true", help="smoke run: 101 and 300 nodes, pixel features, ~1 min")
    parser.add_argument("--runs-file", type=Path, default=RESULTS_DIR / "scale_runs.jsonl")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "scale.md")
    args = parser.parse_args(argv)
    # Children inherit these: one BLAS thread, like the one torch thread (another benchmark uses the other core)
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[name] = "1"
    plan = make_plan(args)

    stages: list[tuple[str, int, Callable[..., dict[str, Any]], tuple[Any, ...]]] = [
        ("buffer", 0, measure_buffer, (plan,))
    ]
    stages += [("build", size, measure_build, (size, plan)) for size in plan.sizes]
    stages += [("fit", size, measure_fit, (size, plan)) for size in plan.sizes]
    stages += [("vecenv", plan.sizes[0], measure_vecenv, (plan,))]
    stages += [("train", size, measure_training, (size, plan)) for size in plan.sizes]
    done = {(r["stage"], r["size"]) for r in read_runs(args.runs_file)}
    print(f"{len(done)} stages already in {args.runs_file}; plan: {asdict(plan)}", flush=True)
    for stage, size, function, function_args in stages:
        if (stage, size) in done:
            continue
        begin = time.perf_counter()
        record = run_in_fresh_process(function, *function_args)
        record["stage_wall_seconds"] = time.perf_counter() - begin
        append_run(args.runs_file, record)
        print(f"{stage} {size}: done in {record['stage_wall_seconds']:.0f} s", flush=True)
    write_report(plan, read_runs(args.runs_file), args.out, argv)


if __name__ == "__main__":
    main()
