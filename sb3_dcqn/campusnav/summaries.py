"""What a run reports: score tables of route evaluations, the route table of a run with closures, the Markdown and
JSON summaries."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from campusnav_env import CampusNavEnv, RouteReport
from campusnav_env.recovery import DEFAULT_SPL_THRESHOLD, DEFAULT_SUCCESS_THRESHOLD, RouteEvaluation, recovery_table
from sb3_dcqn.campusnav.experiments import TrainingOutcome
from sb3_dcqn.campusnav.solved import is_solved, solved_bar

__all__ = [
    "SCORES_LEGEND",
    "evaluation_json",
    "final_json",
    "finite",
    "goal_groups",
    "outcome_json",
    "phases",
    "route_table",
    "routes_to",
    "run_report",
    "score_table",
    "solved_text",
]


# What the score columns mean, printed under every score table (evaluate's, summary.md's)
SCORES_LEGEND = (
    "success rate: share of the routes from every (start, heading) that reach the goal; SPL: success weighted by "
    "shortest path length / max(path length, shortest); coverage: share of starts whose routes succeed at every "
    "heading; optimality gap: mean extra steps over the shortest path of the routes that reach the goal ('-' where "
    "none does: 0.00 beside a low success rate means the few that arrive take the shortest way)"
)


def cell(value: float, digits: int = 3) -> str:
    return "-" if math.isnan(value) else f"{value:.{digits}f}"


def score_cells(report: RouteReport) -> str:
    s = report.summary()
    return (
        f"{cell(s['success_rate'])} | {cell(s['spl'])} | {cell(s['coverage'])} | {cell(s['mean_steps'], 2)} | "
        f"{cell(s['mean_shortest'], 2)} | {cell(s['optimality_gap'], 2)} | {int(s['n_routes'])}"
    )


def score_table(
    report: RouteReport, goals: Sequence[str] | None = None, groups: Mapping[str, Sequence[str]] | None = None
) -> str:
    """
    Markdown table of a route report: all goals, then each group of goals, then each goal.

    :param report: The route evaluation
    :param goals: The goals with a row of their own (default: every goal of the report, sorted)
    :param groups: Name -> goals, a row each (e.g. :func:`goal_groups`: training and held-out goals)
    """
    lines = [
        "| goal | success rate | SPL | coverage | mean steps | mean shortest | optimality gap | routes |",
        "|---|---|---|---|---|---|---|---|",
    ]
    lines.append(f"| all | {score_cells(report)} |")
    for name, members in (groups or {}).items():
        lines.append(f"| {name} | {score_cells(routes_to(report, members))} |")
    by_goal = report.by_goal()
    for goal in sorted(by_goal) if goals is None else goals:
        lines.append(f"| {goal} | {score_cells(by_goal.get(goal, RouteReport()))} |")
    return "\n".join(lines)


def routes_to(report: RouteReport, goals: Sequence[str]) -> RouteReport:
    """The routes of a report to some goals (a group of :func:`goal_groups`)."""
    chosen = set(goals)
    return RouteReport([route for route in report.routes if route.goal in chosen])


def goal_groups(nav: CampusNavEnv) -> dict[str, list[str]]:
    """
    The goals of a goal env that trains on some of its goals only (``CampusNavGoal-v0`` with ``goals`` or
    ``held_out_goals``), by kind: ``{"training goals (N)": [...], "held-out goals (M)": [...], "other goals (K)":
    [...]}`` (never drawn, not held out), the empty kinds left out; ``{}`` for other envs and when every goal trains.
    """
    from campusnav_env.goal_env import CampusNavGoalEnv, goal_names

    if not isinstance(nav, CampusNavGoalEnv) or len(nav.training_goals) == len(nav.goal_nodes):
        return {}
    kinds = {"training goals": set(nav.training_goals), "held-out goals": set(nav.held_out_goals)}
    kinds["other goals"] = set(nav.goal_nodes) - kinds["training goals"] - kinds["held-out goals"]
    return {f"{kind} ({len(nodes)})": goal_names(nav, sorted(nodes)) for kind, nodes in kinds.items() if nodes}


def phases(outcome: TrainingOutcome) -> list[tuple[str, RouteEvaluation]]:
    """
    The evaluations worth a row: before the closures, then right after each and at its recovery (or end), and the
    last one (of the model saved) where it is none of those (training went on after the recovery).
    """
    rows: list[tuple[str, RouteEvaluation]] = []
    before = outcome.before_closures()
    if before is not None:
        rows.append(("trained", before))
    for number, recovery in enumerate(outcome.recoveries, start=1):
        roads = ", ".join(f"{u}-{v}" for u, v in recovery.closure.closed) or "reopened " + ", ".join(
            f"{u}-{v}" for u, v in recovery.closure.reopened
        )
        if recovery.right_after is not None:
            rows.append((f"closure {number} ({roads}): right after", recovery.right_after))
        if recovery.recovered_at is not None:
            rows.append((f"closure {number}: recovered", recovery.recovered_at))
        elif recovery.last is not None and recovery.last is not recovery.right_after:
            rows.append((f"closure {number}: not recovered, at the end", recovery.last))
    evaluations = outcome.evaluation.evaluations
    if evaluations and (not rows or rows[-1][1] is not evaluations[-1]):
        rows.append(("at the end (the model saved)", evaluations[-1]))
    return rows


def route_table(outcome: TrainingOutcome) -> str:
    """Markdown table: the greedy routes' scores before the closures, right after each and once recovered."""
    lines = [
        "| phase | env step | episode | success rate | SPL | coverage | mean steps | mean shortest | optimality gap | "
        "routes |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, evaluation in phases(outcome):
        lines.append(f"| {name} | {evaluation.step} | {evaluation.episode} | {score_cells(evaluation.report)} |")
    return "\n".join(lines)


def finite(value: float) -> float | None:
    return None if math.isinf(value) or math.isnan(value) else value


def evaluation_json(evaluation: RouteEvaluation | None) -> dict[str, Any] | None:
    if evaluation is None:
        return None
    summary = {key: finite(value) for key, value in evaluation.report.summary().items()}
    return {
        "step": evaluation.step,
        "episode": evaluation.episode,
        "train_seconds": evaluation.train_seconds,
        **summary,
    }


def final_json(evaluation: RouteEvaluation) -> dict[str, Any]:
    """``summary.json``'s ``final``: the scores of the model saved beside it (what ``evaluate`` says of it)."""
    return {"step": evaluation.step, "success_rate": evaluation.success_rate, "spl": evaluation.spl}


def outcome_json(outcome: TrainingOutcome) -> dict[str, Any]:
    return {
        "steps": outcome.steps,
        "seconds": outcome.seconds,
        "episodes": len(outcome.progress.episode_rewards),
        "solved_at": evaluation_json(outcome.solved_at()),
        "trained": evaluation_json(outcome.before_closures()),
        "closures": [
            {
                "description": r.closure.description,
                "closed": [list(road) for road in r.closure.closed],
                "reopened": [list(road) for road in r.closure.reopened],
                "refused": [list(pair) for pair in r.closure.refused],
                "routes_affected": r.closure.routes_affected,
                "recovered": r.recovered,
                "recovery_episodes": finite(r.episodes),
                "recovery_steps": finite(r.steps),
                "recovery_seconds": finite(r.seconds),
                "right_after": evaluation_json(r.right_after),
                "recovered_at": evaluation_json(r.recovered_at),
                "last": evaluation_json(r.last),
            }
            for r in outcome.recoveries
        ],
        "refused": [list(pair) for record in outcome.closures.records for pair in record.refused],
        "unfired": [event.describe() for event in outcome.unfired],
    }


def solved_text(outcome: TrainingOutcome, from_model: bool = False) -> str:
    """
    How the routes stood before the first closure, in words.

    :param from_model: The run started from a trained model (``readapt``): report its routes before the first
        closure instead of when training solved the map
    """
    bar = solved_bar()
    before = outcome.before_closures()
    if from_model:
        if before is None:
            return "the model was not evaluated before the closures"
        verdict = "solved" if is_solved(before) else f"not solved ({bar})"
        return (
            f"the model before the first closure (step {before.step}): success {before.success_rate:.3f}, SPL "
            f"{before.spl:.3f}, {verdict}"
        )
    solved = outcome.solved_at()
    if solved is not None:
        return (
            f"solved ({bar}) at step {solved.step}, episode {solved.episode}, after {solved.train_seconds:.1f} s of "
            "training"
        )
    return "not solved before the first closure" if outcome.recoveries else "not solved"


def run_report(title: str, description: str, outcome: TrainingOutcome, files: dict[str, str], from_model: bool) -> str:
    """
    The Markdown summary of a training run (``summary.md``): what ran, the route table, the recovery table, refused
    and unfired closures, and the files written.

    :param title: The heading
    :param description: The env, e.g. ``EnvSettings.describe()``
    :param outcome: The run
    :param files: Name -> path of every file written
    :param from_model: The run started from a trained model (see :func:`solved_text`)
    """
    lines = [
        f"# {title}",
        "",
        f"{description}; {outcome.steps} env steps, {len(outcome.progress.episode_rewards)} episodes, "
        f"{outcome.seconds:.0f} s in all; {solved_text(outcome, from_model)}.",
        "",
        "Routes of the greedy policy from every (start, heading):",
        "",
        route_table(outcome),
        "",
        f"({SCORES_LEGEND}.)",
    ]
    if outcome.closures.records:
        lines += [
            "",
            f"Recovery (success >= {DEFAULT_SUCCESS_THRESHOLD}, SPL >= {DEFAULT_SPL_THRESHOLD}; seconds of training, "
            "evaluations excluded):",
            "",
            recovery_table(outcome.recoveries),
        ]
    refused = [f"{what}: {why}" for record in outcome.closures.records for what, why in record.refused]
    if refused:
        lines += ["", "Refused: " + "; ".join(refused)]
    if outcome.unfired:
        lines += ["", "Not reached within the budget: " + "; ".join(e.describe() for e in outcome.unfired)]
    lines += ["", "Files:", "", *(f"- {name}: {path}" for name, path in files.items())]
    return "\n".join(lines) + "\n"
