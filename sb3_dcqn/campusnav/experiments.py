"""The CampusNav experiments: train until the map is solved, and train -> close roads -> recover.

:func:`train_until_solved` trains one agent inside one ``learn()`` call, evaluating the greedy routes from every
(start, heading) every ``eval_freq`` steps, and stops at the first evaluation at the solved bar
(:mod:`sb3_dcqn.campusnav.solved`) or when the training-time budget is spent (evaluation time excluded).
:func:`train_with_closures` is the loop of the command line and of the closure benchmarks: train (until solved), close
roads (at fixed steps, or one at a time), train on until recovered, and return everything the callbacks recorded (on
Ctrl-C, :class:`TrainingInterrupted` carries what was recorded until then). Its progress bar ends each phase on what
happened (:meth:`TrainingOutcome.headline`: "solved at 9,000 steps", "recovered from 69-81 after 20 episodes").
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.utils import configure_logger

from campusnav_env.callbacks import RoadClosureCallback, RouteEvaluationCallback
from campusnav_env.closures import ClosureEvent, ClosureSchedule
from campusnav_env.recovery import DEFAULT_SPL_THRESHOLD, DEFAULT_SUCCESS_THRESHOLD, Recovery, RouteEvaluation
from sb3_dcqn.campusnav.progress import TqdmProgress
from sb3_dcqn.campusnav.solved import SOLVED_SPL, SOLVED_SUCCESS, is_solved
from sb3_dcqn.route_memory.layer import algorithm_name

__all__ = [
    "ClosurePlan",
    "SolveResult",
    "TrainingBudget",
    "TrainingInterrupted",
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
        """Each evaluation's step, episode, training seconds and scores (and its critics' alone, where evaluated)."""
        return [
            {
                "step": e.step,
                "episode": e.episode,
                "seconds": e.train_seconds,
                "success": e.success_rate,
                "spl": e.spl,
                **(
                    {}
                    if e.critics is None
                    else {"critics_success": e.critics.success_rate, "critics_spl": e.critics.spl}
                ),
            }
            for e in self.evaluations
        ]


def train_until_solved(
    model: BaseAlgorithm,
    max_steps: int,
    budget_seconds: float,
    eval_freq: int,
    evaluation: RouteEvaluationCallback | None = None,
    callbacks: Sequence[BaseCallback] = (),
    **learn_kwargs: Any,
) -> SolveResult:
    """
    Train until the greedy routes from every start meet the thresholds, the step cap or the time budget.

    :param model: The agent (its env is evaluated: the first training env)
    :param max_steps: Step cap
    :param budget_seconds: Training-time cap, evaluations excluded
    :param eval_freq: Evaluate every this many env steps
    :param evaluation: An evaluation callback of your own (default: one at the solved bar)
    :param callbacks: More callbacks for the training (e.g. an entry's
        :meth:`~sb3_dcqn.zoo_entry.ZooEntry.make_callbacks`)
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
        max_steps,
        callback=CallbackList([*callbacks, evaluation, TrainingBudget(evaluation, budget_seconds)]),
        **learn_kwargs,
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
    The closures of a run: those at fixed times (the command line's ``--closures`` file or ``--close-at``) and those
    made one at a time after the first phase (once the map is solved, or right away without one), each after the
    previous one recovered or its budget ran out.

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
    Stop training once every scheduled closure has fired and the latest route evaluation is good: at the solved bar
    while no road has changed yet (if ``when_solved``), else recovered from the latest change (if ``when_recovered``).
    """

    def __init__(
        self, closures: RoadClosureCallback, expected_records: int, when_solved: bool, when_recovered: bool
    ) -> None:
        super().__init__()
        self.closures = closures
        self.expected_records = expected_records
        self.when_solved = when_solved
        self.when_recovered = when_recovered
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
            return not (self.when_recovered and self.closures.recoveries[-1].recovered)
        return not (self.when_solved and is_solved(evaluation.evaluations[-1]))


@dataclass
class TrainingOutcome:
    """
    What a run of :func:`train_with_closures` produced.

    :param evaluation: The route evaluation (``evaluations``: every evaluation in order)
    :param closures: The closure callback (``records``, ``recoveries``, ``graph``: the map with its closures)
    :param progress: The progress bar (``episode_rewards``, ``episode_lengths``: every training episode)
    :param steps: Env steps trained in this run
    :param seconds: Wall seconds of this run (training and evaluations)
    :param first_phase_seconds: Of which the first phase took (up to ``budget`` steps, before the one-at-a-time
        closures)
    :param unfired: Scheduled events that did not fire within the budget
    """

    evaluation: RouteEvaluationCallback
    closures: RoadClosureCallback
    progress: TqdmProgress
    steps: int
    seconds: float
    first_phase_seconds: float
    unfired: list[ClosureEvent]

    @property
    def recoveries(self) -> list[Recovery]:
        return self.closures.recoveries

    def _first_change(self) -> int:
        """Index of the first evaluation after the first change of the road network (all of them if none)."""
        changes = [r for r in self.closures.records if r.changed]
        return changes[0].evaluation_index if changes else len(self.evaluation.evaluations)

    def solved_at(self) -> RouteEvaluation | None:
        """The first evaluation at the solved bar before any road changed."""
        return next((e for e in self.evaluation.evaluations[: self._first_change()] if is_solved(e)), None)

    def before_closures(self) -> RouteEvaluation | None:
        """The last evaluation before the first change of the road network (or the last one if none)."""
        end = self._first_change()
        return self.evaluation.evaluations[end - 1] if end > 0 else None

    def headline(self) -> str:
        """
        What the run came to, in a line (the progress bar ends each phase on it): solved or not (before any closure),
        recovered from the latest closure or not, and the latest evaluation's scores, e.g. ``"solved at 9,000 steps:
        success 1.000, SPL 0.990"`` or ``"not recovered from 69-81; at 6,000 steps: success 0.750, SPL 0.723"``.
        """
        evaluations = self.evaluation.evaluations
        if not evaluations:
            return "not evaluated"
        last = evaluations[-1]
        scores = f"success {last.success_rate:.3f}, SPL {last.spl:.3f}"
        recoveries = self.recoveries
        if recoveries:
            latest = recoveries[-1]
            roads = ", ".join(f"{u}-{v}" for u, v in latest.closure.closed) or "reopened " + ", ".join(
                f"{u}-{v}" for u, v in latest.closure.reopened
            )
            event = latest.recovered_at
            said = f"not recovered from {roads}"
            if event is not None:
                said = f"recovered from {roads} after {latest.episodes:,.0f} episodes ({latest.steps:,.0f} steps)"
        else:
            event = self.solved_at()
            said = "not solved" if event is None else f"solved at {event.step:,} steps"
        return f"{said}: {scores}" if event is last else f"{said}; at {last.step:,} steps: {scores}"


class TrainingInterrupted(KeyboardInterrupt):
    """
    Ctrl-C inside :func:`train_with_closures`: a ``KeyboardInterrupt`` that carries what the run recorded until then.

    :param outcome: The run so far (its route evaluation can still evaluate the model as it is now)
    """

    def __init__(self, outcome: TrainingOutcome) -> None:
        super().__init__()
        self.outcome = outcome


def _has_logger(model: BaseAlgorithm) -> bool:
    try:
        model.logger  # noqa: B018  (SB3 sets it in learn() or set_logger())
    except AttributeError:
        return False
    return True


def train_with_closures(
    model: BaseAlgorithm,
    plan: ClosurePlan,
    *,
    budget: int,
    recovery_budget: int,
    eval_freq: int,
    recovery_eval_freq: int = 5,
    budget_seconds: float = math.inf,
    stop_when_solved: bool = True,
    stop_when_recovered: bool = True,
    callbacks: Sequence[BaseCallback] = (),
    eval_goals: Sequence[str | int] | None = None,
    every_goal: bool = False,
    verbose: int = 0,
    progress: bool = True,
) -> TrainingOutcome:
    """
    Train with route evaluations and closures, the loop of the command line and of the closure benchmarks.

    First up to ``budget`` steps (and ``budget_seconds`` of training), in which the scheduled closures fire; then
    each of ``plan.later`` in turn, each followed by up to ``recovery_budget`` steps. The first phase stops early once
    solved (before any closure) or recovered (after its closures), the later ones once recovered, unless asked not to.
    One route evaluation serves the whole run: at the recovery thresholds (:mod:`campusnav_env.recovery`), every
    ``eval_freq`` steps, and every ``recovery_eval_freq`` episodes while recovering; its episodes, steps and training
    seconds count from the start of the run.

    :param model: The model, with its training env (a ``DummyVecEnv``); a logger of its own if set (else SB3's
        default one, as ``learn`` would configure it)
    :param plan: The closures
    :param budget: Steps of the first phase (0: none)
    :param recovery_budget: Steps after each closure of ``plan.later`` at most
    :param eval_freq: Route evaluation every this many env steps
    :param recovery_eval_freq: While recovering, a route evaluation every this many episodes
    :param budget_seconds: Training seconds of the first phase at most (evaluations excluded)
    :param stop_when_solved: End the first phase at the first evaluation at the solved bar (before any closure)
    :param stop_when_recovered: End a phase once recovered from its closures (else train its budget out)
    :param callbacks: More callbacks for every phase (the levers' adaptation boost:
        :func:`~sb3_dcqn.campusnav.levers.lever_callbacks`)
    :param eval_goals: The goals the route evaluation drives to (default: all of the env's goals; a goal-conditioned
        env has one per intersection: pass a sample)
    :param every_goal: Solved and recovered only when each goal is at the thresholds on its own
    :param verbose: 1: a line per route evaluation and closure event
    :param progress: Show a progress bar on stderr; each phase's bar ends on :meth:`TrainingOutcome.headline`
    :return: the callbacks, with everything they recorded
    :raises TrainingInterrupted: on Ctrl-C (a ``KeyboardInterrupt``), with what was recorded until then
    """
    start, start_steps = time.perf_counter(), model.num_timesteps
    if not _has_logger(model):
        model.set_logger(configure_logger(model.verbose, model.tensorboard_log, algorithm_name(model, for_files=True)))
    evaluation = RouteEvaluationCallback(
        eval_freq=eval_freq,
        unit="step",
        goals=eval_goals,
        success_threshold=DEFAULT_SUCCESS_THRESHOLD,
        spl_threshold=DEFAULT_SPL_THRESHOLD,
        every_goal=every_goal,
        verbose=int(verbose >= 1),
    )
    closures = RoadClosureCallback(
        plan.scheduled, evaluation=evaluation, recovery_eval_freq=recovery_eval_freq, verbose=int(verbose >= 1)
    )
    bar = TqdmProgress(evaluation, disable=not progress)
    closures.init_callback(model)  # learns the map, so that closures can be applied before any training
    first_phase_seconds: float | None = None
    fired: int | None = None

    def outcome() -> TrainingOutcome:
        """The run as it stands (its first phase, if still running, counted up to now)."""
        return TrainingOutcome(
            evaluation=evaluation,
            closures=closures,
            progress=bar,
            steps=model.num_timesteps - start_steps,
            seconds=time.perf_counter() - start,
            first_phase_seconds=time.perf_counter() - start if first_phase_seconds is None else first_phase_seconds,
            unfired=plan.scheduled.ordered()[len(closures.records) if fired is None else fired :],
        )

    def learn(steps: int, phase: str, expected_events: int = 0, seconds: float = math.inf) -> None:
        # The bar after the closures' callback: its last words come after the evaluation at the end of training
        phase_callbacks: list[BaseCallback] = [closures, bar, *callbacks]
        if stop_when_solved or stop_when_recovered:
            expected = len(closures.records) + expected_events
            phase_callbacks.append(_StopWhenDone(closures, expected, stop_when_solved, stop_when_recovered))
        if math.isfinite(seconds):
            phase_callbacks.append(TrainingBudget(evaluation, seconds))
        bar.phase = phase
        model.learn(steps, callback=phase_callbacks, reset_num_timesteps=False)

    bar.ending = lambda: outcome().headline()
    try:
        if budget > 0:
            learn(budget, "train", len(plan.scheduled.events), budget_seconds)
        first_phase_seconds = time.perf_counter() - start
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
    except KeyboardInterrupt:
        raise TrainingInterrupted(outcome()) from None
    return outcome()
