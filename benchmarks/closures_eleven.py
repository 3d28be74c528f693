"""Eleven roads closing at once: how fast DCQN recovers, with and without its re-adaptation levers (the paper's 11).

For every seed and lever set (``campusnav_runs.LEVER_SETS``) an agent trains on CampusNav-v0 until the map is solved,
then keeps training (same model) for ``--window`` env steps after 11 random roads close at once: the glue's loop
(:func:`sb3_dcqn.campusnav.experiments.train_with_closures`, through ``closures_one_at_a_time.train_then_close``). The
roads are drawn once per seed from the open map (:meth:`~campusnav_env.maps.navigation.NavigationGraph.sample_closures`
with ``numpy.random.default_rng(seed)``, the draw of ``ClosureEvent(close_random=11, seed=seed)``), keeping the goal
reachable from every node, and every lever set faces the same roads. A
:class:`~campusnav_env.callbacks.RoadClosureCallback` closes them and drives a
:class:`~campusnav_env.callbacks.RouteEvaluationCallback`: the greedy routes from every (start, heading) are evaluated
right after the closure, then every ``--recovery-eval-freq`` training episodes until back at the recovery thresholds
(:mod:`campusnav_env.recovery`), and at the end of the window; the recovery is counted in training episodes, env steps
and training seconds (evaluations excluded) from the closure.

Every finished run is appended to a JSON-lines file (a rerun skips what is done). The tables (the levers asked for
and any other lever already in the runs file) are printed and written to ``benchmarks/results/closures_eleven.md``,
with PNGs beside it: the route panel and training curves of the first seed's baseline run (named by lever; the first
lever's when the baseline does not run), and the recovery curves (success rate against training episodes after the
closure) of every run.

Usage::

    python benchmarks/closures_eleven.py                          # 6 lever sets, seeds 0 and 1
    python benchmarks/closures_eleven.py --levers baseline revision_per_visible --seeds 0 1 2 --window 20000
    python benchmarks/closures_eleven.py --quick                  # smoke run: pixel features, tiny budgets
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

if not __package__:  # run as `python benchmarks/NAME.py`: the package imports from the repository root
    sys.path[0] = str(Path(__file__).resolve().parents[1])

import numpy as np
import torch as th

from benchmarks.campusnav_runs import LEVER_SETS, TASKS, lever_entry, quick_env_kwargs
from benchmarks.closures_one_at_a_time import (
    QUICK_LEVERS,
    closure_benchmark_parser,
    end_of_window,
    figure_lever,
    medians,
    number,
    roads_text,
    run_figures,
    run_record,
    shown_levers,
    solve_text,
    train_then_close,
)
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
from campusnav_env.figures import figure_image, write_figure
from campusnav_env.maps.navigation import NavigationGraph
from campusnav_env.recovery import DEFAULT_SPL_THRESHOLD, DEFAULT_SUCCESS_THRESHOLD
from sb3_dcqn.campusnav.solved import solved_bar

SCRIPT = "closures_eleven.py"
N_ROADS = 11
# The goal, and the paper's result
GOAL_EPISODES = 150
PAPER_EPISODES = 500
Road = tuple[int, int]

# The lever sets of the results file: the single levers and the two fastest combinations
ELEVEN_LEVERS = ("baseline", "revision", "prioritized", "visible", "revision_blocked", "revision_blocked_prioritized")


def eleven_roads(graph: NavigationGraph, goal: int, seed: int, n_roads: int = N_ROADS) -> list[Road]:
    """
    The roads closed at once for a seed: ``n_roads`` open roads drawn with ``default_rng(seed)`` that keep the goal
    reachable from every node that reaches it now (the draw of ``ClosureEvent(close_random=n_roads, seed=seed)``).
    """
    return graph.sample_closures(n_roads, np.random.default_rng(seed), protect=[goal])


def recovery_curves(runs: Sequence[dict[str, Any]], levers: Sequence[str], title: str) -> np.ndarray:
    """
    Success rate and SPL of the greedy routes against training episodes after the closure, one line per run.

    :param runs: Records of the runs file
    :param levers: Lever keys (one colour each)
    :param title: Title of the figure
    :return: ``(H, W, 3)`` uint8 RGB image
    """
    from matplotlib.figure import Figure

    figure = Figure(figsize=(11, 6.5), dpi=100, layout="constrained")
    axes = figure.subplots(2, 1, sharex=True)
    colours = ["black", "tab:blue", "tab:orange", "tab:green", "tab:purple", "tab:red", "tab:brown", "tab:olive"]
    styles = ["-", "--", ":", "-."]
    seeds = sorted({r["seed"] for r in runs})
    for i, lever in enumerate(levers):
        for run in (r for r in runs if r["lever"] == lever):
            curve = np.asarray(run["recoveries"][0]["curve"], dtype=float) if run["recoveries"] else np.empty((0, 4))
            if not len(curve):
                continue
            style = styles[seeds.index(run["seed"]) % len(styles)]
            label = f"{LEVER_SETS[lever].name}, seed {run['seed']}"
            for ax, column in zip(axes, (2, 3), strict=True):
                ax.plot(curve[:, 0], curve[:, column], style, color=colours[i % len(colours)], lw=1.3, label=label)
    for ax, name, threshold in zip(
        axes, ("success rate", "SPL"), (DEFAULT_SUCCESS_THRESHOLD, DEFAULT_SPL_THRESHOLD), strict=True
    ):
        ax.axhline(threshold, color="0.4", ls=":", lw=1)
        ax.axvline(GOAL_EPISODES, color="tab:red", ls="--", lw=1)
        ax.set_ylabel(f"{name} (every (start, heading))")
        ax.set_ylim(-0.03, 1.03)
        ax.grid(True, alpha=0.3)
    axes[0].set_title(title, fontsize=10)
    axes[-1].set_xlabel(f"training episodes after the closure (red: the goal, {GOAL_EPISODES}; dotted: the threshold)")
    figure.legend(*axes[0].get_legend_handles_labels(), loc="outside right upper", fontsize=8, frameon=False)
    return figure_image(figure)


def summary_table(runs: Sequence[dict[str, Any]], levers: Sequence[str]) -> list[str]:
    header = [
        "lever",
        "seeds",
        "solved before the closure at (per seed)",
        "recovered",
        "median episodes",
        "median env steps",
        "median training s",
        f"goal (median <= {GOAL_EPISODES} ep)",
        f"paper (< {PAPER_EPISODES} ep)",
    ]
    rows = []
    for lever in levers:
        mine = [r for r in runs if r["lever"] == lever]
        if not mine:
            continue
        closures = [c for r in mine for c in r["recoveries"]]
        episodes, steps, seconds = medians(closures)
        rows.append(
            [
                LEVER_SETS[lever].name,
                len(mine),
                "; ".join(solve_text(r) for r in mine),
                f"{sum(c['recovered'] for c in closures)} / {len(closures)}",
                number(episodes),
                number(steps),
                number(seconds, 1),
                "met" if episodes <= GOAL_EPISODES else "**missed**",
                "met" if episodes < PAPER_EPISODES else "**missed**",
            ]
        )
    return markdown_table(header, rows)


def run_table(runs: Sequence[dict[str, Any]], levers: Sequence[str]) -> list[str]:
    header = [
        "lever",
        "seed",
        "routes affected",
        "success / SPL right after",
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
                        "-" if c["routes_affected"] is None else c["routes_affected"],
                        "-" if c["success_after"] is None else f"{c['success_after']:.3f} / {c['spl_after']:.3f}",
                        number(c["episodes"]),
                        number(c["steps"]),
                        number(c["seconds"], 1),
                        f"{end_of_window(c)} ({c['window_episodes']})",
                    ]
                )
    return markdown_table(header, rows)


def main(argv: list[str] | None = None) -> None:
    parser = closure_benchmark_parser(
        __doc__, "closures_eleven", 15_000, "env steps of training after the closure", ELEVEN_LEVERS
    )
    args = parser.parse_args(argv)
    th.set_num_threads(1)

    stem = "closures_eleven" + ("_quick" if args.quick else "")
    out: Path = args.out or RESULTS_DIR / f"{stem}.md"
    runs_file: Path = args.runs_file or out.with_name(f"{out.stem}_runs.jsonl")
    levers = QUICK_LEVERS if args.quick and args.levers == list(ELEVEN_LEVERS) else args.levers
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
    roads = {seed: eleven_roads(probe.graph, goal_node, seed) for seed in seeds}  # type: ignore[attr-defined]
    for seed, drawn in roads.items():
        print(f"seed {seed}: closes {roads_text(drawn)} (same for every lever)", flush=True)

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
            task, LEVER_SETS[lever], seed, [roads[seed]], window, args.recovery_eval_freq, env_kwargs
        )
        record = run_record(run, lever=lever, seed=seed, **settings, wall_seconds=round(time.perf_counter() - begin, 1))
        append_run(runs_file, record)
        stored.append(record)
        print(
            f"{LEVER_SETS[lever].name}, seed {seed}: solved {solve_text(record)}; recovery after "
            f"{number(record['recoveries'][0]['episodes'])} episodes; {record['wall_seconds']:.0f} s",
            flush=True,
        )
        if (lever, seed) == (figure_lever(levers), seeds[0]):
            title = f"CampusNav-v0, {LEVER_SETS[lever].name}, seed {seed}: {N_ROADS} roads closed at once"
            figures += run_figures(run, prefix, lever, title)
    total = time.perf_counter() - started

    levers = shown_levers(levers, stored, seeds)
    runs = [r for r in stored if r["lever"] in levers and r["seed"] in seeds]
    if runs:
        curves = recovery_curves(runs, levers, f"After {N_ROADS} roads closed at once, CampusNav-v0, seeds {seeds}")
        figures.append(write_figure(prefix.with_name(prefix.name + "_recovery.png"), curves))
    pictures = sorted({p.name for p in figures} | {p.name for p in out.parent.glob(f"{out.stem}_*.png")})
    wall = [r["wall_seconds"] for r in runs]
    lines = [
        f"# {N_ROADS} roads closing at once: recovery per re-adaptation lever (the paper's 11 random closures)",
        "",
        machine_line() if todo else measured_on(out, machine_line()),
        "",
        f"Setup: {task.description}{' (smoke run: pixel features of 64x48 views, tiny budgets)' if args.quick else ''},"
        f" DCQN's shipped entry (`hyperparams/dcqn.yml`) plus each lever's options. Each (lever, seed) trains from "
        f"scratch until solved ({solved_bar()} from every (start, heading), "
        f"evaluated every {task.eval_freq} steps; cap {task.max_steps} steps / {task.budget_seconds:.0f} s of "
        f"training), then keeps training (same model) for {window} env steps after {N_ROADS} roads close at once.",
        "",
        "Closures (drawn once per seed from the open map, `sample_closures(11, default_rng(seed), protect=[goal])`, "
        "i.e. `ClosureEvent(close_random=11, seed=seed)`; the goal stays reachable; the same for every lever): "
        + "; ".join(f"seed {seed}: {roads_text(drawn)}" for seed, drawn in roads.items())
        + ".",
        "",
        f"Recovery: the first route evaluation (right after the closure, then every {args.recovery_eval_freq} training "
        f"episodes) with success >= {DEFAULT_SUCCESS_THRESHOLD} and SPL >= {DEFAULT_SPL_THRESHOLD}; counted in "
        f"training episodes, env steps and training seconds (evaluations excluded) from the closure. Not recovered "
        f"within the window: *not recovered* (infinitely slow in the medians). Goal: <= {GOAL_EPISODES} episodes "
        f"(the paper: < {PAPER_EPISODES} episodes).",
        "",
        "Levers: " + "; ".join(f"{LEVER_SETS[k].name}: `{LEVER_SETS[k].options_text()}`" for k in levers) + ".",
        "",
        "## Per lever (median over seeds)",
        "",
        *summary_table(runs, levers),
        "",
        "## Per run",
        "",
        *run_table(runs, levers),
        "",
        "Routes affected: greedy routes (of all (start, heading) pairs) of the last evaluation before the closure that "
        "used a closed road.",
        "",
        f"Figures: {', '.join(f'`{name}`' for name in pictures)} (route panel and training curves `_<lever>`: the "
        "first seed's run of that lever; recovery curves: every run).",
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
