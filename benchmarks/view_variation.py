"""The K-fold cost of a world whose pictures vary between visits (``view_variation``): the campus's cold view build,
fixed and with K renders of every view, in seconds and cache bytes, per encoder.

Each build is the env's own (``CampusNavEnv(encoder=..., view_variation=...)``, the 101-intersection campus, views at
the env's default 640 x 480, built in this process as the campus's are by default) into a cold cache folder of its
own; the seconds are the env's construction (3D world, renders, encodings, the cache file, the features' fit), the
bytes those of the cache folder it leaves. Fixed views first, then K renders per view: K times the renders and the
encodings, the 3D world once.

Usage::

    python benchmarks/view_variation.py                              # pixels and EfficientNet-Lite0, K = 8
    python benchmarks/view_variation.py --renders 4 --encoders pixels
    python benchmarks/view_variation.py --quick                      # pixel features, 64x48 views, K = 2
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path
from typing import Any

import torch as th

from benchmarks.report import RESULTS_DIR, machine_line, markdown_table, publish
from benchmarks.scale_common import EFFNET, PIXELS

VIEWS_PER_NODE = 4


def cold_build(encoder: str, renders: int | None, small: bool) -> dict[str, Any]:
    """The campus env built into a cold cache of its own: seconds, cache bytes, views rendered."""
    from campusnav_env import CampusNavEnv, ViewBuild
    from campusnav_env.rendering.street_view import RenderSettings

    with tempfile.TemporaryDirectory(prefix="view-variation-") as cache_dir:
        build = ViewBuild(
            render_settings=RenderSettings(64, 48) if small else None, cache_dir=cache_dir, progress=False
        )
        begin = time.perf_counter()
        env = CampusNavEnv(encoder=encoder, view_variation=renders, view_build=build)
        seconds = time.perf_counter() - begin
        cache_bytes = sum(path.stat().st_size for path in Path(cache_dir).rglob("*") if path.is_file())
    views = env.graph.n_nodes * VIEWS_PER_NODE * (renders or 1)
    print(
        f"{encoder}, {'fixed' if renders is None else f'K = {renders}'}: {seconds:.1f} s, {cache_bytes:,} B", flush=True
    )
    return {"encoder": encoder, "renders": renders, "seconds": seconds, "bytes": cache_bytes, "views": views}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--renders", type=int, default=8, help="K: renders of every view")
    parser.add_argument("--encoders", nargs="+", default=[PIXELS, EFFNET], choices=[PIXELS, EFFNET])
    parser.add_argument("--quick", action="store_true", help="pixel features of 64x48 views, K = 2 (a smoke run)")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "view_variation.md")
    args = parser.parse_args(argv)
    th.set_num_threads(1)
    if args.quick:
        args.renders, args.encoders = 2, [PIXELS]
    rows = []
    for encoder in args.encoders:
        fixed = cold_build(encoder, None, args.quick)
        varied = cold_build(encoder, args.renders, args.quick)
        for record in (fixed, varied):
            rows.append(
                [
                    encoder,
                    "fixed" if record["renders"] is None else str(record["renders"]),
                    f"{record['views']:,}",
                    f"{record['seconds']:.1f}",
                    f"{1000 * record['seconds'] / record['views']:.1f}",
                    f"{record['bytes'] / 1e6:.2f}",
                    f"{record['seconds'] / fixed['seconds']:.2f}",
                    f"{record['bytes'] / fixed['bytes']:.2f}",
                ]
            )
    size = "64x48" if args.quick else "640x480"
    lines = [
        "# A world that varies: the K-fold cost of its views",
        "",
        machine_line("the builds one after another in one process, each into a cold cache"),
        "",
        f"The campus (101 intersections), views rendered at {size}, built in this process; seconds: the env's "
        "construction from a cold cache (3D world once, renders, encodings, cache file, the features' fit).",
        "",
        *markdown_table(
            [
                "encoder",
                "renders per view",
                "views",
                "seconds",
                "ms per view",
                "cache MB",
                "x fixed time",
                "x fixed bytes",
            ],
            rows,
        ),
    ]
    publish(args.out, lines, "view_variation.py", argv)


if __name__ == "__main__":
    main()
