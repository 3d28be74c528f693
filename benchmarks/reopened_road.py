"""A closed road reopened: training episodes until every goal's greedy routes use it again.

DCQN from the shipped ``CampusNavMulti-v0`` entry (the paper's four goals, the route memory on) trains until the map is
solved, then the road the shortest routes to the four goals use most is closed and training goes on for ``--window`` env
steps (the memory learns the closure from its bumps), then the road is reopened and training goes on for another window.
After the reopening a route evaluation runs every ``--eval-every`` training episodes (1, the default: after every
episode; a count is where it reached a multiple of it, or passed one by the episodes that end within the same few
steps). Counted: the training episodes from the reopening to the first evaluation in which, for every goal, as many
greedy routes travel the road as in the last evaluation before it closed (the routes took it again), and, as a bar, the
episodes until every goal is back at success >= 0.99 and SPL >= 0.98 (solved again). A memory that keeps a closed road
blocked forever never gets there (the reopening is only found by trying the road again: DCQN's ``retry_after``).
Usage::

    python benchmarks/reopened_road.py --seeds 2 5 11
    python benchmarks/reopened_road.py --seeds 2 5 11 --eval-every 2   # a route evaluation every 2 episodes
    python benchmarks/reopened_road.py --quick     # smoke run: pixel features, seed 0
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
from pathlib import Path
from typing import Any

import torch as th

from benchmarks.campusnav_runs import TASKS, VARIANTS, quick_env_kwargs
from benchmarks.closure_runs import positive_int
from benchmarks.report import RESULTS_DIR, described, machine_line, markdown_table, publish, run_missing
from campusnav_env.closures import ClosureEvent, busiest_road, road_usage
from campusnav_env.recovery import RouteEvaluation
from sb3_dcqn.campusnav.experiments import ClosurePlan, train_with_closures
from sb3_dcqn.campusnav.solved import is_solved

Road = tuple[int, int]


def routes_on(evaluation: RouteEvaluation, road: Road) -> dict[str, int]:
    """Per goal, the greedy routes of an evaluation that travel ``road``."""
    counts: dict[str, int] = {}
    for route in evaluation.report.routes:
        counts[route.goal] = counts.get(route.goal, 0) + int(road in road_usage([route.nodes]))
    return counts


def run_one(seed: int, window: int, quick: bool, eval_every: int = 1, max_episodes: int = 100) -> dict[str, Any]:
    """
    Train, close the busiest road, reopen it; the episodes until the routes use it again, seen at a route
    evaluation every ``eval_every`` training episodes after the reopening.
    """
    task = TASKS["multi"]
    env_kwargs: dict[str, Any] = quick_env_kwargs() if quick else {}
    if quick:
        task = dataclasses.replace(task, max_steps=3_000, budget_seconds=30, eval_freq=1_000)
    variant = VARIANTS["DCQN"]
    entry = variant.entry(task)
    env = task.make_env(entry, **env_kwargs)
    graph, goals = env.unwrapped.graph, list(env.unwrapped.goal_nodes)  # type: ignore[attr-defined]
    routes = [graph.shortest_path(start, goal) for goal in goals for start in range(graph.n_nodes) if start != goal]
    road = busiest_road(graph, routes, goals)
    assert road is not None, "no road can be closed without cutting a goal off"
    model = variant.make_model(env, entry, seed)
    plan = ClosurePlan(later=[ClosureEvent(at=0, unit="step", close=(road,))])
    run = train_with_closures(
        model,
        plan,
        budget=task.max_steps,
        budget_seconds=task.budget_seconds,
        recovery_budget=window,
        eval_freq=task.eval_freq,
        stop_when_recovered=False,
        progress=False,
    )
    (closed,) = run.closures.records[-1:]
    evaluations = run.evaluation.evaluations
    before = routes_on(evaluations[closed.evaluation_index - 1], road)
    while_closed = routes_on(evaluations[-1], road)
    used = {goal: count for goal, count in before.items() if count > 0}
    reopened = run.closures.apply(ClosureEvent(at=model.num_timesteps, unit="step", reopen=(road,)))
    back = solved = None
    start_episode, due = model._episode_num, eval_every
    while model._episode_num - start_episode < max_episodes:
        # A few steps at a time (a stopping callback would drop the step it stops at: SB3 stores it after on_step),
        # and the routes from every start once the episodes due have ended
        model.learn(model.train_freq.frequency, reset_num_timesteps=False)
        episodes = model._episode_num - start_episode
        if episodes < due:
            continue
        due = (episodes // eval_every + 1) * eval_every
        run.evaluation.evaluate()
        evaluation = run.evaluation.evaluations[-1]
        if back is None and all(routes_on(evaluation, road).get(g, 0) >= n for g, n in used.items()):
            back = (episodes, evaluation.step - reopened.step)
        if solved is None and is_solved(evaluation):
            solved = episodes
        if back is not None and solved is not None:
            break
    return {
        "seed": seed,
        "window": window,
        "quick": quick,
        "eval_every": eval_every,
        "road": list(road),
        "solved_at_step": run.solved_at().step if run.solved_at() else None,
        "routes_on_road_before": before,
        "routes_on_road_while_closed": while_closed,
        "episodes_until_used": None if back is None else back[0],
        "steps_until_used": None if back is None else back[1],
        "episodes_until_solved": solved,
    }


def episodes_text(values: list[int | None]) -> str:
    """``median (worst)``, a miss (never) counting as the worst."""
    if not values:
        return "-"
    finite = sorted(v for v in values if v is not None)
    misses = len(values) - len(finite)
    median = statistics.median([*finite, *([float("inf")] * misses)])
    worst = "never" if misses else f"{max(finite)}"
    return f"{'never' if median == float('inf') else f'{median:g}'} ({worst})"


def write_report(runs: list[dict[str, Any]], out: Path, argv: list[str] | None, eval_every: int = 1) -> None:
    rows = [
        [
            str(run["seed"]),
            "-".join(map(str, run["road"])),
            f"{run['solved_at_step']:,}" if run["solved_at_step"] else "not solved",
            ", ".join(f"{g}: {n}" for g, n in run["routes_on_road_before"].items()),
            ", ".join(f"{g}: {n}" for g, n in run["routes_on_road_while_closed"].items()),
            "never" if run["episodes_until_used"] is None else str(run["episodes_until_used"]),
            "never" if run["episodes_until_solved"] is None else str(run["episodes_until_solved"]),
        ]
        for run in sorted(runs, key=lambda r: r["seed"])
    ]
    lines = [
        "# A closed road reopened: episodes until the routes use it again",
        "",
        described(__doc__),
        "",
        machine_line("runs one after another in one process"),
        "",
        "Episodes until every goal's routes use the road again: "
        f"{episodes_text([r['episodes_until_used'] for r in runs])}; until solved again: "
        f"{episodes_text([r['episodes_until_solved'] for r in runs])} (median (worst)); a route evaluation every "
        f"{eval_every} training episode{'s' if eval_every != 1 else ''} after the reopening, so no count is below "
        f"{eval_every}.",
        "",
        *markdown_table(
            [
                "seed",
                "road",
                "solved at step",
                "routes on the road before the closure",
                "while closed",
                f"episodes until used again (evaluated every {eval_every})",
                f"episodes until solved again (evaluated every {eval_every})",
            ],
            rows,
        ),
    ]
    publish(out, lines, "reopened_road.py", argv)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0])
    parser.add_argument("--window", type=int, default=2_000, help="env steps trained while the road is closed")
    parser.add_argument(
        "--eval-every",
        type=positive_int,
        default=1,
        help="training episodes between route evaluations after the reopening (1: after every episode)",
    )
    parser.add_argument("--quick", action="store_true", help="smoke run: pixel features, a short training")
    parser.add_argument("--runs-file", type=Path, default=None)
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "reopened_road.md")
    args = parser.parse_args(argv)
    th.set_num_threads(1)
    runs_file: Path = args.runs_file or args.out.with_name(f"{args.out.stem}_runs.jsonl")
    runs = run_missing(
        runs_file,
        args.seeds,
        lambda seed: run_one(seed, args.window, args.quick, args.eval_every),
        key=lambda r: (r["seed"], r.get("eval_every", 1)),  # the runs before --eval-every evaluated every episode
        job_key=lambda seed: (seed, args.eval_every),
        settings={"window": args.window, "quick": args.quick},
        describe=lambda record: (
            f"seed {record['seed']}: road {record['road']}, used again after {record['episodes_until_used']} "
            f"episodes, solved again after {record['episodes_until_solved']}"
        ),
    )
    shown = [r for r in runs.records if r.get("eval_every", 1) == args.eval_every]
    write_report(shown, args.out, argv, args.eval_every)


if __name__ == "__main__":
    main()
