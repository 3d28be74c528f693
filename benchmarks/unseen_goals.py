"""Any goal: a goal-conditioned DCQN with hindsight relabelling, on goals it trained on and goals it never saw.

The agent trains on ``CampusNavGoal-v0`` (every intersection can be the goal, given as its four views) with SB3's
``HerReplayBuffer`` (served by DCQN's ``DCQNHerReplayBuffer``: relabelled transitions that reach their goal are
terminal), from the shipped ``CampusNavGoal-v0`` entry of ``hyperparams/dcqn.yml``. Protocols (``--protocols``):

- ``all``: every intersection is a training goal. Measured: the time until the greedy policy from every (start,
  heading) reaches every intersection (success >= 0.99, SPL >= 0.97), and until each of the paper's four goals is at
  the solved bar (0.99 / 0.98) on its own.
- ``lenient``: a seeded 20% of the intersections (the run's seed) are never an episode's goal; relabelling may still
  use them (the agent is told, in hindsight, that it reached them). Measured: the time until the held-out goals are
  at 0.99 / 0.98.
- ``strict``: the held-out goals are never episode goals and never relabelling targets (the agent may drive through
  them; it is never told that one is a goal; tested in ``tests/test_her_buffer.py``). Measured: success and SPL on the
  held-out goals after the training budget, the best evaluation, and the per-goal spread.

Every evaluation runs the greedy policy from every (start, heading) to every goal of its set (held-out goals, or all
intersections), logged to TensorBoard as ``eval/unseen_goals/*`` (``eval/all_goals/*`` for ``all``) and, for 20
training goals drawn with the run's seed, ``eval/train_goals/*``. Training seconds exclude evaluations.

Levers (``--levers``, for the ablation table; each one option of the product): ``shipped`` (the entry as it is: its
route memory on); ``critics_alone`` (the route memory off: the critics' own figures); ``sb3_dones`` (SB3's dones on
relabelled transitions: what the terminal fix buys); ``relabel8`` (8 relabelled goals per transition instead of 4);
``goal_dropout`` (each goal view hidden with probability 0.25 in training: partial goal pictures);
``revision_blocked`` (experience revision, with the goal left out of the match, and the blocked-action target: for
re-adaptation); ``goal_photos`` (training goals pictured at noon, 7:00, 16:00 and 20:30, one condition per episode);
``night_goals`` (every goal pictured at 19:30 with passing cars, the agent's views at noon, in training too: held-out
goals are found only where the memory recognises their pictures, never through ``achieved_goal``).

With ``--after`` (both, or ``--after appearance`` / ``--after readapt``) the runs go on, once trained:
**appearance change** (the trained policy evaluated on the protocol's goals -- every intersection, or the held-out
ones -- with the goals pictured at 8:30, 17:30, 19:30 (night), with passing cars, at night with cars, and at 22:30
with cars; none a training condition; the agent's own views unchanged) and, for the ``all`` runs, **re-adaptation
for every goal** (the busiest road of the routes to a sample of goals -- the paper's
four plus 10 drawn with the seed -- is closed; episodes of training until every goal of the sample is back at success
0.99 / SPL 0.95, counted from the closure whatever the sample's scores were before it).

Runs are appended to a JSON-lines file (``--runs-file``) as they finish, and a rerun skips those done (same protocol,
lever, seed, budget); the tables are rebuilt from the file. Usage::

    python benchmarks/unseen_goals.py                                   # small: seed 0, 60 s per run
    python benchmarks/unseen_goals.py --seeds 0 1 2 --budget 150 --after
    python benchmarks/unseen_goals.py --protocols strict --levers shipped relabel8 goal_dropout --seeds 0 1 2
"""

from __future__ import annotations

import argparse
import copy
import statistics
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

from benchmarks.campusnav_runs import APPEARANCES, HELD_OUT_FRACTION, TRAINING_PHOTOS, VARIANTS, Task, quick_env_kwargs
from benchmarks.report import RESULTS_DIR, machine_line, markdown_table, measured_on, publish, run_missing
from benchmarks.workers import workers_argument
from campusnav_env.callbacks import RouteEvaluationCallback
from campusnav_env.closures import ClosureEvent
from campusnav_env.features.view_build import ViewBuild
from campusnav_env.goal_env import CampusNavGoalEnv, held_out_split
from campusnav_env.maps.campus import GOALS
from campusnav_env.recovery import RouteEvaluation
from campusnav_env.rendering.street_view import RenderSettings
from campusnav_env.route_evaluation import RouteReport, evaluate_routes
from sb3_dcqn.campusnav.experiments import ClosurePlan, TrainingBudget, train_with_closures
from sb3_dcqn.campusnav.settings import campus_of
from sb3_dcqn.campusnav.solved import SOLVED_SPL, SOLVED_SUCCESS
from sb3_dcqn.replay import RevisionHerReplayBuffer

ALL_GOALS_SPL = 0.97  # the bar for every intersection as the goal (success SOLVED_SUCCESS)
STRICT_SUCCESS, STRICT_SPL = 0.95, 0.90  # the bar for goals never trained on (strict)
RECOVERED_SUCCESS, RECOVERED_SPL = 0.99, 0.95
TRAIN_GOAL_SAMPLE = 20
CLOSURE_SAMPLE = 10  # random goals next to the paper's four in the re-adaptation sample
EVAL_FREQ = 3_000
READAPT_STEPS = 30_000  # training after the closure at most
# How the published runs ran (the results file keeps the line of the machine that measured them)
RUNS_LINE = "two or three runs at once, each in its own process (so 120 s of training bought 15k-29k env steps)"

PROTOCOLS = ("all", "lenient", "strict")
AFTER = ("appearance", "readapt")  # what --after runs once an agent is trained (readapt: 'all' agents)
# Each lever is one option of the product: (what it is, changes to the algorithm's keyword arguments, env arguments)
LEVERS: dict[str, tuple[str, dict[str, Any], dict[str, Any]]] = {
    "shipped": ("as shipped", {}, {}),
    "sb3_dones": ("SB3's dones on relabelled transitions", {"replay_buffer_kwargs": {"terminal_relabels": False}}, {}),
    "relabel8": ("8 relabelled goals per transition", {"replay_buffer_kwargs": {"n_sampled_goal": 8}}, {}),
    "goal_dropout": (
        "goal views hidden at random (p 0.25)",
        {"policy_kwargs": {"features_extractor_kwargs": {"goal_view_dropout": 0.25}}},
        {},
    ),
    "revision_blocked": (
        "experience revision + blocked-action target",
        {"replay_buffer_class": RevisionHerReplayBuffer, "blocked_action_target": True},
        {},
    ),
    "goal_photos": (
        "goals pictured at noon, 7:00, 16:00 and 20:30 (one per episode)",
        {},
        {"goal_render_settings": TRAINING_PHOTOS},
    ),
    "route_memory": (
        "route memory + exploration toward the untried",
        {"route_memory": True},
        {},
    ),
    # The shipped entry turns the route memory on: the critics' own figures need it turned off
    "critics_alone": (
        "critics alone (route memory off)",
        {"route_memory": False},
        {},
    ),
    # Every goal (held-out ones too) pictured at night with passing cars, the agent's own views at noon: the memory
    # routes to a photo only where its recogniser knows the place, the critics act elsewhere
    "night_goals": (
        "goals pictured at 19:30 with passing cars",
        {},
        {"goal_render_settings": (APPEARANCES["night + cars"],)},
    ),
}


@dataclass(frozen=True)
class Job:
    protocol: str
    lever: str
    seed: int
    budget: float
    after: tuple[str, ...]
    quick: bool
    split_seed: int | None = None  # seed of the held-out draw (None: the run's seed)

    @property
    def split(self) -> int:
        return self.seed if self.split_seed is None else self.split_seed


def goal_task(budget: float, quick: bool) -> Task:
    return Task(
        "goal",
        "CampusNavGoal-v0 (101 intersections, any goal)",
        "CampusNavGoal-v0",
        "CampusNavGoal-v0",
        max_steps=1_000_000,
        budget_seconds=budget,
        eval_freq=EVAL_FREQ,
        env_kwargs=quick_env_kwargs() if quick else {},
    )


def split_for(protocol: str, seed: int) -> tuple[list[int], list[int]]:
    """Training and held-out goals of a run (every intersection a training goal for ``all``)."""
    training, held_out = held_out_split(101, HELD_OUT_FRACTION, seed)
    return (training + held_out, []) if protocol == "all" else (training, held_out)


def merge(base: dict[str, Any], changes: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``changes`` merged in, dictionaries key by key."""
    merged = copy.deepcopy(base)
    for key, value in changes.items():
        merged[key] = merge(merged.get(key) or {}, value) if isinstance(value, dict) else value
    return merged


def run_one(job: Job) -> dict[str, Any]:
    """Train one agent under one protocol and lever and return the run's record."""
    th.set_num_threads(1)
    task = goal_task(job.budget, job.quick)
    entry = VARIANTS["DCQN"].entry(task)
    training, held_out = split_for(job.protocol, job.split)
    _, algo_changes, env_changes = LEVERS[job.lever]
    if "goal_render_settings" in env_changes:
        env_changes = {"goal_render_settings": [_sized(c, task) for c in env_changes["goal_render_settings"]]}
    env_kwargs: dict[str, Any] = {"goals": training, **env_changes}
    if job.protocol == "strict":
        env_kwargs["held_out_goals"] = held_out  # never relabelling targets either
    env = task.make_env(entry, **env_kwargs)
    hyperparams = merge(entry.hyperparams, algo_changes)
    model = VARIANTS["DCQN"].make_model(env, replace(entry, hyperparams=hyperparams), job.seed)
    goal_env = campus_of(env)
    assert isinstance(goal_env, CampusNavGoalEnv)

    rng = np.random.default_rng(job.seed)
    train_sample = sorted(rng.choice(training, size=min(TRAIN_GOAL_SAMPLE, len(training)), replace=False).tolist())
    if job.protocol == "all":
        main_goals, log_name = list(range(101)), "all_goals"
        others = {"paper_goals": list(GOALS)}
        success, spl = SOLVED_SUCCESS, ALL_GOALS_SPL
    else:
        main_goals, log_name = held_out, "unseen_goals"
        others = {"train_goals": train_sample}
        success, spl = (SOLVED_SUCCESS, SOLVED_SPL) if job.protocol == "lenient" else (STRICT_SUCCESS, STRICT_SPL)
    evaluation = RouteEvaluationCallback(
        eval_freq=EVAL_FREQ,
        goals=main_goals,
        log_name=log_name,
        other_goals=others,
        success_threshold=success,
        spl_threshold=spl,
        stop_when_solved=job.protocol != "strict",  # strict runs spend their budget: the figure is the end state
    )
    start = time.perf_counter()
    model.learn(task.max_steps, callback=[evaluation, TrainingBudget(evaluation, job.budget)])
    record: dict[str, Any] = {
        "protocol": job.protocol,
        "lever": job.lever,
        "seed": job.seed,
        "split_seed": job.split,
        "quick": job.quick,
        "budget": job.budget,
        "held_out": held_out,
        "steps": int(model.num_timesteps),
        "train_seconds": evaluation.train_seconds,
        "wall_seconds": time.perf_counter() - start,
        "curve": [_point(e) for e in evaluation.evaluations],
        "solved_seconds": _first_seconds(evaluation.evaluations, success, spl),
        "final_per_goal": _per_goal(evaluation.evaluations[-1].report),
    }
    if "appearance" in job.after:  # the goals of the protocol (every intersection, or the held-out ones)
        record["appearance"] = appearance_change(model, task, entry, main_goals)
    if job.protocol == "all":
        record["paper_goals_seconds"] = _first_seconds(
            evaluation.evaluations, SOLVED_SUCCESS, SOLVED_SPL, "paper_goals"
        )
        if "readapt" in job.after:
            record["readapt"] = readapt_every_goal(model, job, rng)
    return record


def _point(evaluation: RouteEvaluation) -> dict[str, float]:
    point = {
        "step": evaluation.step,
        "seconds": round(evaluation.train_seconds, 2),
        "success": evaluation.success_rate,
        "spl": evaluation.spl,
    }
    for name, report in evaluation.others.items():
        point[f"{name}_success"], point[f"{name}_spl"] = report.success_rate, report.spl
    if evaluation.critics is not None:  # the model planned over its route memory: its critics alone, beside
        point["critics_success"], point["critics_spl"] = evaluation.critics.success_rate, evaluation.critics.spl
    return point


def _first_seconds(
    evaluations: list[RouteEvaluation], success: float, spl: float, other: str | None = None
) -> float | None:
    """Training seconds at the first evaluation at the bar (for ``other``: every goal of that set on its own)."""
    for evaluation in evaluations:
        report = evaluation.report if other is None else evaluation.others[other]
        if report.meets(success, spl, every_goal=other is not None):
            return evaluation.train_seconds
    return None


def _per_goal(report: RouteReport) -> dict[str, list[float]]:
    return {goal: [routes.success_rate, routes.spl] for goal, routes in sorted(report.by_goal().items())}


def appearance_change(model: Any, task: Task, entry: Any, goals: list[int]) -> dict[str, list[float]]:
    """
    Success, SPL and the worst goal's success to ``goals`` with the goals pictured otherwise (the agent's views as
    in training).
    """
    results = {}
    for name, settings in APPEARANCES.items():
        eval_env = campus_of(task.make_env(entry, goal_render_settings=_sized(settings, task)))
        report = evaluate_routes(eval_env, model, goals=goals)
        worst = min(routes.success_rate for routes in report.by_goal().values())
        results[name] = [report.success_rate, report.spl, worst]
        print(
            f"appearance {name}: success {report.success_rate:.3f}, SPL {report.spl:.3f}, worst goal {worst:.3f}",
            flush=True,
        )
    return results


def _sized(settings: RenderSettings | None, task: Task) -> RenderSettings | None:
    """Goal photo conditions at the agent's image size (the smoke run's views are small)."""
    views = ViewBuild.of(task.env_kwargs.get("view_build")).render_settings or RenderSettings()
    return None if settings is None else replace(settings, width=views.width, height=views.height)


def readapt_every_goal(model: Any, job: Job, rng: np.random.Generator) -> dict[str, Any]:
    """Close the busiest road of the sample's routes; episodes until every goal of the sample is recovered."""
    env = campus_of(model.get_env().envs[0])
    others = [name for name in env.goal_names if name not in GOALS]
    sample = list(GOALS) + sorted(rng.choice(others, size=CLOSURE_SAMPLE, replace=False).tolist())
    outcome = train_with_closures(
        model,
        ClosurePlan(later=[ClosureEvent(at=0, close_on_route="busiest")]),
        budget=0,
        recovery_budget=READAPT_STEPS if not job.quick else 1_000,
        eval_freq=EVAL_FREQ,
        eval_goals=sample,
        every_goal=True,
        progress=False,
    )
    recovery = outcome.recoveries[0] if outcome.recoveries else None
    closed = [list(road) for record in outcome.closures.records for road in record.closed]
    return {
        "sample": sample,
        "closed": closed,
        "recovered": bool(recovery and recovery.recovered),
        "episodes": None if recovery is None or not recovery.recovered else recovery.episodes,
        "seconds": None if recovery is None or not recovery.recovered else recovery.seconds,
    }


# ------------------------------------------------------------------------------------------------ tables
def _fmt(value: float | None, digits: int = 0) -> str:
    return "miss" if value is None else f"{value:.{digits}f}"


def _median_worst(values: list[float | None], digits: int = 0, worst_is_max: bool = True) -> str:
    """``median (worst) [each run's]`` of values where ``None`` is a miss (infinitely bad)."""
    if not values:
        return "-"
    bad = float("inf") if worst_is_max else float("-inf")
    numbers = [bad if v is None else float(v) for v in values]
    median = statistics.median(numbers)
    worst = max(numbers) if worst_is_max else min(numbers)

    def show(x: float) -> str:
        return "miss" if not np.isfinite(x) else f"{x:.{digits}f}"

    each = ", ".join(show(x) for x in numbers)
    return f"{show(median)} ({show(worst)})" + (f" [{each}]" if 1 < len(numbers) <= 5 else "")


def goals_table(runs: list[dict[str, Any]]) -> list[str]:
    """The issue's goals table: the ``shipped`` runs, and appearance and re-adaptation rows of every lever."""
    shipped = [r for r in runs if r["lever"] == "shipped"]
    by = {p: [r for r in shipped if r["protocol"] == p] for p in PROTOCOLS}
    rows = []
    strict = by["strict"]
    if strict:
        finals = [r["curve"][-1] for r in strict]
        rows.append(
            [
                "held-out goals (20%, strict), success / SPL from every (start, heading) after the budget",
                _median_worst([f["success"] for f in finals], 3, False)
                + " / "
                + _median_worst([f["spl"] for f in finals], 3, False),
                ">= 0.95 / >= 0.90",
                _seeds(strict),
                memory_text(strict),
            ]
        )
    if by["lenient"]:
        rows.append(
            [
                "held-out goals, lenient: training seconds to success / SPL >= 0.99 / 0.98",
                _median_worst([r["solved_seconds"] for r in by["lenient"]]),
                "<= 60 s",
                _seeds(by["lenient"]),
                memory_text(by["lenient"]),
            ]
        )
    if by["all"]:
        rows.append(
            [
                f"every intersection as goal: training seconds to success / SPL >= {SOLVED_SUCCESS} / {ALL_GOALS_SPL}",
                _median_worst([r["solved_seconds"] for r in by["all"]]),
                "<= 120 s",
                _seeds(by["all"]),
                memory_text(by["all"]),
            ]
        )
        rows.append(
            [
                "the paper's four goals, each at 0.99 / 0.98 (agent trained on all goals): training seconds",
                _median_worst([r.get("paper_goals_seconds") for r in by["all"]]),
                "<= 30 s",
                _seeds(by["all"]),
                memory_text(by["all"]),
            ]
        )
    for lever, (description, _, _) in LEVERS.items():
        group = [r for r in runs if r["protocol"] == "all" and r["lever"] == lever]
        for protocol, goals in (("all", "every intersection"), ("strict", "held-out goals (strict)")):
            seen = [r for r in runs if r["protocol"] == protocol and r["lever"] == lever and "appearance" in r]
            for name in APPEARANCES:
                scored = [r["appearance"][name] for r in seen if name in r["appearance"]]
                if scored:
                    measure = f"{goals} pictured otherwise, {name} ({description})"
                    values = _median_worst([v[0] for v in scored], 3, False)
                    rows.append([f"{measure}: success", values, ">= 0.95", _seeds(seen), memory_text(seen)])
                worst = [v[2] for v in scored if len(v) > 2]  # older records kept no per-goal score
                if worst:
                    values = _median_worst(worst, 3, False)
                    rows.append([f"{measure}: worst goal's success", values, ">= 0.5", _seeds(seen), memory_text(seen)])
        readapted = [r for r in group if "readapt" in r]
        if readapted:
            rows.append([
                f"one closure, every goal of the sample (4 paper + 10 random) back at 0.99 / 0.95 ({description}): "
                "episodes", _median_worst([r["readapt"]["episodes"] for r in readapted]), "<= 50", _seeds(readapted),
                memory_text(readapted),
            ])  # fmt: skip
    return markdown_table(["measure", "median (worst)", "goal", "seeds", "route memory"], rows)


def ablation_table(runs: list[dict[str, Any]]) -> list[str]:
    """Every lever under every protocol it ran with: the protocol's figure, median (worst)."""
    rows = []
    for protocol in PROTOCOLS:
        for lever, (description, _, _) in LEVERS.items():
            group = [r for r in runs if r["protocol"] == protocol and r["lever"] == lever]
            if not group:
                continue
            finals = [r["curve"][-1] for r in group]
            train = [f.get("train_goals_success", f.get("paper_goals_success")) for f in finals]
            per_goal = [min(v[0] for v in r["final_per_goal"].values()) for r in group]
            rows.append([
                protocol, description, _seeds(group),
                _median_worst([r["solved_seconds"] for r in group]),
                _median_worst([f["success"] for f in finals], 3, False),
                _median_worst([f["spl"] for f in finals], 3, False),
                _median_worst(per_goal, 2, False),
                _median_worst(train, 3, False),
                _median_worst([r["train_seconds"] for r in group]),
                memory_text(group),
            ])  # fmt: skip
    header = [
        "protocol",
        "lever",
        "seeds",
        "s to the protocol's bar",
        "final success",
        "final SPL",
        "worst goal's success",
        "train/paper goals success",
        "train s",
        "route memory",
    ]
    return markdown_table(header, rows)


def memory_text(runs: list[dict[str, Any]]) -> str:
    """
    Whether the runs' agents planned over a route memory: its evaluations then score the critics alone beside
    (``critics_success`` in the curve), which is how a stored run tells, whatever the entry said when it ran.
    """
    used = {any("critics_success" in point for point in run["curve"]) for run in runs}
    return "on" if used == {True} else "off" if used == {False} else "on in some runs"


def _seeds(runs: list[dict[str, Any]]) -> str:
    """The runs' seeds, and their splits' seeds where a split was drawn apart from the run's seed."""
    seeds = " ".join(str(s) for s in sorted({r["seed"] for r in runs}))
    splits = sorted({_split(r) for r in runs})
    return seeds if all(_split(r) == r["seed"] for r in runs) else f"{seeds} x splits {' '.join(map(str, splits))}"


def _split(record: dict[str, Any]) -> int:
    return record.get("split_seed", record["seed"])  # older records drew the split with the run's seed


def write_report(runs: list[dict[str, Any]], out: Path, argv: list[str] | None) -> None:
    machine = measured_on(out, machine_line(RUNS_LINE))
    lines = [
        "# Any goal: goals trained on and goals never trained on (CampusNavGoal-v0, HER)",
        "",
        "DCQN from the shipped `CampusNavGoal-v0` entry (SB3's `HerReplayBuffer`, future strategy, 4 relabelled goals "
        "per transition, served by `DCQNHerReplayBuffer`: relabelled transitions that reach their goal are terminal). "
        "Held-out goals: 20 of the 101 intersections, drawn with the run's seed or, where the seeds column names "
        "splits, with a split seed of its own (`--split-seeds`: every run seed with every split). Evaluation: the "
        "greedy policy from every (start, heading) to every goal of the set; training seconds exclude evaluations. "
        "`all`: every "
        "intersection a training goal; `lenient`: held-out goals never an episode's goal, relabelling may use them; "
        "`strict`: never an episode's goal, never a relabelling target. Median (worst) over the seeds; a miss counts "
        "as infinitely slow.",
        "",
        machine,
        "",
        "## Goals",
        "",
        *goals_table(runs),
        "",
        "## Levers (ablation)",
        "",
        "Route memory: *on* where the agents planned their greedy actions over the route memory (the shipped entry "
        "turns it on, so every lever but `critics_alone` has it unless the runs predate that), *off* where the figures "
        "are the critics' alone (`--levers critics_alone`).",
        "",
        *ablation_table(runs),
    ]
    publish(out, lines, "unseen_goals.py", argv)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--protocols", nargs="+", default=list(PROTOCOLS), choices=PROTOCOLS)
    parser.add_argument("--levers", nargs="+", default=["shipped"], choices=sorted(LEVERS))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0])
    parser.add_argument(
        "--split-seeds",
        nargs="+",
        type=int,
        help="seeds of the held-out draw, each run with every run seed (default: the run's own seed)",
    )
    parser.add_argument(
        "--budget", type=float, help="training seconds per run, evaluations excluded (default 60; 5 with --quick)"
    )
    parser.add_argument(
        "--after",
        nargs="*",
        choices=AFTER,
        help="after the runs: appearance change (any protocol) and re-adaptation ('all'; both when given alone)",
    )
    parser.add_argument("--quick", action="store_true", help="smoke run: 64x48 pixel features (no CNN)")
    parser.add_argument("--runs-file", type=Path, default=RESULTS_DIR / "unseen_goals_runs.jsonl")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "unseen_goals.md")
    workers_argument(parser)
    args = parser.parse_args(argv)
    th.set_num_threads(1)
    budget = args.budget if args.budget is not None else (5.0 if args.quick else 60.0)
    after = () if args.after is None else tuple(args.after or AFTER)
    jobs = [
        Job(protocol, lever, seed, budget, after, args.quick, split_seed)
        for protocol in args.protocols
        for lever in args.levers
        for seed in args.seeds
        for split_seed in args.split_seeds or [None]
    ]

    def describe(record: dict[str, Any]) -> str:
        final = record["curve"][-1]
        return (
            f"{record['protocol']:<8} {record['lever']:<13} seed {record['seed']} split {_split(record)}: "
            f"{record['steps']} steps, "
            f"{record['train_seconds']:.0f} s, success {final['success']:.3f}, SPL {final['spl']:.3f}, "
            f"solved at {_fmt(record['solved_seconds'])} s"
        )

    runs = run_missing(
        args.runs_file,
        jobs,
        run_one,
        key=lambda r: (r["protocol"], r["lever"], r["seed"], _split(r), r["budget"], r["quick"]),
        job_key=lambda job: (job.protocol, job.lever, job.seed, job.split, job.budget, job.quick),
        workers=args.workers,
        describe=describe,
    )
    write_report(runs.records, args.out, argv)


if __name__ == "__main__":
    main()
