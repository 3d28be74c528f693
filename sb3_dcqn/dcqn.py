"""DCQN: double-critic deep Q-learning (Han & Yilmaz), as a Stable-Baselines3 off-policy algorithm."""

from __future__ import annotations

import warnings
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.utils import LinearSchedule, get_parameters_by_name, polyak_update
from torch.nn import functional as F

from sb3_dcqn.place_frame import place_frame_of
from sb3_dcqn.place_recognition import AlignedNearestPlace
from sb3_dcqn.policies import CnnPolicy, DCQNPolicy, MlpPolicy, MultiInputPolicy, TwinQNetwork
from sb3_dcqn.replay.combine import resolve_replay_buffer, with_variants
from sb3_dcqn.replay.her import DCQNHerReplayBuffer
from sb3_dcqn.replay.prioritized import PrioritizedReplay
from sb3_dcqn.replay.revision import RevisionReplay
from sb3_dcqn.route_memory import RouteMemory, UntriedExplorer, batch_of_one, default_goal_keys, select_rows
from sb3_dcqn.targets import blocked_actions, dcqn_td_target

SelfDCQN = TypeVar("SelfDCQN", bound="DCQN")

# The statistics of the last batch of each ``train`` call, gathered in one tensor (one sync instead of one per value)
_STAT_NAMES = ("q_mean", "q_abs_diff", "target_q_mean")
# Rollouts plan over routes at most this many memory changes old (a search per step costs milliseconds on a city)
_ROLLOUT_STALENESS = 32


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
    SB3 DQN's, so that DCQN is a drop-in replacement: its parameters are DQN's, plus three of its own (the target's
    form: ``pessimistic_target``, ``blocked_action_target``; the memory and its exploration: ``route_memory``).

    Replay variants are replay buffer classes, as in SB3 (:mod:`sb3_dcqn.replay`): experience revision, prioritized
    replay, lean storage, n-step returns with Dict observations and a count bonus are mix-ins that compose
    (``replay_buffer_class=LeanRevisionHerReplayBuffer``, their arguments in ``replay_buffer_kwargs``). SB3's
    ``HerReplayBuffer`` is served by :class:`~sb3_dcqn.replay.her.DCQNHerReplayBuffer` (same arguments): relabelled
    transitions that reach their new goal are terminal (SB3's keep the episode's done, SB3 issue #627);
    ``model.replay_buffer.terminal_relabels`` shows it, ``replay_buffer_kwargs=dict(terminal_relabels=False)`` turns
    it off.

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
    :param replay_buffer_class: Replay buffer class to use (for instance ``HerReplayBuffer``, or one of
        :mod:`sb3_dcqn.replay`'s: ``RevisionDictReplayBuffer``, ``LeanNStepDictReplayBuffer``, ...).
        If ``None``, it will be automatically selected. ``HerReplayBuffer`` is served by
        :class:`~sb3_dcqn.replay.her.DCQNHerReplayBuffer` (same arguments): relabelled transitions that reach their
        new goal are terminal (``replay_buffer_kwargs=dict(terminal_relabels=False)`` for SB3's dones) and goals
        the env does not allow as relabelling targets are never used
    :param replay_buffer_kwargs: Keyword arguments to pass to the replay buffer on creation.
    :param optimize_memory_usage: Enable a memory efficient variant of the replay buffer
        at a cost of more complexity.
    :param n_steps: When n_step > 1, uses n-step return when updating the critics: SB3's ``NStepReplayBuffer`` for
        Box observations, ``NStepDictReplayBuffer`` for Dict observations (SB3 has none), and the ``nstep`` variant
        added to one of DCQN's replay buffer classes; not with hindsight relabelling, experience revision,
        prioritized replay or ``blocked_action_target``
    :param target_update_interval: update the target critics every ``target_update_interval``
        environment steps.
    :param exploration_fraction: fraction of entire training period over which the exploration rate is reduced
    :param exploration_initial_eps: initial value of random action probability
    :param exploration_final_eps: final value of random action probability
    :param max_grad_norm: The maximum value for the gradient clipping
    :param route_memory: ``True`` (or a dict of settings) keeps a route memory (``model.memory``, a
        :class:`~sb3_dcqn.route_memory.RouteMemory`: one graph of every transition the model collected, its states
        the observations without their goal keys, so one graph serves every goal; places and compass slots where the
        env declares its frame, :mod:`sb3_dcqn.place_frame`), acts with it and explores with it:

        - greedy actions (``predict(..., deterministic=True)``: evaluation, routes; and the rollouts' greedy steps)
          follow the shortest remembered route to the observation's goal, and the critics' action where the memory
          has none (an unseen place, a goal not in memory); rollouts may also re-try a road blocked
          ``retry_after`` transitions ago where that route is shorter (a reopened road is found again);
        - exploration (epsilon's share and the warm-up) drives to the nearest untried (place, slot) and tries it
          (Go-Explore's return-then-explore); the critics act at unseen places, epsilon's uniform action applies
          where nothing untried can be reached.

        A collision removes its road from every goal's routes at once (with an experience-revision buffer on a Dict
        base, DCQN passes it the memory's goal keys: every goal's stale copies through the road are revised too).
        The memory is saved in the model's file. Settings (a dict): ``explore`` (default ``True``; ``False``: the
        memory acts, epsilon explores as DQN's) and :class:`~sb3_dcqn.route_memory.RouteMemory`'s ``success_reward``,
        ``max_states``, ``retry_after``, ``max_cache_bytes``, ``goal_tolerance``, ``place_frame`` (``"auto"``: the
        env's declaration; ``None``: pose states), ``place_matcher`` (default: an
        :class:`~sb3_dcqn.place_recognition.AlignedNearestPlace` where the env declares that goals may be pictured
        in other conditions than its views, none elsewhere). For worlds whose observations repeat exactly.
        Off by default: ``predict`` then means what it means for DQN
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
        route_memory: bool | dict[str, Any] = False,
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
        self.route_memory = route_memory
        self.memory: RouteMemory | None = None  # made in _setup_model with route_memory
        self._explorer: UntriedExplorer | None = None
        self.blocked_action_target = blocked_action_target
        self.pessimistic_target = pessimistic_target

        if _init_setup_model:
            self._setup_model()

    @property
    def explores_untried(self) -> bool:
        """Whether exploration drives to the route memory's untried moves (``route_memory``'s ``explore``)."""
        return bool(self.route_memory) and bool(_memory_settings(self.route_memory).get("explore", True))

    def _setup_model(self) -> None:
        frame = place_frame_of(self.env)
        if frame is not None and frame.frame_key is not None and "heading_key" not in self.policy_kwargs:
            # The env declares the frame its actions are relative to: the critics score compass slots
            self.policy_kwargs = {**self.policy_kwargs, "heading_key": frame.frame_key}
        # DCQN's replay variants are buffer classes (sb3_dcqn.replay): which one, and whether they combine
        self.replay_buffer_class, self.replay_buffer_kwargs = resolve_replay_buffer(
            self.replay_buffer_class,
            self.replay_buffer_kwargs,
            isinstance(self.observation_space, spaces.Dict),
            self.n_steps,
            self.gamma,
            self.blocked_action_target,
        )
        if self.route_memory:
            self.replay_buffer_class = _with_revision(
                self.replay_buffer_class, isinstance(self.observation_space, spaces.Dict), self.n_steps > 1
            )
        if self.route_memory and _revises_per_goal(self.replay_buffer_class, self.replay_buffer_kwargs):
            # A closure is one fact for every goal: stale copies through a closed road are revised for every goal
            goal_keys = default_goal_keys(self.observation_space)
            self.replay_buffer_kwargs = {**self.replay_buffer_kwargs, "goal_keys": goal_keys}
        with warnings.catch_warnings():
            if "n_steps" in self.replay_buffer_kwargs:
                # SB3 warns that n_steps goes unused with a given buffer class: the class's n_steps is set
                warnings.filterwarnings("ignore", message=r"`n_steps=\d+` is ignored")
            super()._setup_model()
        self._create_aliases()
        if self.route_memory:
            self._setup_memory()
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
        # Update learning rate according to schedule
        self._update_learning_rate(self.policy.optimizer)
        prioritized = isinstance(self.replay_buffer, PrioritizedReplay)
        if prioritized:  # the importance correction reaches full (beta = 1) by the end of training
            self.replay_buffer.anneal_beta(1.0 - self._current_progress_remaining)  # type: ignore[union-attr]

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

            weights = replay_data.weights if prioritized else None
            loss = self.critic_loss(current_q_values, target_q_values, weights)
            losses.append(loss.detach())
            if prioritized:  # the batch's new TD errors (mean over the critics) become its priorities
                td_errors = (current_q_values.detach() - target_q_values.expand_as(current_q_values)).abs().mean(dim=0)
                self.replay_buffer.update_priorities(replay_data.indices, td_errors.cpu().numpy())  # type: ignore

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
            _record_critic_statistics(self.logger, current_q_values.detach(), target_q_values)
        if hasattr(self.replay_buffer, "revised"):  # experience revision: stored transitions rewritten so far
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

    def critic_loss(
        self, current_q_values: th.Tensor, target_q_values: th.Tensor, weights: th.Tensor | None = None
    ) -> th.Tensor:
        """
        Huber loss of every critic against the shared target, summed over the critics (an extension point: the
        training step samples, computes the target with :meth:`td_target`, and updates priorities itself).

        :param current_q_values: The critics' values of the taken actions, shape ``(n_critics, batch, 1)``
        :param target_q_values: The TD target, shape ``(batch, 1)``
        :param weights: Per-sample importance weights, shape ``(batch, 1)`` (prioritized replay), or ``None``
        :return: The loss to minimise (a scalar)
        """
        n_critics = current_q_values.shape[0]
        targets = target_q_values.expand_as(current_q_values)
        if weights is None:
            # The mean over critics and samples times the number of critics: the sum of the critics' mean losses
            return n_critics * F.smooth_l1_loss(current_q_values, targets)
        return n_critics * (F.smooth_l1_loss(current_q_values, targets, reduction="none") * weights).mean()

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
        if deterministic and self.route_memory and self.memory is not None:
            return self._predict_with_memory(observation, state, episode_start)
        if not deterministic and np.random.rand() < self.exploration_rate:
            if self.explores_untried and self.memory is not None:
                return self._explore(observation, state, episode_start), state
            if self.policy.is_vectorized_observation(observation):
                if isinstance(observation, dict):
                    n_batch = observation[next(iter(observation.keys()))].shape[0]
                else:
                    n_batch = observation.shape[0]
                action = np.array([self.action_space.sample() for _ in range(n_batch)])
            else:
                action = np.array(self.action_space.sample())
        elif self.route_memory and self.memory is not None:  # predict's greedy action, re-trying aged closures
            return self._predict_with_memory(observation, state, episode_start, _ROLLOUT_STALENESS, retry=True)
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

    def _setup_memory(self) -> None:
        """The route memory, fed by every transition the model stores (see ``route_memory``)."""
        if self._vec_normalize_env is not None and getattr(self._vec_normalize_env, "norm_obs", False):
            raise ValueError(
                "route_memory remembers the raw observations while predict sees VecNormalize's normalized ones: use "
                "it without observation normalization"
            )
        if self.memory is None:
            settings = {key: value for key, value in _memory_settings(self.route_memory).items() if key != "explore"}
            frame = settings.pop("place_frame", "auto")
            env = self.env if self.env is not None else self
            declared = place_frame_of(env) if frame == "auto" else frame
            if declared is not None and declared.goals_pictured_otherwise and "place_matcher" not in settings:
                # Goals may be pictured in conditions the agent's views never are: match them to its own views
                settings["place_matcher"] = AlignedNearestPlace(views=declared.views_per_place)
            try:
                self.memory = RouteMemory.for_env(env, place_frame=frame, **settings)
            except TypeError as error:
                raise ValueError(f"route_memory: {error} (settings: explore, {', '.join(_MEMORY_SETTINGS)})") from None
        self._explorer = UntriedExplorer(self.memory, self.n_envs)

    def _store_transition(
        self,
        replay_buffer: ReplayBuffer,
        buffer_action: np.ndarray,
        new_obs: np.ndarray | dict[str, np.ndarray],
        reward: np.ndarray,
        dones: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        # The memory sees what the buffer is given: SB3's unnormalized observations, terminal observations in place
        buffer = replay_buffer if self.memory is None else _Remembering(replay_buffer, self.memory)
        super()._store_transition(buffer, buffer_action, new_obs, reward, dones, infos)  # type: ignore[arg-type]

    def _sample_action(
        self, learning_starts: int, action_noise: Any = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        if self.explores_untried and self.memory is not None and self.num_timesteps < learning_starts:
            action = self._explore(self._last_obs, None, None)  # the warm-up explores towards the untried too
            return action, action
        return super()._sample_action(learning_starts, action_noise, n_envs)

    def _explore(self, observation: Any, state: Any, episode_start: Any) -> np.ndarray:
        """Exploration with the memory: towards the nearest untried action; critics for unseen states; else random."""
        assert self._explorer is not None and self.memory is not None
        batched, batch = _as_batch(self.policy, observation)
        states = self.memory.states_of(batch)
        actions = self._explorer.actions_at(states, batch)
        actions, _ = self._critics_where(states < 0, actions, batch, state, episode_start)
        stuck = actions < 0
        actions[stuck] = [self.action_space.sample() for _ in range(int(stuck.sum()))]
        return actions if batched else actions[0]

    def _predict_with_memory(
        self, observation: Any, state: Any, episode_start: Any, staleness: int = 0, retry: bool = False
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """The memory's route where it has one, the critics' greedy action elsewhere (``staleness``, ``retry``: see
        :meth:`RouteMemory.route_actions`)."""
        assert self.memory is not None
        batched, batch = _as_batch(self.policy, observation)
        actions = self.memory.route_actions(batch, staleness, retry)
        actions, state = self._critics_where(actions < 0, actions, batch, state, episode_start)
        return (actions if batched else actions[0]), state

    def _critics_where(
        self, mask: np.ndarray, actions: np.ndarray, batch: Any, state: Any, episode_start: Any
    ) -> tuple[np.ndarray, Any]:
        """``actions`` with the critics' greedy action where ``mask`` is set (the memory has nothing there)."""
        if mask.any():
            greedy, state = self.policy.predict(select_rows(batch, mask), state, episode_start, deterministic=True)
            actions[mask] = np.asarray(greedy).reshape(-1)
        return actions, state

    def _excluded_save_params(self) -> list[str]:
        # The memory is saved (pickled in the model's data); its explorer's paths are rebuilt
        return [*super()._excluded_save_params(), "q_net", "q_net_target", "_explorer"]

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


def _with_revision(buffer_class: type[ReplayBuffer] | None, is_dict: bool, n_step: bool) -> type[ReplayBuffer] | None:
    """
    With the route memory, the replay buffer revises too (the ``revision`` variant added where it combines: not with
    n-step returns, nor a user's own class): a closure the memory learns from one bump stops the stale transitions
    through that road from voting in the critics' replay, the hindsight-relabelling buffer's included.
    """
    if n_step or (isinstance(buffer_class, type) and issubclass(buffer_class, RevisionReplay)):
        return buffer_class
    try:
        return with_variants(buffer_class, "revision", base="Dict" if is_dict else "Box")
    except ValueError:  # a buffer the variant does not extend or combine with: as given
        return buffer_class


def _revises_per_goal(buffer_class: type | None, buffer_kwargs: dict[str, Any]) -> bool:
    """Whether the buffer revises stored transitions matching the goal too (a Dict base, no goal keys given)."""
    revises = isinstance(buffer_class, type) and issubclass(buffer_class, RevisionReplay)
    her = isinstance(buffer_class, type) and issubclass(buffer_class, DCQNHerReplayBuffer)  # leaves the goal out
    return revises and not her and "goal_keys" not in buffer_kwargs


_MEMORY_SETTINGS = (
    "success_reward",
    "max_states",
    "retry_after",
    "max_cache_bytes",
    "goal_tolerance",
    "place_frame",
    "place_matcher",
)


def _memory_settings(route_memory: bool | dict[str, Any]) -> dict[str, Any]:
    """``route_memory``'s settings (``True``: the defaults); an unknown one is named."""
    if isinstance(route_memory, bool) or route_memory is None:
        return {}
    if not isinstance(route_memory, dict):
        raise ValueError(f"route_memory must be True, False or a dict of settings, got {route_memory!r}")
    unknown = sorted(set(route_memory) - {"explore", *_MEMORY_SETTINGS})
    if unknown:
        raise ValueError(f"route_memory: unknown settings {unknown}; known: explore, {', '.join(_MEMORY_SETTINGS)}")
    return dict(route_memory)


def _as_batch(policy: DCQNPolicy, observation: Any) -> tuple[bool, Any]:
    """Whether ``observation`` is a batch, and it as one."""
    batched = policy.is_vectorized_observation(observation)
    return batched, observation if batched else batch_of_one(observation)


class _Remembering:
    """A replay buffer seen through the route memory: each ``add`` is remembered, then stored."""

    def __init__(self, buffer: ReplayBuffer, memory: RouteMemory) -> None:
        self.buffer = buffer
        self.memory = memory

    def add(
        self, obs: Any, next_obs: Any, action: np.ndarray, reward: np.ndarray, done: np.ndarray, infos: Any
    ) -> None:
        truncated = np.array([info.get("TimeLimit.truncated", False) for info in infos], dtype=bool)
        terminated = np.asarray(done, dtype=bool).reshape(-1) & ~truncated
        rewards = np.asarray(reward, dtype=np.float64).reshape(-1)
        # The env's word on success where it gives one (SB3's is_success), else a reward above the memory's bar
        successes = np.array(
            [
                bool(info["is_success"]) if "is_success" in info else value > self.memory.success_reward
                for info, value in zip(infos, rewards, strict=True)
            ]
        )
        self.memory.add_batch(obs, np.asarray(action).reshape(-1), next_obs, rewards, terminated, successes)
        self.buffer.add(obs, next_obs, action, reward, done, infos)
