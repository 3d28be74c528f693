"""City scale: env steps and seconds to a solved city against its intersections, one entry at every size, beside the
place floor.

Every size runs the one city entry (``CampusNavCity-v0``'s, route memory on, as shipped) on a generated city of that
many intersections (``CampusNavCity-v0``'s ``n_intersections``; sizes 2,626 and 4,406 are those of Liechtenstein and
Baltimore, generated: no real map is on this machine), goal Dreese Lab, until it is solved from every (start,
heading): success >= 0.99 and SPL >= 0.98 (``train_until_solved``; training seconds, evaluations excluded). On cities
of :data:`SAMPLED_FROM` intersections and more, the checks during training evaluate a seeded sample of
:data:`SAMPLE` pairs, and a sample at the bar is confirmed by an evaluation of every pair before the city counts as
solved (``RouteEvaluationCallback(sample=...)``). Beside each run, the place floor on the same city (the
experience-graph agent with the memory's knowledge, ``experience_graph_floor.py``'s ``--memory places``): no learner
that must explore needs fewer env steps; ``ratio`` is DCQN's env steps over the floor's. The slope is a least-squares
fit of log(env steps) on log(intersections) over the sizes from 1,000 up.

Each size builds its views once (a cold cache costs what ``scale_world_build.py`` and the build table of the results
measure); runs are appended to the runs files as they finish and a rerun skips them::

    python benchmarks/city_scale.py --sizes 101 1000 2626 4406 10000 56000 --seeds 0
    python benchmarks/city_scale.py --quick      # a smoke run: 101 intersections, seconds
"""

from __future__ import annotations

import argparse
import math
import statistics
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks import floor_runs
from benchmarks.city_runs import PIXELS, Job, job_entry, make_env, median_worst, run_one
from benchmarks.report import (
    RESULTS_DIR,
    append_run,
    first_paragraph,
    machine_line,
    markdown_table,
    publish,
    read_runs,
    run_missing,
)

SIZES = (101, 1_000, 2_626, 4_406, 10_000, 56_000)
MAP_SEED = 71  # a city seed no entry was tuned on
SAMPLED_FROM = 10_000  # intersections from which the checks during training evaluate a sample
SAMPLE = 4_000  # (start, heading) pairs of a sampled check: a success rate of 1.0 bounds the true one at 0.999 (95%)
SLOPE_FROM = 1_000  # the slope is fitted over the sizes from here up
RUN_KEY = ("size", "map_seed", "seed", "encoder")


def eval_freq(size: int) -> int:
    """Env steps between checks (DCQN's and the floor's): an evaluation routes every pair (or a sample), so sparser on
    big maps; the steps to solved are exact to within this."""
    return (
        250
        if size <= 200
        else 1_000
        if size <= 2_000
        else 2_500
        if size <= 5_000
        else 5_000
        if size <= 20_000
        else 20_000
    )


def budget(size: int) -> float:
    """Training seconds a size may take before it counts as a miss."""
    return 120.0 if size <= 2_000 else 300.0 if size <= 20_000 else 900.0


def job_for(size: int, seed: int, map_seed: int, encoder: str, quick: bool) -> Job:
    return Job(
        "shipped",
        size,
        seed,
        min(budget(size), 10.0) if quick else budget(size),
        3_000 if quick else 2_000_000,
        eval_freq(size),
        encoder,
        quick,
        map_seed,
        sample=SAMPLE if size >= SAMPLED_FROM else None,
    )


def run_floor(job: Job) -> dict[str, Any]:
    """The place floor on the job's city (the same views as the DCQN run, so no second build)."""
    env = make_env(job, job_entry(job).env_kwargs).unwrapped
    return floor_runs.run_one(
        job.size,
        job.seed,
        eval_freq(job.size),
        job.quick,
        env=env,
        map_seed=job.map_seed,
        memory="places",
        sample=SAMPLE if job.size >= SAMPLED_FROM else None,
    )


# ------------------------------------------------------------------------------------------------ report
def slope(sizes: list[int], steps: list[float]) -> float | None:
    """Least-squares slope of log(steps) on log(sizes); None with fewer than two sizes."""
    if len(set(sizes)) < 2:
        return None
    return float(np.polyfit(np.log(sizes), np.log(steps), 1)[0])


def scale_rows(runs: list[dict[str, Any]], floors: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per (size, map seed, features): DCQN's runs and the floor's, medians and worst cases."""
    groups: dict[tuple[int, int, str], list[dict[str, Any]]] = {}
    for run in runs:
        groups.setdefault((run["size"], run["map_seed"], run["encoder"]), []).append(run)
    rows = []
    for (size, map_seed, encoder), group in sorted(groups.items()):
        solved = [r for r in group if r["solved"]]
        floor = [f["env_steps"] for f in floors if f["size"] == size and f["map_seed"] == map_seed and f["solved"]]
        steps = [r["steps"] if r["solved"] else r["final_steps"] for r in group]
        seconds = [r["seconds"] if r["solved"] else r["final_seconds"] for r in group]
        rows.append(
            {
                "size": size,
                "map_seed": map_seed,
                "encoder": encoder,
                "runs": group,
                "solved": len(solved),
                "steps": steps,
                "seconds": seconds,
                "floor": floor,
                "ratio": statistics.median(r["steps"] for r in solved) / statistics.median(floor)
                if solved and floor
                else None,
            }
        )
    return rows


def scale_table(rows: list[dict[str, Any]]) -> list[str]:
    header = [
        "intersections",
        "features",
        "seeds",
        "solved",
        "env steps to solved: median (worst)",
        "place floor (env steps)",
        "DCQN / floor",
        "training s to solved: median (worst)",
        "ms per env step",
        "peak RSS (MB)",
        "memory B per place",
        "evaluations (s, all)",
        "final success / SPL (worst)",
    ]
    lines = []
    for row in rows:
        group = row["runs"]
        lines.append(
            [
                f"{row['size']:,}",
                row["encoder"],
                " ".join(str(r["seed"]) for r in group),
                f"{row['solved']}/{len(group)}",
                median_worst(row["steps"]),
                median_worst(row["floor"]),
                "-" if row["ratio"] is None else f"{row['ratio']:.2f}",
                median_worst(row["seconds"]) + ("" if row["solved"] == len(group) else " (misses: their budget)"),
                f"{statistics.median(r['ms_per_step'] for r in group):.2f}",
                f"{max(r['peak_rss_mb'] for r in group):,.0f}",
                f"{statistics.median(r.get('memory_bytes_per_state', math.nan) for r in group):,.0f}",
                f"{max(r.get('evaluations', 0) for r in group)} ({max(r['evaluation_seconds'] for r in group):,.0f})",
                f"{min(r['final_success'] for r in group):.3f} / {min(r['final_spl'] for r in group):.3f}",
            ]
        )
    return markdown_table(header, lines)


def slope_lines(rows: list[dict[str, Any]]) -> list[str]:
    """The fitted slopes of DCQN's and the floor's env steps (and DCQN's seconds) against intersections."""
    # One line per size: the features every size was run with (pixels), the others' rows stand beside it
    fitted = [r for r in rows if r["size"] >= SLOPE_FROM and r["solved"] == len(r["runs"]) and r["encoder"] == PIXELS]
    sizes = [r["size"] for r in fitted]
    lines = []
    for name, values in (
        ("DCQN env steps", [statistics.median(r["steps"]) for r in fitted]),
        ("DCQN training seconds", [statistics.median(r["seconds"]) for r in fitted]),
    ):
        value = slope(sizes, values)
        lines.append(f"- {name}: slope {'-' if value is None else f'{value:.2f}'} over {len(sizes)} sizes")
    with_floor = [r for r in fitted if r["floor"]]
    value = slope([r["size"] for r in with_floor], [statistics.median(r["floor"]) for r in with_floor])
    lines.append(
        f"- place floor env steps: slope {'-' if value is None else f'{value:.2f}'} over {len(with_floor)} sizes"
    )
    return lines


def draw(rows: list[dict[str, Any]], path: Path) -> None:
    """Env steps and training seconds to solved against intersections, log-log, the floor beside them."""
    from matplotlib.figure import Figure

    from campusnav_env.figures import figure_image, write_figure

    figure = Figure(figsize=(11, 4.6), dpi=100, layout="constrained")
    left, right = figure.subplots(1, 2)
    solved = [r for r in rows if r["solved"]]
    for axis, key, label in ((left, "steps", "env steps to solved"), (right, "seconds", "training seconds to solved")):
        axis.loglog(
            [r["size"] for r in solved], [statistics.median(r[key]) for r in solved], "o-", label="DCQN + memory"
        )
        missed = [r for r in rows if not r["solved"]]
        if missed:
            axis.loglog(
                [r["size"] for r in missed],
                [max(r[key]) for r in missed],
                "x",
                color="red",
                label="not solved (budget)",
            )
        axis.set_xlabel("intersections")
        axis.set_ylabel(label)
        axis.grid(True, which="both", alpha=0.3)
    floored = [r for r in rows if r["floor"]]
    left.loglog(
        [r["size"] for r in floored], [statistics.median(r["floor"]) for r in floored], "s--", label="place floor"
    )
    left.legend()
    right.legend()
    figure.suptitle("One city entry at every size (generated cities, fixed views)")
    write_figure(path, figure_image(figure))


def write_report(runs: list[dict[str, Any]], floors: list[dict[str, Any]], out: Path, argv: list[str] | None) -> None:
    rows = scale_rows(runs, floors)
    picture = out.with_suffix(".png")
    if rows:
        draw(rows, picture)
    machine = machine_line("sizes one after another, each in one process", torch_threads="1 torch thread")
    lines = [
        "# City scale: one entry at every size",
        "",
        first_paragraph(__doc__),
        "",
        machine,
        "",
        f"Views: fixed (the paper's world), 64x48 pixel features projected to 64 per view; map seed {MAP_SEED} "
        "unless the table says otherwise. Medians (worst) over the seeds; a run that spent its budget counts with "
        "its budget. Memory B per place: the route memory pickled (as in the model's file) over its places. "
        "Evaluations: how many checks ran and their seconds, outside the training seconds.",
        "",
        *scale_table(rows),
        "",
        "Slopes of log-log fits (pixel features, sizes from 1,000 up, all seeds solved):",
        "",
        *slope_lines(rows),
        "",
        f"![env steps and seconds against intersections]({picture.name})",
    ]
    publish(out, lines, "city_scale.py", argv)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=list(SIZES))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--map-seed", type=int, default=MAP_SEED)
    parser.add_argument("--encoder", default=PIXELS, help="features: pixels (64x48 views) or efficientnet-lite0")
    parser.add_argument(
        "--parts",
        nargs="+",
        choices=("floor", "dcqn"),
        default=["floor", "dcqn"],
        help="what to run (the table reads every run there is: two processes may run the parts side by side)",
    )
    parser.add_argument("--quick", action="store_true", help="smoke run: 101 intersections, seconds")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "city_scale.md")
    args = parser.parse_args(argv)
    sizes = [101] if args.quick else args.sizes
    seeds = [0] if args.quick else args.seeds
    runs_file = args.out.with_name(args.out.stem + "_runs.jsonl")
    floor_file = args.out.with_name(args.out.stem + "_floor_runs.jsonl")
    jobs = [job_for(size, seed, args.map_seed, args.encoder, args.quick) for size in sizes for seed in seeds]
    floors = [r for r in read_runs(floor_file) if r.get("quick", False) == args.quick]
    if "floor" in args.parts:
        done = {(f["size"], f["map_seed"], f["seed"]) for f in floors}
        for job in jobs:
            if (job.size, job.map_seed, job.seed) not in done:
                record = run_floor(job)
                append_run(floor_file, record)
                floors.append(record)
                print(f"floor {job.size:,}: solved {record['solved']} at {record['env_steps']:,} env steps", flush=True)
    runs = run_missing(
        runs_file,
        jobs if "dcqn" in args.parts else [],
        run_one,
        key=lambda r: tuple(r[k] for k in RUN_KEY),
        job_key=lambda job: (job.size, job.map_seed, job.seed, job.encoder),
        settings={"quick": args.quick},
        describe=lambda run: (
            f"{run['size']:,} seed {run['seed']}: solved {run['solved']} at {run['steps']:,} steps, "
            f"{run['seconds']:.0f} s (success {run['final_success']:.3f}, SPL {run['final_spl']:.3f})"
        ),
    )
    write_report(runs.records, floors, args.out, argv)


if __name__ == "__main__":
    main()
