"""Single-goal against multi-goal agents on the built-in campus (the paper's Fig. 8 and its test over start nodes).

Agents, one set per seed: one multi-goal agent (``TASKS["multi"]``, the CampusNavMulti-v0 entry of
``hyperparams/dcqn.yml``: Dreese Lab, Town house, Cinema and Intramural fields) and one single-goal agent per goal
(the CampusNav-v0 entry, with ``goals=<name>`` passed to the env). Each trains until the greedy routes from every
(start, heading) to its goals are at the solved bar (``sb3_dcqn.campusnav.experiments.train_until_solved``), or its
task's step cap or time budget is spent.

Then, per agent and goal:

- 100 test episodes from random starts (uniform over intersections and headings, as the env's reset draws them),
  200-step cap, deterministic policy: success rate, mean steps, mean shortest steps, SPL, the share of the start
  nodes tried from which the goal was reached, and the share of episodes at the goal in under 20 steps;
- the route evaluator from every (start, heading) (:func:`~campusnav_env.route_evaluation.evaluate_routes`):
  success, SPL, coverage (start nodes whose every heading reaches the goal), the longest successful route and the
  share of start nodes reached in under 20 steps from every heading (the paper: the multi-goal agent reaches every
  goal in under 20 steps from every node; single-goal agents covered 95% of the nodes).

Every finished agent is appended to a JSON-lines file (a rerun skips what is done). The tables are printed and
written to ``benchmarks/results/paper_goals.md``, with PNGs beside it: the training curves (episode reward and length
against episodes) of every agent, and those of the first multi-goal agent with its route evaluations.

Usage::

    python benchmarks/paper_goals.py                    # seed 0: the multi-goal agent (1.5-3 min) and 4 single-goal
    python benchmarks/paper_goals.py --seeds 0 1 2 --test-episodes 200
    python benchmarks/paper_goals.py --quick            # smoke run: pixel features, tiny budgets
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm

from benchmarks.campusnav_runs import TASKS, VARIANTS, Task, quick_env_kwargs
from benchmarks.report import RESULTS_DIR, machine_line, publish, run_missing
from campusnav_env.env import CampusNavEnv
from campusnav_env.figures import figure_image, training_curves, write_figure
from campusnav_env.maps.campus import GOALS
from campusnav_env.route_evaluation import RouteReport, evaluate_routes
from sb3_dcqn.campusnav.experiments import train_until_solved
from sb3_dcqn.campusnav.solved import SOLVED_SPL, SOLVED_SUCCESS

SCRIPT = "paper_goals.py"
MULTI = "multi-goal"
STEP_CAP = 200
FEW_STEPS = 20  # the paper: the multi-goal agent reaches its goals in fewer than 20 steps from every node
PAPER_SINGLE_COVERAGE = 0.95


def agent_task(agent: str, quick: bool) -> Task:
    """The task an agent trains on (``MULTI`` or a goal's name); a smoke run's budgets are tiny."""
    task = TASKS["multi"] if agent == MULTI else TASKS["campus"]
    if quick:
        task = dataclasses.replace(task, max_steps=1_500 if agent == MULTI else 1_000, budget_seconds=20, eval_freq=500)
    return task


def make_env(agent: str, task: Task, env_kwargs: dict[str, Any]) -> Any:
    """The env of an agent: the multi-goal env, or the single-goal env with ``goals=<name>``."""
    entry = VARIANTS["DCQN"].entry(task)
    goals = {} if agent == MULTI else {"goals": agent}
    return task.make_env(entry, **{**goals, **env_kwargs})


def test_episodes(model: BaseAlgorithm, env: CampusNavEnv, goal: str, n_episodes: int, seed: int) -> dict[str, Any]:
    """
    Run the deterministic policy from ``n_episodes`` random starts to ``goal`` (at most ``STEP_CAP`` steps each).

    :return: success rate, mean steps, mean shortest steps, SPL, the share of start nodes tried that reached the goal
        and the share of episodes at the goal in under ``FEW_STEPS`` steps
    """
    env.max_steps = STEP_CAP
    obs, info = env.reset(seed=seed, options={"goal": goal})
    episodes = []
    for k in range(n_episodes):
        if k:
            obs, info = env.reset(options={"goal": goal})
        start, shortest, steps = info["node"], info["shortest_distance"], 0
        terminated = truncated = False
        state = None  # what the model remembers within the episode (a route memory's prior and episode guard)
        while not (terminated or truncated):
            action, state = model.predict(obs, state=state, episode_start=np.array([steps == 0]), deterministic=True)
            obs, _, terminated, truncated, info = env.step(int(np.asarray(action).reshape(-1)[0]))
            steps += 1
        episodes.append((start, bool(terminated), steps, shortest))
    success = np.array([e[1] for e in episodes])
    steps = np.array([e[2] for e in episodes], dtype=float)
    shortest = np.array([e[3] for e in episodes], dtype=float)
    starts = {e[0] for e in episodes}
    reached = {e[0] for e in episodes if e[1]}
    return {
        "episodes": n_episodes,
        "success": float(success.mean()),
        "mean_steps": float(steps.mean()),
        "mean_shortest": float(shortest.mean()),
        "spl": float(np.mean(success * shortest / np.maximum(steps, shortest))),
        "starts_tried": len(starts),
        "starts_reached": len(reached),
        "under_few_steps": float(np.mean(success & (steps < FEW_STEPS))),
    }


def route_summary(report: RouteReport) -> dict[str, Any]:
    """The route evaluator's scores for one goal, with the longest route and the starts reached in few steps."""
    succeeded = [r.steps for r in report.routes if r.success]
    by_start: dict[int, bool] = {}
    any_heading: dict[int, bool] = {}
    for route in report.routes:
        quick = route.success and route.steps < FEW_STEPS
        by_start[route.start] = by_start.get(route.start, True) and quick
        any_heading[route.start] = any_heading.get(route.start, False) or route.success
    return {
        "routes": len(report.routes),
        "success": report.success_rate,
        "spl": report.spl,
        "coverage": report.coverage,
        "nodes_reached": float(np.mean(list(any_heading.values()))) if any_heading else 0.0,
        "max_steps": max(succeeded, default=None),
        "max_shortest": max((r.shortest for r in report.routes), default=None),
        "nodes_under_few_steps": float(np.mean(list(by_start.values()))) if by_start else 0.0,
    }


def train_and_test(agent: str, seed: int, quick: bool, n_episodes: int, env_kwargs: dict[str, Any]) -> dict[str, Any]:
    """Train one agent until solved (or capped), then test it on each of its goals; the runs file's record."""
    task = agent_task(agent, quick)
    entry = VARIANTS["DCQN"].entry(task)
    env = make_env(agent, task, env_kwargs)
    model = VARIANTS["DCQN"].make_model(env, entry, seed)
    solve = train_until_solved(model, task.max_steps, task.budget_seconds, task.eval_freq)
    vec_env = model.get_env()
    assert vec_env is not None
    rewards = vec_env.env_method("get_episode_rewards")[0]
    lengths = vec_env.env_method("get_episode_lengths")[0]
    reached = solve.solved_at or (solve.evaluations[-1] if solve.evaluations else None)

    test_env = make_env(agent, task, env_kwargs).unwrapped  # a fresh env: training's episode state is left alone
    goals = list(GOALS) if agent == MULTI else [agent]
    tests, routes = {}, {}
    start = time.perf_counter()
    for g, goal in enumerate(goals):
        tests[goal] = test_episodes(model, test_env, goal, n_episodes, seed=10_000 + 100 * seed + g)
        report = evaluate_routes(test_env, model, goals=[goal], max_steps=STEP_CAP)
        routes[goal] = route_summary(report)
    return {
        "agent": agent,
        "seed": seed,
        "quick": quick,
        "test_episodes": n_episodes,
        "solved": solve.solved_at is not None,
        "steps": None if reached is None else reached.step,
        "episodes": None if reached is None else reached.episode,
        "train_seconds": None if reached is None else round(reached.train_seconds, 2),
        "wall_seconds": round(solve.wall_seconds, 2),
        "test_seconds": round(time.perf_counter() - start, 2),
        "max_steps": task.max_steps,
        "budget_seconds": task.budget_seconds,
        "evaluations": solve.curve(),
        "episode_rewards": [round(float(r), 4) for r in rewards],
        "episode_lengths": [int(n) for n in lengths],
        "tests": tests,
        "routes": routes,
    }


def _moving_average(values: np.ndarray, window: int) -> np.ndarray:
    sums = np.cumsum(np.concatenate([[0.0], values]))
    ends = np.arange(1, values.size + 1)
    starts = np.maximum(0, ends - window)
    return (sums[ends] - sums[starts]) / (ends - starts)


def comparison_curves(runs: Sequence[dict[str, Any]], window: int = 100) -> np.ndarray:
    """Episode reward and length against training episodes, every agent (moving average of ``window`` episodes)."""
    from matplotlib.figure import Figure

    figure = Figure(figsize=(11, 6.5), dpi=100, layout="constrained")
    axes = figure.subplots(2, 1, sharex=True)
    colours = {MULTI: "black", **dict(zip(GOALS, ("tab:blue", "tab:orange", "tab:green", "tab:purple"), strict=True))}
    styles = ["-", "--", ":", "-."]
    seeds = sorted({r["seed"] for r in runs})
    for run in runs:
        label = ("multi-goal agent (4 goals)" if run["agent"] == MULTI else f"single-goal: {run['agent']}") + (
            f", seed {run['seed']}" if len(seeds) > 1 else ""
        )
        style = styles[seeds.index(run["seed"]) % len(styles)]
        for ax, key in zip(axes, ("episode_rewards", "episode_lengths"), strict=True):
            values = np.asarray(run[key], dtype=float)
            if values.size:
                episodes = np.arange(1, values.size + 1)
                smooth = _moving_average(values, window)
                ax.plot(episodes, smooth, style, color=colours[run["agent"]], lw=1.2, label=label)
    axes[0].set_ylabel(f"episode reward (mean of {window})")
    axes[1].set_ylabel(f"episode length (mean of {window})")
    axes[1].set_xlabel("training episode")
    for ax in axes:
        ax.grid(True, alpha=0.3)
    axes[0].set_title("Training until solved: multi-goal against single-goal agents (CampusNav, DCQN)", fontsize=10)
    figure.legend(*axes[0].get_legend_handles_labels(), loc="outside right upper", fontsize=8, frameon=False)
    return figure_image(figure)


def _solve_text(run: dict[str, Any]) -> str:
    where = (
        "-"
        if run["steps"] is None
        else f"{run['steps']} steps, {run['episodes']} episodes, {run['train_seconds']:.0f} s"
    )
    if run["solved"]:
        return where
    return f"**not solved** (cap {run['max_steps']} steps / {run['budget_seconds']:.0f} s; stopped at {where})"


def training_table(runs: Sequence[dict[str, Any]]) -> list[str]:
    lines = [
        "| agent | seed | solved at (training s, evaluations excluded) | wall s (with evaluations) | last evaluation: "
        "success / SPL |",
        "|---|---|---|---|---|",
    ]
    for run in runs:
        last = run["evaluations"][-1] if run["evaluations"] else None
        final = "-" if last is None else f"{last['success']:.3f} / {last['spl']:.3f}"
        lines.append(
            f"| {_agent_name(run['agent'])} | {run['seed']} | {_solve_text(run)} | {run['wall_seconds']:.0f} | "
            f"{final} |"
        )
    return lines


def test_table(runs: Sequence[dict[str, Any]]) -> list[str]:
    lines = [
        "| goal | agent | seed | test success | mean steps | mean shortest | SPL | start nodes reached | "
        f"at the goal in < {FEW_STEPS} steps |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for goal in GOALS:
        for run in runs:
            test = run["tests"].get(goal)
            if test is None:
                continue
            share = test["starts_reached"] / max(test["starts_tried"], 1)
            lines.append(
                f"| {goal} | {_agent_name(run['agent'])} | {run['seed']} | {test['success']:.2f} | "
                f"{test['mean_steps']:.1f} | {test['mean_shortest']:.1f} | {test['spl']:.3f} | "
                f"{test['starts_reached']} / {test['starts_tried']} ({share:.0%}) | "
                f"{test['under_few_steps']:.0%} |"
            )
    return lines


def route_table(runs: Sequence[dict[str, Any]]) -> list[str]:
    lines = [
        "| goal | agent | seed | routes | success | SPL | coverage (every heading) | nodes reached (any heading) | "
        f"longest successful route (longest shortest path) | nodes reached in < {FEW_STEPS} steps (every heading) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for goal in GOALS:
        for run in runs:
            route = run["routes"].get(goal)
            if route is None:
                continue
            longest = "-" if route["max_steps"] is None else str(route["max_steps"])
            lines.append(
                f"| {goal} | {_agent_name(run['agent'])} | {run['seed']} | {route['routes']} | "
                f"{route['success']:.3f} | {route['spl']:.3f} | {route['coverage']:.1%} | "
                f"{route['nodes_reached']:.1%} | {longest} ({route['max_shortest']}) | "
                f"{route['nodes_under_few_steps']:.1%} |"
            )
    return lines


def paper_claims(runs: Sequence[dict[str, Any]]) -> list[str]:
    """The paper's two claims, checked on every run: met or missed."""
    lines = []
    for run in runs:
        if run["agent"] == MULTI:
            shares = [run["routes"][g]["nodes_under_few_steps"] for g in run["routes"]]
            met = all(share >= 1.0 for share in shares)
            lines.append(
                f"- Multi-goal agent, seed {run['seed']}: every goal in < {FEW_STEPS} steps from every node and "
                "heading: "
                f"{'met' if met else '**missed**'} (per goal: "
                + ", ".join(f"{g} {run['routes'][g]['nodes_under_few_steps']:.0%}" for g in run["routes"])
                + ")."
            )
        else:
            coverage = run["routes"][run["agent"]]["coverage"]
            lines.append(
                f"- Single-goal agent for {run['agent']}, seed {run['seed']}: coverage {coverage:.1%} of the start "
                f"nodes (every heading) against the paper's {PAPER_SINGLE_COVERAGE:.0%}: "
                f"{'as good or better' if coverage >= PAPER_SINGLE_COVERAGE else '**below**'}."
            )
    return lines


def _agent_name(agent: str) -> str:
    return "multi-goal (4 goals)" if agent == MULTI else f"single-goal ({agent})"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", nargs="+", type=int, default=[0])
    parser.add_argument("--agents", nargs="+", choices=[MULTI, *GOALS], default=[MULTI, *GOALS])
    parser.add_argument("--test-episodes", type=int, default=100, help="test episodes per goal")
    parser.add_argument("--quick", action="store_true", help="smoke run: pixel features, tiny budgets, 10 episodes")
    parser.add_argument("--out", type=Path, default=None, help="results file (default results/paper_goals.md)")
    parser.add_argument("--runs-file", type=Path, default=None)
    args = parser.parse_args(argv)
    th.set_num_threads(1)

    stem = "paper_goals" + ("_quick" if args.quick else "")
    out: Path = args.out or RESULTS_DIR / f"{stem}.md"
    runs_file: Path = args.runs_file or out.with_name(f"{out.stem}_runs.jsonl")
    n_episodes = min(args.test_episodes, 10) if args.quick else args.test_episodes
    env_kwargs = quick_env_kwargs() if args.quick else {}

    def describe(record: dict[str, Any]) -> str:
        return (
            f"{_agent_name(record['agent'])}, seed {record['seed']}: {_solve_text(record)}; test success "
            + ", ".join(f"{g} {t['success']:.2f}" for g, t in record["tests"].items())
            + f"; {record['wall_seconds'] + record['test_seconds']:.0f} s"
        )

    ran = run_missing(
        runs_file,
        [(agent, seed) for seed in args.seeds for agent in args.agents],
        lambda job: train_and_test(*job, args.quick, n_episodes, env_kwargs),
        key=lambda r: (r["agent"], r["seed"]),
        settings={"quick": args.quick, "test_episodes": n_episodes},
        describe=describe,
        noun="agents",
    )

    order = {agent: k for k, agent in enumerate([MULTI, *GOALS])}
    runs = sorted(
        (r for r in ran.records if r["agent"] in args.agents and r["seed"] in args.seeds),
        key=lambda r: (r["seed"], order[r["agent"]]),
    )
    prefix = out.with_name(out.stem)
    figures = []
    if runs:
        figures.append(write_figure(prefix.with_name(prefix.name + "_training.png"), comparison_curves(runs)))
        multi = next((r for r in runs if r["agent"] == MULTI), None)
        if multi is not None:
            curves = training_curves(
                multi["episode_rewards"],
                multi["episode_lengths"],
                evaluations=[_evaluation(e) for e in multi["evaluations"]],
                window=100,
                title=f"Multi-goal agent (CampusNavMulti-v0), seed {multi['seed']}: training until solved",
            )
            figures.append(write_figure(prefix.with_name(prefix.name + "_training_multi.png"), curves))
    seconds = [r["wall_seconds"] + r["test_seconds"] for r in runs]
    lines = [
        "# Single-goal against multi-goal agents (the paper's Fig. 8 and its test from every start)",
        "",
        machine_line(),
        "",
        "Agents: one multi-goal agent (CampusNavMulti-v0 entry of `hyperparams/dcqn.yml`, goals "
        + ", ".join(GOALS)
        + ") and one single-goal agent per goal (CampusNav-v0 entry, `goals=<name>`)"
        + (" (smoke run: pixel features of 64x48 views, tiny budgets)" if args.quick else "")
        + f". Each trains until solved: success >= {SOLVED_SUCCESS} and SPL >= {SOLVED_SPL} over every "
        "(start, heading) and goal, or its task's step cap / training-time budget.",
        "",
        "## Training",
        "",
        *training_table(runs),
        "",
        f"## Test: {n_episodes} episodes per goal from random starts ({STEP_CAP}-step cap, deterministic policy)",
        "",
        *test_table(runs),
        "",
        "Mean steps: over all episodes (a failed one counts its steps, up to the cap). Start nodes reached: distinct "
        "start nodes of the test episodes from which the goal was reached, of those tried.",
        "",
        f"## Route evaluator: the greedy policy from every (start, heading), {STEP_CAP}-step cap",
        "",
        *route_table(runs),
        "",
        "## The paper's claims",
        "",
        *paper_claims(runs),
        "",
        f"Figures: {', '.join(f'`{p.name}`' for p in figures)} (episode reward and length against training episodes, "
        "moving average of 100: every agent; the multi-goal agent's with its route evaluations).",
        "",
        f"Time: {len(runs)} agents, {np.sum(seconds):.0f} s in all (training with evaluations, then the tests); "
        + ran.invocation_text("trained"),
    ]
    publish(out, lines, SCRIPT, argv)


def _evaluation(point: dict[str, float]) -> Any:
    """A stored evaluation point as what ``training_curves`` reads (episode, success rate, SPL)."""
    from types import SimpleNamespace

    return SimpleNamespace(episode=point["episode"], success_rate=point["success"], spl=point["spl"])


if __name__ == "__main__":
    main()
