"""The route memory as a layer: any discrete off-policy SB3 algorithm, wearing a memory of the roads it drove.

The route memory (:class:`~sb3_dcqn.route_memory.RouteMemory`) is one graph of the transitions an agent stored, over
places, for every goal. Any off-policy learner with discrete actions stores those transitions, so the memory is not
one algorithm's: :func:`with_route_memory` makes, of any such algorithm class (SB3's ``DQN``, sb3-contrib's
``QRDQN``, :class:`~sb3_dcqn.DCQN`), a subclass that takes ``route_memory=`` and owns everything the memory does
(:class:`RouteMemoryLayer`); the algorithm's own ``train()`` is untouched::

    from sb3_contrib import QRDQN
    from stable_baselines3 import DQN
    from sb3_dcqn import RouteMemoryDCQN, RouteMemoryDQN, with_route_memory

    model = RouteMemoryDQN("MultiInputPolicy", env, route_memory=True)  # with_route_memory(DQN)
    model = with_route_memory(QRDQN)("MultiInputPolicy", env, route_memory={"explore": False})

The classes are made once per algorithm (``with_route_memory(DQN) is with_route_memory(DQN)``), named
``RouteMemory<Algorithm>`` and found by that name in this module, so that they pickle and ``RouteMemoryDQN.load(path)``
works in a fresh process. :func:`algorithm_name` says what ran: ``"DCQN"``, ``"DCQN + memory"``, ``"DQN + memory"``
(TensorBoard runs are spelled ``DCQN-memory_1``: the default ``tb_log_name`` of a model wearing the memory).
"""

from __future__ import annotations

import functools
import importlib
import inspect
import json
import zipfile
from collections.abc import Hashable, Mapping
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import DQN
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.preprocessing import is_image_space, maybe_transpose
from stable_baselines3.common.type_aliases import MaybeCallback, RolloutReturn

from sb3_dcqn.dcqn import DCQN
from sb3_dcqn.replay.combine import with_variants
from sb3_dcqn.replay.her import DCQNHerReplayBuffer
from sb3_dcqn.replay.revision import PlaceKeys, RevisionReplay
from sb3_dcqn.route_memory.evidence import EpisodeTrial
from sb3_dcqn.route_memory.memory import RouteMemory, UntriedExplorer, batch_of_one, select_rows

__all__ = [
    "EXPLORE_FIRST",
    "ROLLOUT_STALENESS",
    "ROLLOUT_STALENESS_PLACES",
    "RouteMemoryDCQN",
    "RouteMemoryDQN",
    "RouteMemoryLayer",
    "algorithm_class_for",
    "algorithm_name",
    "memory_settings",
    "with_route_memory",
]

# Rollouts plan over routes at most this many memory changes old (a search per step costs milliseconds on a city),
# and one more per ROLLOUT_STALENESS_PLACES places remembered: a search reads every move (155 ms at 56,000 places on
# one core), so its cost per step stays flat as the map grows; a route a stale search misses is explored instead
ROLLOUT_STALENESS = 32
ROLLOUT_STALENESS_PLACES = 100
# Evaluation: a move made this often at one place in an episode is a loop (look-alike places remembered as one, or
# a route back to where the algorithm drives the way it came): not given there again; twice may be a dead end's way out
LOOP_REPEATS = 2
# route_memory's explore="first": explore the untried whenever it is within reach, and route once the map is known
EXPLORE_FIRST = "first"
# The layer's own settings; the others are the memory's (RouteMemory.for_env's keyword arguments)
_LAYER_SETTINGS = ("explore", "success_reward")
# Where the algorithms a made class can be named after live, to rebuild it by name in a fresh process (unpickling);
# imported only then, so that sb3-contrib stays optional
_ALGORITHM_HOMES = {"DQN": "stable_baselines3", "DCQN": "sb3_dcqn.dcqn", "QRDQN": "sb3_contrib"}
_PREFIX = "RouteMemory"


@functools.cache
def _memory_keywords() -> tuple[frozenset[str], bool]:
    """The settings the memory takes (its constructor's keyword arguments, and ``place_frame``), and whether it takes
    any other keyword as well (then an unknown one is found when the memory is made)."""
    parameters = inspect.signature(RouteMemory.__init__).parameters
    named = {name for name, p in parameters.items() if p.kind is not inspect.Parameter.VAR_KEYWORD}
    open_ended = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters.values())
    return frozenset(named - {"self", "n_actions", "observation_space", "success_reward"} | {"place_frame"}), open_ended


def memory_settings(route_memory: bool | Mapping[str, Any] | None) -> dict[str, Any] | None:
    """
    ``route_memory``'s settings, checked: ``None`` where the memory is off, ``{}`` for ``True`` (the defaults).

    :raises ValueError: on anything but a bool or a dict, or naming the unknown settings and the known ones
    """
    if route_memory is None or route_memory is False:
        return None
    if route_memory is True:
        return {}
    if not isinstance(route_memory, Mapping):
        raise ValueError(f"route_memory must be True, False or a dict of settings, got {route_memory!r}")
    known, open_ended = _memory_keywords()
    unknown = sorted(set(route_memory) - known - set(_LAYER_SETTINGS))
    if unknown and not open_ended:
        raise ValueError(f"route_memory: unknown settings {unknown}; known: {_known_text(known)}")
    return dict(route_memory)


def _known_text(known: frozenset[str]) -> str:
    return ", ".join([*_LAYER_SETTINGS, *sorted(known)])


class RouteMemoryLayer:
    """
    The route memory, worn by a discrete off-policy algorithm (the class after this one in the MRO; see
    :func:`with_route_memory`). Every other parameter is the algorithm's own.

    :param route_memory: ``True`` (default) or a dict of settings keeps a route memory (``model.memory``, a
        :class:`~sb3_dcqn.route_memory.RouteMemory` made with ``RouteMemory.for_env(env, **settings)``: one graph of
        every transition the model stored, its states the observations without their goal keys, places and compass
        slots where the env declares its frame, :mod:`sb3_dcqn.place_frame`); ``False``: none, the algorithm as it
        is. With the memory:

        - it is fed every transition the replay buffer is given (SB3's unnormalized observations, terminal
          observations in place). A transition reached its goal where the env says so (``info["is_success"]``);
          where the env gives no ``is_success``, none did, unless the settings give ``success_reward`` (then a
          terminated transition with a reward above it did);
        - greedy actions (``predict(..., deterministic=True)``: evaluation, routes; and the rollouts' greedy steps)
          follow the shortest remembered route to the observation's goal, and the algorithm's greedy action where the
          memory has none; rollouts may also re-try a road blocked ``retry_after`` transitions ago where that route is
          shorter (a reopened road is found again);
        - exploration (epsilon's share and the warm-up) drives to the nearest untried (place, slot) and tries it
          (Go-Explore's return-then-explore); a uniform action where the memory knows no way there (a place it does
          not recognise, nothing untried within reach), and a trip begun is driven to its end: the greedy steps
          that follow go on to the untried pair, not back onto the route (one step of a trip between route steps
          reaches nothing; Dabney et al.'s temporally extended epsilon-greedy). So does a rollout's greedy step where
          the memory knows the place but no route from it to the goal (the goal not found yet, or a part of the map
          not joined to it yet): the critics have learnt nothing there that the memory lacks, and on a large map an
          episode spent on their guess is mostly spent in the same loop (a 10,000 city: 85% of the rollout steps
          after 36k env steps). The algorithm's greedy action where nothing untried is within reach. Evaluation never
          explores. Setting ``explore=False``: epsilon explores as DQN's, and a step with no route is the algorithm's;
          ``explore="first"`` (the city entry's): every rollout step drives to the nearest untried pair while one is
          within reach, and routes only once none is (the floor's order: the map is known first, so that every start
          is routed; a 2,626 city solved at 10,000 env steps instead of 45,000, as its floor);
        - evaluation never learns, so a move that bumped is not given again at that place in its episode, nor one
          made there :data:`LOOP_REPEATS` times (a loop: look-alike places remembered as one, say, or a route back
          to where the algorithm drives the way it came): the algorithm's best other action instead (the least made
          where every move there was made that often); a stochastic move may repeat. It needs to know the envs
          and their episodes: SB3's convention for per-env state, ``episode_start`` (``evaluate_policy`` passes it);
          without it, each call stands alone;
        - **the replay buffer revises too**: where ``replay_buffer_class`` is ``None``, SB3's ``ReplayBuffer``,
          ``DictReplayBuffer`` or ``HerReplayBuffer``, or one of :mod:`sb3_dcqn.replay`'s classes, it gains the
          ``revision`` variant (:mod:`sb3_dcqn.replay.revision`; ``HerReplayBuffer`` becomes DCQN's
          ``RevisionHerReplayBuffer``, with terminal relabels), said once at ``verbose >= 1``; not with n-step
          returns or ``optimize_memory_usage``, nor a user's own class. Revision matches on the memory's places and
          slots (a bump at one heading revises the road's copies at every heading, in worlds whose pictures vary
          too), and a Dict base is given the memory's goal keys: a closure is one fact for every goal;
        - the memory is saved in the model's file; its statistics (where it has them) are logged under ``memory/``
          at the end of each rollout. Where it steps aside (it cannot recognise places), the algorithm acts alone.

        Settings (a dict): ``explore`` (default ``True``; ``False`` or ``"first"``), ``success_reward`` (default:
        none) and the memory's own (:meth:`RouteMemory.for_env`: ``place_frame``, ``max_states``, ``retry_after``,
        ...). For discrete actions; not with ``VecNormalize``'s observation normalization (the memory remembers raw
        observations)
    """

    # The algorithm this class was made from (with_route_memory's argument)
    bare_class: ClassVar[type[OffPolicyAlgorithm]]
    route_memory: bool | dict[str, Any]
    memory: RouteMemory | None

    def __init__(self, *args: Any, route_memory: bool | dict[str, Any] = True, **kwargs: Any) -> None:
        # Set before the algorithm's constructor, which sets the model up (_setup_model)
        self.route_memory = route_memory
        self.memory = None
        self._explorer: UntriedExplorer | None = None
        self._episode_guard: _EpisodeGuard | None = None
        self._success_reward: float | None = None
        self._explores = self._explores_first = False
        self._acted = np.zeros(2, dtype=np.int64)  # rollout actions since the last log: the memory's, all
        self._said: set[Hashable] = set()  # the kinds of notice said (standing aside: True, speaking again: False...)
        self._trial: EpisodeTrial | None = None  # who drives while the memory's routes are on trial (saved)
        super().__init__(*args, **kwargs)

    def __repr__(self) -> str:
        return f"<{type(self).__name__}: {algorithm_name(self)}>"

    @property
    def wears_route_memory(self) -> bool:
        """Whether this model keeps a route memory, decided by :func:`memory_settings` alone: ``True``, ``{}`` and any
        dict of settings are on, ``False`` off. Asked by duck typing where the layer cannot be imported
        (``campusnav_env.callbacks``); a model without this property wears none."""
        return memory_settings(self.route_memory) is not None

    @property
    def explores_untried(self) -> bool:
        """Whether exploration drives to the memory's untried moves (``route_memory``'s ``explore``)."""
        return self._explores

    @property
    def _memory_speaks(self) -> bool:
        """Whether the memory answers (it exists, has not stepped aside for places it cannot recognise, and does not
        stand aside for predictions that fail: :attr:`RouteMemory.speaks`)."""
        return self.memory is not None and self.memory.speaks

    @property
    def _routes_on_trial(self) -> bool:
        """Whether the memory speaks and its routes are on trial against the critics' (:class:`EpisodeTrial`): its
        predictions below the bar, or the critics leading (only the memory's shorter episodes win the lead back)."""
        if not self._memory_speaks or self._trial is None:
            return False
        return self._trial.critics_lead or self.memory.predictions.on_trial  # type: ignore[union-attr]

    # ------------------------------------------------------------------------------------------------ setting up
    def _setup_model(self) -> None:
        settings = memory_settings(self.route_memory)
        if settings is not None:
            self._success_reward = settings.get("success_reward")
            explore = settings.get("explore", True)
            if explore not in (True, False, EXPLORE_FIRST):
                raise ValueError(f"route_memory's explore must be True, False or {EXPLORE_FIRST!r}, got {explore!r}")
            self._explores, self._explores_first = explore is not False, explore == EXPLORE_FIRST
            if self.memory is None:  # a loaded model has its own
                self.memory = self._new_memory({k: v for k, v in settings.items() if k not in _LAYER_SETTINGS})
            self._revise_with_memory()
        super()._setup_model()  # type: ignore[misc]
        if self.memory is not None:
            self._explorer = UntriedExplorer(self.memory, self.n_envs)  # type: ignore[attr-defined]
            if self._trial is None or self._trial.n_envs != self.n_envs:  # type: ignore[attr-defined]
                self._trial = EpisodeTrial(self.n_envs)  # type: ignore[attr-defined]

    def _new_memory(self, settings: dict[str, Any]) -> RouteMemory:
        normalizer = self._vec_normalize_env  # type: ignore[attr-defined]
        if normalizer is not None and getattr(normalizer, "norm_obs", False):
            raise ValueError(
                "route_memory remembers the raw observations while predict sees VecNormalize's normalized ones: use "
                "it without observation normalization"
            )
        env = self.env if self.env is not None else self  # type: ignore[attr-defined]
        try:
            return RouteMemory.for_env(env, **settings)
        except TypeError as error:  # a setting the memory does not take
            known, _ = _memory_keywords()
            raise ValueError(f"route_memory: {error}; known settings: {_known_text(known)}") from None

    def _revise_with_memory(self) -> None:
        """The replay buffer gains the ``revision`` variant where it combines, and a Dict base the memory's goal keys
        (see ``route_memory``)."""
        assert self.memory is not None
        given = self.replay_buffer_class  # type: ignore[has-type]
        one_step = self.n_steps == 1 and not self.optimize_memory_usage  # type: ignore[attr-defined]
        is_dict = isinstance(self.observation_space, spaces.Dict)  # type: ignore[attr-defined]
        revising = _with_revision(given, is_dict, one_step)
        if revising is not given:
            self.replay_buffer_class = revising
            if self.verbose >= 1:  # type: ignore[attr-defined]
                named = "the default buffer" if given is None else given.__name__
                print(f"route_memory: {named} revises what the memory's bumps contradict: {revising.__name__}")
        kwargs = self.replay_buffer_kwargs  # type: ignore[has-type]
        if _revises_per_goal(self.replay_buffer_class, kwargs) and self.memory.goal_keys:
            # A closure is one fact for every goal: stale copies through a closed road are revised for every goal
            self.replay_buffer_kwargs = {**kwargs, "goal_keys": tuple(self.memory.goal_keys)}

    # ------------------------------------------------------------------------------------------------ remembering
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
        buffer = replay_buffer if self.memory is None else _Remembering(self, replay_buffer)
        super()._store_transition(buffer, buffer_action, new_obs, reward, dones, infos)  # type: ignore[misc]
        if self.memory is not None and self._trial is not None:
            on_trial = self._routes_on_trial
            # The envs' next drivers, from SB3's seeded generator: drawn only on trial (elsewhere the generator's
            # draws are the algorithm's own, as without the memory)
            draws = np.random.rand(np.asarray(dones).size) if on_trial and np.any(dones) else None
            if self._trial.step(dones, on_trial, draws):
                self.memory.notices.append(self._trial_notice())

    def _trial_notice(self) -> tuple[Hashable, str]:
        """What the layer says where the lead of the trial changed (see :class:`EpisodeTrial`)."""
        assert self._trial is not None and self.memory is not None
        trial, accuracy = self._trial, self.memory.predictions.accuracy
        steps = f"{trial.mean_steps(True):.1f} against {trial.mean_steps(False):.1f} steps per episode"
        if trial.critics_lead:
            return "critics lead", (
                f"route memory: its routes are on trial ({accuracy:.2f} of its predicted moves came true) and the "
                f"critics' episodes are shorter ({steps}): the critics drive, the memory goes on learning"
            )
        return "memory leads", f"route memory: drives again (the critics' episodes: {steps})"

    def _successes(self, infos: list[dict[str, Any]], rewards: np.ndarray, terminated: np.ndarray) -> np.ndarray:
        """Which terminated transitions reached their goal: the env's ``is_success``, else a reward above the
        ``success_reward`` setting, else none."""
        bar = self._success_reward
        said = [
            bool(info["is_success"]) if "is_success" in info else (bar is not None and float(reward) > bar)
            for info, reward in zip(infos, rewards, strict=True)
        ]
        return np.array(said, dtype=bool) & terminated

    def _place_keys(self, observations: Any, actions: np.ndarray, next_observations: Any) -> PlaceKeys:
        """The transitions' places and slots in the memory, for revision by place: none (every move -1, neither revising
        nor revised) where the memory does not speak or the critics lead its trial (the critics' data as they are), or
        where a move is stochastic (the world has not shown itself deterministic there: a new outcome contradicts no
        stored one)."""
        assert self.memory is not None
        size = np.asarray(actions).size
        critics_lead = self._routes_on_trial and self._trial is not None and self._trial.critics_lead
        if not self._memory_speaks or critics_lead:
            unknown = np.full(size, -1, dtype=np.int64)
            return PlaceKeys(unknown, unknown.copy(), np.zeros(size, dtype=bool))
        places, arrivals = self.memory.states_of(observations), self.memory.states_of(next_observations)
        n_slots = int(self.action_space.n)  # type: ignore[attr-defined]
        slots = self._slots(observations, actions)
        revisable = self.memory.deterministic(places, slots)
        moves = np.where(revisable, places * n_slots + slots, -1)
        return PlaceKeys(moves, arrivals, (places == arrivals) & (places >= 0))

    def _slots(self, observations: Any, actions: np.ndarray) -> np.ndarray:
        """The compass slot each action takes at its observation's frame (the actions, where no frame is declared)."""
        frame = self.memory.place_frame if self.memory is not None else None
        actions = np.asarray(actions, dtype=np.int64).reshape(-1)
        if frame is None or frame.frame_key is None or not isinstance(observations, Mapping):
            return actions
        frames = np.asarray(observations[frame.frame_key]).reshape(actions.size, -1).argmax(axis=1)
        return (frames + actions) % int(self.action_space.n)  # type: ignore[attr-defined]

    # ------------------------------------------------------------------------------------------------ acting
    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """
        The memory's route where it has one, the algorithm's greedy action elsewhere; epsilon's share explores
        towards the untried (see ``route_memory``). Without the memory, the algorithm's own ``predict``.

        :param observation: the input observation
        :param state: The last states (can be None, used in recurrent policies)
        :param episode_start: Which envs start an episode (a batch's rows are envs): with it, evaluation does not
            repeat a move that left an env where it was in the same episode
        :param deterministic: Whether or not to return deterministic actions.
        :return: the model's action and the next state (used in recurrent policies)
        """
        if not self._memory_speaks:
            return super().predict(observation, state, episode_start, deterministic)  # type: ignore[misc]
        observation = _channel_first(observation, self.observation_space)  # type: ignore[attr-defined]
        critics = self._critics_drive(observation, deterministic)
        if critics.all():  # the memory's routes are on trial and the critics drive (see EpisodeTrial)
            return super().predict(observation, state, episode_start, deterministic)  # type: ignore[misc]
        actions, state = self._memory_predict(observation, state, episode_start, deterministic)
        if critics.any():  # some training envs' episodes are the critics' to drive
            theirs, _ = super().predict(observation, None, episode_start, deterministic)  # type: ignore[misc]
            actions = np.where(critics, theirs, actions)
        return actions, state

    def _memory_predict(
        self, observation: Any, state: Any, episode_start: Any, deterministic: bool
    ) -> tuple[np.ndarray, Any]:
        """:meth:`predict` where the memory drives."""
        if deterministic:
            return self._routes(observation, state, episode_start)
        if np.random.rand() < self.exploration_rate:  # type: ignore[attr-defined]
            if self.explores_untried:
                return self._explore(observation, state, episode_start), state
            batched, batch = _as_batch(self.policy, observation)  # type: ignore[attr-defined]
            actions = self._uniform_where(np.full(_rows(batch), -1, dtype=np.int64))
            return (actions if batched else actions[0]), state
        return self._routes(observation, state, episode_start, rollout=True)

    def _critics_drive(self, observation: Any, deterministic: bool) -> np.ndarray:
        """Per row of ``observation``: whether the critics act for the trial (:class:`EpisodeTrial`; a training batch's
        rows are its envs, a batch of another size follows the lead)."""
        if not self._routes_on_trial:
            return np.zeros(1, dtype=bool)  # the memory drives every row (the batch is not read: the common case)
        assert self._trial is not None
        _, batch = _as_batch(self.policy, observation)  # type: ignore[attr-defined]
        rows = _rows(batch)
        drive = self._trial.critics_drive()
        if deterministic or drive.size != rows:
            return np.full(rows, self._trial.critics_lead, dtype=bool)
        return drive

    def _sample_action(
        self, learning_starts: int, action_noise: Any = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        self._acted[1] += n_envs
        if self.explores_untried and self._memory_speaks and self.num_timesteps < learning_starts:  # type: ignore[attr-defined]
            action = self._explore(self._last_obs, None, None)  # type: ignore[attr-defined]  # the warm-up explores too
            return action, action
        return super()._sample_action(learning_starts, action_noise, n_envs)  # type: ignore[misc]

    def _explore(self, observation: Any, state: Any, episode_start: Any) -> np.ndarray:
        """Exploration with the memory: towards the nearest untried move; a uniform action where the memory knows
        none (a place it does not recognise, or nothing untried within reach)."""
        assert self._explorer is not None and self.memory is not None
        batched, batch = _as_batch(self.policy, observation)  # type: ignore[attr-defined]
        states = self.memory.states_of(batch)
        actions = self._explorer.actions_at(states, batch)
        self._acted[0] += int((actions >= 0).sum())
        actions = self._uniform_where(actions)  # epsilon's own draw where the memory knows no way to the untried
        return actions if batched else actions[0]

    def _explore_where(self, mask: np.ndarray, actions: np.ndarray, batch: Any, states: np.ndarray) -> np.ndarray:
        """``actions`` with the way to the nearest untried move where ``mask`` is set (-1 where there is none);
        ``states``: the batch's memory states."""
        if mask.any():
            assert self._explorer is not None
            masked = np.where(mask, states, -1)  # envs with a route drop their exploring path
            actions = np.where(mask, self._explorer.actions_at(masked, batch), actions)
        return actions

    def _routes(
        self, observation: Any, state: Any, episode_start: Any, rollout: bool = False
    ) -> tuple[np.ndarray, Any]:
        """
        The memory's route where it has one, the algorithm's greedy action elsewhere.

        :param rollout: A rollout's greedy step: routes up to :data:`ROLLOUT_STALENESS` changes of the memory old (and
            one more per :data:`ROLLOUT_STALENESS_PLACES` states), and roads blocked long enough ago are tried again
            (:meth:`RouteMemory.route_actions`); else evaluation's exact routes, with no bump twice nor a loop in an
            episode where ``episode_start`` says which rows are envs
        """
        assert self.memory is not None
        batched, batch = _as_batch(self.policy, observation)  # type: ignore[attr-defined]
        staleness = ROLLOUT_STALENESS + self.memory.n_states // ROLLOUT_STALENESS_PLACES if rollout else 0
        # Recognised once for the explorer's calls below (a picture's digest is most of a recognition's cost)
        evaluation = not rollout and episode_start is not None
        if evaluation:  # each env's last place and move say where it should be now (the graph's prior)
            starts = np.asarray(episode_start, dtype=bool).reshape(-1)
            guard = _EpisodeGuard.of(state)
            if guard is not None and guard.n_envs == starts.size:
                self._episode_guard, state = guard, None  # the caller's (one record per env), not the algorithm's state
            elif self._episode_guard is None or self._episode_guard.n_envs != starts.size:
                self._episode_guard = _EpisodeGuard(starts.size)
            self._episode_guard.start(starts)
            states = self.memory.states_of(batch, expected=self._episode_guard.expected_states(self.memory))
        else:
            states = self.memory.states_of(batch) if rollout and self.explores_untried else None
        if rollout and states is not None and self._explores_first:
            assert self._explorer is not None
            untried = self._explorer.actions_at(states, batch, untried_only=True)
            if (untried >= 0).all():
                return (untried if batched else untried[0]), state
            actions = self.memory.route_actions(batch, staleness, retry=rollout, states=states)
            actions = np.where(untried >= 0, untried, actions)
        else:
            not_goal = self._episode_guard.not_goal() if evaluation and self._episode_guard is not None else None
            actions, arrived = self.memory.routes(batch, staleness, retry=rollout, states=states, not_goal=not_goal)
            if evaluation and arrived.any():
                actions = self._beyond_a_wrong_goal(batch, states, arrived)
        if rollout and states is not None:
            assert self._explorer is not None
            # A trip to the untried, once begun (epsilon's draw), is driven to its end: one step of it between route
            # steps back to the goal would never reach the untried pair (temporally extended exploration)
            driving = self._explorer.driving(states)
            actions = self._explore_where((actions < 0) | driving, actions, batch, states)
        if rollout:
            self._acted[0] += int((actions >= 0).sum())
        actions, state = self._greedy_where(actions < 0, actions, batch, state, episode_start)
        if evaluation:
            actions = self._without_repeated_moves(batch, actions, states)
            assert self._episode_guard is not None
            state = self._episode_guard.state() if state is None else state
        return (actions if batched else actions[0]), state

    def _beyond_a_wrong_goal(self, batch: Any, states: np.ndarray, arrived: np.ndarray) -> np.ndarray:
        """The routes again where an episode went on at a place the memory took for its goal (``arrived``: a goal
        picture matched to a wrong place, or one of a matcher's candidates): the goal is not there for the rest of
        the episode, and its route leads to the goal's other places (the next candidate), or the algorithm acts where
        none is left. Evaluation does not learn (training rules the place out for good instead)."""
        assert self._episode_guard is not None and self.memory is not None
        for env in np.flatnonzero(arrived):
            self._episode_guard.envs[env].not_goal |= {int(states[env])}
        actions, _ = self.memory.routes(batch, states=states, not_goal=self._episode_guard.not_goal())
        return actions

    def _without_repeated_moves(self, batch: Any, actions: np.ndarray, states: np.ndarray) -> np.ndarray:
        """``actions`` with a move that bumped at that place in this episode, or that its env made there
        ``LOOP_REPEATS`` times, replaced by the best other action; where every move was made that often, the best of
        the least made that did not bump (``states``: the batch's memory states; the guard has been told which envs
        start an episode)."""
        assert self.memory is not None and self._episode_guard is not None
        frame = self.memory.place_frame
        places = _guard_places(batch, states, None if frame is None else frame.frame_key)
        self._episode_guard.observe(places)
        n_slots = int(self.action_space.n)  # type: ignore[attr-defined]
        frames = self._slots(batch, np.zeros_like(actions))  # the slot of action 0: the frame (0 where none)
        slot_of_action = (frames[:, None] + np.arange(n_slots)[None, :]) % n_slots
        made, bumped = self._episode_guard.made_slots(places, n_slots)
        made[bumped] = np.iinfo(made.dtype).max  # a move that bumped counts as made for good
        chance = np.zeros(made.shape, dtype=bool)  # a repeat of a stochastic move is chance, not a loop
        chance[states >= 0] = self.memory.edges.stochastic[states[states >= 0]]
        banned = made >= LOOP_REPEATS
        fewest = made.min(axis=1, keepdims=True)  # where every move was made that often: the least made
        banned = np.where(banned.all(axis=1, keepdims=True), made > fewest, banned) & ~chance
        banned = np.take_along_axis(banned, slot_of_action, axis=1)
        hit = banned[np.arange(actions.size), actions] & ~banned.all(axis=1)
        if hit.any():
            values = self._action_values(select_rows(batch, hit))
            values[banned[hit]] = -np.inf
            actions[hit] = values.argmax(axis=1)
        self._episode_guard.remember(places, self._slots(batch, actions))
        return actions

    def _action_values(self, observations: Any) -> np.ndarray:
        """The algorithm's values of every action, whose argmax is its greedy action: ``policy.q_net`` (DQN, DCQN:
        the critics' mean) or the mean of ``policy.quantile_net``'s quantiles (QR-DQN)."""
        policy = self.policy  # type: ignore[attr-defined]
        policy.set_training_mode(False)
        tensor, _ = policy.obs_to_tensor(observations)
        quantile_net = getattr(policy, "quantile_net", None)
        with th.no_grad():
            values = policy.q_net(tensor) if quantile_net is None else quantile_net(tensor).mean(dim=1)
        return values.cpu().numpy().astype(np.float64)

    def _greedy_where(
        self, mask: np.ndarray, actions: np.ndarray, batch: Any, state: Any, episode_start: Any
    ) -> tuple[np.ndarray, Any]:
        """``actions`` with the algorithm's greedy action where ``mask`` is set (the memory has nothing there)."""
        if mask.any():
            policy = self.policy  # type: ignore[attr-defined]
            greedy, state = policy.predict(select_rows(batch, mask), state, episode_start, deterministic=True)
            actions[mask] = np.asarray(greedy).reshape(-1)
        return actions, state

    def _uniform_where(self, actions: np.ndarray) -> np.ndarray:
        """``actions`` with a uniform action where they are -1 (epsilon's, as DQN's)."""
        stuck = actions < 0
        actions[stuck] = [self.action_space.sample() for _ in range(int(stuck.sum()))]  # type: ignore[attr-defined]
        return actions

    # ------------------------------------------------------------------------------------------------ logging, saving
    def collect_rollouts(self, *args: Any, **kwargs: Any) -> RolloutReturn:
        rollout = super().collect_rollouts(*args, **kwargs)  # type: ignore[misc]
        if self.memory is not None:
            for name, value in getattr(self.memory, "statistics", dict)().items():
                self.logger.record(f"memory/{name}", value)  # type: ignore[attr-defined]
            if self._trial is not None:  # who drives while its routes are on trial, and the episodes' lengths
                self.logger.record("memory/routes_on_trial", float(self._routes_on_trial))  # type: ignore[attr-defined]
                self.logger.record("memory/critics_lead", float(self._trial.critics_lead))  # type: ignore[attr-defined]
                for side, name in ((False, "memory"), (True, "critics")):
                    self.logger.record(f"memory/episode_steps_{name}", self._trial.mean_steps(side))  # type: ignore[attr-defined]
            memory_actions, actions = self._acted.tolist()
            # The share of the rollout's actions the memory chose (routes, exploration), the rest the algorithm's
            self.logger.record("memory/action_share", memory_actions / actions if actions else 0.0)  # type: ignore[attr-defined]
            self._acted[:] = 0
            self._say(getattr(self.memory, "notices", []))
        return rollout

    def _say(self, notices: list[tuple[Hashable, str]]) -> None:
        """Print the memory's notices (standing aside, speaking again, the trial's lead) at ``verbose >= 1``, the first
        of each kind only (``verbose >= 2``: every one); they are taken either way."""
        for kind, words in notices:
            if self.verbose >= 2 or (self.verbose >= 1 and kind not in self._said):  # type: ignore[attr-defined]
                print(words)
            self._said.add(kind)
        notices.clear()

    def learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str | None = None,
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> Any:
        """The algorithm's ``learn``; the TensorBoard run is named by what ran (``DQN-memory``, see
        :func:`algorithm_name`)."""
        return super().learn(  # type: ignore[misc]
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=algorithm_name(self, for_files=True) if tb_log_name is None else tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )

    def _excluded_save_params(self) -> list[str]:
        # The memory is saved (pickled in the model's data); its explorer's paths and the episode guard are rebuilt
        excluded = [
            "_explorer",
            "_episode_guard",
            "_success_reward",
            "_explores",
            "_explores_first",
            "_acted",
            "_said",
        ]  # rebuilt from route_memory on load
        return [*super()._excluded_save_params(), *excluded]  # type: ignore[misc]


class _EpisodeGuard:
    """
    Per env of an evaluation (the rows of ``predict``'s batch; episodes marked by ``episode_start``): the (place,
    slot) each env last moved by (where the memory expects it now: the prior that recognises its next picture), and
    the moves that bumped and those it made ``LOOP_REPEATS`` times, not to be given again at that place in the same
    episode (evaluation does not teach the memory a bump, nor that a route of it leads round in circles: two
    look-alike places remembered as one, say; a place left by one road twice may be a dead end visited twice). A
    place is the memory's state, or the observation itself where the memory does not know it (a deterministic world
    shows the same one after a bump), less its heading where the frame is declared (the place's views are in compass
    order, its slots compass slots).

    The guard is the evaluation's ``state`` of ``predict`` (one object per env, a row each: a caller that drops the
    rows of finished episodes, as route evaluation does, drops theirs); a caller that passes no state back has the
    model's own guard, kept between calls.

    :param n_envs: Number of envs
    :param envs: The envs' records, as :meth:`state` gave them (instead of ``n_envs`` fresh ones)
    """

    def __init__(self, n_envs: int = 0, envs: np.ndarray | None = None) -> None:
        self.envs = envs if envs is not None else _records(n_envs)

    @property
    def n_envs(self) -> int:
        return len(self.envs)

    @staticmethod
    def of(state: Any) -> _EpisodeGuard | None:
        """The guard a ``predict`` state holds (``None``: it holds none)."""
        if isinstance(state, tuple) and len(state) == 1 and isinstance(state[0], np.ndarray):
            records = state[0]
            if records.dtype == object and records.size and isinstance(records.flat[0], _EnvMoves):
                return _EpisodeGuard(envs=records.reshape(-1))
        return None

    def state(self) -> tuple[np.ndarray]:
        """The guard as ``predict``'s state: one record per env."""
        return (self.envs,)

    def start(self, episode_start: np.ndarray) -> None:
        """Envs that start an episode remember nothing."""
        for env in np.flatnonzero(episode_start):
            self.envs[env] = _EnvMoves()

    def observe(self, places: list[Hashable]) -> None:
        """An env still at the place of its last move bumped."""
        for record, place in zip(self.envs, places, strict=True):
            if record.last is not None and record.last[0] == place:
                record.bumped.add(record.last)

    def made_slots(self, places: list[Hashable], n_slots: int) -> tuple[np.ndarray, np.ndarray]:
        """``(envs, slots)`` twice: how often each env took each slot at its place in this episode, and which of those
        bumped."""
        made = np.zeros((self.n_envs, n_slots), dtype=np.int64)
        bumped = np.zeros((self.n_envs, n_slots), dtype=bool)
        for env, (record, place) in enumerate(zip(self.envs, places, strict=True)):
            for slot in range(n_slots):  # looked up at this place: the episode's other moves are not read
                made[env, slot] = record.taken.get((place, slot), 0)
                bumped[env, slot] = (place, slot) in record.bumped
        return made, bumped

    def remember(self, places: list[Hashable], slots: np.ndarray) -> None:
        """Each env's move now."""
        for record, place, slot in zip(self.envs, places, slots.tolist(), strict=True):
            record.last = (place, int(slot))
            record.taken[record.last] = record.taken.get(record.last, 0) + 1

    def not_goal(self) -> list[frozenset[int]]:
        """Per env, the states where its episode went on though the memory placed its goal there."""
        return [record.not_goal for record in self.envs]

    def expected_states(self, memory: RouteMemory) -> np.ndarray:
        """Per env, the state its last move should have led to by the memory (-1: none, or a new episode)."""
        lasts = [record.last for record in self.envs]
        known = [last if last is not None and isinstance(last[0], int) else (-1, -1) for last in lasts]
        states, slots = np.array(known, dtype=np.int64).reshape(-1, 2).T
        return memory.expected_states(states, slots)


class _EnvMoves:
    """One env's episode for the guard: its last (place, slot), the moves it made and those that bumped, and the
    states where it went on though the memory placed its goal there."""

    __slots__ = ("bumped", "last", "not_goal", "taken")

    def __init__(self) -> None:
        self.last: tuple[Hashable, int] | None = None
        self.taken: dict[tuple[Hashable, int], int] = {}  # how often each move was made
        self.bumped: set[tuple[Hashable, int]] = set()
        self.not_goal: frozenset[int] = frozenset()


def _records(n_envs: int) -> np.ndarray:
    records = np.empty(n_envs, dtype=object)
    for env in range(n_envs):
        records[env] = _EnvMoves()
    return records


def _guard_places(batch: Any, states: np.ndarray, frame_key: str | None = None) -> list[Hashable]:
    """Each observation's place for the episode guard: its memory state, else its bytes (every key, sorted; but the
    frame's key, where the frame is declared: the slots are compass slots then, the same at every heading)."""
    if isinstance(batch, Mapping):
        arrays = [np.asarray(batch[key]) for key in sorted(batch) if key != frame_key]
    else:
        arrays = [np.asarray(batch)]
    return [
        int(state) if state >= 0 else b"".join(array[row].tobytes() for array in arrays)
        for row, state in enumerate(states.tolist())
    ]


class _Remembering:
    """A replay buffer seen through the route memory: each ``add`` is remembered, then stored (with its places where
    the buffer revises)."""

    def __init__(self, layer: RouteMemoryLayer, buffer: ReplayBuffer) -> None:
        self.layer = layer
        self.buffer = buffer

    def add(
        self, obs: Any, next_obs: Any, action: np.ndarray, reward: np.ndarray, done: np.ndarray, infos: Any
    ) -> None:
        memory = self.layer.memory
        assert memory is not None
        truncated = np.array([info.get("TimeLimit.truncated", False) for info in infos], dtype=bool)
        terminated = np.asarray(done, dtype=bool).reshape(-1) & ~truncated
        rewards = np.asarray(reward, dtype=np.float64).reshape(-1)
        actions = np.asarray(action).reshape(-1)
        successes = self.layer._successes(infos, rewards, terminated)
        memory.add_batch(obs, actions, next_obs, rewards, terminated, successes)
        if isinstance(self.buffer, RevisionReplay):
            places = self.layer._place_keys(obs, actions, next_obs)
            self.buffer.add(obs, next_obs, action, reward, done, infos, places=places)
        else:
            self.buffer.add(obs, next_obs, action, reward, done, infos)


def _with_revision(buffer_class: type[ReplayBuffer] | None, is_dict: bool, one_step: bool) -> type[ReplayBuffer] | None:
    """The buffer class with the ``revision`` variant, where it combines (one-step transitions, next observations
    stored: not with n-step returns nor ``optimize_memory_usage``; not a user's own class); else as given."""
    if not one_step or (isinstance(buffer_class, type) and issubclass(buffer_class, RevisionReplay)):
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


def _as_batch(policy: Any, observation: Any) -> tuple[bool, Any]:
    """Whether ``observation`` is a batch, and it as one."""
    batched = policy.is_vectorized_observation(observation)
    return batched, observation if batched else batch_of_one(observation)


def _channel_first(observation: Any, space: spaces.Space) -> Any:
    """
    An observation as the memory met it in training: an image channel first, as SB3's ``VecTransposeImage`` gave it
    (a raw env's channel-last image, the one users pass to ``predict``, transposed as SB3's policy transposes it).
    """
    if isinstance(space, spaces.Dict) and isinstance(observation, Mapping):
        return {
            key: maybe_transpose(np.asarray(value), space[key])
            if key in space.spaces and is_image_space(space[key])
            else value
            for key, value in observation.items()
        }
    return maybe_transpose(np.asarray(observation), space) if is_image_space(space) else observation


def _rows(batch: Any) -> int:
    first = next(iter(batch.values())) if isinstance(batch, Mapping) else batch
    return int(np.asarray(first).shape[0])


# ------------------------------------------------------------------------------------------------ making the classes
_MADE: dict[type, type] = {}


def with_route_memory(algorithm_class: type[OffPolicyAlgorithm]) -> type[OffPolicyAlgorithm]:
    """
    The algorithm class wearing the route memory: a subclass that takes ``route_memory=`` (see
    :class:`RouteMemoryLayer`), made once per class (``with_route_memory(DQN) is with_route_memory(DQN)``) and named
    ``RouteMemory<Algorithm>`` in this module (it pickles, and loads in a fresh process).

    :param algorithm_class: A discrete off-policy SB3 algorithm class (``DQN``, ``QRDQN``, ``DCQN``, a subclass); a
        class that wears the memory already is returned as it is
    :raises ValueError: for anything but an off-policy algorithm class
    """
    if not (isinstance(algorithm_class, type) and issubclass(algorithm_class, OffPolicyAlgorithm)):
        raise ValueError(
            f"with_route_memory takes a discrete off-policy SB3 algorithm class (DQN, QRDQN, DCQN), got "
            f"{algorithm_class!r}"
        )
    if issubclass(algorithm_class, RouteMemoryLayer):
        return algorithm_class
    made = _MADE.get(algorithm_class)
    if made is None:
        taken = {cls.__name__ for cls in _MADE.values()}
        name, count = f"{_PREFIX}{algorithm_class.__name__}", 1
        while name in taken:  # another module's algorithm of the same name
            count += 1
            name = f"{_PREFIX}{algorithm_class.__name__}{count}"
        doc = (
            f"{algorithm_class.__name__} wearing the route memory (:func:`sb3_dcqn.with_route_memory`): "
            f"{algorithm_class.__name__}'s parameters, and ``route_memory`` (:class:`{__name__}.RouteMemoryLayer`)."
        )
        namespace = {"__module__": __name__, "__qualname__": name, "__doc__": doc, "bare_class": algorithm_class}
        made = type(name, (RouteMemoryLayer, algorithm_class), namespace)
        _MADE[algorithm_class] = made
    return made


def algorithm_class_for(algorithm_class: type[OffPolicyAlgorithm], hyperparams: Mapping[str, Any]) -> type:
    """
    The class whose constructor takes these keyword arguments (an entry's, or a saved model's data): the algorithm
    wearing the route memory where they give ``route_memory`` (``route_memory: false`` too: the zoo passes an entry's
    keys to the class as they are), the algorithm itself elsewhere. Whether the memory is on is the model's
    ``wears_route_memory`` (:func:`memory_settings`), never this choice.

    :param algorithm_class: The algorithm (``DCQN``, ``DQN``, ``QRDQN``)
    :param hyperparams: Its keyword arguments
    """
    return with_route_memory(algorithm_class) if "route_memory" in hyperparams else algorithm_class


def saved_algorithm_class(path: str | Path, algorithm_class: type[OffPolicyAlgorithm]) -> type:
    """
    The class that loads a model file saved by ``algorithm_class`` or by it wearing the route memory: the memory-
    wearing class where the file holds the ``route_memory`` setting (``algorithm_class.load`` would drop the memory
    and act without it).

    :param path: The model's zip (SB3's ``save``; the ``.zip`` may be left out, as ``load`` allows)
    :param algorithm_class: The algorithm (``DCQN``, ``DQN``, ``QRDQN``)
    """
    path = Path(path)
    if not path.is_file() and path.with_suffix(".zip").is_file():
        path = path.with_suffix(".zip")
    with zipfile.ZipFile(path) as archive:
        data = json.loads(archive.read("data").decode())
    return algorithm_class_for(algorithm_class, data)


def algorithm_name(model_or_class: Any, *, for_files: bool = False) -> str:
    """
    What ran, for tables, summaries and TensorBoard: the algorithm, and whether it wore the route memory.

    :param model_or_class: A model, or an algorithm class
    :param for_files: The spelling for run folders (TensorBoard's): ``"DQN-memory"`` instead of ``"DQN + memory"``
    :return: ``"DCQN"``, ``"DCQN + memory"``, ``"QRDQN + memory"``, ...; a model whose ``route_memory`` is off is
        named by its algorithm alone
    """
    cls = model_or_class if isinstance(model_or_class, type) else type(model_or_class)
    bare = getattr(cls, "bare_class", cls)
    # A class is named as it can run; a model as it runs (the property reads its setting through memory_settings)
    wears = issubclass(cls, RouteMemoryLayer) and (
        isinstance(model_or_class, type) or model_or_class.wears_route_memory
    )
    if not wears:
        return bare.__name__
    return f"{bare.__name__}-memory" if for_files else f"{bare.__name__} + memory"


RouteMemoryDQN = with_route_memory(DQN)
RouteMemoryDCQN = with_route_memory(DCQN)


def __getattr__(name: str) -> Any:
    # A made class by its name (PEP 562), for unpickling: made in this process, or made now from a known algorithm
    for made in _MADE.values():
        if made.__name__ == name:
            return made
    bare = name[len(_PREFIX) :] if name.startswith(_PREFIX) else ""
    if bare in _ALGORITHM_HOMES:
        return with_route_memory(getattr(importlib.import_module(_ALGORITHM_HOMES[bare]), bare))
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
