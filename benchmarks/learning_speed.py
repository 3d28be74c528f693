"""Learning speed: training time to a solved map, DCQN against SB3's DQN in the same run, several seeds and maps.

A map is *solved* at the first route evaluation (the greedy policy from every (start, heading) pair to every goal,
run every ``eval_freq`` env steps inside one ``learn()`` call) at the solved bar (``sb3_dcqn.campusnav.solved``). The
figure is the training wall time to that evaluation, evaluation time excluded, with the env steps and episodes it
took. A run that spends its step cap or time budget unsolved is a miss and is reported as one.

Tasks (``--tasks``): ``campus`` (CampusNav-v0: 101 intersections, goal Dreese Lab), ``multi`` (CampusNavMulti-v0: the
four goals), ``campus200`` and ``campus500`` (generated campuses of 200 and 500 intersections, goal Dreese Lab),
``city`` (CampusNavCity-v0: 1,000 intersections, goal Dreese Lab, its entry's start curriculum). All use
EfficientNet-Lite0 features projected to 64 dimensions per view (the shipped ``env_kwargs``). An entry's callbacks
train along (the city's curriculum). Agents (``--variants``): ``DCQN`` as shipped (``hyperparams/dcqn.yml``; the
multi-goal and city entries wear the route memory), ``DCQN, no heading_key`` (the critics read the heading as an
input: the network DQN has), ``DQN`` (SB3's DQN, same settings and network), ``DCQN, paper settings``
(``hyperparams/dcqn_paper.yml``: lr 1e-4, buffer 412, full 1280-d features), and what the twin critics add once the
memory routes: ``DQN + memory``, ``QRDQN + memory``, ``DCQN + memory`` (the same route memory worn by each,
:func:`sb3_dcqn.with_route_memory`) against ``DCQN, critics alone``.

Runs go one after another in this process (one torch thread), each finished run appended to a JSON-lines file, so
an interrupted benchmark keeps its results and a rerun skips what is done. Writes ``results/learning_speed.md`` and
``results/learning_speed.png`` (success vs training seconds, one line per run).

Usage::

    python benchmarks/learning_speed.py                                    # campus and multi, seeds 0 1 2
    python benchmarks/learning_speed.py --tasks campus200 campus500 --variants DCQN DQN --seeds 0 1
    python benchmarks/learning_speed.py --tasks multi city --seeds 0 1 2 \
        --variants "DQN + memory" "QRDQN + memory" "DCQN + memory" "DCQN, critics alone"
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from matplotlib.figure import Figure

from benchmarks.campusnav_runs import SEVERITY_SWEEP, TASKS, VARIANTS, WORLDS
from benchmarks.report import RESULTS_DIR, machine_line, publish, run_missing, write_results
from campusnav_env.figures import figure_image, write_figure
from sb3_dcqn.campusnav.experiments import train_until_solved
from sb3_dcqn.campusnav.solved import SOLVED_SPL, SOLVED_SUCCESS

DEFAULT_VARIANTS = ("DCQN", "DCQN, no heading_key", "DQN")
# The route memory against the critics alone (the same entry with route_memory: false), where both ran in a world
MEMORY_TWINS = (("DCQN", "DCQN, critics alone"), ("DCQN + memory", "DCQN, critics alone"))
MEMORY_WITHIN = 1.1  # issue 46: the memory solves within 1.1x the critics' env steps


def run_one(
    task_name: str,
    variant_name: str,
    seed: int,
    budget_seconds: float | None = None,
    max_steps: int | None = None,
    eval_freq: int | None = None,
    world_name: str = "fixed",
) -> dict[str, Any]:
    """Train one agent on one task, in one world, to the threshold (or its caps) and return the run's record."""
    task, variant, world = TASKS[task_name], VARIANTS[variant_name], WORLDS[world_name]
    task = replace(
        task,
        budget_seconds=budget_seconds or task.budget_seconds,
        max_steps=max_steps or task.max_steps,
        eval_freq=eval_freq or task.eval_freq,
    )
    entry = variant.entry(task)
    env = world.make_env(task, entry)
    model = variant.make_model(env, entry, seed)
    result = train_until_solved(
        model, task.max_steps, task.budget_seconds, task.eval_freq, callbacks=entry.make_callbacks()
    )
    last = result.evaluations[-1]
    solved = result.solved_at
    memory = getattr(model, "memory", None)
    return {
        "task": task_name,
        "variant": variant_name,
        "world": world_name,
        "seed": seed,
        "memory_states": None if memory is None else memory.n_states,
        "memory_stepped_aside": None if memory is None else memory.stepped_aside,
        "memory_speaks": None if memory is None else memory.speaks,  # not standing aside on its predictions' evidence
        "memory_prediction_accuracy": None if memory is None else memory.predictions.accuracy,
        # Who drove at the end while the memory's routes were on trial (EpisodeTrial), and how often the lead changed
        "critics_lead": None if memory is None else bool(model._trial.critics_lead),
        "trial_changes": None if memory is None else int(model._trial.changes),
        "solved": solved is not None,
        "seconds": solved.train_seconds if solved else last.train_seconds,
        "steps": solved.step if solved else last.step,
        "episodes": solved.episode if solved else last.episode,
        "final_success": last.success_rate,
        "final_spl": last.spl,
        "wall_seconds": result.wall_seconds,
        "budget_seconds": task.budget_seconds,
        "max_steps": task.max_steps,
        "eval_freq": task.eval_freq,
        "curve": result.curve(),
    }


def profile_costs(task_name: str, variant_name: str, repeats: int = 300) -> dict[str, float]:
    """
    Milliseconds per env step, action selection, replay sample and gradient step (its sample included) of one agent,
    measured after 2,000 steps of training so that the buffer holds real transitions, and what one training env step
    costs from them: an env step and an action, plus ``gradient_steps`` gradient steps every ``train_freq`` steps.
    """
    task, variant = TASKS[task_name], VARIANTS[variant_name]
    entry = variant.entry(task)
    env = task.make_env(entry)
    model = variant.make_model(env, entry, seed=0)
    model.learn(2_000)
    rng = np.random.default_rng(0)
    observation, _ = env.reset(seed=0)

    def env_step() -> None:
        _, _, terminated, truncated, _ = env.step(int(rng.integers(4)))
        if terminated or truncated:
            env.reset()

    def per_call(function: Any) -> float:
        function()  # warm up
        start = time.perf_counter()
        for _ in range(repeats):
            function()
        return 1e3 * (time.perf_counter() - start) / repeats

    costs = {
        "env step": per_call(env_step),
        "action selection": per_call(lambda: model.predict(observation, deterministic=True)),
        "replay sample": per_call(lambda: model.replay_buffer.sample(model.batch_size)),
        "gradient step": per_call(lambda: model.train(gradient_steps=1, batch_size=model.batch_size)),
    }
    updates_per_step = max(model.gradient_steps, 1) / model.train_freq.frequency
    costs["training env step"] = (
        costs["env step"] + costs["action selection"] + updates_per_step * costs["gradient step"]
    )
    return costs


PROFILE_COLUMNS = ("env step", "action selection", "replay sample", "gradient step", "training env step")


def profile_table(profiles: dict[str, dict[str, float]]) -> list[str]:
    """Where the training time goes, per agent (milliseconds)."""
    lines = [f"| agent | {' | '.join(PROFILE_COLUMNS)} |", "|---|" + "---|" * len(PROFILE_COLUMNS)]
    for variant, costs in profiles.items():
        lines.append(f"| {variant} | " + " | ".join(f"{costs[name]:.2f}" for name in PROFILE_COLUMNS) + " |")
    return lines


def _seconds(run: dict[str, Any]) -> str:
    return f"{run['seconds']:.0f}" if run["solved"] else f"miss ({run['seconds']:.0f} s: {run['final_success']:.3f})"


def _median(value: float) -> str:
    return f"{value:.0f}" if np.isfinite(value) else "not solved"


def _cost(run: dict[str, Any], key: str) -> float:
    # A miss counts as infinitely slow, so that neither a median nor a ratio hides it
    return float(run[key]) if run["solved"] else np.inf


def _median_of(group: list[dict[str, Any]], key: str) -> float:
    return float(np.median([_cost(r, key) for r in group]))


def _world(run: dict[str, Any]) -> str:
    return run.get("world", "fixed")  # runs recorded before worlds were fixed views


def summary_table(runs: list[dict[str, Any]], tasks: list[str], variants: list[str]) -> list[str]:
    """
    One row per (task, world, variant): seeds solved, median and per-seed time, steps and episodes to the threshold;
    against DQN (median time) and against the same agent in fixed views (median env steps).
    """
    lines = [
        "| task | world | agent | solved | median time to solved (s) | per seed: time (s) | median env steps | "
        "per seed: env steps | median episodes | goal | vs DQN (median time) | vs fixed views (median steps) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    worlds = [world for world in WORLDS if any(_world(r) == world for r in runs)]
    for task_name in tasks:
        task = TASKS[task_name]
        for world in worlds:
            mine = sorted((r for r in runs if r["task"] == task_name and _world(r) == world), key=lambda r: r["seed"])
            groups = {
                v: [r for r in mine if r["variant"] == v] for v in variants if any(r["variant"] == v for r in mine)
            }
            dqn = _median_of(groups["DQN"], "seconds") if "DQN" in groups else None
            for variant, group in groups.items():
                median = _median_of(group, "seconds")
                steps = _median_of(group, "steps")
                ratio = "" if dqn is None or not np.isfinite([dqn, median]).all() else f"{median / dqn:.2f}x"
                fixed = [r for r in runs if r["task"] == task_name and _world(r) == "fixed" and r["variant"] == variant]
                base = _median_of(fixed, "steps") if fixed and world != "fixed" else None
                versus = "" if base is None or not np.isfinite([base, steps]).all() else f"{steps / base:.2f}x"
                per_seed = ", ".join(f"{r['seed']}: {_seconds(r)}" for r in group)
                per_seed_steps = ", ".join(f"{r['steps']:,}" + ("" if r["solved"] else " (miss)") for r in group)
                hit = "hit" if median <= task.goal_seconds else "miss"
                lines.append(
                    f"| {task.description} | {world} | {variant} | {sum(r['solved'] for r in group)}/{len(group)} | "
                    f"{_median(median)} | {per_seed} | {_median(steps)} | {per_seed_steps} | "
                    f"{_median(_median_of(group, 'episodes'))} | <= {task.goal_seconds:.0f} s: {hit} | {ratio} | "
                    f"{versus} |"
                )
    return lines


def memory_against_critics_table(runs: list[dict[str, Any]], tasks: list[str]) -> list[str]:
    """
    One row per (task, world, memory twin) where both ran: env steps to solved, median (worst) and per seed, of the
    memory-wearing agent and of the critics alone; the ratio of the medians and the worst seed's ratio (a miss is
    infinitely slow), against :data:`MEMORY_WITHIN`.
    """
    lines = [
        "| task | world | seeds | memory: median (worst) env steps | per seed | critics alone: median (worst) | "
        f"per seed | ratio of medians | worst seed's ratio | within {MEMORY_WITHIN:g}x |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]

    def shown(value: float) -> str:
        return f"{value:,.0f}" if np.isfinite(value) else "miss"

    def ratio(value: float) -> str:
        if np.isnan(value):
            return "both missed"
        return {0.0: "0 (critics missed)", np.inf: "inf (memory missed)"}.get(float(value), f"{value:.2f}")

    for task_name in tasks:
        for world in WORLDS:
            mine = [r for r in runs if r["task"] == task_name and _world(r) == world]
            for memory, critics in MEMORY_TWINS:
                with_memory = {r["seed"]: r for r in mine if r["variant"] == memory}
                without = {r["seed"]: r for r in mine if r["variant"] == critics}
                seeds = sorted(with_memory.keys() & without.keys())
                if not seeds:
                    continue
                ours = np.array([_cost(with_memory[seed], "steps") for seed in seeds])
                theirs = np.array([_cost(without[seed], "steps") for seed in seeds])
                with np.errstate(invalid="ignore"):  # both missed: no ratio (nan), left out of the worst
                    ratios, median_ratio = ours / theirs, np.median(ours) / np.median(theirs)
                worst = np.nanmax(ratios) if not np.isnan(ratios).all() else np.nan
                # Never slower: the worst seed is judged beside the median (both missed on a seed: not slower)
                verdict = "missed" if not median_ratio <= MEMORY_WITHIN else "met"
                if verdict == "met" and worst > MEMORY_WITHIN:
                    verdict = "median only"
                lines.append(
                    f"| {TASKS[task_name].description} | {world} | {' '.join(map(str, seeds))} | "
                    f"{shown(np.median(ours))} ({shown(ours.max())}) | {', '.join(map(shown, ours))} | "
                    f"{shown(np.median(theirs))} ({shown(theirs.max())}) | {', '.join(map(shown, theirs))} | "
                    f"{ratio(median_ratio)} | {ratio(worst)} | {verdict} |"
                )
    return lines if len(lines) > 2 else []


def plot_curves(runs: list[dict[str, Any]], tasks: list[str], path: Path) -> None:
    """Success rate vs training seconds, one panel per task, one line per run (colour: agent)."""
    tasks = [t for t in tasks if any(r["task"] == t for r in runs)]
    if not tasks:
        return
    figure = Figure(figsize=(5.5 * len(tasks), 4), dpi=100, layout="constrained")
    axes = figure.subplots(1, len(tasks), squeeze=False)
    variants = sorted({r["variant"] for r in runs})
    colours = {variant: f"C{index}" for index, variant in enumerate(variants)}
    for axis, task_name in zip(axes[0], tasks, strict=True):
        labelled: set[str] = set()
        for run in (r for r in runs if r["task"] == task_name):
            curve = run["curve"]
            label = None if run["variant"] in labelled else run["variant"]
            labelled.add(run["variant"])
            axis.plot(
                [p["seconds"] for p in curve],
                [p["success"] for p in curve],
                color=colours[run["variant"]],
                label=label,
                alpha=0.8,
            )
        axis.axhline(SOLVED_SUCCESS, color="grey", linestyle=":", linewidth=1)
        axis.axvline(TASKS[task_name].goal_seconds, color="grey", linestyle="--", linewidth=1)
        axis.set_title(TASKS[task_name].description)
        axis.set_xlabel("training seconds (evaluation excluded)")
        axis.set_ylabel("greedy success from every (start, heading)")
        axis.set_ylim(0, 1.02)
        axis.legend(loc="lower right", fontsize=8)
    write_figure(path, figure_image(figure))


def _twins_section(table: list[str]) -> list[str]:
    if not table:
        return []
    return [
        "## The route memory against the critics alone (env steps to solved)",
        "",
        "The same entry with the memory on and with `route_memory: false`, per seed; a miss is infinitely slow (it "
        f"sets the worst and can set the median). Goal: the memory within {MEMORY_WITHIN:g}x the critics' steps, on "
        'the median and on the worst seed ("median only": the median is, a seed is not).',
        "",
        *table,
        "",
    ]


def _profile_section(path: Path) -> list[str]:
    if not path.exists():
        return []
    return [
        "",
        "## Where the time goes (CampusNav-v0, milliseconds per call, `--profile`)",
        "",
        "A gradient step includes its replay sample; a training env step is an env step and an action selection plus "
        "`gradient_steps / train_freq` gradient steps.",
        "",
        *profile_table(json.loads(path.read_text())),
    ]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", nargs="+", default=["campus", "multi"], choices=sorted(TASKS))
    parser.add_argument("--variants", nargs="+", default=list(DEFAULT_VARIANTS), choices=sorted(VARIANTS))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument(
        "--worlds",
        nargs="+",
        default=["fixed"],
        choices=[*WORLDS, "severity sweep"],
        help="fixed views, noise on them, K renders, or 'severity sweep': the harder world with one of its renders, "
        "hours, yaw and noise made easier or harder at a time",
    )
    parser.add_argument("--budget-seconds", type=float, help="training-time cap per run (default: the task's)")
    parser.add_argument("--max-steps", type=int, help="env-step cap per run (default: the task's)")
    parser.add_argument("--eval-freq", type=int, help="env steps between route evaluations (default: the task's)")
    parser.add_argument(
        "--profile", action="store_true", help="measure where the training time goes (CampusNav-v0, each --variants)"
    )
    parser.add_argument("--runs-file", type=Path, default=RESULTS_DIR / "learning_speed_runs.jsonl")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "learning_speed.md")
    args = parser.parse_args(argv)
    args.worlds = [name for world in args.worlds for name in (SEVERITY_SWEEP if world == "severity sweep" else [world])]
    th.set_num_threads(1)

    # Beside its runs file: learning_speed_runs.jsonl -> learning_speed_profile.json (another runs file, its own)
    profile_file = args.runs_file.with_name(args.runs_file.stem.removesuffix("_runs") + "_profile.json")
    if args.profile:
        profiles = {variant: profile_costs("campus", variant) for variant in args.variants}
        write_results(profile_file, json.dumps(profiles, indent=2))
        print("\n".join(profile_table(profiles)), flush=True)
    jobs = [
        (task, variant, seed, world)
        for task in args.tasks
        for world in args.worlds
        for seed in args.seeds
        for variant in args.variants
    ]

    def run_job(job: tuple[str, str, int, str]) -> dict[str, Any]:
        task, variant, seed, world = job
        return run_one(task, variant, seed, args.budget_seconds, args.max_steps, args.eval_freq, world_name=world)

    runs = run_missing(
        args.runs_file,
        jobs,
        run_job,
        key=lambda r: (r["task"], r["variant"], r["seed"], _world(r)),
        describe=lambda run: (
            f"{run['task']:<10} {_world(run):<12} {run['variant']:<22} seed {run['seed']}: {_seconds(run)} s, "
            f"{run['steps']} steps, "
            f"{run['episodes']} episodes (wall {run['wall_seconds']:.0f} s)"
        ),
    ).records
    all_tasks = [t for t in TASKS if any(r["task"] == t for r in runs)]
    all_variants = [v for v in VARIANTS if any(r["variant"] == v for r in runs)]
    picture = args.out.with_suffix(".png")
    plot_curves(runs, all_tasks, picture)
    lines = [
        "# Learning speed: training time to a solved map",
        "",
        "Solved: the greedy policy from every (start, heading) pair to every goal reaches it with success >= "
        f"{SOLVED_SUCCESS} and SPL >= {SOLVED_SPL}, evaluated every few thousand env steps inside one `learn()` call "
        "(resolution: one evaluation interval). Time: training wall time to that evaluation, evaluation excluded. "
        "A miss counts as infinitely slow in the median. Features: EfficientNet-Lite0 (1280-d), projected to 64 per "
        "view (shipped `env_kwargs`), except the paper-settings variant (full 1280-d).",
        "",
        machine_line("one run at a time, no GPU (the timings are noisy)"),
        "",
        *summary_table(runs, all_tasks, all_variants),
        "",
        *_twins_section(memory_against_critics_table(runs, all_tasks)),
        f"![success vs training time]({picture.name})",
        *_profile_section(profile_file),
    ]
    publish(args.out, lines, "learning_speed.py", argv)


if __name__ == "__main__":
    main()
