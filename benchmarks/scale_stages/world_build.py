"""Scale, world build: the map, the 3D world and every street view rendered and encoded into a cold feature cache.

Per size: map, 3D world, render + encode of every view into a cold cache, the cache's size on disk, env construction
from the warm cache, peak RSS. EfficientNet-Lite0 (640x480 views, the default) up to ``--effnet-max-nodes``; above,
its cost is measured on ``--effnet-sample`` nodes and extrapolated, and the map is built with the cheap ``"pixels"``
encoder on 64x48 views (every size gets a pixel build, for a like-for-like line).

The EfficientNet build runs the way the env builds (``"workers"``: views rendered at the size the CNN consumes, 299x224
for 640x480, by one worker process per core, :mod:`campusnav_env.features.parallel_build`) and, with
``--paths workers serial``, also the way it built before (``"serial"``: 640x480 rendered, in one process);
``"workers-bf16"``: the worker build with the CNN in bfloat16 (``precision="bfloat16"``, another cache entry).
Render and encode columns are per core (one thread, in the stage's process, on a sample of nodes); the total is the
wall time of the build (where the map is not built in full: the workers' start, timed on one batch per worker, plus
the sample's further wall time per node times the remaining nodes). Peak RSS of a worker build adds the workers'
(each counted as big as the largest of them).

Run by ``scale.py`` (stage ``build``); alone::

    python benchmarks/scale_world_build.py --sizes 101 1000 --runs-file /tmp/build.jsonl --out /tmp/build.md
    python benchmarks/scale_world_build.py --sizes 10000 --full-effnet  # the cold 10,000 build in full
    python benchmarks/scale_world_build.py --sizes 1000 --paths workers serial --effnet-sample 500  # old vs new
"""

from __future__ import annotations

import gc
import os
import resource
import time
from typing import Any

import numpy as np

from benchmarks.report import markdown_table
from benchmarks.scale_common import (
    EFFNET,
    GOAL,
    MB,
    PIXELS,
    VIEW_DIM,
    WORLD_SEED,
    Plan,
    env_kwargs_for,
    fmt,
    make_graph,
    peak_memory,
    rss_mb,
)

STAGE = "build"
# Sampled nodes are encoded in the batches the feature cache encodes: 32 views, 8 nodes
NODES_PER_BATCH = 8
# The EfficientNet builds to measure (stage processes read it: set by this script's --paths)
PATHS_ENV = "CAMPUSNAV_BUILD_PATHS"
PATHS = ("workers", "workers-bf16", "serial")
# Nodes rendered and encoded in the stage's process to time a worker build's render and encode per core (--quick: 2)
PER_CORE_NODES, QUICK_PER_CORE_NODES = 16, 2


def build_paths() -> tuple[str, ...]:
    """The EfficientNet builds this run measures (``$CAMPUSNAV_BUILD_PATHS``, default the env's: workers)."""
    paths = tuple(p for p in os.environ.get(PATHS_ENV, "workers").split(",") if p)
    unknown = sorted(set(paths) - set(PATHS))
    if unknown:
        raise ValueError(f"${PATHS_ENV}: unknown build paths {unknown}; choose from {PATHS}")
    return paths


class SampledRenderer:
    """
    Renders node ``nodes[i]`` of the world as node ``i``: a worker build of a sample of the map (picklable; the
    workers call it once to build their renderer).

    :param world: The 3D world
    :param settings: The render settings
    :param nodes: The sampled nodes
    """

    def __init__(self, world: Any, settings: Any, nodes: np.ndarray) -> None:
        self.world, self.settings, self.nodes = world, settings, nodes
        self.renderer: Any = None

    def __call__(self) -> SampledRenderer:
        from campusnav_env.rendering.street_view import StreetViewRenderer

        self.renderer = StreetViewRenderer(self.world, self.settings)
        return self

    def render_node(self, index: int) -> np.ndarray:
        return self.renderer.render_node(int(self.nodes[index]))


def children_peak_mb() -> float:
    """The largest peak RSS of this process's finished children (MB): the biggest worker."""
    return resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024 / MB


class TimedEncoder:
    """
    A view encoder (same name, so the same cache entry) that counts the seconds spent encoding.

    :param inner: The encoder that does the work
    """

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.name, self.output_shape, self.dtype = inner.name, inner.output_shape, inner.dtype
        self.seconds = 0.0

    def encode(self, images: np.ndarray) -> np.ndarray:
        start = time.perf_counter()
        out = self.inner.encode(images)
        self.seconds += time.perf_counter() - start
        return out


def measure_views(graph: Any, world: Any, encoder: str, full: bool, plan: Plan) -> dict[str, Any]:
    """
    Render and encode every view into a cold cache (``full``), or a sample of nodes to extrapolate from, in this
    process at the requested view size (the build before worker processes); then, for a full build, construct the
    env from the warm cache.

    :return: the encoder's part of the build record
    """
    from campusnav_env.features.feature_cache import cache_path, cached_view_features
    from campusnav_env.features.view_source import ViewSource
    from campusnav_env.rendering.street_view import StreetViewRenderer

    settings = env_kwargs_for(encoder)["view_build"].render_settings
    n_nodes = graph.n_nodes
    start = time.perf_counter()
    source = ViewSource(
        graph,
        "features",
        encoder,
        None,
        settings,
        WORLD_SEED,
        plan.cache_dir,
        False,
        workers=1,
        fit_views_to_encoder=False,
    )
    load_seconds = time.perf_counter() - start
    renderer = StreetViewRenderer(world, settings)
    timed = TimedEncoder(source.encoder)
    render_seconds = 0.0

    def render(node: int) -> np.ndarray:
        nonlocal render_seconds
        begin = time.perf_counter()
        views = renderer.render_node(node)
        render_seconds += time.perf_counter() - begin
        return views

    record: dict[str, Any] = {"encoder": encoder, "view": f"{settings.width}x{settings.height}", "full": full}
    record |= {"path": "serial", "encoder_load_seconds": load_seconds}
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
            sample = np.unique(np.linspace(0, n_nodes - 1, plan.effnet_sample).astype(int))  # spread over the map
            source.encoder.encode(renderer.render_node(0))  # warm-up (first CNN call, first ground textures)
            for begin_index in range(0, sample.size, NODES_PER_BATCH):
                batch = [render(int(node)) for node in sample[begin_index : begin_index + NODES_PER_BATCH]]
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
    if full and encoder != EFFNET:  # the env renders EfficientNet's views at the CNN's size: another cache entry
        del renderer, timed
        record |= measure_env(graph, encoder, plan)
    return record


def measure_env(graph: Any, encoder: str, plan: Plan) -> dict[str, Any]:
    """``CampusNavEnv(...)`` from the warm cache: seconds and memory."""
    from campusnav_env.env import CampusNavEnv
    from campusnav_env.features.view_build import with_view_build

    gc.collect()
    with peak_memory() as env_peak:
        begin = time.perf_counter()
        env = CampusNavEnv(
            world=graph,
            goals=GOAL,
            view_dim=VIEW_DIM,
            **with_view_build(env_kwargs_for(encoder), cache_dir=plan.cache_dir, progress=False),
        )
        seconds = time.perf_counter() - begin
    del env
    return {"env_seconds": seconds, "env_extra_mb": env_peak.extra_mb, "env_peak_mb": env_peak.peak_mb}


def measure_worker_build(
    graph: Any, world: Any, encoder: str, full: bool, plan: Plan, precision: str = "float32"
) -> dict[str, Any]:
    """
    The env's build: views rendered at the size the encoder consumes, by one worker process per core, into a cold
    cache (``full``), or a sample of nodes whose wall time is extrapolated; render and encode per core timed in this
    process on :data:`PER_CORE_NODES` nodes. A full float32 build is the env's cache (then the env is built from it).

    :return: the encoder's part of the build record
    """
    from campusnav_env.features.feature_cache import cache_path, node_batches, render_nodes
    from campusnav_env.features.parallel_build import encode_views_in_workers
    from campusnav_env.features.view_source import ViewSource

    requested = env_kwargs_for(encoder)["view_build"].render_settings
    n_nodes = graph.n_nodes
    start = time.perf_counter()
    kwargs = {"precision": precision}
    source = ViewSource(graph, "features", encoder, kwargs, requested, WORLD_SEED, plan.cache_dir, False, world=world)
    load_seconds = time.perf_counter() - start
    settings, workers = source.settings, source.build_workers()
    record: dict[str, Any] = {"encoder": encoder, "view": f"{requested.width}x{requested.height}", "full": full}
    record |= {"path": "workers", "workers": workers, "rendered": f"{settings.width}x{settings.height}"}
    record["precision"] = precision
    record["encoder_load_seconds"] = load_seconds
    # Per core: this process runs one torch thread
    timed = TimedEncoder(source.encoder)
    per_core_nodes = QUICK_PER_CORE_NODES if plan.quick else PER_CORE_NODES
    per_core = np.unique(np.linspace(0, n_nodes - 1, min(per_core_nodes, n_nodes)).astype(int))
    source.encoder.encode(source.renderer.render_node(0))  # warm-up (first CNN call, first ground textures)
    begin = time.perf_counter()
    views = [render_nodes([int(node)], source.renderer.render_node) for node in per_core]
    render_seconds = time.perf_counter() - begin
    for batch in node_batches(len(views)):
        timed.encode(np.concatenate(views[batch.start : batch.stop]))
    record |= {
        "render_s_per_node": render_seconds / len(per_core),
        "encode_s_per_view": timed.seconds / (4 * len(per_core)),
    }
    del views, timed
    features_bytes = 4 * n_nodes * int(np.prod(source.encoder.output_shape)) * np.dtype(source.encoder.dtype).itemsize
    with peak_memory() as peak:
        begin = time.perf_counter()
        if full:
            path = cache_path(source.key_parts, n_nodes, source.encoder, cache_dir=plan.cache_dir)
            path.unlink(missing_ok=True)  # this benchmark's own cache folder: measure a cold build
            source.open_views()
            record |= {"cache_bytes": path.stat().st_size, "nodes_measured": n_nodes}
            record["build_seconds"] = time.perf_counter() - begin
        else:
            sample = np.unique(np.linspace(0, n_nodes - 1, plan.effnet_sample).astype(int))  # spread over the map
            # The workers' start (unpickling the world, building renderer and CNN) and one batch each, timed apart so
            # that the extrapolation pays it once
            first = min(sample.size, workers * NODES_PER_BATCH)
            encode_views_in_workers(
                first, SampledRenderer(world, settings, sample[:first]), source.encoder, workers=workers, progress=False
            )
            start_seconds = time.perf_counter() - begin
            begin = time.perf_counter()
            make_renderer = SampledRenderer(world, settings, sample)
            encode_views_in_workers(len(sample), make_renderer, source.encoder, workers=workers, progress=False)
            wall = time.perf_counter() - begin
            per_node = (wall - start_seconds) / (sample.size - first) if sample.size > first else wall / sample.size
            record |= {"cache_bytes": features_bytes, "nodes_measured": int(sample.size)}
            record |= {"start_seconds": start_seconds, "sample_seconds": wall}
            record["build_seconds"] = start_seconds + per_node * (n_nodes - first)
    record |= {"peak_mb": peak.peak_mb, "extra_mb": peak.extra_mb, "workers_peak_mb": workers * children_peak_mb()}
    if full and precision == "float32":
        record |= measure_env(graph, encoder, plan)
    return record


def measure_build(n_nodes: int, plan: Plan) -> dict[str, Any]:
    """
    Map, 3D world and every view rendered and encoded into a cold cache, for each encoder of this size.

    :param n_nodes: Intersections of the generated map
    :param plan: The run
    :return: the stage's record for this size
    """
    from campusnav_env.features.parallel_build import stop_workers
    from campusnav_env.maps.navigation import NavigationGraph
    from campusnav_env.rendering.world import build_world

    record: dict[str, Any] = {"stage": STAGE, "size": n_nodes, "extent": plan.extent, "import_rss_mb": rss_mb()}
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
    effnet_in_full = not plan.quick and n_nodes <= plan.effnet_max_nodes
    record["encoders"] = [measure_views(graph, world, PIXELS, True, plan)]
    for path in build_paths():
        if path == "serial":
            record["encoders"].append(measure_views(graph, world, EFFNET, effnet_in_full, plan))
        else:
            precision = "bfloat16" if path == "workers-bf16" else "float32"
            record["encoders"].append(measure_worker_build(graph, world, EFFNET, effnet_in_full, plan, precision))
    stop_workers()  # else the stage's process waits at exit for the pool's idle workers to time out (30 s)
    return record


def build_peak_mb(build: dict[str, Any]) -> tuple[float, bool]:
    """
    The build's peak RSS: the highest of its phases (each measured from a reset high-water mark, so the process's
    ``ru_maxrss`` only covers the last one). Returns the peak and whether it is exact: records without the world's
    absolute peak add its rise to the RSS after the imports (the map before it takes a few MB: a slight underestimate).
    """
    phases = [
        peak
        for enc in build["encoders"]
        for peak in (enc["peak_mb"] + enc.get("workers_peak_mb", 0.0), enc.get("env_peak_mb", 0.0))
    ]
    if "world_peak_mb" in build:
        return max(build["world_peak_mb"], *phases), True
    return max(build["import_rss_mb"] + build["world_extra_mb"], *phases), False


def build_table(builds: dict[int, dict[str, Any]]) -> list[str]:
    """World build cost per size and encoder."""
    header = [
        "intersections",
        "states",
        "encoder, views",
        "map (s)",
        "3D world (s)",
        "render (ms/node)",
        "encode (ms/view)",
        "render + encode, cold cache (s)",
        "feature cache (MB)",
        "env from warm cache (s)",
        "peak RSS of the build (MB)",
        "longest route to the goal (hops)",
    ]
    rows = []
    for size in sorted(builds):
        build = builds[size]
        peak, exact = build_peak_mb(build)
        for enc in build["encoders"]:
            how = "measured" if enc["full"] else f"extrapolated from {enc['nodes_measured']} nodes"
            views = enc["view"]
            if enc.get("path") == "workers":
                views += f" rendered {enc['rendered']}, {enc['workers']} workers"
                views += ", bfloat16" if enc.get("precision") == "bfloat16" else ""
            rows.append(
                [
                    f"{size:,}",
                    f"{build['states']:,}",
                    f"{enc['encoder']}, {views}",
                    f"{build['map_seconds']:.2f}",
                    f"{build['world_seconds']:.1f}",
                    f"{1e3 * enc['render_s_per_node']:.1f}",
                    f"{1e3 * enc['encode_s_per_view']:.2f}",
                    f"{fmt(enc['build_seconds'])} ({how})",
                    f"{enc['cache_bytes'] / MB:,.1f}{'' if enc['full'] else ' (computed)'}",
                    fmt(enc.get("env_seconds"), 2),
                    f"{'' if exact else '~'}{peak:,.0f}",
                    build["longest_route"],
                ]
            )
    return markdown_table(header, rows)


def world_build_section(builds: dict[int, dict[str, Any]]) -> list[str]:
    """The results section: what the build counts, and its table."""
    return [
        "## World build per size",
        "",
        "Cold cache: the feature file is removed first. Render + encode counts rendering, encoding, checks and the "
        "cache write (measured) or rendering and encoding (extrapolated). Env from warm cache: `CampusNavEnv(...)` "
        "reading that file (map, navigation graph, feature transform). Peak RSS: the highest of the build's phases "
        "(3D world, each encoder's views, env construction); ~: estimated as the world's rise above the RSS after the "
        "imports (records made before the world's absolute peak was kept).",
        "",
        *build_table(builds),
    ]
