"""Scale: how the world build, the time to a solved map and memory grow with 101, 1,000 and 10,000 intersections.

Generated campuses (:func:`campusnav_env.maps.campus.generate_campus`, seed 0, goal Dreese Lab). By default the
extent grows with the map (``--extent scaled``: 2.5 km x 1.7 km times ``sqrt(n / 101)``), so that every size has the
street density of the built-in campus (101 nodes: exactly the built-in campus); at a fixed extent (``--extent fixed``,
as ``campusnav_runs.Task``) 10,000 intersections lie about 20 m apart, less than the 21 m that a road, its verges and
sidewalks take, and the street views no longer show a town.

This script runs the stages of five benchmarks, one question each, in this order, each stage in a fresh process
(spawned; 1 torch thread and 1 BLAS thread) so that its peak RSS is its own, each finished stage appended to a
JSON-lines runs file (an interrupted benchmark keeps them, a rerun skips them), and writes their sections into one
results file:

1. ``buffer`` (``scale_replay.py``): replay-buffer bytes per transition, and what state indices would take instead.
2. ``build`` per size (``scale_world_build.py``): map, 3D world, render + encode of every view into a cold feature
   cache, env construction from the warm cache, peak RSS.
3. ``fit`` per size (``scale_feature_transform.py``): the env's feature transform (standardise, PCA to 64 per view)
   on 1280-d features of the size's view count.
4. ``vecenv`` (``scale_vec_env.py``): env steps/s with ``DummyVecEnv`` and ``SubprocVecEnv``, one env step by part.
5. ``train`` per size (``scale_training.py``): DCQN as shipped until the map is solved or the budget is spent.

Writes ``results/scale.md`` and ``results/scale.png`` (time and memory against intersections, log x); the results
always show every stage in the runs file, so ``--stages`` (or running one of the five scripts) measures one question
again and keeps the others.

Usage::

    python benchmarks/scale.py                                  # 101, 1000, 10000 intersections (about 20 minutes)
    python benchmarks/scale.py --budget 1000=600 10000=300      # more training time for the large maps
    python benchmarks/scale.py --stages vecenv                  # one question (the runs file must not hold it yet)
    python benchmarks/scale.py --quick --out /tmp/scale.md --runs-file /tmp/scale_runs.jsonl   # smoke run, ~1 min
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

from benchmarks.report import RESULTS_DIR, markdown_table, publish, run_missing
from benchmarks.scale_common import EFFNET, GAMMA, MB, PIXELS, Plan, fmt, records_by_size
from benchmarks.scale_stages import feature_transform as scale_feature_transform
from benchmarks.scale_stages import replay as scale_replay
from benchmarks.scale_stages import training as scale_training
from benchmarks.scale_stages import vec_env as scale_vec_env
from benchmarks.scale_stages import world_build as scale_world_build
from benchmarks.scale_stages.world_build import build_peak_mb
from benchmarks.workers import run_in_fresh_process

STAGES = (
    scale_replay.STAGE,
    scale_world_build.STAGE,
    scale_feature_transform.STAGE,
    scale_vec_env.STAGE,
    scale_training.STAGE,
)


def planned_stages(plan: Plan, stages: tuple[str, ...] = STAGES) -> list[tuple[str, int, Callable[..., Any], tuple]]:
    """
    The stages of a run, in order: (stage, size, function, arguments), each function run in a fresh process.

    :param plan: The run
    :param stages: The stages to run (of :data:`STAGES`)
    """
    planned: list[tuple[str, int, Callable[..., Any], tuple]] = [
        (scale_replay.STAGE, 0, scale_replay.measure_replay_buffer, (plan,))
    ]
    planned += [(scale_world_build.STAGE, n, scale_world_build.measure_build, (n, plan)) for n in plan.sizes]
    planned += [(scale_feature_transform.STAGE, n, scale_feature_transform.measure_fit, (n, plan)) for n in plan.sizes]
    planned += [(scale_vec_env.STAGE, plan.sizes[0], scale_vec_env.measure_vecenv, (plan,))]
    planned += [(scale_training.STAGE, n, scale_training.measure_training, (n, plan)) for n in plan.sizes]
    return [stage for stage in planned if stage[0] in stages]


# ------------------------------------------------------------------------------------------------------- the report
# What the measurements say, by the stage that shows it: statements only, the figures are in the tables
FINDINGS = {
    "build": (
        "- **Cold build, one-off, O(N):** the CNN's forward passes (EfficientNet-Lite0, one thread) are the largest "
        "single cost of a large map, the rest is rendering and the 3D world (shares in the table below). It is paid "
        "once per map and settings (the feature cache), and it is not ours to make cheaper short of a smaller encoder "
        "or a GPU. The 3D world's time and memory grow about in proportion to the intersections."
    ),
    "train": (
        "- **Per step, nothing grows with the map:** env.step and a training env step cost about the same at every "
        "size (hop distances for `info['shortest_distance']` are cached per goal, observations are row gathers; the "
        "network and batch do not depend on N).\n"
        "- **Route evaluation grows with 4N starts x route length** (an untrained policy loops early and is stopped, "
        "so a trained one costs more), and so does its memory: all 4N starts go through the policy as one batch. It "
        "is excluded from the training time; `eval_freq` grows with the map to keep it a small part of the wall time.\n"
        "- **Time to threshold grows with the number of states to learn** (samples, not per-step cost; the training "
        "table). The replay buffer's arrays take the same whatever the map (the replay section).\n"
        "- **Long routes, same discount:** with the shipped gamma the goal's reward is worth little from the farthest "
        "start of a large map (last column below), so the value gap between the best action and one a hop longer is "
        "tiny there; SPL at the threshold from every start needs the critics to resolve it everywhere, a likely "
        "reason why SPL, not success, is the last to reach the threshold on large maps (not changed here: the "
        "settings are the shipped ones)."
    ),
    "fit": (
        "- **Ours, and growing with the map in every process that builds an env: the feature transform's PCA** on "
        "1280-d views, fixed (the last table)."
    ),
}


def cost_table(builds: dict[int, dict[str, Any]], trains: dict[int, dict[str, Any]]) -> list[str]:
    """Where the time goes at each size: the one-off build against the recurring costs of training."""
    header = [
        "intersections",
        "cold build, EfficientNet (s)",
        "of which render / encode / 3D world",
        "3D world: memory while built (MB)",
        "env.step (us)",
        "reset (us)",
        "training ms per env step",
        "one route evaluation (s)",
        "its top functions (own time)",
        f"farthest start: hops, worth of the goal's reward (gamma {GAMMA})",
    ]
    rows = []
    for size in sorted(set(builds) | set(trains)):
        build, run = builds.get(size), trains.get(size)
        cells = ["-"] * 3
        if build is not None:
            enc = next((e for e in build["encoders"] if e["encoder"] == EFFNET), build["encoders"][0])
            total = enc["build_seconds"] + build["world_seconds"]
            render = enc["render_s_per_node"] * size
            encode = 4 * enc["encode_s_per_view"] * size
            how = "" if enc["full"] else " (extrapolated)"
            shares = (100 * render / total, 100 * encode / total, 100 * build["world_seconds"] / total)
            cells = [
                f"{total:,.0f}{how}",
                " / ".join(f"{share:.0f}%" for share in shares),
                f"{build['world_extra_mb']:,.0f}",
            ]
        if run is not None:
            top = "; ".join(f"{f['function']} {100 * f['own_share']:.0f}%" for f in run["evaluation_profile"][:3])
            memory = f", {run['evaluation_extra_mb']:,.0f} MB" if "evaluation_extra_mb" in run else ""
            cells += [
                f"{run['env_step_us']:.0f}",
                f"{run['reset_us']:.0f}",
                f"{scale_training.train_ms_per_step(run):.2f}",
                f"{run['profiled_evaluation_seconds']:.2f} ({run['routes']:,} routes, "
                f"success {run['final_success']:.3f}{memory})",
                top,
            ]
        else:
            cells += ["-"] * 5
        hops = build["longest_route"] if build is not None else None
        cells.append("-" if hops is None else f"{hops}: {GAMMA**hops:.4f}")
        rows.append([f"{size:,}", *cells])
    return markdown_table(header, rows)


def cost_section(
    builds: dict[int, dict[str, Any]], trains: dict[int, dict[str, Any]], fits: dict[int, dict[str, Any]]
) -> list[str]:
    """What the measurements say (statements; the figures are in the tables), and the cost table."""
    measured = {"build": builds, "train": trains, "fit": fits}
    return [
        "## Where the cost goes as the map grows",
        "",
        *(FINDINGS[stage] for stage, records in measured.items() if records),
        "",
        *cost_table(builds, trains),
    ]


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
    # "before": only in the records of the run that measured the code before the fix (scale_feature_transform.py)
    for when, style in (("before", "x--"), ("after", "x-")):
        measured = {s: f for s, f in fits.items() if f"{when}_seconds" in f}
        time_points = [(s, f[f"{when}_seconds"], True) for s, f in measured.items()]
        memory_points = [(s, f[f"{when}_extra_mb"], True) for s, f in measured.items()]
        line(left, time_points, f"feature transform, 1280-d, {when} the fix", style)
        line(right, memory_points, f"feature transform, {when} the fix", style)
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


def write_report(plan: Plan, runs: list[dict[str, Any]], out: Path, argv: list[str] | None) -> None:
    """Write the results file (and its picture beside it) from every stage in ``runs``."""
    from benchmarks.report import machine_line

    builds, trains = records_by_size(runs, scale_world_build.STAGE), records_by_size(runs, scale_training.STAGE)
    fits = records_by_size(runs, scale_feature_transform.STAGE)
    buffer = next((r for r in runs if r["stage"] == scale_replay.STAGE), None)
    vec = next((r for r in runs if r["stage"] == scale_vec_env.STAGE), None)
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
        f"at about {fmt(next((r['import_rss_mb'] for r in runs if 'import_rss_mb' in r), None), 0)} MB). "
        "EfficientNet-Lite0 on 640x480 views (the default) is used where a full encode is affordable; above "
        f"{plan.effnet_max_nodes:,} intersections its cost is measured on a sample and extrapolated, and the map is "
        "built and trained with the cheap `pixels` encoder on 64x48 views (stated in every row).",
        "",
        machine_line(
            "stages one after another, each in a fresh process, 1 BLAS thread; other engineers' jobs (another "
            "benchmark) used the other core throughout this run, so CPU-bound figures are slower and noisier than on "
            "a quiet machine"
        ),
    ]
    # Each question's section where the runs file holds its stage (a script of one question writes only its own)
    if builds:
        lines += ["", *scale_world_build.world_build_section(builds)]
    if trains:
        lines += ["", *scale_training.training_section(trains)]
    if buffer is not None:
        lines += ["", *scale_replay.replay_section(buffer, sizes)]
    if vec is not None:
        lines += ["", *scale_vec_env.vec_env_section(vec)]
    if builds or trains:
        lines += ["", *cost_section(builds, trains, fits)]
    if fits:
        lines += ["", *scale_feature_transform.feature_transform_section(fits)]
    lines += ["", f"![time and memory against intersections]({picture.name})"]
    publish(out, lines, "scale.py", argv)


# ------------------------------------------------------------------------------------------------------------ main
def size_values(pairs: list[str] | None, sizes: tuple[int, ...], default: Callable[[int], float]) -> dict[int, float]:
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
    """The run that the command line asks for."""
    from campusnav_env.features.feature_cache import default_cache_dir

    quick = args.quick
    sizes = tuple(args.sizes or ((30, 60) if quick else (101, 1_000, 10_000)))
    if quick:
        budgets = size_values(args.budget, sizes, lambda _: 4.0)
        eval_freq = {size: int(v) for size, v in size_values(args.eval_freq, sizes, lambda _: 500).items()}
        max_steps = dict.fromkeys(sizes, 2_000)  # learning starts at 1,000
    else:
        budgets = size_values(args.budget, sizes, scale_training.default_budget)
        eval_freq = {
            size: int(v) for size, v in size_values(args.eval_freq, sizes, scale_training.default_eval_freq).items()
        }
        max_steps = {size: 60_000 if size <= 200 else 3_000_000 for size in sizes}
    return Plan(
        sizes=sizes,
        budgets=budgets,
        eval_freq=eval_freq,
        max_steps=max_steps,
        extent=args.extent,
        effnet_max_nodes=args.effnet_max_nodes,
        effnet_sample=2 if quick else args.effnet_sample,
        vec_counts=(1,) if quick else (1, 2, 4),
        vec_seconds=0.5 if quick else 4.0,
        env_steps=500 if quick else 5_000,
        quick=quick,
        cache_dir=str(args.cache_dir or default_cache_dir() / "scale"),
    )


def run_stage(stage: tuple[str, int, Callable[..., Any], tuple]) -> dict[str, Any]:
    """Run a planned stage in a fresh process (its peak memory its own); its record, with the stage's wall time."""
    _, _, function, function_args = stage
    begin = time.perf_counter()
    record = run_in_fresh_process(function, *function_args)
    record["stage_wall_seconds"] = time.perf_counter() - begin
    return record


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", nargs="+", type=int, help="intersections (default 101 1000 10000; quick: 30 60)")
    parser.add_argument("--stages", nargs="+", choices=STAGES, default=list(STAGES), help="stages to run (all)")
    parser.add_argument("--budget", nargs="+", help="training seconds: SIZE=SECONDS per size, or one number for all")
    parser.add_argument("--eval-freq", nargs="+", help="env steps between route evaluations: SIZE=STEPS, or one number")
    parser.add_argument("--extent", choices=("scaled", "fixed"), default="scaled")
    parser.add_argument("--effnet-max-nodes", type=int, default=1_000, help="largest map encoded with EfficientNet")
    parser.add_argument("--effnet-sample", type=int, default=32, help="nodes encoded to extrapolate larger maps")
    parser.add_argument("--cache-dir", type=Path, help="feature cache (default: $CAMPUSNAV_CACHE/scale)")
    parser.add_argument("--quick", action="store_true", help="smoke run: 30 and 60 nodes, pixel features, ~1 min")
    parser.add_argument("--runs-file", type=Path, default=RESULTS_DIR / "scale_runs.jsonl")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "scale.md")
    args = parser.parse_args(argv)
    # Children inherit these: one BLAS thread, like the one torch thread (another benchmark uses the other core)
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[name] = "1"
    plan = make_plan(args)
    print(f"plan: {asdict(plan)}", flush=True)
    runs = run_missing(
        args.runs_file,
        planned_stages(plan, tuple(args.stages)),
        run_stage,
        key=lambda r: (r["stage"], r["size"]),
        job_key=lambda stage: stage[:2],
        describe=lambda r: f"{r['stage']} {r['size']}: done in {r['stage_wall_seconds']:.0f} s",
        noun="stages",
    )
    write_report(plan, runs.records, args.out, argv)


if __name__ == "__main__":
    main()
