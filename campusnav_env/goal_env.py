"""CampusNavGoal: CampusNav with any intersection as the goal, in SB3's goal-env convention (for HER)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from os import PathLike
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from campusnav_env.env import (
    DEFAULT_ENCODER,
    CampusNavEnv,
    auto_max_steps,
    place_frame,
    resolve_goals,
    resolve_world,
)
from campusnav_env.features.encoders import ViewEncoder, make_encoder
from campusnav_env.features.view_build import ViewBuild
from campusnav_env.maps.navigation import NavigationGraph
from campusnav_env.maps.road_graph import RoadGraph
from campusnav_env.rendering.street_view import RenderSettings

# Two goal vectors are the same place when no entry differs by more than this (features are whitened, O(1))
GOAL_MATCH_TOLERANCE = 1e-4


class CampusNavGoalEnv(CampusNavEnv):
    """
    ## Description
    CampusNav (see :class:`~campusnav_env.env.CampusNavEnv`) where every intersection can be the goal, with the
    observation in SB3's goal-env convention, so that SB3's ``HerReplayBuffer`` can relabel any transition with a
    goal the agent actually reached. The goal is still given only as pictures: the four views at the goal.

    ## Action Space
    ``Discrete(4)``, relative to the heading: 0 forward, 1 right, 2 back, 3 left (as in CampusNav).

    ## Observation Space
    A ``Dict`` (features mode only), each view block of size D as in CampusNav (``view_dim`` when set):

    - ``"observation"``: ``Box(4 * D,)`` float32, the current intersection's views (N, E, S, W), closure barriers
      included with ``visible_closures``;
    - ``"achieved_goal"``: ``Box(4 * D,)`` float32, the current intersection as a goal is pictured: its open-map views
      under the goal's render settings (``goal_render_settings``), so that at the goal it equals ``"desired_goal"``;
    - ``"desired_goal"``: ``Box(4 * D,)`` float32, the goal's views, pictured in the same way;
    - ``"heading"``: ``Box(0, 1, (4,))`` float32, the one-hot compass heading.

    ## Frame
    As CampusNav's (``metadata["place_frame"]``), with ``"observation"`` picturing the place and ``"desired_goal"``
    the goal place (goal pictures in other conditions than the agent's views need no declaration: the memory
    recognises each picture or is unsure of it). ``"achieved_goal"`` is left out of the declaration: it is the env's
    rendering of the agent's location under the goal's conditions, which HER may use and a fair memory must not.

    ## Rewards
    As in CampusNav: ``goal_reward`` (+1.0) on reaching the goal, ``collision_penalty`` (-0.01) for an action with no
    open road that way, ``step_penalty`` (-0.005) otherwise. :meth:`compute_reward` gives the same from
    ``(achieved_goal, desired_goal, info)``, vectorised; the collision comes from ``info["collision"]`` (every
    ``info`` of :meth:`step` carries it; :class:`sb3_dcqn.replay.DCQNHerReplayBuffer` keeps it per transition,
    SB3's ``HerReplayBuffer`` needs ``copy_info_dict=True``). :meth:`compute_terminated` is true where the goal is
    reached.

    ## Starting State
    A goal drawn uniformly from ``goals``, then a uniformly random intersection that can reach it and a random
    heading. ``reset(options={"goal": g})`` may name any intersection (node id or landmark name), held-out ones
    included: that is how a policy is evaluated on goals it never trained on.

    ## Episode End
    Terminated on reaching the goal; truncated after ``max_steps`` steps (default 200). ``max_steps="auto"``
    (:func:`~campusnav_env.env.auto_max_steps`) follows the goals episodes draw (``goals``), not every intersection a
    goal may be asked for or relabelled to: on the seed-0 city of 1,000 intersections with ``goals=["Dreese Lab"]``,
    200, as CampusNavCity's own cap (every intersection's longest route would make it 240).

    ## Goals never trained on
    ``held_out_goals`` are never drawn as an episode's goal and :meth:`relabelling_allowed` is false for them, which
    DCQN's HER buffer obeys (the strict protocol: the agent may drive through a held-out intersection, it is never told
    that it is a goal). For the lenient protocol leave them out of ``goals`` without holding them out.

    ## Arguments
    ```python
    gym.make("CampusNavGoal-v0")                                   # every intersection a goal
    gym.make("CampusNavGoal-v0", goals=train_nodes, held_out_goals=test_nodes, view_dim=64)
    gym.make("CampusNavGoal-v0", goal_render_settings=RenderSettings(time_of_day="dusk"))
    ```
    - ``goals``: node ids or landmark names episodes draw their goal from (default: every intersection not held
      out).
    - ``held_out_goals``: node ids or landmark names never drawn and never relabelling targets.
    - ``goal_render_settings``: how the goal's pictures are taken (time of day, passing cars; default: as the agent's
      views, ``render_settings``); the features go through the projection fit on the agent's own views. A sequence of
      conditions (``None`` among them: as the agent's views) pictures each episode's goal in one drawn uniformly
      (``reset(options={"goal_condition": k})`` picks one): training on goals photographed in several conditions.
      Between episodes, :meth:`observations_at` uses the last episode's condition.
    - every other argument as in :class:`~campusnav_env.env.CampusNavEnv` (``world``, ``map_coords``, ``view_dim``,
      ``view_variation``, ``visible_closures``, ``encoder``, ``view_build``, ...); ``observation_mode`` must be
      ``"features"``.

    With ``view_variation`` the agent's views vary between visits (see CampusNav) while ``"achieved_goal"`` and
    ``"desired_goal"`` stay each intersection's first render (a photo of the goal taken once, and the same photo of
    wherever the agent is, so that HER's relabelled goals and :meth:`compute_reward` keep working); goals pictured in
    other conditions (``goal_render_settings``) are fixed pictures in those conditions.

    ## Information
    As in CampusNav (``node``, ``goal_node``, ``collision``, ``shortest_distance``, ``action_mask``, ``is_success``).

    ## Version History
    * v0: Initial version (CampusNav's arguments about building the views since gathered into ``view_build``;
      ``view_variation`` added).
    """

    views_key = "observation"
    # The info keys :meth:`compute_reward` reads: a HER buffer keeps these per transition
    reward_info_keys = ("collision",)

    def __init__(
        self,
        world: str | PathLike[str] | RoadGraph | NavigationGraph = "campus",
        goals: Sequence[str | int] | None = None,
        held_out_goals: Sequence[str | int] = (),
        goal_render_settings: RenderSettings | Sequence[RenderSettings | None] | None = None,
        observation_mode: str = "features",
        encoder: str | ViewEncoder = DEFAULT_ENCODER,
        max_steps: int | str = 200,
        map_coords: str = "auto",
        view_build: ViewBuild | Mapping[str, Any] | None = None,
        **env_kwargs: Any,
    ) -> None:
        if observation_mode != "features":
            raise ValueError(
                f"CampusNavGoal needs observation_mode='features' (goals are compared as feature vectors), "
                f"got {observation_mode!r}"
            )
        graph = resolve_world(world, map_coords)
        every_node = list(range(graph.n_nodes))
        _, held_out = resolve_goals(graph.map, list(held_out_goals)) if len(held_out_goals) else ([], [])
        if goals is None:
            training = [node for node in every_node if node not in set(held_out)]
        else:
            _, training = resolve_goals(graph.map, goals)
        overlap = sorted(set(training) & set(held_out))
        if overlap:
            raise ValueError(f"goals and held_out_goals share intersections {overlap}: a held-out goal is never drawn")
        if not training:
            raise ValueError("CampusNavGoal: no goal left to draw (every intersection is held out)")
        if max_steps == "auto":  # the routes to the goals episodes draw: the parent is given every intersection
            max_steps = auto_max_steps(graph, training)
        conditions = _as_conditions(goal_render_settings)
        view_build = ViewBuild.of(view_build)
        if isinstance(encoder, str) and any(settings is not None for settings in conditions):
            # One CNN for the views and every condition
            encoder = make_encoder(encoder, **view_build.encoder_kwargs)
        super().__init__(
            world=graph,  # a file's map is read once, here: map_coords has done its work
            goals=every_node,  # every intersection can be asked for (reset options, evaluation); draws use `goals`
            observation_mode=observation_mode,
            encoder=encoder,
            max_steps=max_steps,
            view_build=view_build,
            **env_kwargs,
        )
        self.training_goals: list[int] = training
        self.held_out_goals: frozenset[int] = frozenset(held_out)
        # One table of goal vectors per condition the goals are pictured in (None: as the agent sees the views)
        tables = []
        for settings in conditions:
            if settings is None:  # the agent's views (their first render on a varied world: a photo taken once)
                tables.append(self._open_views.reshape(self.graph.n_nodes, -1))
                continue
            source = self.make_view_source(graph.map, "features", encoder, pictured_in=settings)
            tables.append(self._features.transform(source.open_views()).reshape(self.graph.n_nodes, -1))
        self.goal_conditions: tuple[RenderSettings | None, ...] = conditions
        self._goal_tables = np.stack(tables)  # (conditions, nodes, 4 * D)
        self._condition = 0  # the condition of the current episode's goal pictures
        self._node_of_goal = _unique_rows(self._goal_tables)
        self.observation_space = self._goal_observation_space(unbounded=self.visible_closures)
        self.metadata = {**type(self).metadata, "place_frame": place_frame("observation", "desired_goal")}

    @property
    def _goal_rows(self) -> np.ndarray:
        """The goal vectors of every intersection, as pictured in the current episode's condition."""
        return self._goal_tables[self._condition]

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray] | np.ndarray, dict[str, Any]]:
        options = dict(options or {})
        condition = options.pop("goal_condition", None)
        if seed is not None:
            gym.Env.reset(self, seed=seed)  # seed first: the condition is drawn from the env's rng
        if condition is None:
            condition = int(self.np_random.integers(len(self.goal_conditions))) if len(self.goal_conditions) > 1 else 0
        if not 0 <= int(condition) < len(self.goal_conditions):
            raise ValueError(
                f"CampusNavGoal.reset: goal_condition {condition} out of range [0, {len(self.goal_conditions)})"
            )
        self._condition = int(condition)
        return super().reset(options=options)

    def _goal_observation_space(self, *, unbounded: bool) -> spaces.Dict:
        if unbounded or self.goal_conditions != (None,):  # goals pictured otherwise may leave the views' range
            low, high = float(np.finfo(np.float32).min), float(np.finfo(np.float32).max)
        else:  # the range of CampusNav's view space
            low, high = (
                float(self.observation_space["views"].low.min()),
                float(self.observation_space["views"].high.max()),
            )
        vector = spaces.Box(low, high, shape=(self._goal_tables.shape[2],), dtype=np.float32)
        return spaces.Dict(
            {
                "observation": vector,
                "achieved_goal": vector,
                "desired_goal": vector,
                "heading": spaces.Box(0.0, 1.0, shape=(4,), dtype=np.float32),
            }
        )

    # --- goals ----------------------------------------------------------------------------------------------------

    def _draw_goal_index(self) -> int:
        return self.goal_nodes.index(self.training_goals[int(self.np_random.integers(len(self.training_goals)))])

    def _feature_observations(
        self, views: np.ndarray, nodes: np.ndarray, headings: np.ndarray, goal_nodes: np.ndarray
    ) -> dict[str, np.ndarray]:
        return {
            "observation": views.reshape(nodes.size, -1),
            "achieved_goal": self._goal_rows[nodes],
            "desired_goal": self._goal_rows[goal_nodes],
            "heading": np.eye(4, dtype=np.float32)[headings],
        }

    def goal_vector(self, goal: str | int) -> np.ndarray:
        """The ``desired_goal`` vector of a goal (node id or landmark name)."""
        return self._goal_rows[self.goal_nodes[self._goal_index_of(goal)]].copy()

    def goal_nodes_of(self, goals: np.ndarray) -> np.ndarray:
        """
        The intersections that goal vectors picture (the inverse of :meth:`goal_vector`).

        :param goals: ``(..., 4 * D)`` goal vectors, as in ``achieved_goal`` / ``desired_goal``
        :return: int64 node ids, shape ``goals.shape[:-1]``
        :raises ValueError: if a vector is no intersection's goal vector
        """
        goals = np.asarray(goals, dtype=np.float32)
        flat = goals.reshape(-1, self._goal_rows.shape[1])
        nodes = np.array([self._node_of_goal.get(row.tobytes(), -1) for row in flat], dtype=np.int64)
        missing = np.flatnonzero(nodes < 0)
        if missing.size:  # not bit-equal (another code path): the nearest row of any condition, within the tolerance
            rows = self._goal_tables.reshape(-1, flat.shape[1])
            distance = np.abs(flat[missing, None, :] - rows[None]).max(axis=2)
            nearest = distance.argmin(axis=1)
            if (distance[np.arange(missing.size), nearest] > GOAL_MATCH_TOLERANCE).any():
                raise ValueError("goal_nodes_of: some goal vectors picture no intersection of this env")
            nodes[missing] = nearest % self.graph.n_nodes
        return nodes.reshape(goals.shape[:-1])

    def relabelling_allowed(self, goals: np.ndarray) -> np.ndarray:
        """Whether each goal vector may be a relabelled goal (false for held-out goals: the strict protocol)."""
        if not self.held_out_goals:  # every goal allowed: no lookup
            return np.ones(np.shape(goals)[:-1], dtype=bool)
        return ~np.isin(self.goal_nodes_of(goals), list(self.held_out_goals))

    # --- the goal-env interface (vectorised) ---------------------------------------------------------------------

    def compute_terminated(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray | bool:
        """True where ``achieved_goal`` pictures the same intersection as ``desired_goal`` (the goal is reached)."""
        difference = np.abs(np.asarray(achieved_goal, np.float32) - np.asarray(desired_goal, np.float32))
        reached = difference.max(axis=-1) <= GOAL_MATCH_TOLERANCE
        return bool(reached) if reached.ndim == 0 else reached

    def compute_truncated(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray | bool:
        """Never from the goals: episodes are truncated by the step limit alone."""
        shape = np.shape(achieved_goal)[:-1]
        return False if shape == () else np.zeros(shape, dtype=bool)

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray | float:
        """
        The reward :meth:`step` gives for reaching ``achieved_goal`` when heading for ``desired_goal``.

        :param achieved_goal: ``(4 * D,)`` or ``(batch, 4 * D)`` (the next observation's achieved goal)
        :param desired_goal: Same shape
        :param info: The step's info dict, or a sequence (or array) of them, or a dict of arrays, each with
            ``"collision"``
        :return: the reward (a float for one transition, a float64 array for a batch)
        :raises KeyError: if an info lacks ``"collision"``
        """
        reached = np.asarray(self.compute_terminated(achieved_goal, desired_goal, info))
        collision = _collisions(info, reached.shape)
        reward = np.where(reached, self.goal_reward, np.where(collision, self.collision_penalty, self.step_penalty))
        return float(reward) if reward.ndim == 0 else reward.astype(np.float64)


def _collisions(info: Any, shape: tuple[int, ...]) -> np.ndarray:
    """The ``"collision"`` flags of one info dict, a dict of arrays, or a sequence of info dicts."""
    try:
        if isinstance(info, Mapping):
            return np.broadcast_to(np.asarray(info["collision"], dtype=bool), shape)
        flags = np.array([bool(item["collision"]) for item in _as_list(info)], dtype=bool)
    except (KeyError, TypeError):
        raise KeyError(
            "CampusNavGoal.compute_reward needs info['collision'] (a collision is penalised more than a step): "
            "SB3's HerReplayBuffer keeps infos only with copy_info_dict=True; DCQN's HER buffer keeps the flag"
        ) from None
    return flags.reshape(shape)


def _as_list(info: Any) -> list[Any]:
    return list(info.reshape(-1)) if isinstance(info, np.ndarray) else list(info)


def _unique_rows(tables: np.ndarray) -> dict[bytes, int]:
    """Row bytes -> node, over every condition's table; two intersections pictured alike could not be told apart."""
    index: dict[bytes, int] = {}
    for table in tables:
        for node, row in enumerate(table):
            other = index.setdefault(row.tobytes(), node)
            if other != node:
                raise ValueError(
                    f"intersections {other} and {node} have the same goal views: a goal pictures one place"
                )
    return index


def _as_conditions(
    goal_render_settings: RenderSettings | Sequence[RenderSettings | None] | None,
) -> tuple[RenderSettings | None, ...]:
    if goal_render_settings is None or isinstance(goal_render_settings, RenderSettings):
        return (goal_render_settings,)
    conditions = tuple(goal_render_settings)
    if not conditions:
        raise ValueError("goal_render_settings: give at least one condition (None: as the agent's views)")
    for item in conditions:
        if item is not None and not isinstance(item, RenderSettings):
            raise TypeError(f"goal_render_settings: expected RenderSettings or None, got {type(item).__name__}")
    return conditions


def held_out_split(n_nodes: int, fraction: float, seed: int) -> tuple[list[int], list[int]]:
    """
    A seeded split of intersections ``0 .. n_nodes - 1`` into training goals and held-out goals.

    :param n_nodes: Number of intersections
    :param fraction: Share held out (rounded to the nearest count, at least one when > 0)
    :param seed: Seed of the draw
    :return: ``(training, held_out)``, both sorted
    """
    if not 0.0 <= fraction < 1.0:
        raise ValueError(f"held-out fraction must be in [0, 1), got {fraction}")
    count = max(1, round(fraction * n_nodes)) if fraction > 0 else 0
    held_out = np.random.default_rng(seed).choice(n_nodes, size=count, replace=False)
    held = sorted(int(node) for node in held_out)
    return [node for node in range(n_nodes) if node not in set(held)], held


def goal_names(env: CampusNavEnv, nodes: Iterable[int]) -> list[str]:
    """The env's names (landmark or ``"node k"``) of intersections."""
    return [env.goal_names[env.goal_nodes.index(int(node))] for node in nodes]
