"""Roads closing one at a time: how fast DCQN recovers, with and without its re-adaptation levers (paper Fig. 7b/9).

For every seed and lever set (``campusnav_runs.LEVER_SETS``: DCQN as shipped, each of its re-adaptation levers, and
combinations of them) an agent trains on CampusNav-v0 until the map is solved, then keeps training (same model) while
roads close one at a time, cumulatively: a closure, then ``--window`` env steps in which the recovery is measured,
then the next closure. The loop is the glue's (:func:`sb3_dcqn.campusnav.experiments.train_with_closures`, the one
``dcqn-campusnav`` runs): a :class:`~campusnav_env.callbacks.RoadClosureCallback` closes the roads and drives a
:class:`~campusnav_env.callbacks.RouteEvaluationCallback`: the greedy routes from every (start, heading) are evaluated
right after each closure, then every ``--recovery-eval-freq`` training episodes until back at the recovery thresholds
(:mod:`campusnav_env.recovery`), and at the end of each window; the recovery is counted in training episodes, env
steps and training seconds (evaluations excluded) from the closure.

Every lever faces the same closures: the roads are chosen from the map, never from an agent's routes: the road most
used by the shortest paths from every intersection to the goal, then the busiest on the shortest paths with that one
closed, and so on, skipping roads whose closure would cut the goal off.

Every finished run is appended to a JSON-lines file, so an interrupted benchmark keeps its runs and a rerun skips
them. The tables are printed and written to ``benchmarks/results/closures_one_at_a_time.md``, with PNGs beside it:
the route panels and training curves of the first seed's baseline run (``_routes_<lever>.png``,
``_training_<lever>.png``; the first lever's when the baseline does not run), and a bar chart of the recovery per
lever. The tables show the levers asked for and any other lever already in the runs file.

Usage::

    python benchmarks/closures_one_at_a_time.py                        # 8 lever sets, seeds 0 and 1, 3 closures
    python benchmarks/closures_one_at_a_time.py --levers baseline revision_per_visible --seeds 0 1 2 --window 8000
    python benchmarks/closures_one_at_a_time.py --quick                # smoke run: pixel features, tiny budgets
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

if not __package__:  # run as `python benchmarks/NAME.py`: the package imports from the repository root
    sys.path[0] = str(Path(__file__).resolve().parents[1])

import numpy as np
import torch as th

from benchmarks.campusnav_runs import LEVER_SETS, TASKS, VARIANTS, Task, lever_entry, quick_env_kwargs
from benchmarks.report import (
    RESULTS_DIR,
    append_run,
    command_line,
    machine_line,
    markdown_table,
    measured_on,
    read_runs,
    write_results,
)
from campusnav_env.closures import ClosureEvent, busiest_road
from campusnav_env.figures import closure_route_panels, figure_image, training_curves, write_figure
from campusnav_env.maps.navigation import NavigationGraph
from campusnav_env.recovery import DEFAULT_SPL_THRESHOLD, DEFAULT_SUCCESS_THRESHOLD, Recovery, median_recovery
from sb3_dcqn.campusnav.experiments import ClosurePlan, TrainingOutcome, train_with_closures
from sb3_dcqn.campusnav.levers import LeverSet, lever_callbacks
from sb3_dcqn.campusnav.solved import solved_bar

SCRIPT = "closures_one_at_a_time.py"
DEFAULT_LEVERS = (
    "baseline",
    "revision",
    "prioritized",
    "visible",
    "blocked",
    "revision_blocked",
    "revision_blocked_visible",
    "revision_blocked_prioritized",
)
# A smoke run's: DCQN as shipped and the demo's levers
QUICK_LEVERS = ["baseline", "revision_blocked_prioritized"]
# The goal per closure, and the paper's result
GOAL_EPISODES = 50
GOAL_SECONDS = 10.0
PAPER_EPISODES = 300
Road = tuple[int, int]


# ------------------------------------------------------------------------------- shared with closures_eleven.py
def busiest_closures(graph: NavigationGraph, goal: int, n_closures: int) -> list[Road]:
    """
    Roads to close one after another, chosen from the map alone (so every agent faces the same ones).

    The first is the road used by the most shortest paths from every intersection to the goal; each next one the
    busiest on the shortest paths with the roads before it closed. Roads whose closure would cut the goal off from a
    node that reaches it are skipped (:func:`~campusnav_env.closures.busiest_road`).

    :param graph: The map (not changed)
    :param goal: The goal node
    :param n_closures: Number of roads
    :return: the roads, in the order they close (fewer if no more can be closed)
    """
    trial = graph.copy()
    roads: list[Road] = []
    for _ in range(n_closures):
        routes = [trial.shortest_path(start, goal) for start in range(trial.n_nodes) if start != goal]
        road = busiest_road(trial, routes, [goal])
        if road is None:
            break
        trial.close_road(*road, protect=[goal])
        roads.append(road)
    return roads


def train_then_close(
    task: Task,
    lever_set: LeverSet,
    seed: int,
    closures: Sequence[Sequence[Road]],
    window: int,
    recovery_eval_freq: int,
    env_kwargs: dict[str, Any] | None = None,
) -> TrainingOutcome:
    """
    Train one agent until the map is solved, then keep training while ``closures`` close one event after another
    (the glue's :func:`~sb3_dcqn.campusnav.experiments.train_with_closures`: each window trained out, recovered or not).

    :param task: The map, goal, step cap and time budget of the training to the solved map
    :param lever_set: DCQN's options (and the env's) for this run
    :param seed: Seed of the agent
    :param closures: The roads of each closure event (the first once solved, then one every ``window`` env steps)
    :param window: Env steps of training after each closure
    :param recovery_eval_freq: While recovering, evaluate the routes every this many training episodes
    :param env_kwargs: Env keyword arguments on top of the entry's (e.g. the cheap settings of a smoke run)
    :return: the run
    """
    entry = lever_entry(lever_set, task)
    model = VARIANTS["DCQN"].make_model(task.make_env(entry, **(env_kwargs or {})), entry, seed)
    plan = ClosurePlan(later=[ClosureEvent(at=0, unit="step", close=tuple(roads)) for roads in closures])
    return train_with_closures(
        model,
        plan,
        budget=task.max_steps,
        budget_seconds=task.budget_seconds,
        recovery_budget=window,
        eval_freq=task.eval_freq,
        recovery_eval_freq=recovery_eval_freq,
        stop_when_recovered=False,
        callbacks=lever_callbacks(lever_set.levers),
        progress=False,
    )


def _finite(value: float, digits: int = 3) -> float | None:
    return None if math.isinf(value) else round(float(value), digits)


def recovery_record(number: int, recovery: Recovery, run: TrainingOutcome) -> dict[str, Any]:
    """What the runs file keeps of one closure: the roads, the recovery and the evaluations of its window."""
    closure = recovery.closure
    evaluations = run.evaluation.evaluations
    later = [r.closure for r in run.recoveries if r.closure.step > closure.step]
    window = evaluations[closure.evaluation_index : later[0].evaluation_index if later else len(evaluations)]
    episodes_in_window = (later[0].episode if later else run.evaluation.episodes) - closure.episode
    return {
        "closure": number,
        "roads": [list(road) for road in closure.closed],
        "step": closure.step,
        "episode": closure.episode,
        "routes_affected": closure.routes_affected,
        "success_after": None if recovery.right_after is None else recovery.right_after.success_rate,
        "spl_after": None if recovery.right_after is None else recovery.right_after.spl,
        "recovered": recovery.recovered,
        "episodes": _finite(recovery.episodes, 0),
        "steps": _finite(recovery.steps, 0),
        "seconds": _finite(recovery.seconds),
        "success_end": None if recovery.last is None else recovery.last.success_rate,
        "spl_end": None if recovery.last is None else recovery.last.spl,
        "window_episodes": episodes_in_window,
        # success and SPL against episodes and steps since the closure (the recovery curve)
        "curve": [
            [e.episode - closure.episode, e.step - closure.step, round(e.success_rate, 4), round(e.spl, 4)]
            for e in window
        ],
    }


def run_record(run: TrainingOutcome, **fields: Any) -> dict[str, Any]:
    """What the runs file keeps of one run: ``fields`` (lever, seed, settings), the solve and the recoveries."""
    solved = run.solved_at()
    reached = solved or run.before_closures()
    return {
        **fields,
        "solved": solved is not None,
        "solve_steps": None if reached is None else reached.step,
        "solve_episodes": None if reached is None else reached.episode,
        "solve_seconds": None if reached is None else round(reached.train_seconds, 3),
        "solve_wall_seconds": round(run.first_phase_seconds, 3),
        "closure_wall_seconds": round(run.seconds - run.first_phase_seconds, 3),
        "recoveries": [recovery_record(k, r, run) for k, r in enumerate(run.recoveries, start=1)],
    }


@dataclass(frozen=True)
class _Stored:
    """A recovery read back from the runs file (what :func:`median_recovery` reads)."""

    episodes: float
    steps: float
    seconds: float


def stored_recoveries(records: Sequence[dict[str, Any]]) -> list[_Stored]:
    """The recoveries of the runs file's closure records, never-recovered as ``inf``."""
    return [
        _Stored(*(math.inf if r[key] is None else float(r[key]) for key in ("episodes", "steps", "seconds")))
        for r in records
    ]


def _stored_episodes(values: Sequence[float]) -> list[_Stored]:
    return [_Stored(value, 0.0, 0.0) for value in values]


def medians(records: Sequence[dict[str, Any]]) -> tuple[float, float, float]:
    """Median episodes, env steps and training seconds over closure records (unrecovered count as ``inf``)."""
    stored: Any = stored_recoveries(records)  # duck-typed Recovery: median_recovery reads these three attributes
    return tuple(median_recovery(stored, measure) for measure in ("episodes", "steps", "seconds"))  # type: ignore


def number(value: float | None, digits: int = 0) -> str:
    """A table cell: the value, or "not recovered" for a recovery that never came."""
    if value is None or math.isinf(value):
        return "not recovered"
    if math.isnan(value):
        return "-"
    return f"{value:.{digits}f}"


def roads_text(roads: Sequence[Sequence[int]]) -> str:
    return ", ".join(f"{u}-{v}" for u, v in roads)


def solve_text(run: dict[str, Any]) -> str:
    steps, seconds = run["solve_steps"], run["solve_seconds"]
    where = f"{steps} steps, {seconds:.1f} s" if steps is not None else "-"
    return where if run["solved"] else f"**not solved** (stopped at {where})"


def recovery_bars(
    runs: Sequence[dict[str, Any]], levers: Sequence[str], title: str, goal: float | None = GOAL_EPISODES
) -> np.ndarray:
    """
    A bar chart of the recovery episodes per lever and closure: the bar is the median over seeds, a dot each seed;
    a closure never recovered from is a hatched bar (or an x) at the top of the chart.

    :param runs: Records of the runs file
    :param levers: Lever keys, in the order of the bars
    :param title: Title of the chart
    :param goal: The goal in episodes, drawn as a dashed line (``None``: none)
    :return: ``(H, W, 3)`` uint8 RGB image
    """
    from matplotlib.figure import Figure

    n_closures = max((len(r["recoveries"]) for r in runs), default=0)
    finite = [c["episodes"] for r in runs for c in r["recoveries"] if c["episodes"] is not None]
    top = 1.15 * max([*finite, goal or 0, 1])
    figure = Figure(figsize=(max(9.0, 1.5 * len(levers) + 4), 4.6), dpi=100, layout="constrained")
    ax = figure.subplots()
    width = 0.8 / max(n_closures, 1)
    colours = ["tab:blue", "tab:orange", "tab:green", "tab:purple", "tab:brown", "tab:olive"]
    for k in range(n_closures):
        for i, lever in enumerate(levers):
            values = [
                math.inf if r["recoveries"][k]["episodes"] is None else r["recoveries"][k]["episodes"]
                for r in runs
                if r["lever"] == lever and len(r["recoveries"]) > k
            ]
            if not values:
                continue
            x = i + (k - (n_closures - 1) / 2) * width
            median = median_recovery(_stored_episodes(values), "episodes")  # type: ignore[arg-type]
            colour = colours[k % len(colours)]
            label = f"closure {k + 1}" if i == 0 else None
            if math.isinf(median):
                ax.bar(x, top, width * 0.9, color="white", edgecolor=colour, hatch="//", label=label)
            else:
                ax.bar(x, median, width * 0.9, color=colour, alpha=0.8, label=label)
            for v in values:
                ax.plot(x, min(v, top * 0.97), "x" if math.isinf(v) else "o", color="black", ms=4)
    if goal is not None:
        ax.axhline(goal, color="tab:red", ls="--", lw=1, label=f"goal: {goal:.0f} episodes")
    ax.plot([], [], "x", color="black", label="a seed never recovered (hatched: the median)")
    ax.set_xticks(range(len(levers)), [LEVER_SETS[lever].name for lever in levers], rotation=15, ha="right", fontsize=8)
    ax.set_ylim(0, top)
    ax.set_ylabel("training episodes to recovery")
    ax.set_title(title, fontsize=10)
    figure.legend(fontsize=8, loc="outside right upper", frameon=False)
    ax.grid(True, axis="y", alpha=0.3)
    return figure_image(figure)


def run_figures(run: TrainingOutcome, prefix: Path, lever: str, title: str) -> list[Path]:
    """
    The route panels and the training curves of one run, next to the results file: ``<prefix>_routes_<lever>.png``
    and ``<prefix>_training_<lever>.png`` (named by lever, so that a run of other levers leaves them alone).
    """
    panels = closure_route_panels(run.closures.graph, run.evaluation.evaluations, run.recoveries, size=520)
    progress = run.progress
    curves = training_curves(
        progress.episode_rewards, progress.episode_lengths, run.recoveries, run.evaluation.evaluations, title=title
    )
    return [
        write_figure(prefix.with_name(f"{prefix.name}_routes_{lever}.png"), panels),
        write_figure(prefix.with_name(f"{prefix.name}_training_{lever}.png"), curves),
    ]


def figure_lever(levers: Sequence[str]) -> str:
    """The lever whose first seed's run gets route panels and training curves: the baseline if it runs."""
    return "baseline" if "baseline" in levers else levers[0]


def shown_levers(levers: Sequence[str], stored: Sequence[dict[str, Any]], seeds: Sequence[int]) -> list[str]:
    """
    The levers of the tables: those asked for, then any other lever whose runs (same settings and seeds) are in the
    runs file, so that an invocation with other levers adds rows instead of replacing the tables.
    """
    known = [r["lever"] for r in stored if r["seed"] in seeds and r["lever"] in LEVER_SETS]
    others = {lever for lever in known if lever not in levers}
    return [*levers, *(lever for lever in LEVER_SETS if lever in others)]


# ------------------------------------------------------------------------------------------------ this benchmark
def summary_table(runs: Sequence[dict[str, Any]], levers: Sequence[str], goal_episodes: float) -> list[str]:
    header = [
        "lever",
        "seeds",
        "solved before the closures at (per seed)",
        "closures recovered",
        "median episodes",
        "median env steps",
        "median training s",
        "closures within the goal",
        f"goal (median <= {goal_episodes:.0f} ep and <= {GOAL_SECONDS:.0f} s)",
        f"paper (< {PAPER_EPISODES} ep)",
    ]
    rows = []
    for lever in levers:
        mine = [r for r in runs if r["lever"] == lever]
        if not mine:
            continue
        closures = [c for r in mine for c in r["recoveries"]]
        episodes, steps, seconds = medians(closures)
        within = sum(
            c["episodes"] is not None and c["episodes"] <= goal_episodes and c["seconds"] <= GOAL_SECONDS
            for c in closures
        )
        met = episodes <= goal_episodes and seconds <= GOAL_SECONDS
        rows.append(
            [
                LEVER_SETS[lever].name,
                len(mine),
                "; ".join(solve_text(r) for r in mine),
                f"{sum(c['recovered'] for c in closures)} / {len(closures)}",
                number(episodes),
                number(steps),
                number(seconds, 1),
                f"{within} / {len(closures)}",
                "met" if met else "**missed**",
                "met" if episodes < PAPER_EPISODES else "**missed**",
            ]
        )
    return markdown_table(header, rows)


def closure_table(runs: Sequence[dict[str, Any]], levers: Sequence[str]) -> list[str]:
    header = [
        "lever",
        "seed",
        "closure",
        "road",
        "routes affected",
        "success right after",
        "recovery episodes",
        "env steps",
        "training s",
        "success / SPL at the end of the window (episodes in it)",
    ]
    rows = []
    for lever in levers:
        for run in sorted((r for r in runs if r["lever"] == lever), key=lambda r: r["seed"]):
            for c in run["recoveries"]:
                rows.append(
                    [
                        LEVER_SETS[lever].name,
                        run["seed"],
                        c["closure"],
                        roads_text(c["roads"]),
                        "-" if c["routes_affected"] is None else c["routes_affected"],
                        "-" if c["success_after"] is None else f"{c['success_after']:.3f}",
                        number(c["episodes"]),
                        number(c["steps"]),
                        number(c["seconds"], 1),
                        f"{end_of_window(c)} ({c['window_episodes']})",
                    ]
                )
    return markdown_table(header, rows)


def end_of_window(closure: dict[str, Any]) -> str:
    """A closure record's success / SPL at the end of its window."""
    return "-" if closure["success_end"] is None else f"{closure['success_end']:.3f} / {closure['spl_end']:.3f}"


def closure_benchmark_parser(
    doc: str | None, name: str, window: int, window_help: str, levers: Sequence[str] = DEFAULT_LEVERS
) -> argparse.ArgumentParser:
    """The flags the closure benchmarks share: seeds, levers, the window after a closure, evaluation rhythm, files."""
    parser = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    parser.add_argument(
        "--levers", nargs="+", choices=sorted(LEVER_SETS), default=list(levers), help="default: " + " ".join(levers)
    )
    parser.add_argument("--window", type=int, default=window, help=window_help)
    parser.add_argument(
        "--recovery-eval-freq", type=int, default=2, help="episodes between evaluations while recovering"
    )
    parser.add_argument(
        "--quick", action="store_true", help="smoke run: pixel features, tiny budgets, 2 levers, 1 seed"
    )
    parser.add_argument("--out", type=Path, default=None, help=f"results file (default results/{name}.md)")
    parser.add_argument("--runs-file", type=Path, default=None)
    return parser


def main(argv: list[str] | None = None) -> None:
    parser = closure_benchmark_parser(
        __doc__, "closures_one_at_a_time", 6_000, "env steps of training after each closure"
    )
    parser.add_argument("--closures", type=int, default=3, help="roads closed one after another")
    args = parser.parse_args(argv)
    th.set_num_threads(1)

    stem = "closures_one_at_a_time" + ("_quick" if args.quick else "")
    out: Path = args.out or RESULTS_DIR / f"{stem}.md"
    runs_file: Path = args.runs_file or out.with_name(f"{out.stem}_runs.jsonl")
    levers = QUICK_LEVERS if args.quick and args.levers == list(DEFAULT_LEVERS) else args.levers
    task = TASKS["campus"]
    env_kwargs: dict[str, Any] = {}
    window = args.window
    seeds = args.seeds
    if args.quick:
        task = dataclasses.replace(task, max_steps=1_500, budget_seconds=20, eval_freq=500)
        env_kwargs = quick_env_kwargs()
        window = min(window, 300)
        seeds = seeds[:1]
    settings = {"window": window, "recovery_eval_freq": args.recovery_eval_freq, "quick": args.quick}

    probe = task.make_env(lever_entry(LEVER_SETS["baseline"], task), **env_kwargs).unwrapped
    goal_node = probe.goal_nodes[0]  # type: ignore[attr-defined]
    roads = busiest_closures(probe.graph, goal_node, args.closures)  # type: ignore[attr-defined]
    goal_roads = [r for r in probe.graph.map.roads if goal_node in r]  # type: ignore[attr-defined]
    print(f"closures (same for every lever and seed): {roads_text(roads)}", flush=True)

    stored = [r for r in read_runs(runs_file) if all(r.get(k) == v for k, v in settings.items())]
    done = {(r["lever"], r["seed"]) for r in stored}
    todo = [(lever, seed) for seed in seeds for lever in levers if (lever, seed) not in done]
    print(f"{len(done)} runs already in {runs_file}, {len(todo)} to do", flush=True)
    figures: list[Path] = []
    prefix = out.with_name(out.stem)
    started = time.perf_counter()
    for lever, seed in todo:
        begin = time.perf_counter()
        run = train_then_close(
            task, LEVER_SETS[lever], seed, [[road] for road in roads], window, args.recovery_eval_freq, env_kwargs
        )
        record = run_record(run, lever=lever, seed=seed, **settings, wall_seconds=round(time.perf_counter() - begin, 1))
        append_run(runs_file, record)
        stored.append(record)
        recovered = ", ".join(number(c["episodes"]) for c in record["recoveries"])
        print(
            f"{LEVER_SETS[lever].name}, seed {seed}: solved {solve_text(record)}; recovery episodes per closure: "
            f"{recovered}; {record['wall_seconds']:.0f} s",
            flush=True,
        )
        if (lever, seed) == (figure_lever(levers), seeds[0]):
            title = f"CampusNav-v0, {LEVER_SETS[lever].name}, seed {seed}: roads closing one at a time"
            figures += run_figures(run, prefix, lever, title)
    total = time.perf_counter() - started

    levers = shown_levers(levers, stored, seeds)
    runs = [r for r in stored if r["lever"] in levers and r["seed"] in seeds]
    if runs:
        bars = recovery_bars(runs, levers, f"Recovery after each closure, CampusNav-v0, seeds {seeds}")
        figures.append(write_figure(prefix.with_name(prefix.name + "_recovery.png"), bars))
    pictures = sorted({p.name for p in figures} | {p.name for p in out.parent.glob(f"{out.stem}_*.png")})
    wall = [r["wall_seconds"] for r in runs]
    lines = [
        "# Roads closing one at a time: recovery per re-adaptation lever (the paper's Fig. 7b/9)",
        "",
        machine_line() if todo else measured_on(out, machine_line()),
        "",
        f"Setup: {task.description}{' (smoke run: pixel features of 64x48 views, tiny budgets)' if args.quick else ''},"
        f" DCQN's shipped entry (`hyperparams/dcqn.yml`) plus each lever's options. Each (lever, seed) trains from "
        f"scratch until solved ({solved_bar()} from every (start, heading), "
        f"evaluated every {task.eval_freq} steps; cap {task.max_steps} steps / {task.budget_seconds:.0f} s of "
        f"training), then keeps training (same model) while {len(roads)} roads close one at a time, cumulatively: "
        f"one closure, then {window} env steps of training, then the next.",
        "",
        f"Closures (the same for every lever and seed, chosen from the map: the road most used by the shortest paths "
        f"from every intersection to the goal, then the busiest with it closed, ...; roads that would cut the goal off "
        f"are skipped): {roads_text(roads)}. The goal (node {goal_node}) has the roads {roads_text(goal_roads)}: "
        f"{sum(r in goal_roads for r in roads)} of the closures are at the goal itself.",
        "",
        f"Recovery: the first route evaluation (right after the closure, then every {args.recovery_eval_freq} training "
        f"episodes) with success >= {DEFAULT_SUCCESS_THRESHOLD} and SPL >= {DEFAULT_SPL_THRESHOLD}; counted in "
        f"training episodes, env steps and training seconds (evaluations excluded) from the closure. A closure not "
        f"recovered from within its window is *not recovered* and counts as infinitely slow in the medians. The "
        "visible closures' rendering and encoding of the new views happens at the closure, outside the training "
        "seconds. "
        f"Goal: <= {GOAL_EPISODES} episodes and <= {GOAL_SECONDS:.0f} s per closure (the paper: < {PAPER_EPISODES} "
        "episodes).",
        "",
        "Levers: " + "; ".join(f"{LEVER_SETS[k].name}: `{LEVER_SETS[k].options_text()}`" for k in levers) + ".",
        "",
        "## Per lever (median over closures and seeds)",
        "",
        *summary_table(runs, levers, GOAL_EPISODES),
        "",
        "## Per closure",
        "",
        *closure_table(runs, levers),
        "",
        "Routes affected: greedy routes (of all (start, heading) pairs) of the last evaluation before the closure that "
        "used the closed road.",
        "",
        f"Figures: {', '.join(f'`{name}`' for name in pictures)} (route panels and training curves `_<lever>`: the "
        "first seed's run of that lever; recovery: every run).",
        "",
        f"Time: {len(runs)} runs, {np.sum(wall):.0f} s in all (per run {min(wall, default=0):.0f}-"
        f"{max(wall, default=0):.0f} s, evaluations and the visible closures' rendering included); "
        + (f"this invocation ran {len(todo)} of them in {total:.0f} s." if todo else "all read from the runs file."),
        "",
        command_line(SCRIPT, argv),
    ]
    print("\n".join(lines))
    write_results(out, "\n".join(lines))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
