"""The CampusNav experiments: train until the map is solved, and train -> close roads -> recover.

:func:`train_until_solved` trains one agent inside one ``learn()`` call, evaluating the greedy routes from every
(start, heading) every ``eval_freq`` steps, and stops at the first evaluation at the solved bar
(:mod:`sb3_dcqn.campusnav.solved`) or when the training-time budget is spent (evaluation time excluded).
:func:`train_with_closures` is the loop of the command line and of the closure benchmarks: train (until solved), close
roads (at fixed steps, or one at a time), train on until recovered, and return everything the callbacks recorded.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field, replace
from typing import Any

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CallbackList

from campusnav_env.callbacks import RoadClosureCallback, RouteEvaluationCallback
from campusnav_env.closures import ClosureEvent, ClosureSchedule
from campusnav_env.recovery import DEFAULT_SPL_THRESHOLD, DEFAULT_SUCCESS_THRESHOLD, Recovery, RouteEvaluation
from sb3_dcqn.campusnav.progress import TqdmProgress
from sb3_dcqn.campusnav.solved import SOLVED_SPL, SOLVED_SUCCESS
from sb3_dcqn.dcqn import DCQN

__all__ = [
    "ClosurePlan",
    "SolveResult",
    "TrainingBudget",
    "TrainingOutcome",
    "train_until_solved",
    "train_with_closures",
]


# ------------------------------------------------------------------------------------------------ until solved
class TrainingBudget(BaseCallback):
    """Stops training once ``evaluation`` has counted ``seconds`` of training (its evaluations excluded)."""

    def __init__(self, evaluation: RouteEvaluationCallback, seconds: float) -> None:
        super().__init__()
        self.evaluation = evaluation
        self.seconds = seconds

    def _on_step(self) -> bool:
        return self.evaluation.train_seconds < self.seconds


@dataclass(frozen=True)
class SolveResult:
    """
    One training run to the threshold.

    :param solved_at: The first evaluation at the thresholds, or ``None`` (a miss)
    :param evaluations: Every evaluation of the run
    :param wall_seconds: Wall time of ``learn()``, evaluations included
    :param evaluation_seconds: Of which the evaluations took
    """

    solved_at: RouteEvaluation | None
    evaluations: list[RouteEvaluation]
    wall_seconds: float
    evaluation_seconds: float = 0.0

    def curve(self) -> list[dict[str, float]]:
        return [
            {"step": e.step, "episode": e.episode, "seconds": e.train_seconds, "success": e.success_rate, "spl": e.spl}
            for e in self.evaluations
        ]


def train_until_solved(
    model: BaseAlgorithm,
    max_steps: int,
    budget_seconds: float,
    eval_freq: int,
    evaluation: RouteEvaluationCallback | None = None,
    **learn_kwargs: Any,
) -> SolveResult:
    """
    Train until the greedy routes from every start meet the thresholds, the step cap or the time budget.

    :param model: The agent (its env is evaluated: the first training env)
    :param max_steps: Step cap
    :param budget_seconds: Training-time cap, evaluations excluded
    :param eval_freq: Evaluate every this many env steps
    :param evaluation: An evaluation callback of your own (default: one at the solved bar)
    :return: the first evaluation at the thresholds (or ``None``) and all evaluations
    """
    if evaluation is None:
        evaluation = RouteEvaluationCallback(
            eval_freq=eval_freq,
            success_threshold=SOLVED_SUCCESS,
            spl_threshold=SOLVED_SPL,
            stop_when_solved=True,
            every_goal=True,
        )
    start = time.perf_counter()
    model.learn(
        max_steps, callback=CallbackList([evaluation, TrainingBudget(evaluation, budget_seconds)]), **learn_kwargs
    )
    wall = time.perf_counter() - start
    solved = next(
        (
            e
            for e in evaluation.evaluations
            if e.meets(evaluation.success_threshold, evaluation.spl_threshold, evaluation.every_goal)
        ),
        None,
    )
    return SolveResult(solved, list(evaluation.evaluations), wall, evaluation.excluded_seconds)


# ------------------------------------------------------------------------------------------------ closures
@dataclass
class ClosurePlan:
    """
    The closures of a run: those at fixed times (``--closures`` file or ``--close-at``) and those made one at a time
    once the map is solved (or right away in ``readapt``), each after the previous one recovered or its budget ran out.

    :param scheduled: Events the closure callback fires when due
    :param later: Events applied between ``learn`` calls, one at a time
    """

    scheduled: ClosureSchedule = field(default_factory=ClosureSchedule)
    later: list[ClosureEvent] = field(default_factory=list)

    @property
    def empty(self) -> bool:
        return not self.scheduled.events and not self.later


class _StopWhenDone(BaseCallback):
    """
    Stop training once every scheduled closure has fired and the latest route evaluation is good: at the solved
    thresholds while no road has changed yet, else recovered from the latest change (the evaluation's thresholds).
    """

    def __init__(self, closures: RoadClosureCallback, expected_records: int) -> None:
        super().__init__()
        self.closures = closures
        self.expected_records = expected_records
        self._seen = -1

    def _on_step(self) -> bool:
        evaluation = self.closures.evaluation
        assert evaluation is not None
        if len(self.closures.records) < self.expected_records or len(evaluation.evaluations) == self._seen:
            return True
        self._seen = len(evaluation.evaluations)
        if not self._seen:
            return True
        if any(record.changed for record in self.closures.records):
            return not self.closures.recoveries[-1].recovered
        return not evaluation.evaluations[-1].meets(SOLVED_SUCCESS, SOLVED_SPL, every_goal=True)


@dataclass
class TrainingOutcome:
    """
    What a run of :func:`train_with_closures` produced.

    :param evaluation: The route evaluation (``evaluations``: every evaluation in order)
    :param closures: The closure callback (``records``, ``recoveries``)
    :param progress: The progress bar (``episode_rewards``, ``episode_lengths``)
    :param steps: Env steps trained in this run
    :param seconds: Wall seconds of this run (training and evaluations)
    :param unfired: Scheduled events that did not fire within the budget
    """

    evaluation: RouteEvaluationCallback
    closures: RoadClosureCallback
    progress: TqdmProgress
    steps: int
    seconds: float
    unfired: list[ClosureEvent]

    @property
    def recoveries(self) -> list[Recovery]:
        return self.closures.recoveries

    def solved_at(self) -> RouteEvaluation | None:
        """The first evaluation at the solved thresholds before any road changed."""
        changes = [r for r in self.closures.records if r.changed]
        end = changes[0].evaluation_index if changes else len(self.evaluation.evaluations)
        return next(
            (e for e in self.evaluation.evaluations[:end] if e.meets(SOLVED_SUCCESS, SOLVED_SPL, every_goal=True)),
            None,
        )

    def before_closures(self) -> RouteEvaluation | None:
        """The last evaluation before the first change of the road network (or the last one if none)."""
        changes = [r for r in self.closures.records if r.changed]
        end = changes[0].evaluation_index if changes else len(self.evaluation.evaluations)
        return self.evaluation.evaluations[end - 1] if end > 0 else None


def train_with_closures(
    model: DCQN,
    plan: ClosurePlan,
    *,
    budget: int,
    recovery_budget: int,
    eval_freq: int,
    recovery_eval_freq: int = 5,
    keep_training: bool = False,
    verbose: int = 0,
    progress: bool = True,
) -> TrainingOutcome:
    """
    Train with route evaluations and closures: first up to ``budget`` steps (scheduled closures fire on the way; stop
    once solved and recovered from them), then each of ``plan.later`` in turn, training on up to ``recovery_budget``
    steps after each (stop once recovered).

    :param model: The model, with its training env (a ``DummyVecEnv``) and logger set
    :param plan: The closures
    :param budget: Steps of the first phase (0: none)
    :param recovery_budget: Steps after each closure of ``plan.later`` at most
    :param eval_freq: Route evaluation every this many env steps
    :param recovery_eval_freq: While recovering, a route evaluation every this many episodes
    :param keep_training: Train every budget out, even when solved or recovered
    :param verbose: 1: a line per route evaluation and closure event
    :param progress: Show a progress bar on stderr
    :return: the callbacks, with everything they recorded
    """
    start, start_steps = time.perf_counter(), model.num_timesteps
    evaluation = RouteEvaluationCallback(
        eval_freq=eval_freq,
        unit="step",
        success_threshold=DEFAULT_SUCCESS_THRESHOLD,
        spl_threshold=DEFAULT_SPL_THRESHOLD,
        verbose=int(verbose >= 1),
    )
    closures = RoadClosureCallback(
        plan.scheduled, evaluation=evaluation, recovery_eval_freq=recovery_eval_freq, verbose=int(verbose >= 1)
    )
    bar = TqdmProgress(evaluation, disable=not progress)
    closures.init_callback(model)  # learns the map, so that closures can be applied before any training

    def learn(steps: int, phase: str, expected_events: int = 0) -> None:
        callbacks: list[BaseCallback] = [closures, bar]
        if not keep_training:
            callbacks.append(_StopWhenDone(closures, len(closures.records) + expected_events))
        bar.phase = phase
        model.learn(steps, callback=callbacks, reset_num_timesteps=False)

    if budget > 0:
        learn(budget, "train", len(plan.scheduled.events))
    fired = len(closures.records)
    if plan.later and not evaluation.evaluations:
        evaluation.evaluate()  # the routes before the first closure
    for event in plan.later:
        record = closures.apply(replace(event, at=model.num_timesteps))  # described as "step N: ..."
        if not record.changed:
            for what, why in record.refused:
                print(f"closure refused: {what}: {why}", file=sys.stderr)
            continue
        roads = ", ".join(f"{u}-{v}" for u, v in record.closed)
        if recovery_budget > 0:
            learn(recovery_budget, f"closed {roads}")
    return TrainingOutcome(
        evaluation=evaluation,
        closures=closures,
        progress=bar,
        steps=model.num_timesteps - start_steps,
        seconds=time.perf_counter() - start,
        unfired=plan.scheduled.ordered()[fired:],
    )
