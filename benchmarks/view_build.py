"""View build: nodes per second of the serial build, the local pool (loky) and Ray on this machine, Ray's start-up
cost, and the plan for a StreetLearn-size region (56k intersections) on N machines from the measured per-node cost.

Each build is the env's (:class:`~campusnav_env.features.view_source.ViewSource`: views rendered at the size the CNN
consumes, through the sharded feature cache, into a cold cache folder of its own) on one generated city whose 3D world
is built once, beforehand:

- ``serial``: this process (``build_workers=1``);
- ``pool``: ``--workers`` processes of the local pool (``parallel_build``, loky);
- ``ray``: ``--workers`` Ray actors of one CPU on a local Ray instance of ``--workers`` CPUs (like for like with the
  pool); ``ray-plan``: the actors of Ray's default plan there (every CPU of the driver's node but one);

the features of each build are compared with the serial build's (largest absolute difference). Start-up: ``ray.init``
of a local instance, and each parallel build's start (a build of one batch per worker, less that many batches' serial
time). The plan divides the 56k nodes' core-seconds (the pool's wall time x workers / nodes, so its overheads are
counted) by the actors of N machines of C cores (every core but one on the driver's node), plus Ray's start-up.

Usage::

    python benchmarks/view_build.py                          # 1,000 intersections, EfficientNet-Lite0
    python benchmarks/view_build.py --paths serial pool ray ray-plan
    python benchmarks/view_build.py --quick                  # 64 intersections, pixel features, 64x48 views
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

from benchmarks.report import RESULTS_DIR, machine_line, markdown_table, publish
from benchmarks.scale_common import EFFNET, PIXELS, WORLD_SEED, env_kwargs_for, make_graph

PATHS = ("serial", "pool", "ray", "ray-plan")
# The region to plan for (StreetLearn's Manhattan + Pittsburgh is about 56k panoramas) and the time to plan it in
REGION_NODES = 56_000
REGION_MINUTES = 30
CORES_PER_MACHINE = (4, 8, 16, 32)


def make_source(graph: Any, world: Any, encoder: Any, settings: Any, cache_dir: Path, path: str, workers: int) -> Any:
    """The env's view source for one build path (its own cold cache folder)."""
    from campusnav_env.features.view_source import ViewSource

    backend = "ray" if path.startswith("ray") else "local"
    count = {"serial": 1, "pool": workers, "ray": workers, "ray-plan": None}[path]
    return ViewSource(
        graph,
        observation_mode="features",
        encoder=encoder,
        encoder_kwargs=None,
        render_settings=settings,
        world_seed=WORLD_SEED,
        cache_dir=cache_dir,
        progress=False,
        workers=count,
        backend=backend,
        world=world,
    )


def start_seconds(source: Any, path: str, serial_s_per_node: float, workers: int) -> float:
    """A parallel build's start: one batch per worker, less those nodes' serial time."""
    from campusnav_env.features.feature_cache import node_batches

    batches = node_batches(source.graph.n_nodes)[:workers]
    begin = time.perf_counter()
    for _ in source._build_open_views(batches):
        pass
    return (
        time.perf_counter() - begin - serial_s_per_node * sum(map(len, batches)) / (1 if path == "serial" else workers)
    )


def measure(args: argparse.Namespace) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Every build path on one city: wall time, nodes/s, start, features against the serial build's."""
    from campusnav_env.features.encoders import make_encoder
    from campusnav_env.features.parallel_build import stop_workers
    from campusnav_env.rendering.world import build_world

    kwargs = env_kwargs_for(args.encoder)
    encoder = make_encoder(args.encoder, **({"dim": 64} if args.encoder == PIXELS else {}))
    graph = make_graph(args.nodes, "scaled")
    begin = time.perf_counter()
    world = build_world(graph, seed=WORLD_SEED)
    facts: dict[str, Any] = {"world_seconds": time.perf_counter() - begin, "nodes": graph.n_nodes}
    ray = None
    if any(path.startswith("ray") for path in args.paths):
        import ray

        begin = time.perf_counter()
        ray.init(num_cpus=args.workers, include_dashboard=False, logging_level="ERROR")
        facts["ray_init_seconds"] = time.perf_counter() - begin
    rows: list[dict[str, Any]] = []
    serial: np.ndarray | None = None
    serial_s_per_node = 0.0
    try:
        for path in args.paths:
            with tempfile.TemporaryDirectory(prefix="view-build-") as cache_dir:
                source = make_source(
                    graph, world, encoder, kwargs["view_build"].render_settings, Path(cache_dir), path, args.workers
                )
                begin = time.perf_counter()
                features = source.open_views()
                wall = time.perf_counter() - begin
                row = {"path": path, "wall": wall, "rate": graph.n_nodes / wall, "settings": source.settings}
                if path == "ray-plan":
                    from campusnav_env.features.ray_build import _actor_options

                    row["actors"] = len(_actor_options(ray, None))
                else:
                    row["actors"] = 1 if path == "serial" else args.workers
                if serial is None and path == "serial":
                    serial, serial_s_per_node = features, wall / graph.n_nodes
                row["diff"] = float(np.abs(features - serial).max()) if serial is not None else None
                stop_workers()  # the next build starts its own: each pays its start
                row["start"] = (
                    start_seconds(source, path, serial_s_per_node, row["actors"])
                    if path != "serial" and serial_s_per_node
                    else None
                )
                stop_workers()
                rows.append(row)
                print(f"{path}: {wall:.1f} s, {row['rate']:.1f} nodes/s", flush=True)
    finally:
        if ray is not None:
            ray.shutdown()
    return rows, facts


def plan_lines(rows: list[dict[str, Any]], facts: dict[str, Any], workers: int) -> list[str]:
    """The plan on paper for :data:`REGION_NODES` intersections from the measured per-node cost."""
    by_path = {row["path"]: row for row in rows}
    basis = by_path.get("pool") or by_path.get("ray") or by_path["serial"]
    cores = basis["actors"]
    core_s_per_node = basis["wall"] * cores / facts["nodes"]
    startup = facts.get("ray_init_seconds", 0.0) + (basis["start"] or 0.0)
    budget = REGION_MINUTES * 60 - startup
    one_machine = REGION_NODES * core_s_per_node / max(1, workers)
    plan_rows = []
    for per_machine in CORES_PER_MACHINE:
        actors_needed = REGION_NODES * core_s_per_node / budget
        machines = math.ceil((actors_needed + 1) / per_machine)  # one core of the driver's node stays free
        minutes = (startup + REGION_NODES * core_s_per_node / (machines * per_machine - 1)) / 60
        plan_rows.append([str(per_machine), str(machines), f"{machines * per_machine - 1}", f"{minutes:.1f}"])
    return [
        f"## Plan: {REGION_NODES:,} intersections",
        "",
        f"Per node: {core_s_per_node:.3f} core-seconds ({basis['path']} build above: {basis['wall']:.1f} s x "
        f"{cores} cores / {facts['nodes']:,} nodes; render + encode + the driver's shards). On this machine "
        f"({workers} workers): {one_machine / 3600:.1f} h. On a cluster, under {REGION_MINUTES} min with "
        f"{startup:.0f} s of start-up (ray.init + actors' start, measured here), one CPU actor per core:",
        "",
        *markdown_table(["cores per machine", "machines", "actors", "minutes"], plan_rows),
        "",
        f"The driver receives {REGION_NODES * 4 * 1280 * 4 / 1e9:.2f} GB of EfficientNet features (1280 float32 per "
        "view) and writes them as shards: a second of local disk per few hundred MB, not the bottleneck. A GPU "
        "actor per GPU instead (the default plan where the cluster has GPUs) encodes much faster than a core; no GPU "
        "machine was lent to this task, so GPU views per second are not measured here.",
    ]


def main(argv: list[str] | None = None) -> None:
    from campusnav_env.features.ray_build import import_ray
    from campusnav_env.features.view_worker import default_workers

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--nodes", type=int, default=1000, help="intersections of the generated city")
    parser.add_argument("--encoder", default=EFFNET, choices=[EFFNET, PIXELS])
    parser.add_argument("--paths", nargs="+", default=["serial", "pool", "ray"], choices=PATHS)
    parser.add_argument("--workers", type=int, default=min(2, default_workers()), help="processes / Ray actors")
    parser.add_argument("--quick", action="store_true", help="64 intersections, pixel features (a smoke run)")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "view_build.md")
    args = parser.parse_args(argv)
    th.set_num_threads(1)
    if args.quick:
        args.nodes, args.encoder = 64, PIXELS
    if any(path.startswith("ray") for path in args.paths):
        try:
            import_ray()
        except ImportError as e:
            print(f"{e}: measuring without it", file=sys.stderr)
            args.paths = [path for path in args.paths if not path.startswith("ray")]
    if "serial" not in args.paths:
        args.paths = ["serial", *args.paths]  # the reference of the features and of the start-up
    rows, facts = measure(args)
    pool = next((row for row in rows if row["path"] == "pool"), None)
    settings = rows[0]["settings"]
    table = [
        [
            row["path"],
            str(row["actors"]),
            f"{row['wall']:.1f}",
            f"{row['rate']:.2f}",
            f"{row['rate'] / rows[0]['rate']:.2f}",
            f"{row['rate'] / pool['rate']:.2f}" if pool else "-",
            "-" if row["start"] is None else f"{row['start']:.1f}",
            "reference" if row["path"] == "serial" else f"{row['diff']:.1e}",
        ]
        for row in rows
    ]
    lines = [
        "# View build: serial, local pool, Ray",
        "",
        machine_line(
            "the builds one after another, each into a cold cache", torch_threads="1 torch thread per process"
        ),
        "",
        f"{facts['nodes']:,} intersections, encoder {args.encoder}, views rendered at "
        f"{settings.width}x{settings.height}; 3D world built once beforehand in {facts['world_seconds']:.1f} s "
        "(not counted)."
        + (
            f" Ray start-up (ray.init, local instance): {facts['ray_init_seconds']:.1f} s."
            if "ray_init_seconds" in facts
            else ""
        ),
        "",
        *markdown_table(
            [
                "build",
                "processes / actors",
                "seconds",
                "nodes/s",
                "vs serial",
                "vs pool",
                "start s",
                "max abs diff vs serial",
            ],
            table,
        ),
        "",
        *plan_lines(rows, facts, args.workers),
    ]
    publish(args.out, lines, "view_build.py", argv)


if __name__ == "__main__":
    main()
