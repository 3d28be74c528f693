"""The experience-graph floor: how few env steps an agent that only remembers what it saw needs to solve a map.

The agent (:class:`FloorAgent`) is told nothing but observations, rewards and terminations: no map, no distances, no
action mask. It keeps every transition in an :class:`sb3_dcqn.route_memory.RouteMemory` and acts on it. With the same
knowledge as DCQN's memory (``--memory places``, the default): the env's declared frame (``metadata["place_frame"]``:
views in compass order, actions relative to the heading, two-way roads), so states are places, moves compass slots,
and a driven road's way back is inferred; with ``--memory poses``: exact observations (views and heading) as states
and the actions as edges, the floor before places. Both floors are reported, each beside the learner that has the
same knowledge. It acts:

- **explore** while an untried (state, slot) can be reached over the transitions seen: drive to the nearest one
  (breadth-first search over the known graph) and try it; a collision counts as tried;
- **plan** once nothing untried can be reached from where it stands: drive the shortest route over the transitions
  seen to the goal (breadth-first search back from the transitions that reached it); where it knows none, a fixed
  action.

It runs episodes like a learner (the env's random starts, the env's ``max_steps`` cap) and every ``eval_every`` env
steps its greedy plan-or-explore policy (:meth:`FloorAgent.policy`: the planned action where a route is known, else
the first action towards the nearest untried one, else a fixed action; an unseen observation: the fixed action) is
evaluated from every (start, heading) with ``evaluate_routes``, until solved (``sb3_dcqn.campusnav.solved``: success
>= 0.99 and SPL >= 0.98). Steps to solved are counted at the evaluation that first finds it solved, so they are
exact to within ``eval_every``. It is the floor of sample efficiency for any learner of this env that does not
generalise across observations. The agent and its run live in ``floor_runs.py``, shared with the scripts that report a
floor beside a learner.

Features: 64x48 pixel features (the scale benchmarks' cheap build; the floor sees only whether observations are
equal, so the encoder does not change its steps as long as distinct views stay distinct). Runs are appended to a
JSON-lines file (``--runs-file``) as they finish, and a rerun skips those done (same size, seed, eval_every, quick,
step cap); the table is rebuilt from the file. Usage::

    python benchmarks/experience_graph_floor.py --sizes 101 1000 --seeds 0 1 2
    python benchmarks/experience_graph_floor.py --sizes 10000 --seeds 0
    python benchmarks/experience_graph_floor.py --quick            # smoke run: 101 nodes, seed 0
"""

from __future__ import annotations

import argparse
import functools
import statistics
from pathlib import Path
from typing import Any

from benchmarks.floor_runs import (
    MEMORIES,
    RUNS_LINE,
    default_eval_every,
    make_env,
    run_one,
)
from benchmarks.report import RESULTS_DIR, machine_line, markdown_table, measured_on, publish, run_missing
from benchmarks.scale_common import GOAL, fmt
from sb3_dcqn.campusnav.solved import solved_bar


def floor_table(runs: list[dict[str, Any]]) -> list[str]:
    """One row per (memory, size, map seed, eval_every): median and range over seeds."""
    groups: dict[tuple[str, int, int, int], list[dict[str, Any]]] = {}
    for run in sorted(runs, key=lambda r: (memory_of(r), r["size"], r.get("map_seed", 0), r["eval_every"], r["seed"])):
        groups.setdefault((memory_of(run), run["size"], run.get("map_seed", 0), run["eval_every"]), []).append(run)
    rows = []
    for (memory, size, map_seed, eval_every), group in groups.items():
        solved = [r for r in group if r["solved"]]
        steps = [r["env_steps"] for r in solved]
        rows.append([
            memory, f"{size:,}", str(map_seed), f"{group[0]['state_actions']:,}",
            f"{group[0]['start_only_states']:,}", f"{eval_every:,}",
            " ".join(str(r["seed"]) for r in group),
            f"{len(solved)}/{len(group)}",
            _median_range(steps), _median_range([r["episodes"] for r in solved]),
            _median_range([r["driven_solved_steps"] for r in group if r["driven_solved_steps"] is not None]),
            " ".join(f"{r['env_steps']:,}" + ("" if r["solved"] else " (cap)") for r in group),
            _median_range([r["tried"] for r in group]),
            _median_range([r["wall_seconds"] for r in group], 1),
            _median_range([r["evaluation_seconds"] for r in group], 1),
        ])  # fmt: skip
    header = [
        "memory",
        "intersections",
        "map seed",
        "(node, heading, action) triples",
        "start-only states",
        "eval every",
        "seeds",
        "solved",
        "env steps to solved",
        "episodes to solved",
        "env steps to solved, driven-to states only",
        "env steps per seed (cap: not solved by then)",
        "pairs tried",
        "wall s",
        "of which eval s",
    ]
    return markdown_table(header, rows)


def memory_of(run: dict[str, Any]) -> str:
    """The run's memory (runs from before places were pose runs)."""
    return str(run.get("memory", "poses"))


def run_key(run: dict[str, Any]) -> tuple[Any, ...]:
    """What tells a run apart: memory, size, map seed, seed, evaluation period, smoke run, step cap."""
    fields = (run["size"], run.get("map_seed", 0), run["seed"], run["eval_every"], run["quick"], run["max_env_steps"])
    return (memory_of(run), *fields)


def _median_range(values: list[float], digits: int = 0) -> str:
    """``median (min-max)``, ``-`` where there are none."""
    if not values:
        return "-"
    low, high = fmt(min(values), digits), fmt(max(values), digits)
    middle = fmt(statistics.median(values), digits)
    return middle if low == high else f"{middle} ({low}-{high})"


def write_report(runs: list[dict[str, Any]], out: Path, argv: list[str] | None) -> None:
    machine = measured_on(out, machine_line(RUNS_LINE))
    lines = [
        "# The experience-graph floor: env steps to solved",
        "",
        "An agent told only observations, rewards and terminations keeps every transition in a graph over exact "
        "observations, explores to the nearest untried (observation, action) and plans shortest routes over what it "
        f"saw (`benchmarks/experience_graph_floor.py`). Solved: {solved_bar()} from every (start, heading), goal "
        f"{GOAL}, evaluated every `eval every` env steps (steps to solved are exact to within that). Episodes from the "
        "env's random starts, capped at its `max_steps`. Features: 64x48 pixel features. Start-only states: (node, "
        "heading) pairs no move leads to (a move leaves the agent facing away from the road it came along), seen only "
        "as an episode's random start; an agent that does not generalise across observations has to wait for each "
        "of them, so the last column scores the same evaluations on the routes from the other starts only. Median "
        "(range) over seeds; wall time includes the evaluations, not the env build.",
        "",
        machine,
        "",
        *floor_table(runs),
    ]
    publish(out, lines, "experience_graph_floor.py", argv)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", nargs="+", type=int, help="intersections (default 101 1000; 101 with --quick)")
    parser.add_argument("--seeds", nargs="+", type=int, help="seeds of the starts (default 0 1 2; 0 with --quick)")
    parser.add_argument("--eval-every", type=int, help="env steps between evaluations (default: by size)")
    parser.add_argument("--max-env-steps", type=int, help="step cap per run (default: 200 per (state, action) pair)")
    parser.add_argument("--quick", action="store_true", help="smoke run: 101 nodes, seed 0")
    parser.add_argument("--map-seed", type=int, default=0, help="seed of the generated city (CampusNavCity's map_seed)")
    parser.add_argument("--memory", nargs="+", choices=MEMORIES, default=["places"], help="what the agent knows")
    parser.add_argument("--runs-file", type=Path, default=RESULTS_DIR / "experience_graph_floor_runs.jsonl")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "experience_graph_floor.md")
    args = parser.parse_args(argv)
    sizes = args.sizes or ([101] if args.quick else [101, 1000])
    seeds = args.seeds or ([0] if args.quick else [0, 1, 2])
    # One env per map, built when its first run is due (the jobs come map by map)
    env_of = functools.lru_cache(maxsize=1)(make_env)
    jobs = [
        (memory, size, seed, args.eval_every or default_eval_every(size))
        for size in sizes
        for memory in args.memory
        for seed in seeds
    ]

    def run_job(job: tuple[str, int, int, int]) -> dict[str, Any]:
        memory, size, seed, eval_every = job
        env = env_of(size, args.map_seed)
        return run_one(size, seed, eval_every, args.quick, args.max_env_steps, env, args.map_seed, memory)

    def describe(record: dict[str, Any]) -> str:
        return (
            f"{memory_of(record)}, {record['size']} nodes seed {record['seed']}: "
            f"{'solved' if record['solved'] else 'NOT solved'} at {record['env_steps']:,} env steps, "
            f"{record['episodes']:,} episodes, {record['wall_seconds']:.1f} s "
            f"(success {record['success']:.3f}, SPL {record['spl']:.3f})"
        )

    runs = run_missing(
        args.runs_file,
        jobs,
        run_job,
        key=run_key,
        job_key=lambda job: (*job[:2], args.map_seed, *job[2:], args.quick, args.max_env_steps),
        describe=describe,
    )
    write_report(runs.records, args.out, argv)


if __name__ == "__main__":
    main()
