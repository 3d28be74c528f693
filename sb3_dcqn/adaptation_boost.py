"""A temporary exploration and replay-ratio boost when the world seems to have changed, as an SB3 callback.

After a road closes, an agent that has settled on its routes explores little (epsilon at its floor) and replays each
new transition a few times among thousands of stale ones. :class:`AdaptationBoost` raises both for a while when a
trigger fires: the replay buffer revised contradicted experience (``"revision"``, needs a replay buffer with
experience revision, :class:`~sb3_dcqn.replay.RevisionReplay`), the last episodes ran much longer than usual
(``"episode_length"``), or a training loss jumped above its running mean (``"td_error"``). It works with any SB3
off-policy algorithm with epsilon-greedy exploration (DCQN, DQN, QR-DQN)::

    model.learn(20_000, callback=AdaptationBoost(trigger="episode_length"))

What it does to recovery after closures is measured in ``benchmarks/closures_one_at_a_time.py`` (its results
file has the figures; they are not repeated here, where they would go stale). It is off unless passed, and is not
one of the demo's levers.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

__all__ = ["TRIGGERS", "AdaptationBoost", "BoostedSchedule"]

TRIGGERS = ("revision", "episode_length", "td_error")


class BoostedSchedule:
    """
    An exploration schedule with a floor that applies while ``active`` (kept picklable: a model saved mid-boost
    stores it as its ``exploration_schedule``).

    :param schedule: The algorithm's own schedule (progress remaining -> epsilon)
    :param floor: The epsilon floor while active
    """

    def __init__(self, schedule: Callable[[float], float], floor: float) -> None:
        self.schedule = schedule
        self.floor = floor
        self.active = False

    def __call__(self, progress_remaining: float) -> float:
        epsilon = self.schedule(progress_remaining)
        return max(epsilon, self.floor) if self.active else epsilon


class AdaptationBoost(BaseCallback):
    """
    Raise exploration (to at least ``exploration``) and the replay ratio (``replay_ratio`` times the gradient steps)
    for ``steps`` env steps each time the trigger fires.

    :param trigger: ``"revision"`` (the replay buffer's count of revised transitions grew), ``"episode_length"`` (the
        mean length of the last 5 episodes exceeds ``factor`` times that of the episode buffer, once it holds 20) or
        ``"td_error"`` (a training loss above ``factor`` times its running mean)
    :param exploration: Epsilon floor while boosted
    :param replay_ratio: Gradient steps per training call are multiplied by this while boosted
    :param steps: Env steps a boost lasts (a new trigger restarts it)
    :param factor: Threshold of the ``episode_length`` and ``td_error`` triggers
    :param verbose: Verbosity level
    """

    def __init__(
        self,
        trigger: str,
        exploration: float = 0.3,
        replay_ratio: int = 4,
        steps: int = 2000,
        factor: float = 2.0,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose)
        if trigger not in TRIGGERS:
            raise ValueError(f"AdaptationBoost: trigger must be one of {TRIGGERS}, got {trigger!r}")
        if not 0.0 <= exploration <= 1.0 or replay_ratio < 1 or steps < 1 or factor <= 0:
            raise ValueError(
                "AdaptationBoost: need 0 <= exploration <= 1, replay_ratio >= 1, steps >= 1 and factor > 0; got "
                f"exploration={exploration}, replay_ratio={replay_ratio}, steps={steps}, factor={factor}"
            )
        self.trigger = trigger
        self.exploration = exploration
        self.replay_ratio = int(replay_ratio)
        self.steps = int(steps)
        self.factor = factor
        self.boosts = 0  # how many times the trigger fired
        self._until = 0  # boosted while num_timesteps < _until
        self._base_gradient_steps = 1
        self._schedule: BoostedSchedule | None = None
        self._revised_seen = 0
        self._updates_seen = 0
        self._loss_average: float | None = None

    @property
    def boosted(self) -> bool:
        """Whether the boost is on now."""
        return self.num_timesteps < self._until

    def _on_training_start(self) -> None:
        model = self.model
        if not hasattr(model, "exploration_schedule"):
            raise ValueError(f"AdaptationBoost needs an epsilon-greedy algorithm, got {type(model).__name__}")
        if self.trigger == "revision" and not hasattr(model.replay_buffer, "revised"):
            raise ValueError(
                "AdaptationBoost(trigger='revision') needs a replay buffer with experience revision "
                f"(sb3_dcqn.replay's Revision... classes), got {type(model.replay_buffer).__name__}"
            )
        if self.replay_ratio > 1 and model.gradient_steps < 0:
            raise ValueError("AdaptationBoost: replay_ratio > 1 needs a fixed number of gradient_steps (not -1)")
        self._base_gradient_steps = model.gradient_steps
        self._schedule = BoostedSchedule(model.exploration_schedule, self.exploration)  # type: ignore[attr-defined]
        model.exploration_schedule = self._schedule  # type: ignore[attr-defined]
        self._revised_seen = getattr(model.replay_buffer, "revised", 0)
        self._updates_seen = model._n_updates

    def _on_step(self) -> bool:
        if self._triggered():
            self._until = self.num_timesteps + self.steps
            self.boosts += 1
        assert self._schedule is not None
        self._schedule.active = self.boosted
        self.model.gradient_steps = self._base_gradient_steps * (self.replay_ratio if self.boosted else 1)
        self.logger.record("train/boosted", float(self.boosted))
        return True

    def _on_training_end(self) -> None:
        # Leave the model as it was: its own schedule, its own replay ratio
        assert self._schedule is not None
        self.model.exploration_schedule = self._schedule.schedule  # type: ignore[attr-defined]
        self.model.gradient_steps = self._base_gradient_steps

    def _triggered(self) -> bool:
        model = self.model
        if self.trigger == "revision":
            revised = model.replay_buffer.revised  # type: ignore[union-attr]
            fired, self._revised_seen = revised > self._revised_seen, revised
            return fired
        if self.trigger == "episode_length":
            lengths = [info["l"] for info in model.ep_info_buffer or ()]
            return len(lengths) >= 20 and np.mean(lengths[-5:]) > self.factor * np.mean(lengths)
        # td_error: a new training loss well above its running mean means the world stopped matching the critics
        if model._n_updates == self._updates_seen or "train/loss" not in self.logger.name_to_value:
            return False
        self._updates_seen = model._n_updates
        loss = float(self.logger.name_to_value["train/loss"])
        fired = self._loss_average is not None and loss > self.factor * self._loss_average
        self._loss_average = loss if self._loss_average is None else 0.99 * self._loss_average + 0.01 * loss
        return fired
