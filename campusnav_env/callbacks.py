"""Stable-Baselines3 callbacks for dynamic routing: close roads during training, evaluate routes, measure recovery.

This is the one module of ``campusnav_env`` that imports Stable-Baselines3. The callbacks work with any SB3
algorithm (DCQN, DQN, PPO, ...), with one env or several (``DummyVecEnv`` or ``SubprocVecEnv``).

- :class:`RouteEvaluationCallback` runs :func:`~campusnav_env.route_evaluation.evaluate_routes` (the greedy policy
  from every start to every goal) every ``eval_freq`` steps or episodes and logs ``eval/success_rate``, ``eval/spl``,
  ``eval/coverage``, ``eval/mean_steps`` and ``eval/optimality_gap``, overall and per goal (``eval/<goal>/...``, up
  to 16 goals); named goal sets (e.g. goals never trained on) under ``eval/<set>/...``.
- :class:`RoadClosureCallback` closes and reopens roads on a :class:`~campusnav_env.closures.ClosureSchedule`, in
  every training env (``VecEnv.env_method``) and in the evaluation env alike, logs each event (``closure/...``) and,
  with a route evaluation attached, evaluates right after each closure and then every ``recovery_eval_freq``
  episodes until the routes are good again: the recovery (episodes, env steps and training seconds) is logged as
  ``closure/recovery_episodes``, ``closure/recovery_steps``, ``closure/recovery_seconds`` and returned by
  :attr:`RoadClosureCallback.recoveries` (see :mod:`campusnav_env.recovery`).
- :class:`StartCurriculumCallback` starts episodes near the goal and moves the starts out as the agent succeeds
  (StreetLearn's near-to-far curriculum), logging ``curriculum/start_distance_limit``.

Training seconds exclude the time spent evaluating routes, so that a recovery measures what training costs.

Example::

    evaluation = RouteEvaluationCallback(eval_env, eval_freq=2_000)
    closures = RoadClosureCallback([ClosureEvent(at=3_000, close_on_route="busiest")], evaluation=evaluation)
    model.learn(60_000, callback=closures)
    print(recovery_table(closures.recoveries))
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, EventCallback
from stable_baselines3.common.vec_env import DummyVecEnv

from campusnav_env.closures import (
    ClosureEvent,
    ClosureSchedule,
    apply_fixed_event,
    busiest_road,
    first_road_on_route,
    road_usage,
)
from campusnav_env.env import CampusNavEnv
from campusnav_env.maps.navigation import NavigationGraph
from campusnav_env.recovery import (
    DEFAULT_SPL_THRESHOLD,
    DEFAULT_SUCCESS_THRESHOLD,
    ClosureRecord,
    Recovery,
    RouteEvaluation,
    measure_recoveries,
)
from campusnav_env.route_evaluation import Policy, RouteReport, evaluate_routes

__all__ = ["RoadClosureCallback", "RouteEvaluationCallback", "StartCurriculumCallback", "campus_env"]

_SUMMARY_KEYS = ("success_rate", "spl", "coverage", "mean_steps", "optimality_gap")
# Goal sets up to this size are also logged goal by goal
PER_GOAL_LOG_LIMIT = 16


class _TrainingProgress(BaseCallback):
    """Counts training episodes and training wall time (only while training runs, minus the excluded seconds).

    ``excluded_seconds``: the evaluations' seconds inside training runs (those between ``learn`` calls never counted).
    """

    def __init__(self, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.episodes = 0
        self.excluded_seconds = 0.0
        self._trained_seconds = 0.0
        self._started: float | None = None
        self._first_timestep: int | None = None

    @property
    def train_seconds(self) -> float:
        running = 0.0 if self._started is None else time.perf_counter() - self._started
        return self._trained_seconds + running - self.excluded_seconds

    @property
    def steps(self) -> int:
        """Env steps since this callback first started training."""
        return self.num_timesteps - (self._first_timestep or 0)

    def _on_training_start(self) -> None:
        if self._first_timestep is None:
            self._first_timestep = self.model.num_timesteps
        self._started = time.perf_counter()

    def _on_training_end(self) -> None:
        if self._started is not None:
            self._trained_seconds += time.perf_counter() - self._started
            self._started = None

    def _on_step(self) -> bool:
        dones = self.locals.get("dones")
        self.episodes += 0 if dones is None else int(np.sum(dones))
        return True


def campus_env(env: gym.Env | CampusNavEnv, needed_by: str = "") -> CampusNavEnv:
    """
    The ``CampusNavEnv`` inside ``env`` (its wrappers removed): the one unwrapping of the package and its users.

    :param env: A ``CampusNavEnv`` or a wrapper of one
    :param needed_by: What needs it, for the message (e.g. ``"route evaluation"``)
    :raises TypeError: if it is another env
    """
    nav = env.unwrapped if isinstance(env, gym.Env) else env
    if not isinstance(nav, CampusNavEnv):
        needs = f"{needed_by} needs a CampusNavEnv (or a wrapper of one), got" if needed_by else "not a CampusNav env:"
        raise TypeError(f"{needs} {type(nav).__name__}")
    return nav


class RouteEvaluationCallback(_TrainingProgress):
    """
    Evaluate the greedy policy from every start to every goal during training.

    :param eval_env: A ``CampusNavEnv`` or a wrapper of one. ``None``: the first training env, when training runs in
        a ``DummyVecEnv`` (with a ``SubprocVecEnv`` pass an env of your own; a :class:`RoadClosureCallback` applies
        its closures to it too)
    :param eval_freq: Evaluate every ``eval_freq`` env steps (``unit="step"``) or training episodes
    :param unit: ``"step"`` or ``"episode"``
    :param goals: Goals to evaluate, by name or node id (default: all of the env's goals)
    :param max_steps: Step limit per route (default: the env's ``max_steps``)
    :param log_name: Log the scores under ``eval/<log_name>/...`` instead of ``eval/...`` (e.g. ``"unseen_goals"``)
    :param other_goals: More named goal sets evaluated at the same times, logged under ``eval/<name>/...`` and kept in
        each evaluation's ``others``; only ``goals`` decide whether the map is solved (e.g. ``{"train_goals": [...]}``
        next to held-out ``goals``)
    :param success_threshold: Success rate at which the map counts as solved
    :param spl_threshold: SPL at which the map counts as solved
    :param stop_when_solved: Stop training at the first evaluation at both thresholds
    :param every_goal: The map counts as solved only when each goal is at both thresholds on its own (not only the
        routes to all goals together)
    :param evaluate_at_end: Evaluate once more when training ends, unless the last evaluation is :attr:`current`
        (SB3 stores a step's transition after the callbacks have seen the step, and runs the gradient steps after the
        rollout: an evaluation made during the last step is of a model that changed since)
    :param policy: Makes the policy evaluated from the model, anew at each evaluation (default: the model itself,
        its greedy ``predict`` asked with episode starts and its state per route)
    :param critics_alone: Where the model's greedy ``predict`` plans over a route memory (a model whose
        ``wears_route_memory`` is true: sb3_dcqn's ``with_route_memory`` classes with the memory on), also evaluate
        its critics alone (``model.policy.predict``) on ``goals``: kept in each evaluation's ``critics`` and logged
        under ``eval/<log_name>/critics/...``
    :param sample: Evaluate only this many (start, heading) pairs per goal, drawn anew at each evaluation (seed
        ``sample_seed`` plus the number of evaluations so far, so that a lucky draw is not kept), e.g. on a city whose
        every pair takes minutes. A sample at both thresholds is confirmed at once by an evaluation of every pair of
        ``goals``, which is the one recorded (its ``others`` and ``critics`` stay those of the sample): a map counts as
        solved, and training stops, only on every pair. Every logged report says what it covers:
        ``eval/.../sampled_pairs`` is the sample's size, 0 for every pair. Unless a :class:`RoadClosureCallback`
        drives this callback (its closures read the routes' nodes), the routes keep only their start node
        (``keep_nodes=False``). ``None`` (default): every evaluation covers every pair
    :param sample_seed: Seed of the first sample's draw
    :param verbose: 1 prints a line per evaluation
    """

    def __init__(
        self,
        eval_env: gym.Env | CampusNavEnv | None = None,
        eval_freq: int = 2_000,
        unit: str = "step",
        goals: Sequence[str | int] | None = None,
        max_steps: int | None = None,
        log_name: str | None = None,
        other_goals: Mapping[str, Sequence[str | int]] | None = None,
        success_threshold: float = DEFAULT_SUCCESS_THRESHOLD,
        spl_threshold: float = DEFAULT_SPL_THRESHOLD,
        stop_when_solved: bool = False,
        every_goal: bool = False,
        evaluate_at_end: bool = True,
        policy: Callable[[BaseAlgorithm], Policy] | None = None,
        critics_alone: bool = True,
        sample: int | None = None,
        sample_seed: int = 0,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose)
        if sample is not None and sample < 1:
            raise ValueError(f"sample must be at least 1 pair (or None), got {sample}")
        if unit not in ("step", "episode"):
            raise ValueError(f"unit must be 'step' or 'episode', got {unit!r}")
        if eval_freq < 1:
            raise ValueError(f"eval_freq must be at least 1, got {eval_freq}")
        self.eval_env = None if eval_env is None else campus_env(eval_env, "route evaluation")
        # The env as the policy observes it (eval_env with its wrappers, e.g. observation noise): routes run in it
        self.observed_env: gym.Env | None = eval_env
        self.eval_freq = eval_freq
        self.unit = unit
        self.goals = goals
        self.max_steps = max_steps
        self.log_name = log_name
        self.other_goals = dict(other_goals or {})
        if log_name in self.other_goals:
            raise ValueError(f"other_goals: the name {log_name!r} is already log_name's")
        self.success_threshold = success_threshold
        self.spl_threshold = spl_threshold
        self.stop_when_solved = stop_when_solved
        self.every_goal = every_goal
        self.evaluate_at_end = evaluate_at_end
        self.policy = policy
        self.critics_alone = critics_alone
        self.sample = sample
        self.sample_seed = sample_seed
        # Sampled evaluations at both thresholds that the evaluation of every pair then confirmed or refuted
        self.confirmed = 0
        self.refuted = 0
        self.evaluations: list[RouteEvaluation] = []
        self.shares_training_env = False
        self._next_due = eval_freq
        self._dense_every: int | None = None
        self._next_dense = 0
        self._current = False

    def _init_callback(self) -> None:
        if self.eval_env is None:
            env = self.training_env
            if not isinstance(env, DummyVecEnv):
                raise ValueError(
                    "RouteEvaluationCallback: with a SubprocVecEnv (or another VecEnv than DummyVecEnv) pass "
                    "eval_env=gym.make(...) with the same map; closures are applied to it as well"
                )
            self.eval_env = campus_env(env.envs[0], "route evaluation")
            self.observed_env = env.envs[0]
            self.shares_training_env = True

    @property
    def current(self) -> bool:
        """
        Whether the last evaluation is of the model as it is now: nothing has changed it since (no transition stored,
        no gradient step). An evaluation during a step is current only if training stops at that step: otherwise SB3
        stores the step's transition (and a route memory learns from it) and, at the end of the rollout, trains.
        """
        return self._current

    @property
    def solved(self) -> bool:
        """Whether the last evaluation is at both thresholds."""
        return bool(self.evaluations) and self.evaluations[-1].meets(
            self.success_threshold, self.spl_threshold, self.every_goal
        )

    def dense(self, every_episodes: int | None) -> None:
        """Also evaluate every ``every_episodes`` training episodes from now on (``None``: stop doing so)."""
        self._dense_every = every_episodes
        self._next_dense = self.episodes + (every_episodes or 0)

    def _on_step(self) -> bool:
        super()._on_step()  # count the episodes that just ended
        self._current = False  # the previous step's transition was stored since
        progress = self.steps if self.unit == "step" else self.episodes
        due = progress >= self._next_due
        if self._dense_every is not None and self.episodes >= self._next_dense:
            due = True
            self._next_dense = self.episodes + self._dense_every
        if due:
            while self._next_due <= progress:
                self._next_due += self.eval_freq
            self.evaluate()
            if self.stop_when_solved and self.solved:
                return False
        return True

    def _on_rollout_end(self) -> None:
        self._current = False  # the rollout's last transition is stored, and the gradient steps come next

    def _on_training_end(self) -> None:
        if self.evaluate_at_end and not self.current:
            self.evaluate()
        super()._on_training_end()

    def evaluate(self) -> RouteEvaluation:
        """Evaluate now, record the result, log it and return it (its time does not count as training)."""
        assert self.eval_env is not None and self.observed_env is not None, "the callback is not initialised"
        start = time.perf_counter()
        # Read before evaluating: the evaluation's own time is subtracted only once it has finished
        train_seconds = self.train_seconds
        model = self.model

        # The model itself: asked with episode starts and its state per route (the memory's prior, its episode guard)
        policy: Policy = model if self.policy is None else self.policy(model)
        observed = self.observed_env
        if self.sample is None:
            sampling: dict[str, Any] = {}
        else:
            # A fresh draw at each evaluation; the same pairs for the policy, the other goal sets and the critics
            sampling = {
                "sample": self.sample,
                "seed": self.sample_seed + len(self.evaluations),
                "keep_nodes": isinstance(self.parent, RoadClosureCallback),
            }
        report = evaluate_routes(observed, policy, goals=self.goals, max_steps=self.max_steps, **sampling)
        others = {
            name: evaluate_routes(observed, policy, goals=goals, max_steps=self.max_steps, **sampling)
            for name, goals in self.other_goals.items()
        }
        critics = None
        # The model says whether it wears a memory (sb3_dcqn's layer: wears_route_memory), never its setting's
        # truthiness: route_memory={} wears one. Duck typing: this package imports nothing from sb3_dcqn
        if self.critics_alone and self.policy is None and getattr(model, "wears_route_memory", False):

            def critics_policy(observations: Any) -> np.ndarray:
                return model.policy.predict(observations, deterministic=True)[0]

            critics = evaluate_routes(observed, critics_policy, goals=self.goals, max_steps=self.max_steps, **sampling)
        sampled = report if report.is_sample else None
        if sampled is not None and sampled.meets(self.success_threshold, self.spl_threshold, self.every_goal):
            # A sample may have missed the starts that fail: only every pair counts the map as solved
            report = evaluate_routes(
                observed,
                policy,
                goals=self.goals,
                max_steps=self.max_steps,
                keep_nodes=sampling["keep_nodes"],
            )
            solved = report.meets(self.success_threshold, self.spl_threshold, self.every_goal)
            self.confirmed += solved
            self.refuted += not solved
        step = self.model.num_timesteps
        evaluation = RouteEvaluation(
            step=step,
            episode=self.episodes,
            train_seconds=train_seconds,
            report=report,
            others=others,
            critics=critics,
        )
        self.evaluations.append(evaluation)
        prefix = "eval" if self.log_name is None else f"eval/{self.log_name}"
        self._log_report(prefix, report)
        if critics is not None:
            self._log_report(f"{prefix}/critics", critics)
        for name, other in others.items():
            self._log_report(f"eval/{name}", other)
        self.logger.record("eval/train_seconds", evaluation.train_seconds)
        self.logger.dump(step)
        if self.verbose >= 1:
            scope = ""
            if sampled is report:
                scope = f" (a sample of {sampled.evaluated_pairs} of {sampled.total_pairs} pairs)"
            elif sampled is not None:
                scope = (
                    f" (every pair, after a sample of {sampled.evaluated_pairs} at success "
                    f"{sampled.success_rate:.3f}, SPL {sampled.spl:.3f})"
                )
            print(
                f"[routes] step {evaluation.step}, episode {evaluation.episode}, {evaluation.train_seconds:.1f} s: "
                f"success {report.success_rate:.3f}, SPL {report.spl:.3f}{scope}"
                + ("" if critics is None else f" (critics alone {critics.success_rate:.3f} / {critics.spl:.3f})"),
                flush=True,
            )
        if self._started is not None:  # outside training (a closure applied between learn calls) nothing ran to exclude
            self.excluded_seconds += time.perf_counter() - start
        self._current = True
        return evaluation

    def _log_report(self, prefix: str, report: RouteReport) -> None:
        """Scores under ``prefix``; per goal too for up to :data:`PER_GOAL_LOG_LIMIT` goals (not a hundred curves)."""
        summary = report.summary()
        for key in _SUMMARY_KEYS:
            self.logger.record(f"{prefix}/{key}", summary[key])
        if self.sample is not None:  # whether the figures above come from a sample (0: from every pair)
            self.logger.record(f"{prefix}/sampled_pairs", report.evaluated_pairs if report.is_sample else 0)
        by_goal = report.by_goal()
        if 1 < len(by_goal) <= PER_GOAL_LOG_LIMIT:
            for goal in sorted(by_goal):
                per_goal = by_goal[goal].summary()
                for key in _SUMMARY_KEYS:
                    self.logger.record(f"{prefix}/{goal}/{key}", per_goal[key])


class RoadClosureCallback(EventCallback):
    """
    Close (and reopen) roads during training on a schedule, in every training env and in the evaluation env.

    The schedule is checked against the map before training starts: an unknown road, a closure that would cut a
    goal off or a random draw that cannot be met raise an error naming the event. Roads chosen on the route at run
    time that cannot be closed are skipped and reported in :attr:`records` (``refused``) and in the log.

    :param schedule: A :class:`~campusnav_env.closures.ClosureSchedule`, a list of events, or a YAML file
    :param evaluation: Route evaluation to drive (this callback calls it; do not pass it to ``learn`` as well). It
        measures the recovery after each closure; without it only the events are recorded
    :param recovery_eval_freq: While recovering, evaluate every this many training episodes
    :param verbose: 1 prints a line per event and per recovery
    """

    callback: RouteEvaluationCallback | None

    def __init__(
        self,
        schedule: ClosureSchedule | Sequence[ClosureEvent] | str | Path,
        evaluation: RouteEvaluationCallback | None = None,
        recovery_eval_freq: int = 5,
        verbose: int = 0,
    ) -> None:
        super().__init__(evaluation, verbose)
        if isinstance(schedule, (str, Path)):
            schedule = ClosureSchedule.from_yaml(schedule)
        elif not isinstance(schedule, ClosureSchedule):
            schedule = ClosureSchedule(list(schedule))
        if recovery_eval_freq < 1:
            raise ValueError(f"recovery_eval_freq must be at least 1, got {recovery_eval_freq}")
        self.schedule = schedule
        self.recovery_eval_freq = recovery_eval_freq
        self.records: list[ClosureRecord] = []
        self._pending = schedule.ordered()
        self._progress = evaluation if evaluation is not None else _TrainingProgress()
        self._graph: NavigationGraph | None = None
        self._protect: list[int] = []
        self._recovering: ClosureRecord | None = None

    @property
    def evaluation(self) -> RouteEvaluationCallback | None:
        return self.callback

    @property
    def recoveries(self) -> list[Recovery]:
        """The recovery after every closure so far (needs a route evaluation)."""
        if self.evaluation is None:
            raise ValueError("recoveries need a RouteEvaluationCallback: pass evaluation=... to RoadClosureCallback")
        evaluation = self.evaluation
        return measure_recoveries(
            self.records,
            evaluation.evaluations,
            evaluation.success_threshold,
            evaluation.spl_threshold,
            evaluation.every_goal,
        )

    @property
    def graph(self) -> NavigationGraph:
        """This callback's copy of the training envs' navigation graph (their closures, mirrored)."""
        if self._graph is None:
            raise ValueError("the callback is not initialised: it learns the map when training starts")
        return self._graph

    def init_callback(self, model: Any) -> None:
        super().init_callback(model)
        if self.evaluation is None:
            self._progress.init_callback(model)

    def _init_callback(self) -> None:
        env = self.training_env
        goals = env.get_attr("goal_nodes")[0]
        self._protect = list(goals)
        # A copy: with DummyVecEnv get_attr hands out the env's own graph, which only env_method may change
        self._graph = env.get_attr("graph")[0].copy()
        # Events still to come (a later learn() call continues the schedule), checked against the map as it is now
        ClosureSchedule(self._pending).validate(self._graph, self._protect)

    def _on_training_start(self) -> None:
        super()._on_training_start()
        if self.evaluation is None:
            self._progress.on_training_start(self.locals, self.globals)

    def on_training_end(self) -> None:
        if self.callback is not None:
            self.callback.on_training_end()
        else:
            self._progress.on_training_end()
        super().on_training_end()

    def update_child_locals(self, locals_: dict[str, Any]) -> None:
        super().update_child_locals(locals_)
        if self.evaluation is None:
            self._progress.update_locals(locals_)

    def _on_rollout_end(self) -> None:
        # SB3's EventCallback passes no rollout end on: the evaluation needs it to know when the model trains
        if self.callback is not None:
            self.callback.on_rollout_end()

    def _on_step(self) -> bool:
        continue_training = self._on_event() if self.evaluation is not None else self._progress.on_step()
        while self._pending and self._due(self._pending[0]):
            self.apply(self._pending.pop(0))
        # Every evaluation since the closure belongs to its window (the first one was made right after it)
        recovering, evaluation = self._recovering, self.evaluation
        if recovering is not None and evaluation and len(evaluation.evaluations) > recovering.evaluation_index:
            latest = evaluation.evaluations[-1]
            if latest.meets(evaluation.success_threshold, evaluation.spl_threshold, evaluation.every_goal):
                self._log_recovery(recovering, latest)
        return continue_training

    def _due(self, event: ClosureEvent) -> bool:
        progress = self._progress.episodes if event.unit == "episode" else self._progress.steps
        return progress >= event.at

    def apply(self, event: ClosureEvent) -> ClosureRecord:
        """
        Apply an event now (scheduled events are applied when due; call this for a closure of your own between or
        during ``learn`` calls).

        :return: what was closed, reopened and refused
        """
        graph = self.graph
        refused: list[tuple[str, str]] = []
        closed: list[tuple[int, int]] = []
        reopened: list[tuple[int, int]] = []
        if event.close_on_route is not None:
            road = self._road_on_route(event, refused)
            if road is not None:
                graph.close_road(*road, protect=self._protect)
                closed.append(road)
        else:
            try:
                closed, reopened = apply_fixed_event(graph, event, self._protect)
            except (KeyError, ValueError) as error:  # RoadClosureError is a ValueError
                refused.append((event.describe(), str(error.args[0] if isinstance(error, KeyError) else error)))
        # The routes the closure interrupts: those of the last evaluation (made just now for a route closure)
        before = self.evaluation.evaluations[-1] if self.evaluation and self.evaluation.evaluations else None
        for road in closed:
            self._everywhere("close_road", road, force=True)  # already checked on the mirror
        for road in reopened:
            self._everywhere("reopen_road", road)
        affected = None
        if before is not None and closed:
            closed_set = set(closed)
            affected = sum(bool(closed_set & set(road_usage([r.nodes]))) for r in before.report.routes)
        record = ClosureRecord(
            description=event.describe(),
            step=self.model.num_timesteps,
            episode=self._progress.episodes,
            train_seconds=self._progress.train_seconds,
            closed=tuple(closed),
            reopened=tuple(reopened),
            refused=tuple(refused),
            evaluation_index=len(self.evaluation.evaluations) if self.evaluation else 0,
            routes_affected=affected,
        )
        self.records.append(record)
        self._log_event(record)
        if record.changed and self.evaluation is not None:
            if self._recovering is not None:
                self._log_not_recovered(self._recovering)
            self._recovering = record
            self.evaluation.evaluate()  # right after the closure, before any more training
            self.evaluation.dense(self.recovery_eval_freq)
        return record

    def _road_on_route(self, event: ClosureEvent, refused: list[tuple[str, str]]) -> tuple[int, int] | None:
        if self.evaluation is None or self.evaluation.eval_env is None:
            refused.append((event.describe(), "closing a road on the route needs a RouteEvaluationCallback"))
            return None
        routes = self.evaluation.evaluate().report.routes  # the current greedy routes
        if event.close_on_route == "busiest":
            road = busiest_road(self.graph, [r.nodes for r in routes], self._protect)
        else:
            # The longest of the start's routes (its headings may differ): the one with the most roads to choose from
            from_start = [r.nodes for r in routes if r.start == int(event.close_on_route)]
            road = first_road_on_route(self.graph, max(from_start, key=len), self._protect) if from_start else None
        if road is None:
            refused.append((event.describe(), "no road on the current route can be closed without cutting a goal off"))
        return road

    def _everywhere(self, method: str, road: tuple[int, int], **kwargs: Any) -> None:
        self.training_env.env_method(method, *road, **kwargs)
        evaluation = self.evaluation
        if evaluation is not None and evaluation.eval_env is not None and not evaluation.shares_training_env:
            getattr(evaluation.eval_env, method)(*road, **kwargs)

    def _log_event(self, record: ClosureRecord) -> None:
        self.logger.record("closure/events", len(self.records))
        self.logger.record("closure/closed_roads", len(self.graph.closed_roads))
        self.logger.record("closure/refused", sum(len(r.refused) for r in self.records))
        if record.routes_affected is not None:
            self.logger.record("closure/routes_affected", record.routes_affected)
        self.logger.dump(self.model.num_timesteps)
        if self.verbose >= 1:
            roads = ", ".join(f"{u}-{v}" for u, v in record.closed) or "-"
            again = ", ".join(f"{u}-{v}" for u, v in record.reopened) or "-"
            refused = "; ".join(f"{what}: {why}" for what, why in record.refused)
            print(
                f"[closure] {record.description}: closed {roads}, reopened {again}"
                + (f", refused {refused}" if refused else ""),
                flush=True,
            )

    def _log_recovery(self, closure: ClosureRecord, at: RouteEvaluation) -> None:
        self._recovering = None
        assert self.evaluation is not None
        self.evaluation.dense(None)
        self.logger.record("closure/recovered", 1)
        self.logger.record("closure/recovery_episodes", at.episode - closure.episode)
        self.logger.record("closure/recovery_steps", at.step - closure.step)
        self.logger.record("closure/recovery_seconds", at.train_seconds - closure.train_seconds)
        self.logger.dump(self.model.num_timesteps)
        if self.verbose >= 1:
            print(
                f"[closure] recovered from '{closure.description}' after {at.episode - closure.episode} episodes, "
                f"{at.step - closure.step} steps, {at.train_seconds - closure.train_seconds:.1f} s",
                flush=True,
            )

    def _log_not_recovered(self, closure: ClosureRecord) -> None:
        self.logger.record("closure/recovered", 0)
        self.logger.dump(self.model.num_timesteps)
        if self.verbose >= 1:
            print(f"[closure] not recovered from '{closure.description}' before the next event", flush=True)


class StartCurriculumCallback(BaseCallback):
    """
    A near-to-far start curriculum (StreetLearn's goal curriculum, Mirowski et al. 2018): episodes start within a
    limit of hops of the goal (:attr:`~campusnav_env.env.CampusNavEnv.start_distance_limit`), and the limit widens
    each time the agent succeeds often enough, until starts may lie anywhere on the map. The agent never sees the
    distances; only where its episodes begin changes.

    The limit begins at ``initial`` when training starts. Each episode end (from the ``is_success`` of its last info;
    an episode ended without one, e.g. by a ``TimeLimit`` wrapper, counts as a failure) joins a window of the last
    ``window`` episodes ended since the last widening. When that window is full and its success rate reaches
    ``success_threshold``, the limit grows multiplicatively, by at least one hop:
    ``limit <- max(limit + 1, ceil(limit * growth))``, and the window empties. Once the limit reaches the longest
    shortest route to the goals (:meth:`~campusnav_env.env.CampusNavEnv.longest_route`, read from the envs at each
    widening, so closures count) it becomes ``None``: the whole map, and the curriculum is over. Every training env
    gets the same limit (``VecEnv.env_method("set_start_distance_limit", ...)``, which reaches the env through
    wrappers and subprocesses); it applies from each env's next reset. A later ``learn()`` goes on from the current
    limit.

    Logs ``curriculum/start_distance_limit`` (the map's longest route once the limit is ``None``) and
    ``curriculum/success_rate`` (over the current window) to SB3's logger.

    Example::

        env = make_vec_env("CampusNavCity-v0", n_envs=4, env_kwargs=dict(view_dim=64))
        curriculum = StartCurriculumCallback(initial=2, growth=1.5, success_threshold=0.8, window=50)
        DCQN("MultiInputPolicy", env).learn(500_000, callback=curriculum)

    :param initial: The first limit, in hops (at least 1)
    :param growth: Widening factor (more than 1); 2.0 doubles the limit at each widening
    :param success_threshold: Success rate over the window at which the limit widens, in ``(0, 1]``
    :param window: Episodes ended since the last widening that the success rate is measured over (at least 1)
    :param verbose: 1 prints a line at each widening
    """

    def __init__(
        self,
        initial: int = 2,
        growth: float = 1.5,
        success_threshold: float = 0.8,
        window: int = 50,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose)
        if isinstance(initial, bool) or not isinstance(initial, (int, np.integer)) or initial < 1:
            raise ValueError(f"initial must be an int of at least 1 hop, got {initial!r}")
        if not (math.isfinite(growth) and growth > 1.0):
            raise ValueError(f"growth must be a finite factor above 1, got {growth}")
        if not 0.0 < success_threshold <= 1.0:
            raise ValueError(f"success_threshold must lie in (0, 1], got {success_threshold}")
        if window < 1:
            raise ValueError(f"window must be at least 1 episode, got {window}")
        self.initial = int(initial)
        self.growth = float(growth)
        self.success_threshold = float(success_threshold)
        self.window = int(window)
        self.widenings: list[tuple[int, int | None]] = []  # (timestep, new limit) per widening
        self._limit: int | None = self.initial
        self._started = False
        self._outcomes: deque[bool] = deque(maxlen=self.window)
        self._map_longest_route = 0  # as last read from the envs

    @property
    def start_distance_limit(self) -> int | None:
        """The limit the training envs have now (``None``: the whole map)."""
        return self._limit

    @property
    def finished(self) -> bool:
        """Whether starts may lie anywhere (the curriculum is over)."""
        return self._started and self._limit is None

    def _on_training_start(self) -> None:
        if not self._started:
            self._started = True
            if self.initial >= self._longest_route():
                self._limit = None
        self._apply()  # also after set_env: the envs may be new

    def _on_step(self) -> bool:
        dones, infos = self.locals.get("dones"), self.locals.get("infos")
        if dones is not None and infos is not None and self._limit is not None:
            for done, info in zip(dones, infos, strict=True):
                if done:
                    self._outcomes.append(bool(info.get("is_success", False)))
            if len(self._outcomes) == self.window and np.mean(self._outcomes) >= self.success_threshold:
                self._widen()
        self.logger.record("curriculum/start_distance_limit", self._logged_limit())
        if self._outcomes:
            self.logger.record("curriculum/success_rate", float(np.mean(self._outcomes)))
        return True

    def _widen(self) -> None:
        assert self._limit is not None
        wider = max(self._limit + 1, math.ceil(self._limit * self.growth))
        self._limit = None if wider >= self._longest_route() else wider
        self._outcomes.clear()
        self.widenings.append((self.num_timesteps, self._limit))
        self._apply()
        if self.verbose >= 1:
            where = "anywhere" if self._limit is None else f"within {self._limit} hops of the goal"
            print(f"[curriculum] step {self.num_timesteps}: starts {where}", flush=True)

    def _apply(self) -> None:
        self.training_env.env_method("set_start_distance_limit", self._limit)

    def _longest_route(self) -> int:
        self._map_longest_route = max(self.training_env.env_method("longest_route"))
        return self._map_longest_route

    def _logged_limit(self) -> int:
        return self._map_longest_route if self._limit is None else self._limit
