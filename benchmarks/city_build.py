"""City build: what a cold build of a city's views costs as the map grows, what comes before the first view, and what
a resumed build keeps.

Per size (generated cities, ``CampusNavCity-v0``'s ``n_intersections``, map seed :data:`MAP_SEED`), each in a fresh
process (its own peak RSS):

- **before the views**: the map (``generate_city``), the 3D world placed around it (``build_world``: buildings, trees,
  parks) and written to the cache folder, the world read back as a resumed build reads it
  (:mod:`campusnav_env.features.world_cache`, maps of 2,000 intersections and more), the world's file size;
- **the views**: a sample of nodes rendered and encoded by the env's own build paths, this machine's pool of worker
  processes (one per core) and a local Ray (as many actors), each path's start (the first batch: workers import,
  unpickle the world, build the renderer) and its rate after; EfficientNet-Lite0's rate per core on a smaller sample;
- **projected**: the cold build of every view = before + start + nodes / (rate per worker x workers x machines), on
  this machine and on N such machines (a Ray cluster of N machines of as many cores: the world and the renderer are
  per actor, so the rate adds up; the cache is written where the driver runs).

The views' cache is resumable batch by batch (``feature_cache``); with the world kept too, a resumed build redoes only
the world's read, the workers' start and at most a batch per worker. Usage::

    python benchmarks/city_build.py --sizes 1000 2626 4406 10000 56000
    python benchmarks/city_build.py --quick     # a smoke run: 300 intersections, a few nodes
"""

from __future__ import annotations

import argparse
import functools
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.report import RESULTS_DIR, first_paragraph, machine_line, markdown_table, publish, run_missing
from benchmarks.scale_common import peak_memory
from benchmarks.workers import run_in_fresh_process

MAP_SEED = 71
SIZES = (1_000, 2_626, 4_406, 10_000, 56_000)
SAMPLE_NODES = 800  # nodes of the sampled view builds (100 batches of 8)
EFFNET_NODES = 24  # nodes of EfficientNet's per-core rate
MACHINES = (1, 4, 16)  # machines of this one's cores the projection is made for
PIXELS, EFFNET = "pixels", "efficientnet-lite0"


def _timed_batches(batches: Any) -> tuple[float, float, int]:
    """Seconds to the first finished batch, seconds after it, and nodes built after it."""
    began = time.perf_counter()
    first = None
    after = 0
    for nodes, _ in batches:
        if first is None:
            first = time.perf_counter() - began
        else:
            after += len(nodes)
    total = time.perf_counter() - began
    return float(first or 0.0), total - float(first or 0.0), after


def measure(size: int, sample: int, effnet_nodes: int, workers: int, ray: bool) -> dict[str, Any]:
    """One size's record (run in a fresh process)."""
    import torch

    torch.set_num_threads(1)
    from campusnav_env.features.encoders import make_encoder
    from campusnav_env.features.feature_cache import encode_batches, node_batches
    from campusnav_env.features.parallel_build import encode_batches_in_workers, stop_workers
    from campusnav_env.features.view_source import settings_for_encoder
    from campusnav_env.features.world_cache import cached_world, world_cache_path
    from campusnav_env.maps.campus import generate_city
    from campusnav_env.rendering.street_view import RenderSettings, StreetViewRenderer

    record: dict[str, Any] = {"size": size, "map_seed": MAP_SEED, "sample": sample, "workers": workers}
    with peak_memory() as peak, tempfile.TemporaryDirectory() as cache:
        began = time.perf_counter()
        graph = generate_city(size, seed=MAP_SEED)
        record["map_s"] = time.perf_counter() - began
        began = time.perf_counter()
        world = cached_world(graph, 0, cache)
        record["world_s"] = time.perf_counter() - began  # placed, and written where the map is big enough
        path = world_cache_path(graph, 0, cache)
        record["world_file_mb"] = path.stat().st_size / 2**20 if path.exists() else None
        record["buildings"], record["trees"] = len(world.buildings), len(world.trees)
        if path.exists():
            began = time.perf_counter()
            world = cached_world(graph, 0, cache)
            record["world_read_s"] = time.perf_counter() - began
    record["placement_peak_rss_mb"] = peak.peak_mb
    nodes = min(sample, size)
    for encoder_name, count in ((PIXELS, nodes), (EFFNET, min(effnet_nodes, size))):
        encoder = make_encoder(encoder_name)
        settings = settings_for_encoder(RenderSettings(64, 48) if encoder_name == PIXELS else RenderSettings(), encoder)
        make_renderer = functools.partial(StreetViewRenderer, world, settings)
        batches = node_batches(count)
        began = time.perf_counter()
        renderer = make_renderer()
        for _ in encode_batches(batches, renderer.render_node, encoder):
            pass
        record[f"{encoder_name}_per_core_nodes_s"] = count / (time.perf_counter() - began)
        if encoder_name != PIXELS:
            continue
        start, after, built = _timed_batches(
            encode_batches_in_workers(batches, make_renderer, encoder, workers=workers)
        )
        stop_workers()
        record["pool_start_s"], record["pool_nodes_s"] = start, built / after if after > 0 else None
        if ray:
            from campusnav_env.features.ray_build import encode_batches_on_ray

            start, after, built = _timed_batches(encode_batches_on_ray(batches, make_renderer, encoder, actors=workers))
            record["ray_start_s"], record["ray_nodes_s"] = start, built / after if after > 0 else None
    return record


def run_size(job: tuple[int, int, int, int, bool]) -> dict[str, Any]:
    return run_in_fresh_process(measure, *job)


def projected_minutes(record: dict[str, Any], encoder: str, machines: int) -> float | None:
    """Minutes of a cold build of every view: before + the pool's start + nodes at the per-worker rate of the sample."""
    workers = record["workers"]
    if encoder == PIXELS:
        rate = record.get("pool_nodes_s")  # the pool's measured rate: every worker together
        per_worker = rate / workers if rate else None
    else:
        per_worker = record[f"{encoder}_per_core_nodes_s"]  # in-process; the pool's overhead is the pixels' start
    if not per_worker:
        return None
    before = record["map_s"] + record["world_s"] + record["pool_start_s"]
    return (before + record["size"] / (per_worker * workers * machines)) / 60


def build_table(records: list[dict[str, Any]]) -> list[str]:
    header = [
        "intersections",
        "map (s)",
        "3D world placed and kept (s)",
        "buildings / trees",
        "world file (MB)",
        "world read back (s)",
        "peak RSS of the placement (MB)",
        "pool start (s)",
        "pool: nodes/s (pixels)",
        "Ray start (s)",
        "Ray: nodes/s (pixels)",
        "per core: nodes/s pixels / EfficientNet",
    ]

    def number(value: Any, digits: int = 1) -> str:
        return "-" if value is None else f"{value:,.{digits}f}"

    rows = [
        [
            f"{r['size']:,}",
            number(r["map_s"]),
            number(r["world_s"]),
            f"{r['buildings']:,} / {r['trees']:,}",
            number(r["world_file_mb"]),
            number(r.get("world_read_s")),
            number(r["placement_peak_rss_mb"], 0),
            number(r["pool_start_s"]),
            number(r["pool_nodes_s"]),
            number(r.get("ray_start_s")),
            number(r.get("ray_nodes_s")),
            f"{number(r['pixels_per_core_nodes_s'])} / {number(r[EFFNET + '_per_core_nodes_s'], 2)}",
        ]
        for r in sorted(records, key=lambda r: r["size"])
    ]
    return markdown_table(header, rows)


def projection_table(records: list[dict[str, Any]]) -> list[str]:
    header = ["intersections", "features", *[f"{m} machine{'s' if m > 1 else ''} (min)" for m in MACHINES]]
    rows = []
    for record in sorted(records, key=lambda r: r["size"]):
        for encoder in (PIXELS, EFFNET):
            minutes = [projected_minutes(record, encoder, m) for m in MACHINES]
            rows.append([f"{record['size']:,}", encoder, *["-" if m is None else f"{m:,.1f}" for m in minutes]])
    return markdown_table(header, rows)


def write_report(records: list[dict[str, Any]], out: Path, argv: list[str] | None) -> None:
    machine = machine_line("sizes one after another, each in a fresh process", torch_threads="1 torch thread")
    lines = [
        "# City build: before the views, the views, and N machines",
        "",
        first_paragraph(__doc__),
        "",
        machine,
        "",
        f"Generated cities, map seed {MAP_SEED}; pixel features on 64x48 views (rendered at the encoder's size), "
        "EfficientNet-Lite0 on 640x480 views rendered at 299x224. Pool and Ray: the sample's nodes built by "
        f"{records[0]['workers'] if records else '-'} worker processes / actors; start: the first batch; rate: "
        "the nodes after it over their seconds.",
        "",
        *build_table(records),
        "",
        "Projected cold build of every view (before the views + the pool's start + the nodes at the measured rate "
        "per worker, times the workers of one machine and the machines):",
        "",
        *projection_table(records),
    ]
    publish(out, lines, "city_build.py", argv)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=list(SIZES))
    parser.add_argument("--sample", type=int, default=SAMPLE_NODES, help="nodes of the sampled view builds")
    parser.add_argument("--workers", type=int, default=2, help="worker processes and Ray actors")
    parser.add_argument("--no-ray", action="store_true", help="the local pool only")
    parser.add_argument("--quick", action="store_true", help="smoke run: 300 intersections, 16 nodes")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "city_build.md")
    args = parser.parse_args(argv)
    sizes, sample, effnet = ([300], 16, 2) if args.quick else (args.sizes, args.sample, EFFNET_NODES)
    jobs = [(size, sample, effnet, args.workers, not args.no_ray) for size in sizes]
    runs = run_missing(
        args.out.with_name(args.out.stem + "_runs.jsonl"),
        jobs,
        run_size,
        key=lambda r: (r["size"], r["map_seed"], r["sample"], r["workers"]),
        job_key=lambda job: (job[0], MAP_SEED, job[1], job[3]),
        describe=lambda r: f"{r['size']:,}: world {r['world_s']:.1f} s, pool {r['pool_nodes_s'] or 0:.1f} nodes/s",
    )
    write_report(runs.records, args.out, argv)


if __name__ == "__main__":
    main()
