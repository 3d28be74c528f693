"""DCQN: double-critic deep Q-learning (Han & Yilmaz), as a Stable-Baselines3 off-policy algorithm."""

from __future__ import annotations

import warnings
from typing import Any, ClassVar, TypeVar

import torch as th
from gymnasium import spaces
from stable_baselines3 import DQN
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.utils import LinearSchedule, get_parameters_by_name
from torch.nn import functional as F

from sb3_dcqn.policies import CnnPolicy, DCQNPolicy, MlpPolicy, MultiInputPolicy, TwinQNetwork
from sb3_dcqn.replay.combine import resolve_replay_buffer
from sb3_dcqn.replay.feedback import feedback_of
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
    SB3 DQN's, so that DCQN is a drop-in replacement: DQN's parameters plus the target's two options, and DQN's
    ``predict``. The route memory is not DCQN's: it is a layer that DQN, QR-DQN and DCQN wear alike
    (:func:`sb3_dcqn.with_route_memory`, :class:`sb3_dcqn.RouteMemoryDCQN`).

    :param policy: The policy model to use (MlpPolicy, CnnPolicy, MultiInputPolicy, ...)
    :param env: The environment to learn from (if registered in Gym, can be str)
    :param learning_rate: The learning rate, it can be a function of the current progress remaining (from 1 to 0)
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
    :param replay_buffer_class: Replay buffer class to use (for instance ``HerReplayBuffer``, or one of
        :mod:`sb3_dcqn.replay`'s variants, which compose: ``RevisionDictReplayBuffer``, ``LeanNStepDictReplayBuffer``,
        ...; ``train()`` tells them each gradient step's TD errors through :mod:`sb3_dcqn.replay.feedback`).
        If ``None``, it will be automatically selected. ``HerReplayBuffer`` is served by
        :class:`~sb3_dcqn.replay.her.DCQNHerReplayBuffer` (same arguments): relabelled transitions that reach their
        new goal are terminal (SB3 issue #627; ``replay_buffer_kwargs=dict(terminal_relabels=False)`` for SB3's
        dones) and goals the env does not allow as relabelling targets are never used
    :param replay_buffer_kwargs: Keyword arguments to pass to the replay buffer on creation.
    :param optimize_memory_usage: Enable a memory efficient variant of the replay buffer at a cost of more complexity.
    :param n_steps: When n_step > 1, uses n-step return when updating the critics: SB3's ``NStepReplayBuffer`` for
        Box observations, ``NStepDictReplayBuffer`` for Dict observations (SB3 has none), and the ``nstep`` variant
        added to one of DCQN's replay buffer classes; not with hindsight relabelling, experience revision,
        prioritized replay or ``blocked_action_target``
    :param target_update_interval: update the target critics every ``target_update_interval`` environment steps.
    :param exploration_fraction: fraction of entire training period over which the exploration rate is reduced
    :param exploration_initial_eps: initial value of random action probability
    :param exploration_final_eps: final value of random action probability
    :param max_grad_norm: The maximum value for the gradient clipping
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
        self.blocked_action_target = blocked_action_target
        self.pessimistic_target = pessimistic_target

        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        # DCQN's replay variants are buffer classes (sb3_dcqn.replay): which one, and whether they combine
        self.replay_buffer_class, self.replay_buffer_kwargs = resolve_replay_buffer(
            self.replay_buffer_class,
            self.replay_buffer_kwargs,
            isinstance(self.observation_space, spaces.Dict),
            self.n_steps,
            self.gamma,
            self.blocked_action_target,
        )
        with warnings.catch_warnings():
            if "n_steps" in self.replay_buffer_kwargs:
                # SB3 warns that n_steps goes unused with a given buffer class: the class's n_steps is set
                warnings.filterwarnings("ignore", message=r"`n_steps=\d+` is ignored")
            super()._setup_model()
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

    def _create_aliases(self) -> None:
        self.q_net = self.policy.q_net
        self.q_net_target = self.policy.q_net_target

    # DQN's own: each target critic tracks its own online critic (their parameters are stacked per critic in the same
    # order), and epsilon follows the exploration schedule
    _on_step = DQN._on_step

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        # Switch to train mode (this affects batch norm / dropout)
        self.policy.set_training_mode(True)
        # Update learning rate according to schedule
        self._update_learning_rate(self.policy.optimizer)
        # The replay variants hear each gradient step's TD errors through one channel (prioritized replay, revision)
        feedback = feedback_of(self.replay_buffer)
        statistics: dict[str, float] = {}

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

            loss = self.critic_loss(current_q_values, target_q_values, feedback.loss_weights(replay_data))
            losses.append(loss.detach())

            # Optimize the policy
            self.policy.optimizer.zero_grad()
            loss.backward()
            # Clip gradient norm
            th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
            self.policy.optimizer.step()

            # The batch's absolute TD errors, mean over the critics, (batch, 1)
            td_errors = (current_q_values.detach() - target_q_values.expand_as(current_q_values)).abs().mean(dim=0)
            statistics = feedback.after_gradient_step(replay_data, td_errors, 1.0 - self._current_progress_remaining)

        # Increase update counter
        self._n_updates += gradient_steps

        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        if losses:
            self.logger.record("train/loss", th.stack(losses).mean().item())
            _record_critic_statistics(self.logger, current_q_values.detach(), target_q_values)
        for name, value in statistics.items():
            self.logger.record(f"train/{name}", value)

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

    def critic_loss(
        self, current_q_values: th.Tensor, target_q_values: th.Tensor, weights: th.Tensor | None = None
    ) -> th.Tensor:
        """
        Huber loss of every critic against the shared target, summed over the critics (an extension point: the
        training step samples, computes the target with :meth:`td_target`, and feeds the TD errors back itself).

        :param current_q_values: The critics' values of the taken actions, shape ``(n_critics, batch, 1)``
        :param target_q_values: The TD target, shape ``(batch, 1)``
        :param weights: Per-sample importance weights, shape ``(batch, 1)`` (prioritized replay), or ``None``
        :return: The loss to minimise (a scalar)
        """
        targets = target_q_values.expand_as(current_q_values)
        losses = F.smooth_l1_loss(current_q_values, targets, reduction="none" if weights is not None else "mean")
        # The mean over critics and samples times the number of critics: the sum of the critics' mean losses
        return current_q_values.shape[0] * (losses if weights is None else (losses * weights).mean())

    # DQN's own: epsilon-greedy over the greedy action (the mean of the critics, see ``TwinQNetwork``)
    predict = DQN.predict

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

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "q_net", "q_net_target"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts = ["policy", "policy.optimizer"]
        return state_dicts, []


def _record_critic_statistics(logger: Logger, current_q_values: th.Tensor, target_q_values: th.Tensor) -> None:
    """Log the last batch's per-critic losses, mean Q, mean |Q1 - Q2| and mean target (one sync)."""
    targets = target_q_values.expand_as(current_q_values)
    critic_losses = F.smooth_l1_loss(current_q_values, targets, reduction="none").mean(dim=(1, 2))
    q_abs_diff = (current_q_values[0] - current_q_values[-1]).abs().mean()
    summary = th.cat([th.stack([current_q_values.mean(), q_abs_diff, target_q_values.mean()]), critic_losses])
    values = summary.cpu().numpy()
    for name, value in zip(_STAT_NAMES, values[: len(_STAT_NAMES)], strict=True):
        logger.record(f"train/{name}", float(value))
    for critic, value in enumerate(values[len(_STAT_NAMES) :], start=1):
        logger.record(f"train/critic_{critic}_loss", float(value))
