"""DCQN: double-critic deep Q-learning (Han & Yilmaz), as a Stable-Baselines3 off-policy algorithm."""

from __future__ import annotations

import warnings
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.utils import LinearSchedule, get_parameters_by_name, polyak_update
from stable_baselines3.her.her_replay_buffer import HerReplayBuffer
from torch.nn import functional as F

from sb3_dcqn.buffers import DCQNDictReplayBuffer, DCQNReplayBuffer
from sb3_dcqn.her_buffer import DCQNHerReplayBuffer
from sb3_dcqn.policies import CnnPolicy, DCQNPolicy, MlpPolicy, MultiInputPolicy, TwinQNetwork
from sb3_dcqn.replay_graph import ReplaySearchPolicy
from sb3_dcqn.targets import blocked_actions, dcqn_td_target

SelfDCQN = TypeVar("SelfDCQN", bound="DCQN")

# The statistics of the last batch of each ``train`` call, gathered in one tensor (one sync instead of one per value)
_STAT_NAMES = ("q_mean", "q_abs_diff", "target_q_mean")


class DCQN(OffPolicyAlgorithm):
    """
    Double-Critic Deep Q-Network (DCQN)

    Paper: Han & Yilmaz, "Dynamic Routing for Navigation in Changing Unknown Maps Using Deep Reinforcement Learning".
    DQN with two online critics and two target critics. Both critics regress (Huber loss, summed) to the same target
    ``r + gamma * (1 - done) * max_a' min(Q1'(s', a'), Q2'(s', a'))``. The greedy action maximises the mean of the
    two online critics, in ``predict``, in evaluation and in epsilon-greedy exploration alike: ``model.q_net(obs)``
    returns that mean, shape ``(batch, n_actions)`` as DQN's ``q_net`` does, and ``model.q_net.critic_values(obs)``
    every critic's values, ``(n_critics, batch, n_actions)`` (likewise ``q_net_target``). The critics' MLPs (and
    the targets') are evaluated in one batched forward pass; a features extractor with parameters is shared by the
    critics (``policy_kwargs=dict(share_features_extractor=True)``) or run once per critic (the default).

    The paper's settings are ``learning_rate=1e-4, gamma=0.95, buffer_size=412`` with Adam; the defaults below are
    SB3 DQN's, so that DCQN is a drop-in replacement.

    :param policy: The policy model to use (MlpPolicy, CnnPolicy, MultiInputPolicy, ...)
    :param env: The environment to learn from (if registered in Gym, can be str)
    :param learning_rate: The learning rate, it can be a function
        of the current progress remaining (from 1 to 0)
    :param buffer_size: size of the replay buffer
    :param learning_starts: how many steps of the model to collect transitions for before learning starts
    :param batch_size: Minibatch size for each gradient update
    :param tau: the soft update coefficient ("Polyak update", between 0 and 1) default 1 for hard update
    :param gamma: the discount factor
    :param train_freq: Update the model every ``train_freq`` steps. Alternatively pass a tuple of frequency and unit
        like ``(5, "step")`` or ``(2, "episode")``.
    :param gradient_steps: How many gradient steps to do after each rollout (see ``train_freq``)
        Set to ``-1`` means to do as many gradient steps as steps done in the environment
        during the rollout.
    :param replay_buffer_class: Replay buffer class to use (for instance ``HerReplayBuffer``).
        If ``None``, it will be automatically selected. ``HerReplayBuffer`` is served by
        :class:`~sb3_dcqn.her_buffer.DCQNHerReplayBuffer` (same arguments): relabelled transitions that reach their
        new goal are terminal (``replay_buffer_kwargs=dict(terminal_relabels=False)`` for SB3's dones) and goals
        the env does not allow as relabelling targets are never used
    :param replay_buffer_kwargs: Keyword arguments to pass to the replay buffer on creation.
    :param optimize_memory_usage: Enable a memory efficient variant of the replay buffer
        at a cost of more complexity.
    :param n_steps: When n_step > 1, uses n-step return when updating the critics: SB3's ``NStepReplayBuffer`` for
        Box observations, :class:`~sb3_dcqn.buffers.DCQNDictReplayBuffer` for Dict observations (SB3 has none);
        not with hindsight relabelling, experience revision, prioritised replay or ``blocked_action_target``
    :param target_update_interval: update the target critics every ``target_update_interval``
        environment steps.
    :param exploration_fraction: fraction of entire training period over which the exploration rate is reduced
    :param exploration_initial_eps: initial value of random action probability
    :param exploration_final_eps: final value of random action probability
    :param max_grad_norm: The maximum value for the gradient clipping
    :param experience_revision: Relabel stored transitions that the agent's new experience contradicts (a collision
        where a stored transition of the same observation and action drove on: a closed road), see
        :mod:`sb3_dcqn.buffers` (with ``HerReplayBuffer``: :mod:`sb3_dcqn.her_buffer`, the goal left out of the
        match). Off by default: the paper's agent keeps its stale experience
    :param prioritized_replay: Replay transitions in proportion to their TD error, importance-weighted (Schaul et al.
        2016); ``beta`` is annealed to 1 over training. Off by default
    :param lean_replay: Store each distinct observation vector once per Dict key and row indices per transition
        (:class:`~sb3_dcqn.buffers.DCQNDictReplayBuffer` or, with ``HerReplayBuffer``,
        :class:`~sb3_dcqn.her_buffer.DCQNHerReplayBuffer` with ``lean=True``): the same samples, a few tens of bytes
        per transition where observations repeat (CampusNav). Dict observations only. Off by default
    :param count_bonus: Exploration towards rarely seen observations: sampled rewards get
        ``count_bonus / sqrt(n(next observation))``, ``n`` the times that observation was added to the replay buffer
        (a count-based bonus, see :mod:`sb3_dcqn.buffers`). Dict observations, not with ``HerReplayBuffer``. 0 (off)
        by default
    :param replay_search: Greedy actions (``predict(..., deterministic=True)``: evaluation, routes) follow the shortest
        route stored in the replay buffer where it has one, the critics' greedy action elsewhere
        (:class:`~sb3_dcqn.replay_graph.ReplaySearchPolicy`, after SoRB, Eysenbach et al. 2019): routes longer than
        the critics can value yet, for a world whose observations repeat exactly (stored transitions are exact
        edges). The graph is read from the buffer when the model has trained since the last call, and is not saved
        with the model (a model loaded without its buffer acts on its critics). Exploration is unchanged. Off by
        default
    :param blocked_action_target: For a transition after which the observation did not change (a collision), leave
        the taken action out of the target's max (see :func:`blocked_actions`): a blocked action's value falls below
        the open roads' in one update instead of shrinking by ``gamma`` per target update. Off by default (the
        paper's target)
    :param pessimistic_target: Bootstrap from the element-wise minimum of the target critics (DCQN's target, the
        default). ``False`` is an ablation: the target takes the first target critic's values instead of the minimum
        (both online critics still regress to that shared target, and acting still maximises the mean of the
        critics), to measure what the minimum does against over-estimation
    :param stats_window_size: Window size for the rollout logging, specifying the number of episodes to average
        the reported success rate, mean episode length, and mean reward over
    :param tensorboard_log: the log location for tensorboard (if None, no logging)
    :param policy_kwargs: additional arguments to be passed to the policy on creation
        (e.g. ``net_arch``, ``n_critics``, ``share_features_extractor``, ``features_extractor_class``)
    :param verbose: Verbosity level: 0 for no output, 1 for info messages (such as device or wrappers used), 2 for
        debug messages
    :param seed: Seed for the pseudo random generators
    :param device: Device (cpu, cuda, ...) on which the code should be run.
        Setting it to auto, the code will be run on the GPU if possible.
    :param _init_setup_model: Whether or not to build the network at the creation of the instance
    """

    # Replay buffers asked for that DCQN serves with its own subclass (same arguments)
    replay_buffer_substitutes: ClassVar[dict[type[ReplayBuffer], type[ReplayBuffer]]] = {
        HerReplayBuffer: DCQNHerReplayBuffer
    }
    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        "MlpPolicy": MlpPolicy,
        "CnnPolicy": CnnPolicy,
        "MultiInputPolicy": MultiInputPolicy,
    }
    # Linear schedule will be defined in `_setup_model()`
    exploration_schedule: Schedule
    q_net: TwinQNetwork
    q_net_target: TwinQNetwork
    policy: DCQNPolicy

    def __init__(
        self,
        policy: str | type[DCQNPolicy],
        env: GymEnv | str,
        learning_rate: float | Schedule = 1e-4,
        buffer_size: int = 1_000_000,
        learning_starts: int = 100,
        batch_size: int = 32,
        tau: float = 1.0,
        gamma: float = 0.99,
        train_freq: int | tuple[int, str] = 4,
        gradient_steps: int = 1,
        replay_buffer_class: type[ReplayBuffer] | None = None,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        optimize_memory_usage: bool = False,
        n_steps: int = 1,
        target_update_interval: int = 10000,
        exploration_fraction: float = 0.1,
        exploration_initial_eps: float = 1.0,
        exploration_final_eps: float = 0.05,
        max_grad_norm: float = 10,
        experience_revision: bool = False,
        prioritized_replay: bool = False,
        lean_replay: bool = False,
        count_bonus: float = 0.0,
        replay_search: bool = False,
        blocked_action_target: bool = False,
        pessimistic_target: bool = True,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        super().__init__(
            policy,
            env,
            learning_rate,
            buffer_size,
            learning_starts,
            batch_size,
            tau,
            gamma,
            train_freq,
            gradient_steps,
            action_noise=None,  # No action noise: exploration is epsilon-greedy
            replay_buffer_class=replay_buffer_class,
            replay_buffer_kwargs=replay_buffer_kwargs,
            optimize_memory_usage=optimize_memory_usage,
            n_steps=n_steps,
            policy_kwargs=policy_kwargs,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            verbose=verbose,
            device=device,
            seed=seed,
            sde_support=False,
            supported_action_spaces=(spaces.Discrete,),
            support_multi_env=True,
        )

        self.exploration_initial_eps = exploration_initial_eps
        self.exploration_final_eps = exploration_final_eps
        self.exploration_fraction = exploration_fraction
        self.target_update_interval = target_update_interval
        # For updating the target critics with multiple envs
        self._n_calls = 0
        self.max_grad_norm = max_grad_norm
        # "epsilon" for the epsilon-greedy exploration
        self.exploration_rate = 0.0
        self.experience_revision = experience_revision
        self.prioritized_replay = prioritized_replay
        self.lean_replay = lean_replay
        self.count_bonus = count_bonus
        self.replay_search = replay_search
        self._search: ReplaySearchPolicy | None = None
        self._search_buffer: ReplayBuffer | None = None  # the buffer the search reads (a loaded one replaces it)
        self.blocked_action_target = blocked_action_target
        self.pessimistic_target = pessimistic_target
        if blocked_action_target and n_steps > 1:
            raise ValueError(
                "blocked_action_target needs one-step transitions (n_steps=1): with n_steps > 1 an "
                "unchanged observation after n steps does not mean the first action was blocked"
            )

        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        if self.replay_buffer_class is not None:
            self.replay_buffer_class = self.replay_buffer_substitutes.get(
                self.replay_buffer_class, self.replay_buffer_class
            )
        own_n_steps = self._select_dcqn_buffer()
        with warnings.catch_warnings():
            if own_n_steps:  # SB3 warns that n_steps goes unused with a given buffer class: DCQN's buffer takes it
                warnings.filterwarnings("ignore", message=r"`n_steps=\d+` is ignored")
            super()._setup_model()
        self._beta0 = getattr(self.replay_buffer, "beta", 1.0)
        self._create_aliases()
        # Copy running stats, see SB3 GH issue #996
        self.batch_norm_stats = get_parameters_by_name(self.q_net, ["running_"])
        self.batch_norm_stats_target = get_parameters_by_name(self.q_net_target, ["running_"])
        self.exploration_schedule = LinearSchedule(
            self.exploration_initial_eps,
            self.exploration_final_eps,
            self.exploration_fraction,
        )
        if self.n_envs > 1 and self.n_envs > self.target_update_interval:
            warnings.warn(
                "The number of environments used is greater than the target network "
                f"update interval ({self.n_envs} > {self.target_update_interval}), "
                "therefore the target critics will be updated after each call to env.step() "
                f"which corresponds to {self.n_envs} steps."
            )

    def _select_dcqn_buffer(self) -> bool:
        """
        Use DCQN's replay buffer matching the observation space where a flag asks for it (revision, priorities,
        lean storage, count bonus) or SB3 has none (n-step returns with Dict observations), configured by the flags.

        :return: whether DCQN's buffer computes the n-step returns (``n_steps`` passed to it)
        """
        is_dict = isinstance(self.observation_space, spaces.Dict)
        given = self.replay_buffer_class
        is_her = given is not None and issubclass(given, DCQNHerReplayBuffer)
        if is_her and self.n_steps > 1:
            raise ValueError("n-step returns (n_steps > 1) do not combine with hindsight relabelling (HerReplayBuffer)")
        readaptation = self.experience_revision or self.prioritized_replay
        dict_options = self.lean_replay or self.count_bonus > 0
        dict_n_steps = is_dict and self.n_steps > 1 and (given is None or issubclass(given, DCQNDictReplayBuffer))
        if not (readaptation or dict_options or dict_n_steps):
            return False
        if readaptation and self.n_steps > 1:
            raise ValueError("experience_revision and prioritized_replay do not support n-step returns (n_steps > 1)")
        if dict_options and not is_dict:
            raise ValueError(
                "lean_replay and count_bonus need a Dict observation space (they store and count each key's "
                f"vectors), got {type(self.observation_space).__name__}"
            )
        lean = {"lean": True} if self.lean_replay else {}
        if is_her:
            if self.prioritized_replay:
                raise ValueError(
                    "prioritized_replay does not combine with hindsight relabelling (HerReplayBuffer): a stored "
                    "transition stands for every goal it is relabelled with, its TD error for none of them"
                )
            if self.count_bonus > 0:
                raise ValueError("count_bonus does not combine with hindsight relabelling (HerReplayBuffer)")
            revision = {"revise_experience": True} if self.experience_revision else {}
            self.replay_buffer_kwargs = {**self.replay_buffer_kwargs, **revision, **lean}
            return False
        if given is None:
            self.replay_buffer_class = DCQNDictReplayBuffer if is_dict else DCQNReplayBuffer
        elif not issubclass(given, (DCQNReplayBuffer, DCQNDictReplayBuffer)):
            raise ValueError(
                "experience_revision, prioritized_replay, lean_replay and count_bonus need DCQNReplayBuffer or "
                f"DCQNDictReplayBuffer, got replay_buffer_class={given.__name__} (or HerReplayBuffer, for "
                "experience_revision and lean_replay)"
            )
        kwargs: dict[str, Any] = {**lean}
        if readaptation:
            kwargs.update(revise_experience=self.experience_revision, prioritized=self.prioritized_replay)
        if self.count_bonus > 0:
            kwargs.update(count_bonus=self.count_bonus)
        if dict_n_steps:
            kwargs.update(n_steps=self.n_steps, gamma=self.gamma)
        self.replay_buffer_kwargs = {**self.replay_buffer_kwargs, **kwargs}
        return dict_n_steps

    def _create_aliases(self) -> None:
        self.q_net = self.policy.q_net
        self.q_net_target = self.policy.q_net_target

    def _on_step(self) -> None:
        """
        Update the exploration rate and the target critics if needed.

        This method is called in ``collect_rollouts()`` after each step in the environment.
        """
        self._n_calls += 1
        # Each call to step() corresponds to n_envs transitions
        if self._n_calls % max(self.target_update_interval // self.n_envs, 1) == 0:
            # Each target critic tracks its own online critic: parameters are stacked per critic in the same order
            polyak_update(self.q_net.parameters(), self.q_net_target.parameters(), self.tau)
            polyak_update(self.batch_norm_stats, self.batch_norm_stats_target, 1.0)

        self.exploration_rate = self.exploration_schedule(self._current_progress_remaining)
        self.logger.record("rollout/exploration_rate", self.exploration_rate)

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        # Switch to train mode (this affects batch norm / dropout)
        self.policy.set_training_mode(True)
        # Update learning rate according to schedule (and, with prioritised replay, the importance correction)
        self._update_learning_rate(self.policy.optimizer)
        self._update_importance_correction()

        losses = []
        for _ in range(gradient_steps):
            # Sample replay buffer
            replay_data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]

            with th.no_grad():
                target_q_values = self.td_target(replay_data)

            # Get current Q-values estimates of every critic, (n_critics, batch, n_actions)
            current_q_values = self.q_net.critic_values(replay_data.observations)
            # Retrieve the q-values for the actions from the replay buffer, (n_critics, batch, 1)
            action_index = replay_data.actions.long().expand(current_q_values.shape[0], -1, -1)
            current_q_values = th.gather(current_q_values, dim=2, index=action_index)

            loss = self.critic_loss(current_q_values, target_q_values, replay_data)
            losses.append(loss.detach())

            # Optimize the policy
            self.policy.optimizer.zero_grad()
            loss.backward()
            # Clip gradient norm
            th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
            self.policy.optimizer.step()

        # Increase update counter
        self._n_updates += gradient_steps

        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        if losses:
            self.logger.record("train/loss", th.stack(losses).mean().item())
            self._record_critic_statistics(current_q_values.detach(), target_q_values)
        if self.experience_revision:
            self.logger.record("train/revised_transitions", self.replay_buffer.revised)  # type: ignore[union-attr]

    def td_target(self, replay_data: Any) -> th.Tensor:
        """
        The TD target of a replay batch (see :func:`dcqn_td_target`): the minimum over the target critics, or the
        first one's values with ``pessimistic_target=False``; with ``blocked_action_target``, a transition that left
        the observation unchanged bootstraps from the best other action (:func:`blocked_actions`).

        :param replay_data: A batch sampled from the replay buffer
        :return: The target, shape ``(batch, 1)``
        """
        # For n-step replay, discount factor is gamma**n_steps (when no early termination)
        discounts = replay_data.discounts if replay_data.discounts is not None else self.gamma
        excluded = None
        if self.blocked_action_target:
            n_actions = int(self.action_space.n)  # type: ignore[attr-defined]
            excluded = blocked_actions(
                replay_data.observations, replay_data.next_observations, replay_data.actions, n_actions
            )
        next_q_values = self.q_net_target.critic_values(replay_data.next_observations)
        return dcqn_td_target(
            next_q_values, replay_data.rewards, replay_data.dones, discounts, excluded, self.pessimistic_target
        )

    def critic_loss(self, current_q_values: th.Tensor, target_q_values: th.Tensor, replay_data: Any) -> th.Tensor:
        """
        Huber loss of every critic against the shared target, summed over the critics.

        With prioritised replay each sample is weighted by its importance weight, and the batch's new TD errors
        (mean over the critics) become its priorities.

        :param current_q_values: The critics' values of the taken actions, shape ``(n_critics, batch, 1)``
        :param target_q_values: The TD target, shape ``(batch, 1)``
        :param replay_data: The batch (its importance ``weights`` and ``indices`` with prioritised replay)
        :return: The loss to minimise (a scalar)
        """
        n_critics = current_q_values.shape[0]
        targets = target_q_values.expand_as(current_q_values)
        if not self.prioritized_replay:
            # The mean over critics and samples times the number of critics: the sum of the critics' mean losses
            return n_critics * F.smooth_l1_loss(current_q_values, targets)
        per_sample = F.smooth_l1_loss(current_q_values, targets, reduction="none") * replay_data.weights
        td_errors = (current_q_values.detach() - targets).abs().mean(dim=0)
        self.replay_buffer.update_priorities(replay_data.indices, td_errors.cpu().numpy())  # type: ignore[union-attr]
        return n_critics * per_sample.mean()

    def _update_importance_correction(self) -> None:
        """Anneal prioritised replay's importance correction to full (beta = 1) by the end of training."""
        if self.prioritized_replay:
            elapsed = 1.0 - self._current_progress_remaining
            self.replay_buffer.beta = self._beta0 + (1.0 - self._beta0) * elapsed  # type: ignore[union-attr]

    def _record_critic_statistics(self, current_q_values: th.Tensor, target_q_values: th.Tensor) -> None:
        """Log the last batch's per-critic losses, mean Q, mean |Q1 - Q2| and mean target (one sync)."""
        targets = target_q_values.expand_as(current_q_values)
        critic_losses = F.smooth_l1_loss(current_q_values, targets, reduction="none").mean(dim=(1, 2))
        q_abs_diff = (current_q_values[0] - current_q_values[-1]).abs().mean()
        summary = th.cat([th.stack([current_q_values.mean(), q_abs_diff, target_q_values.mean()]), critic_losses])
        values = summary.cpu().numpy()
        for name, value in zip(_STAT_NAMES, values[: len(_STAT_NAMES)], strict=True):
            self.logger.record(f"train/{name}", float(value))
        for critic, value in enumerate(values[len(_STAT_NAMES) :], start=1):
            self.logger.record(f"train/critic_{critic}_loss", float(value))

    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """
        Overrides the base_class predict function to include epsilon-greedy exploration.

        :param observation: the input observation
        :param state: The last states (can be None, used in recurrent policies)
        :param episode_start: The last masks (can be None, used in recurrent policies)
        :param deterministic: Whether or not to return deterministic actions.
        :return: the model's action and the next state
            (used in recurrent policies)
        """
        if deterministic and self.replay_search and self.replay_buffer is not None:
            return self._replay_search_policy().predict(observation, state, episode_start, deterministic)
        if not deterministic and np.random.rand() < self.exploration_rate:
            if self.policy.is_vectorized_observation(observation):
                if isinstance(observation, dict):
                    n_batch = observation[next(iter(observation.keys()))].shape[0]
                else:
                    n_batch = observation.shape[0]
                action = np.array([self.action_space.sample() for _ in range(n_batch)])
            else:
                action = np.array(self.action_space.sample())
        else:
            action, state = self.policy.predict(observation, state, episode_start, deterministic)
        return action, state

    def learn(
        self: SelfDCQN,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str = "DCQN",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfDCQN:
        return super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )

    def _replay_search_policy(self) -> ReplaySearchPolicy:
        """The replay search over this model's buffer, brought up to date with what was stored since its last use."""
        if self._search is None or self._search_buffer is not self.replay_buffer:
            self._search = ReplaySearchPolicy(self, fallback=self.policy.predict)
            self._search_buffer = self.replay_buffer
        else:
            self._search.refresh()
        return self._search

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "q_net", "q_net_target", "_search", "_search_buffer"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts = ["policy", "policy.optimizer"]
        return state_dicts, []
