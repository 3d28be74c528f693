"""Hindsight relabelling for DCQN: SB3's ``HerReplayBuffer`` with terminal relabelled goals and held-out goals.

SB3's ``HerReplayBuffer`` gives a relabelled transition the ``done`` of the original episode (SB3 issue #627). A
transition relabelled with a goal it reached then bootstraps past the goal (``r + gamma * max Q(s', .)`` where the
episode would have ended), and one taken from the last step of an episode that reached its own goal is terminal under
a goal it did not reach. :class:`DCQNHerReplayBuffer` asks the env instead: a relabelled transition is terminal where
``env.compute_terminated(next_achieved_goal, new_goal, info)`` says so (the Gymnasium-Robotics ``GoalEnv``
interface). Envs without ``compute_terminated`` keep SB3's behaviour, with a warning.

It also keeps, per transition, just the info entries the env's ``compute_reward`` reads (``env.reward_info_keys``,
e.g. a collision flag) instead of deep copies of whole info dicts (``copy_info_dict``), and it never relabels with a
goal for which ``env.relabelling_allowed(goals)`` is false (goals held out of training: the new goal is drawn again
from the episode's future, up to ``relabel_tries`` times, and the transition keeps its own goal if none is allowed).

Variants: experience revision (:class:`~sb3_dcqn.replay.revision.RevisionReplay`: here the goal is left out of "the
same observation", the stored next observation gets the new one's physical keys, its own desired goal kept, and its
reward and termination are computed anew for its own goal with ``compute_reward`` / ``compute_terminated``: every
goal a stored transition is relabelled with then sees the road as it is now) and lean storage
(:class:`~sb3_dcqn.replay.lean.LeanReplay`), e.g. ``RevisionHerReplayBuffer``, ``LeanRevisionHerReplayBuffer``
(:func:`~sb3_dcqn.replay.replay_buffer_class`).

**DCQN serves SB3's ``HerReplayBuffer`` with this class.** ``DCQN(..., replay_buffer_class=HerReplayBuffer)`` builds
a ``DCQNHerReplayBuffer`` with the same arguments (``model.replay_buffer_class`` and ``type(model.replay_buffer)``
show it, ``model.replay_buffer.terminal_relabels`` says which dones it computes); ``replay_buffer_kwargs=
dict(terminal_relabels=False)`` restores SB3's dones, to measure what the fix does. DQN with SB3's ``HerReplayBuffer``
keeps SB3's dones.
"""

from __future__ import annotations

import copy
import warnings
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.type_aliases import DictReplayBufferSamples
from stable_baselines3.common.vec_env import VecEnv, VecNormalize
from stable_baselines3.her.goal_selection_strategy import GoalSelectionStrategy
from stable_baselines3.her.her_replay_buffer import HerReplayBuffer

from sb3_dcqn.replay.base import observation_bytes
from sb3_dcqn.replay.feedback import TrainingFeedback

__all__ = ["DCQNHerReplayBuffer"]


class DCQNHerReplayBuffer(TrainingFeedback, HerReplayBuffer):
    """
    SB3's ``HerReplayBuffer`` with relabelled transitions made terminal where they reach their new goal, the info
    entries ``compute_reward`` needs kept per transition, and goals that may not be relabelling targets left out (see
    the module docstring).

    :param buffer_size: Max number of element in the buffer
    :param observation_space: Observation space (a goal-env Dict)
    :param action_space: Action space
    :param env: The training environment
    :param device: PyTorch device
    :param n_envs: Number of parallel environments
    :param optimize_memory_usage: Not supported (as in SB3's HER)
    :param handle_timeout_termination: Handle timeout termination (due to timelimit) separately and treat the task
        as infinite horizon task
    :param n_sampled_goal: Number of virtual transitions to create per real transition, by sampling new goals
    :param goal_selection_strategy: ``"future"``, ``"final"`` or ``"episode"``
    :param copy_info_dict: Keep whole info dicts (deep copies) for ``compute_reward``; by default only the entries
        named by ``env.reward_info_keys`` are kept
    :param terminal_relabels: Relabelled transitions are terminal where they reach their new goal (the env's
        ``compute_terminated``); ``False``: the original episode's done (SB3)
    :param relabel_tries: How many times a relabelled goal that the env does not allow is drawn again
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Dict,
        action_space: spaces.Space,
        env: VecEnv,
        device: Any = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        n_sampled_goal: int = 4,
        goal_selection_strategy: GoalSelectionStrategy | str = "future",
        copy_info_dict: bool = False,
        terminal_relabels: bool = True,
        relabel_tries: int = 8,
    ) -> None:
        super().__init__(
            buffer_size,
            observation_space,
            action_space,
            env,
            device=device,
            n_envs=n_envs,
            optimize_memory_usage=optimize_memory_usage,
            handle_timeout_termination=handle_timeout_termination,
            n_sampled_goal=n_sampled_goal,
            goal_selection_strategy=goal_selection_strategy,
            copy_info_dict=copy_info_dict,
        )
        if relabel_tries < 0:
            raise ValueError(f"relabel_tries must be >= 0, got {relabel_tries}")
        self.terminal_relabels = terminal_relabels
        self.relabel_tries = relabel_tries
        self.reward_info_keys: tuple[str, ...] = () if copy_info_dict else tuple(_env_attr(env, "reward_info_keys", ()))
        self.reward_infos = {
            key: np.zeros((self.buffer_size, self.n_envs), dtype=np.float32) for key in self.reward_info_keys
        }
        self._terminated_fallback_warned = False

    def add(  # type: ignore[override]
        self,
        obs: dict[str, np.ndarray],
        next_obs: dict[str, np.ndarray],
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        pos = self.pos
        for key, values in self.reward_infos.items():  # before super().add moves ``pos`` on
            values[pos] = [float(info[key]) for info in infos]
        super().add(obs, next_obs, action, reward, done, infos)

    # ------------------------------------------------------------------ what a transition is (experience revision)
    def _physical_keys(self) -> list[str]:
        return sorted(key for key in self.observations if key != "desired_goal")

    def _transition_bytes(self, obs: dict[str, np.ndarray], action: np.ndarray, env: int) -> bytes:
        """The observation without its goal, and the action: one transition for every goal."""
        return observation_bytes(obs, env, self.observations, self._physical_keys()) + np.asarray(action)[env].tobytes()

    def _outcome_bytes(self, pos: int, env: int, arrival: bytes | None = None) -> bytes:
        """Where the agent ended up (every key but the goal, or the place a route memory names: ``arrival``); the
        reward is each goal's own."""
        if arrival is not None:
            return arrival
        return b"".join(self.next_observations[k][pos, env].tobytes() for k in self._physical_keys())

    def _stay_in_place(self, slots: np.ndarray) -> None:
        """The stored transitions in ``slots`` end where they started (their physical keys), as a bump's do."""
        rows, envs = np.divmod(slots, self.n_envs)
        for k in self._physical_keys():
            self.next_observations[k][rows, envs] = self.observations[k][rows, envs]

    def _copy_outcome(self, slots: np.ndarray, pos: int, env: int) -> None:
        """Give the stored transitions in ``slots`` the outcome of ``(pos, env)``, each for its own goal."""
        rows, envs = np.divmod(slots, self.n_envs)
        for k in self._physical_keys():
            self.next_observations[k][rows, envs] = self.next_observations[k][pos, env]
        for values in self.reward_infos.values():
            values[rows, envs] = values[pos, env]
        assert self.env is not None
        goals = self.observations["desired_goal"][rows, envs]
        achieved = np.repeat(self.next_observations["achieved_goal"][pos, env][None], len(slots), axis=0)
        infos = self._reward_infos(rows, envs)
        rewards = self.env.env_method("compute_reward", achieved, goals, infos, indices=[0])[0]
        self.rewards[rows, envs] = np.asarray(rewards, dtype=np.float32).reshape(-1)
        if _env_has(self.env, "compute_terminated"):
            terminated = np.asarray(self.env.env_method("compute_terminated", achieved, goals, infos, indices=[0])[0])
            terminated = terminated.reshape(-1).astype(np.float32)
            # A time limit stays a time limit; a transition that now ends its episode's task is a real termination
            self.dones[rows, envs] = np.maximum(terminated, self.timeouts[rows, envs])
            self.timeouts[rows, envs] = np.where(terminated > 0, 0.0, self.timeouts[rows, envs])

    def _get_virtual_samples(
        self,
        batch_indices: np.ndarray,
        env_indices: np.ndarray,
        env: VecNormalize | None = None,
    ) -> DictReplayBufferSamples:
        obs = {key: obs[batch_indices, env_indices, :] for key, obs in self.observations.items()}
        next_obs = {key: obs[batch_indices, env_indices, :] for key, obs in self.next_observations.items()}
        infos = self._reward_infos(batch_indices, env_indices)
        new_goals = self._allowed_goals(batch_indices, env_indices)
        obs["desired_goal"] = new_goals
        next_obs["desired_goal"] = new_goals  # the goal does not change within a transition

        assert self.env is not None, "HER needs the VecEnv to compute the rewards of relabelled transitions"
        # r_t depends on s_{t+1}: the next achieved goal against the new goal
        rewards = self.env.env_method("compute_reward", next_obs["achieved_goal"], new_goals, infos, indices=[0])[0]
        dones = self._relabelled_dones(batch_indices, env_indices, next_obs["achieved_goal"], new_goals, infos)
        obs = self._normalize_obs(obs, env)  # type: ignore[assignment]
        next_obs = self._normalize_obs(next_obs, env)  # type: ignore[assignment]
        return DictReplayBufferSamples(
            observations={key: self.to_torch(value) for key, value in obs.items()},
            actions=self.to_torch(self.actions[batch_indices, env_indices]),
            next_observations={key: self.to_torch(value) for key, value in next_obs.items()},
            dones=self.to_torch(dones).reshape(-1, 1),
            rewards=self.to_torch(self._normalize_reward(np.asarray(rewards, np.float32).reshape(-1, 1), env)),
        )

    def _reward_infos(self, batch_indices: np.ndarray, env_indices: np.ndarray) -> Any:
        if self.copy_info_dict:
            return copy.deepcopy(self.infos[batch_indices, env_indices])
        columns = {key: values[batch_indices, env_indices] for key, values in self.reward_infos.items()}
        return [{key: column[i] for key, column in columns.items()} for i in range(len(batch_indices))]

    def _allowed_goals(self, batch_indices: np.ndarray, env_indices: np.ndarray) -> np.ndarray:
        """New goals from the episodes' future (SB3's strategies), none of them one the env does not allow."""
        goals = self._sample_goals(batch_indices, env_indices)
        if self.env is None or not _env_has(self.env, "relabelling_allowed"):
            return goals
        pending = np.arange(len(batch_indices))
        for _ in range(self.relabel_tries + 1):
            allowed = np.asarray(self.env.env_method("relabelling_allowed", goals[pending], indices=[0])[0], dtype=bool)
            pending = pending[~allowed]
            if pending.size == 0:
                return goals
            goals[pending] = self._sample_goals(batch_indices[pending], env_indices[pending])
        # Still not allowed: the transition keeps the goal it was collected with (never a held-out one)
        goals[pending] = self.observations["desired_goal"][batch_indices[pending], env_indices[pending]]
        return goals

    def _relabelled_dones(
        self,
        batch_indices: np.ndarray,
        env_indices: np.ndarray,
        next_achieved: np.ndarray,
        new_goals: np.ndarray,
        infos: Any,
    ) -> np.ndarray:
        original = self.dones[batch_indices, env_indices] * (1 - self.timeouts[batch_indices, env_indices])
        if not self.terminal_relabels:
            return original
        assert self.env is not None
        if not _env_has(self.env, "compute_terminated"):
            if not self._terminated_fallback_warned:
                warnings.warn(
                    "terminal_relabels: the env has no compute_terminated(achieved_goal, desired_goal, info); "
                    "relabelled transitions keep the original episode's done (SB3 issue #627)",
                    stacklevel=2,
                )
                self._terminated_fallback_warned = True
            return original
        terminated = self.env.env_method("compute_terminated", next_achieved, new_goals, infos, indices=[0])[0]
        return np.asarray(terminated, dtype=np.float32).reshape(-1)


def _env_has(env: VecEnv, name: str) -> bool:
    return bool(env.has_attr(name)) if hasattr(env, "has_attr") else hasattr(env, name)


def _env_attr(env: VecEnv | None, name: str, default: Any) -> Any:
    if env is None or not _env_has(env, name):
        return default
    return env.get_attr(name, indices=[0])[0]
