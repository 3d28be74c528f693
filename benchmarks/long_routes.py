"""Long routes on a city: what each long-route lever buys, in env steps and seconds to a solved map, against the floor.

Routes on a city are 45 hops long at 1,000 intersections and 132 at 10,000 (seed 0, Dreese Lab). The rows: the
CampusNav-v0 entry on the city (today's agent: gamma 0.95, one-step returns, epsilon-greedy from random starts), that
entry with one lever added, and the shipped ``CampusNavCity`` entry (its levers together). The levers:

- ``gamma``: discount 0.99 (the gap between the values of 131 and 132 hops is ``gamma^131 (1 - gamma)``);
- ``nstep``: n-step returns with Dict observations (DCQN's Dict buffer; SB3 refuses them);
- ``curriculum``: starts near the goal first, farther as the agent succeeds (StreetLearn's near-to-far,
  :class:`~campusnav_env.callbacks.StartCurriculumCallback`; the agent never sees the distances);
- ``her``: hindsight relabelling with the goal-conditioned env on the same city (``CampusNavGoal``, episodes to the
  one goal, transitions relabelled with the places reached);
- ``count``: a count bonus on observation digests (exploration towards unvisited views);
- ``memory``: greedy actions planned over the route memory (DCQN's ``route_memory=dict(explore=False)``,
  SPTM/SoRB-style), the critics' greedy action where the memory has no route; ``memory_explore``: the memory as
  shipped (``route_memory=True``): also exploration toward the nearest untried road of the memory in place of
  epsilon's random action;
- ``lean``: lean replay (memory only: it must not change what is learned).

Solved: success >= 0.99 and SPL >= 0.98 from every (start, heading) (``train_until_solved``; time: training seconds,
evaluations excluded). The floor: env steps of the experience-graph agent (``experience_graph_floor.py``'s runs file).
Each run is one process of one torch thread; runs already in the runs file are skipped::

    python benchmarks/long_routes.py --size 1000 --rows base gamma nstep curriculum her count memory explore \
        memory_explore shipped --seeds 0 --budget 300 --workers 2
    python benchmarks/long_routes.py --size 1000 --rows shipped --seeds 0 1 2 --budget 300 --encoder efficientnet-lite0
    python benchmarks/long_routes.py --quick     # a smoke run: 101 intersections, pixel features, seconds
    python benchmarks/long_routes.py --map-seed 23 --rows base memory_explore --floor-runs-file \
        benchmarks/results/new_map_floor_runs.jsonl --out benchmarks/results/new_map.md   # a city never tuned on
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path
from typing import Any

from benchmarks.city_runs import PIXELS, ROWS, Job, median_worst, run_one
from benchmarks.report import (
    RESULTS_DIR,
    first_paragraph,
    machine_line,
    markdown_table,
    measured_on,
    publish,
    read_runs,
    run_missing,
)
from benchmarks.workers import workers_argument

# ------------------------------------------------------------------------------------------------ report
FLOOR_RUNS = RESULTS_DIR / "experience_graph_floor_runs.jsonl"


def floor_steps(
    size: int, key: str = "env_steps", map_seed: int = 0, runs_file: Path = FLOOR_RUNS, memory: str = "poses"
) -> list[int]:
    """
    Env steps to solved of the experience-graph floor on this map (its runs file; records without a map seed are
    of map seed 0, records without a memory are of poses): from every (start, heading) (``env_steps``), or from the
    states a move leads to (``driven_solved_steps``: the floor's exploration alone, without its wait for each
    start-only state to come up as a random start). ``memory``: the floor with the same knowledge as the row
    (``"places"`` for rows with the route memory, ``"poses"`` for the critics alone)
    """
    runs = read_runs(runs_file)
    solved = [
        r
        for r in runs
        if r.get("size") == size
        and r.get("map_seed", 0) == map_seed
        and not r.get("quick")
        and r.get("memory", "poses") == memory
    ]
    return [int(r[key]) for r in solved if r.get(key) is not None and (r.get("solved") or key != "env_steps")]


def row_uses_memory(row: str) -> bool:
    """Whether a row's DCQN keeps the route memory (its floor is then the floor over places): the layer's reading of
    the setting, not its truthiness (``{}``, the memory's defaults, keeps one)."""
    from sb3_dcqn.route_memory.layer import memory_settings

    return row == "shipped" or memory_settings(ROWS[row].overrides.get("route_memory")) is not None


def ablation_table(runs: list[dict[str, Any]], floor_runs: Path = FLOOR_RUNS) -> list[str]:
    """
    One line per (size, map seed, features, row): solved runs, time and env steps to solved, the ratio to the floor
    of the same size and map seed, final scores.
    """
    header = [
        "intersections",
        "map seed",
        "features",
        "row",
        "step cap",
        "seeds",
        "solved",
        "training s to solved: median (worst)",
        "env steps to solved: median (worst)",
        "DCQN steps / floor (median)",
        "DCQN steps / floor's exploration alone",
        "final success: median (worst)",
        "final SPL: median (worst)",
        "ms per env step",
        "peak RSS (MB)",
        "replay B / transition",
    ]
    groups: dict[tuple[int, int, str, str, int], list[dict[str, Any]]] = {}
    for run in runs:
        key = (run["size"], run.get("map_seed", 0), run["encoder"], run["row"], run["max_steps"])
        groups.setdefault(key, []).append(run)
    order = list(ROWS)
    lines = []
    for (size, map_seed, encoder, row, cap), group in sorted(
        groups.items(), key=lambda item: (*item[0][:3], order.index(item[0][3]), item[0][4])
    ):
        solved = [r for r in group if r["solved"]]
        # A run that spent its budget counts with its budget: the worst case is at least that
        seconds = [r["seconds"] if r["solved"] else r["final_seconds"] for r in group]
        steps = [r["steps"] if r["solved"] else r["final_steps"] for r in group]
        ratios = []
        solved_steps = [r["steps"] for r in solved]
        memory = "places" if row_uses_memory(row) else "poses"
        for key in ("env_steps", "driven_solved_steps"):
            floor = floor_steps(size, key, map_seed, floor_runs, memory)
            ratio = statistics.median(solved_steps) / statistics.median(floor) if floor and solved else None
            ratios.append("-" if ratio is None else f"{ratio:.1f}")
        time_cell = median_worst(seconds) + ("" if len(solved) == len(group) else " (misses: their budget)")
        lines.append(
            [
                f"{size:,}",
                str(map_seed),
                encoder,
                ROWS[row].name,
                f"{cap:,}",
                " ".join(str(r["seed"]) for r in sorted(group, key=lambda r: r["seed"])),
                f"{len(solved)}/{len(group)}",
                time_cell,
                median_worst(steps),
                *ratios,
                median_worst([r["final_success"] for r in group], worst_is_max=False, digits=3),
                median_worst([r["final_spl"] for r in group], worst_is_max=False, digits=3),
                f"{statistics.median(r['ms_per_step'] for r in group):.2f}",
                f"{max(r['peak_rss_mb'] for r in group):,.0f}",
                f"{statistics.median(r['replay_bytes_per_transition'] for r in group):,.0f}",
            ]
        )
    return markdown_table(header, lines)


def write_report(runs: list[dict[str, Any]], out: Path, argv: list[str] | None, floor_runs: Path = FLOOR_RUNS) -> None:
    machine = machine_line("runs one after another, each in one process", torch_threads="1 torch thread per run")
    maps = {(r["size"], r.get("map_seed", 0)) for r in runs}
    floors = sorted(
        m
        for m in maps
        if any(floor_steps(m[0], map_seed=m[1], runs_file=floor_runs, memory=memory) for memory in ("places", "poses"))
    )
    lines = [
        "# Long routes: what each lever buys on a city",
        "",
        first_paragraph(__doc__),
        "",
        measured_on(out, machine),
        "",
        "Solved: success >= 0.99 and SPL >= 0.98 from every (start, heading), goal Dreese Lab, evaluated every N env "
        "steps inside one `learn()` call; time: training seconds, evaluations excluded; a run that spent its budget "
        "counts with its budget and its last evaluation. Floor: the experience-graph agent's median env steps to "
        "solved from every (start, heading), and from the states a move leads to (its exploration alone: the rest "
        "is waiting for each start-only state to come up as a random start, which DCQN, whose critics generalise "
        f"across headings, need not do; `{floor_runs.name}`, the floor of the same size and map seed, with the same "
        "knowledge: over places for the rows with the route memory, over poses for the others; maps with a "
        f"floor: {', '.join(f'{s:,} (map seed {m})' for s, m in floors) or 'none'}). Ratios over solved runs only.",
        "",
        *ablation_table(runs, floor_runs),
    ]
    publish(out, lines, "long_routes.py", argv)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", type=int, default=1_000, help="intersections of the city")
    parser.add_argument("--rows", nargs="+", default=["base", "shipped"], choices=list(ROWS))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--budget", type=float, default=300.0, help="training seconds per run (evaluations excluded)")
    parser.add_argument("--max-steps", type=int, default=None, help="env-step cap per run (default: 2M)")
    parser.add_argument("--eval-freq", type=int, default=None, help="env steps between route evaluations")
    parser.add_argument("--encoder", default=PIXELS, help="features: pixels (64x48 views) or efficientnet-lite0")
    parser.add_argument("--map-seed", type=int, default=0, help="seed of the generated city (CampusNavCity's map_seed)")
    parser.add_argument("--quick", action="store_true", help="smoke run: 101 intersections, a few seconds per row")
    parser.add_argument(
        "--floor-runs-file", type=Path, default=FLOOR_RUNS, help="the experience-graph floor's runs (for the ratios)"
    )
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "long_routes.md")
    parser.add_argument("--runs-file", type=Path, default=None, help="default: next to --out, *_runs.jsonl")
    workers_argument(parser)
    args = parser.parse_args(argv)
    if args.quick:
        args.size, args.budget, args.encoder = 101, min(args.budget, 5.0), PIXELS
    eval_freq = args.eval_freq or (1_000 if args.size <= 200 else 5_000 if args.size <= 2_000 else 20_000)
    max_steps = args.max_steps or (3_000 if args.quick else 2_000_000)
    runs_file = args.runs_file or args.out.with_name(args.out.stem + "_runs.jsonl")
    jobs = [
        Job(row, args.size, seed, args.budget, max_steps, eval_freq, args.encoder, args.quick, args.map_seed)
        for row in args.rows
        for seed in args.seeds
    ]
    runs = run_missing(
        runs_file,
        jobs,
        run_one,
        key=lambda r: (r["row"], r["size"], r.get("map_seed", 0), r["seed"], r["encoder"], r["max_steps"]),
        job_key=lambda job: (job.row, job.size, job.map_seed, job.seed, job.encoder, job.max_steps),
        workers=args.workers,
        describe=lambda run: (
            f"{run['row']} seed {run['seed']}: solved {run['solved']} at {run['steps']:,} steps, "
            f"{run['seconds']:.0f} s (success {run['final_success']:.3f}, SPL {run['final_spl']:.3f})"
        ),
    )
    write_report(runs.records, args.out, argv, args.floor_runs_file)


if __name__ == "__main__":
    main()
