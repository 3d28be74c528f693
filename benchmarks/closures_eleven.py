"""Eleven roads closing at once: how fast DCQN recovers, with and without its re-adaptation levers (the paper's 11).

For every seed and lever set (``campusnav_runs.LEVER_SETS``) an agent trains on CampusNav-v0 until the map is solved,
then keeps training (same model) for ``--window`` env steps after 11 random roads close at once: the glue's loop
(:func:`sb3_dcqn.campusnav.experiments.train_with_closures`, through ``closure_runs.train_then_close``). The
roads are drawn once per seed from the open map (:meth:`~campusnav_env.maps.navigation.NavigationGraph.sample_closures`
with ``numpy.random.default_rng(seed)``, the draw of ``ClosureEvent(close_random=11, seed=seed)``), keeping the goal
reachable from every node, and every lever set faces the same roads. A
:class:`~campusnav_env.callbacks.RoadClosureCallback` closes them and drives a
:class:`~campusnav_env.callbacks.RouteEvaluationCallback`: the greedy routes from every (start, heading) are evaluated
right after the closure, then every ``--eval-every`` training episodes until back at the recovery thresholds
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

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch as th

from benchmarks.campusnav_runs import LEVER_SETS
from benchmarks.closure_runs import (
    PAPER_ROADS,
    ClosureSetup,
    closure_benchmark_parser,
    closure_jobs,
    eleven_roads,
    figures_text,
    lever_cells,
    median_columns,
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
from campusnav_env.recovery import DEFAULT_SPL_THRESHOLD, DEFAULT_SUCCESS_THRESHOLD

SCRIPT = "closures_eleven.py"
N_ROADS = PAPER_ROADS
# The goal, and the paper's result
GOAL_EPISODES = 150
PAPER_EPISODES = 500

# The lever sets of the results file: the single levers and the two fastest combinations
ELEVEN_LEVERS = ("baseline", "revision", "prioritized", "visible", "revision_blocked", "revision_blocked_prioritized")


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


def summary_table(runs: Sequence[dict[str, Any]], levers: Sequence[str], eval_every: int) -> list[str]:
    header = ["lever", "seeds", "solved before the closure at (per seed)", "recovered", *median_columns(eval_every)]
    header += [f"goal (median <= {GOAL_EPISODES} ep)", f"paper (< {PAPER_EPISODES} ep)"]
    rows = []
    for lever, mine in runs_by_lever(runs, levers):
        cells, episodes, _ = lever_cells(lever, mine)
        met = [
            "met" if episodes <= GOAL_EPISODES else "**missed**",
            "met" if episodes < PAPER_EPISODES else "**missed**",
        ]
        rows.append([*cells, *met])
    return markdown_table(header, rows)


def run_table(runs: Sequence[dict[str, Any]], levers: Sequence[str], eval_every: int) -> list[str]:
    header = ["lever", "seed", "routes affected", "success / SPL right after", *recovery_columns(eval_every)]
    header.append("success / SPL at the end of the window (episodes in it)")
    rows = []
    for lever, mine in runs_by_lever(runs, levers):
        for run in sorted(mine, key=lambda r: r["seed"]):
            for c in run["recoveries"]:
                right_after = "-" if c["success_after"] is None else f"{c['success_after']:.3f} / {c['spl_after']:.3f}"
                affected = "-" if c["routes_affected"] is None else c["routes_affected"]
                rows.append(
                    [LEVER_SETS[lever].name, run["seed"], affected, right_after, *recovery_cells(c), window_cell(c)]
                )
    return markdown_table(header, rows)


def main(argv: list[str] | None = None) -> None:
    parser = closure_benchmark_parser(
        __doc__, "closures_eleven", 15_000, "env steps of training after the closure", ELEVEN_LEVERS
    )
    args = parser.parse_args(argv)
    th.set_num_threads(1)
    setup = ClosureSetup.from_args(args, "closures_eleven", ELEVEN_LEVERS)

    probe = setup.probe()
    goal_node = probe.goal_nodes[0]
    roads = {seed: eleven_roads(probe.graph, goal_node, seed) for seed in setup.seeds}
    for seed, drawn in roads.items():
        print(f"seed {seed}: closes {roads_text(drawn)} (same for every lever)", flush=True)

    def describe(record: dict[str, Any]) -> str:
        return (
            f"{LEVER_SETS[record['lever']].name}, seed {record['seed']}: solved {solve_text(record)}; recovery after "
            f"{number(record['recoveries'][0]['episodes'])} episodes; {record['wall_seconds']:.0f} s"
        )

    jobs = closure_jobs(
        setup,
        lambda seed: (tuple(roads[seed]),),
        lambda lever, seed: f"CampusNav-v0, {LEVER_SETS[lever].name}, seed {seed}: {N_ROADS} roads closed at once",
    )
    stored = run_closure_jobs(setup, jobs, describe)
    levers, runs = shown_runs(setup, stored)
    if runs:
        title = f"After {N_ROADS} roads closed at once, CampusNav-v0, seeds {setup.seeds}"
        write_figure(setup.prefix.with_name(setup.prefix.name + "_recovery.png"), recovery_curves(runs, levers, title))
    lines = [
        f"# {N_ROADS} roads closing at once: recovery per re-adaptation lever (the paper's 11 random closures)",
        "",
        stored.machine(setup.out, machine_line()),
        "",
        setup.setup_text(f"for {setup.window} env steps after {N_ROADS} roads close at once"),
        "",
        "Closures (drawn once per seed from the open map, `sample_closures(11, default_rng(seed), protect=[goal])`, "
        "i.e. `ClosureEvent(close_random=11, seed=seed)`; the goal stays reachable; the same for every lever): "
        + "; ".join(f"seed {seed}: {roads_text(drawn)}" for seed, drawn in roads.items())
        + ".",
        "",
        setup.recovery_text()
        + " Not recovered within the window: *not recovered* (infinitely slow in the medians). Goal: <= "
        f"{GOAL_EPISODES} episodes (the paper: < {PAPER_EPISODES} episodes).",
        "",
        setup.levers_text(levers),
        "",
        "## Per lever (median over seeds)",
        "",
        *summary_table(runs, levers, setup.eval_every),
        "",
        "## Per run",
        "",
        *run_table(runs, levers, setup.eval_every),
        "",
        "Routes affected: greedy routes (of all (start, heading) pairs) of the last evaluation before the closure that "
        "used a closed road.",
        "",
        figures_text(
            setup,
            "route panel and training curves `_<lever>`: the first seed's run of that lever; recovery curves: every "
            "run",
        ),
        "",
        time_text(stored, runs),
    ]
    publish(setup.out, lines, SCRIPT, argv)


if __name__ == "__main__":
    main()
