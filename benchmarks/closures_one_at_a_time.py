"""Roads closing one at a time: how fast DCQN recovers, with and without its re-adaptation levers (paper Fig. 7b/9).

For every seed and lever set (``campusnav_runs.LEVER_SETS``: DCQN as shipped, each of its re-adaptation levers, and
combinations of them) an agent trains on CampusNav-v0 until the map is solved, then keeps training (same model) while
roads close one at a time, cumulatively: a closure, then ``--window`` env steps in which the recovery is measured,
then the next closure. The loop is the glue's (:func:`sb3_dcqn.campusnav.experiments.train_with_closures`, the one
``dcqn-campusnav`` runs): a :class:`~campusnav_env.callbacks.RoadClosureCallback` closes the roads and drives a
:class:`~campusnav_env.callbacks.RouteEvaluationCallback`: the greedy routes from every (start, heading) are evaluated
right after each closure, then every ``--eval-every`` training episodes until back at the recovery thresholds
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

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch as th

from benchmarks.campusnav_runs import LEVER_SETS
from benchmarks.closure_runs import (
    ClosureSetup,
    busiest_closures,
    closure_benchmark_parser,
    closure_jobs,
    figures_text,
    lever_cells,
    median_columns,
    median_episodes,
    medians,
    number,
    recovery_cells,
    recovery_columns,
    roads_text,
    run_closure_jobs,
    runs_by_lever,
    shown_runs,
    solve_text,
    time_text,
    window_cell,
)
from benchmarks.report import machine_line, markdown_table, publish
from campusnav_env.figures import figure_image, write_figure

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
# The goal per closure, and the paper's result
GOAL_EPISODES = 50
GOAL_SECONDS = 10.0
PAPER_EPISODES = 300


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
            median = median_episodes(values)
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


# ------------------------------------------------------------------------------------------------ this benchmark
def summary_table(
    runs: Sequence[dict[str, Any]], levers: Sequence[str], goal_episodes: float, eval_every: int
) -> list[str]:
    header = ["lever", "seeds", "solved before the closures at (per seed)", "closures recovered"]
    header += [*median_columns(eval_every), "closures within the goal"]
    header += [f"goal (median <= {goal_episodes:.0f} ep and <= {GOAL_SECONDS:.0f} s)", f"paper (< {PAPER_EPISODES} ep)"]
    rows = []
    for lever, mine in runs_by_lever(runs, levers):
        cells, episodes, closures = lever_cells(lever, mine)
        seconds = medians(closures)[2]
        within = sum(
            c["episodes"] is not None and c["episodes"] <= goal_episodes and c["seconds"] <= GOAL_SECONDS
            for c in closures
        )
        met = episodes <= goal_episodes and seconds <= GOAL_SECONDS
        rows.append(
            [
                *cells,
                f"{within} / {len(closures)}",
                "met" if met else "**missed**",
                "met" if episodes < PAPER_EPISODES else "**missed**",
            ]
        )
    return markdown_table(header, rows)


def closure_table(runs: Sequence[dict[str, Any]], levers: Sequence[str], eval_every: int) -> list[str]:
    header = ["lever", "seed", "closure", "road", "routes affected", "success right after"]
    header += [*recovery_columns(eval_every), "success / SPL at the end of the window (episodes in it)"]
    rows = []
    for lever, mine in runs_by_lever(runs, levers):
        for run in sorted(mine, key=lambda r: r["seed"]):
            for c in run["recoveries"]:
                rows.append(
                    [
                        LEVER_SETS[lever].name,
                        run["seed"],
                        c["closure"],
                        roads_text(c["roads"]),
                        "-" if c["routes_affected"] is None else c["routes_affected"],
                        "-" if c["success_after"] is None else f"{c['success_after']:.3f}",
                        *recovery_cells(c),
                        window_cell(c),
                    ]
                )
    return markdown_table(header, rows)


def main(argv: list[str] | None = None) -> None:
    parser = closure_benchmark_parser(
        __doc__, "closures_one_at_a_time", 6_000, "env steps of training after each closure", DEFAULT_LEVERS
    )
    parser.add_argument("--closures", type=int, default=3, help="roads closed one after another")
    args = parser.parse_args(argv)
    th.set_num_threads(1)
    setup = ClosureSetup.from_args(args, "closures_one_at_a_time", DEFAULT_LEVERS)

    probe = setup.probe()
    goal_node = probe.goal_nodes[0]
    roads = busiest_closures(probe.graph, goal_node, args.closures)
    goal_roads = [r for r in probe.graph.map.roads if goal_node in r]
    print(f"closures (same for every lever and seed): {roads_text(roads)}", flush=True)

    def describe(record: dict[str, Any]) -> str:
        recovered = ", ".join(number(c["episodes"]) for c in record["recoveries"])
        return (
            f"{LEVER_SETS[record['lever']].name}, seed {record['seed']}: solved {solve_text(record)}; recovery "
            f"episodes per closure: {recovered}; {record['wall_seconds']:.0f} s"
        )

    jobs = closure_jobs(
        setup,
        lambda seed: tuple((road,) for road in roads),
        lambda lever, seed: f"CampusNav-v0, {LEVER_SETS[lever].name}, seed {seed}: roads closing one at a time",
    )
    stored = run_closure_jobs(setup, jobs, describe)
    levers, runs = shown_runs(setup, stored)
    if runs:
        bars = recovery_bars(runs, levers, f"Recovery after each closure, CampusNav-v0, seeds {setup.seeds}")
        write_figure(setup.prefix.with_name(setup.prefix.name + "_recovery.png"), bars)
    lines = [
        "# Roads closing one at a time: recovery per re-adaptation lever (the paper's Fig. 7b/9)",
        "",
        stored.machine(setup.out, machine_line()),
        "",
        setup.setup_text(
            f"while {len(roads)} roads close one at a time, cumulatively: one closure, then {setup.window} env steps "
            "of training, then the next"
        ),
        "",
        f"Closures (the same for every lever and seed, chosen from the map: the road most used by the shortest paths "
        f"from every intersection to the goal, then the busiest with it closed, ...; roads that would cut the goal off "
        f"are skipped): {roads_text(roads)}. The goal (node {goal_node}) has the roads {roads_text(goal_roads)}: "
        f"{sum(r in goal_roads for r in roads)} of the closures are at the goal itself.",
        "",
        setup.recovery_text()
        + " A closure not recovered from within its window is *not recovered* and counts as infinitely slow in the "
        "medians. The visible closures' rendering and encoding of the new views happens at the closure, outside the "
        f"training seconds. Goal: <= {GOAL_EPISODES} episodes and <= {GOAL_SECONDS:.0f} s per closure (the paper: "
        f"< {PAPER_EPISODES} episodes).",
        "",
        setup.levers_text(levers),
        "",
        "## Per lever (median over closures and seeds)",
        "",
        *summary_table(runs, levers, GOAL_EPISODES, setup.eval_every),
        "",
        "## Per closure",
        "",
        *closure_table(runs, levers, setup.eval_every),
        "",
        "Routes affected: greedy routes (of all (start, heading) pairs) of the last evaluation before the closure that "
        "used the closed road.",
        "",
        figures_text(
            setup,
            "route panels and training curves `_<lever>`: the first seed's run of that lever; recovery: every run",
        ),
        "",
        time_text(stored, runs),
    ]
    publish(setup.out, lines, SCRIPT, argv)


if __name__ == "__main__":
    main()
