"""The experience-graph floor's agent and run, shared by the scripts that report a floor beside a learner
(``experience_graph_floor.py``, its own tables; ``city_scale.py``, one city entry at every size). What the agent
does and why it is a floor: ``experience_graph_floor.py``'s docstring."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from benchmarks.scale_common import GOAL, PIXELS, env_kwargs_for, make_graph
from campusnav_env.env import CampusNavEnv
from campusnav_env.features.view_build import with_view_build
from campusnav_env.recovery import RouteEvaluation
from campusnav_env.route_evaluation import RouteReport, evaluate_routes
from sb3_dcqn.campusnav.solved import is_solved
from sb3_dcqn.route_memory import RouteMemory, batch_of_one, select_rows

FIXED_ACTION = 0  # forward: what the agent does where it knows nothing
# What the agent knows of the env: its declared frame (places, compass slots, two-way roads), or exact observations
MEMORIES = ("places", "poses")
RUNS_LINE = "runs one after another in one process, evaluations included in the wall time"


def default_eval_every(n_nodes: int) -> int:
    """Env steps between evaluations: an evaluation routes all ~4N (start, heading) pairs, so sparser on big maps."""
    return 250 if n_nodes <= 200 else 2_500 if n_nodes <= 2_000 else 25_000


@dataclass(frozen=True)
class FloorResult:
    """
    One run of the experience-graph floor.

    :param solved: Whether an evaluation found the map solved within the step cap
    :param env_steps: Env steps at that evaluation (or at the cap)
    :param episodes: Episodes started by then
    :param wall_seconds: Wall time, evaluations included
    :param evaluation_seconds: Of which evaluations
    :param evaluations: Evaluations run
    :param success: Success rate of the last evaluation
    :param spl: SPL of the last evaluation
    :param states: States remembered (places, or (observation) poses)
    :param tried: (state, slot) pairs tried
    :param driven_solved_steps: Env steps at the first evaluation at the solved bar on the routes from the states a
        move leads to (the start-only states left out: the coverage of random starts aside), ``None`` if never
    :param driven_solved_episodes: Episodes started by then
    """

    solved: bool
    env_steps: int
    episodes: int
    wall_seconds: float
    evaluation_seconds: float
    evaluations: int
    success: float
    spl: float
    states: int
    tried: int
    driven_solved_steps: int | None = None
    driven_solved_episodes: int | None = None


class FloorAgent:
    """
    The experience-graph agent (see the module docstring): explores towards untried actions, then plans.

    :param graph: Its memory of transitions (empty to start with)
    :param fixed_action: The action where it knows nothing
    """

    def __init__(self, graph: RouteMemory, fixed_action: int = FIXED_ACTION) -> None:
        self.graph = graph
        self.fixed_action = fixed_action
        # The exploration path being driven: the states it expects to pass and the action at each
        self._path: list[tuple[int, int]] = []

    def act(self, observation: Any) -> int:
        """The training action at one (unbatched) observation."""
        batch = batch_of_one(observation)
        state = int(self.graph.states_of(batch, add=True)[0])
        if not (self._path and self._path[0][0] == state):
            slots = self.graph.path_to_untried(state)
            if slots is None:
                self._path = []
                route = int(self.graph.route_actions(batch)[0])
                return route if route >= 0 else self.fixed_action
            self._path = self._states_along(state, slots)
        return int(self.graph.slot_actions(batch, np.array([self._path.pop(0)[1]]))[0])

    def _states_along(self, state: int, slots: list[int]) -> list[tuple[int, int]]:
        """The (state, slot) pairs of a path of known edges (its last slot untried)."""
        pairs = []
        for slot in slots:
            pairs.append((state, slot))
            state = int(self.graph.target[state, slot])
        return pairs

    def policy(self, observations: Any) -> np.ndarray:
        """The greedy batch policy that is evaluated: plan, else explore, else the fixed action."""
        actions = self.graph.route_actions(observations)
        unplanned = actions < 0
        if unplanned.any():
            actions[unplanned] = self.graph.explore_actions(select_rows(observations, unplanned))
        actions[actions < 0] = self.fixed_action
        return actions


def floor_steps(
    env: CampusNavEnv,
    seed: int,
    eval_every: int,
    max_env_steps: int | None = None,
    memory: str = "places",
    sample: int | None = None,
) -> FloorResult:
    """
    Run the experience-graph agent on ``env`` until its greedy policy solves the map (or ``max_env_steps``).

    :param env: The environment (its goals, closures and ``max_steps`` apply)
    :param seed: Seed of the env's starts (the agent itself is deterministic)
    :param eval_every: Env steps between evaluations
    :param max_env_steps: Step cap (default: 200 steps per (observation, action) pair, far beyond need)
    :param memory: ``"places"`` (the env's declared frame) or ``"poses"`` (exact observations)
    :param sample: Check a seeded sample of this many (start, heading) pairs at each evaluation and every pair only
        once the sample is at the bar (a large city); None: every pair at every evaluation
    :return: the run's figures
    """
    if eval_every < 1:
        raise ValueError(f"eval_every must be at least 1, got {eval_every}")
    if memory not in MEMORIES:
        raise ValueError(f"memory must be one of {MEMORIES}, got {memory!r}")
    # The floor keeps exact observations: its places are told apart bit for bit, as the fixed views repeat
    graph = RouteMemory.for_env(env, place_frame="auto" if memory == "places" else None, recognition="exact")
    agent = FloorAgent(graph)
    driven = entered_states(env)  # for the report only: the agent is never told
    cap = max_env_steps if max_env_steps is not None else 200 * env.graph.transition_table.size
    start = time.perf_counter()
    evaluation_seconds = 0.0
    steps = episodes = evaluations = 0
    evaluation: RouteEvaluation | None = None
    driven_solved: tuple[int, int] | None = None
    solved = False
    observation, _ = env.reset(seed=seed)
    while steps < cap and not solved:
        episodes += 1
        done = False
        while not done and steps < cap:
            action = agent.act(observation)
            next_observation, reward, terminated, truncated, info = env.step(action)
            graph.add(observation, action, next_observation, float(reward), terminated, info.get("is_success"))
            steps += 1
            observation, done = next_observation, terminated or truncated
            if steps % eval_every == 0:
                began = time.perf_counter()
                report = evaluate_routes(env, agent.policy, sample=sample, seed=evaluations, keep_nodes=False)
                if report.is_sample and is_solved(RouteEvaluation(steps, episodes, 0.0, report)):
                    report = evaluate_routes(env, agent.policy, keep_nodes=False)  # only every pair counts
                evaluation_seconds += time.perf_counter() - began
                evaluations += 1
                evaluation = RouteEvaluation(steps, episodes, time.perf_counter() - start, report)
                if driven_solved is None and is_solved(routes_from(evaluation, env, driven)):
                    driven_solved = steps, episodes
                solved = is_solved(evaluation)
                if solved:
                    break
        if done:
            observation, _ = env.reset()
    return FloorResult(
        solved=solved,
        env_steps=steps,
        episodes=episodes,
        wall_seconds=time.perf_counter() - start,
        evaluation_seconds=evaluation_seconds,
        evaluations=evaluations,
        success=evaluation.success_rate if evaluation else 0.0,
        spl=evaluation.spl if evaluation else 0.0,
        states=graph.n_states,
        tried=graph.n_tried,
        driven_solved_steps=driven_solved[0] if driven_solved else None,
        driven_solved_episodes=driven_solved[1] if driven_solved else None,
    )


def entered_states(env: CampusNavEnv) -> np.ndarray:
    """Whether a move leads to each state (node, heading); the others the agent sees only as an episode's start."""
    table = env.graph.transition_table
    entered = np.zeros(table.shape[0], dtype=bool)
    entered[table[table >= 0]] = True
    return entered


def start_only_states(env: CampusNavEnv) -> int:
    """States no move leads to, the goal's excluded: seeing them all waits on the env's random starts."""
    goal_states = np.isin(env.graph.map.state_nodes, env.goal_nodes)
    return int((~entered_states(env) & ~goal_states).sum())


def routes_from(evaluation: RouteEvaluation, env: CampusNavEnv, starts: np.ndarray) -> RouteEvaluation:
    """The evaluation's routes from the start states marked in ``starts`` only."""
    state_of = env.graph.map.state_of
    kept = [route for route in evaluation.report.routes if starts[state_of[route.start, route.heading]]]
    return replace(evaluation, report=RouteReport(kept))


def make_env(n_nodes: int, map_seed: int = 0) -> CampusNavEnv:
    """
    The floor's env: the generated map of ``n_nodes`` (the built-in campus at 101, map seed 0), goal Dreese Lab,
    pixels. ``map_seed``: the city's (``CampusNavCity-v0``'s ``map_seed``); 0 is the maps of the scale benchmarks.
    """
    from campusnav_env.maps.campus import generate_city

    world = make_graph(n_nodes, "scaled") if map_seed == 0 else generate_city(n_nodes, seed=map_seed)
    return CampusNavEnv(world=world, goals=GOAL, **with_view_build(env_kwargs_for(PIXELS), progress=False))


def run_one(
    n_nodes: int,
    seed: int,
    eval_every: int,
    quick: bool,
    max_env_steps: int | None = None,
    env: CampusNavEnv | None = None,
    map_seed: int = 0,
    memory: str = "places",
    sample: int | None = None,
) -> dict[str, Any]:
    """One run as a JSON-lines record (``env``: the size's env on that map seed, if already built; ``sample``: as
    :func:`floor_steps`'s)."""
    env = make_env(n_nodes, map_seed) if env is None else env
    result = floor_steps(env, seed, eval_every, max_env_steps, memory, sample)
    return {
        "memory": memory,
        "size": n_nodes,
        "map_seed": map_seed,
        "seed": seed,
        "eval_every": eval_every,
        "quick": quick,
        "max_env_steps": max_env_steps,
        "state_actions": int(env.graph.transition_table.size),
        "start_only_states": start_only_states(env),
        **asdict(result),
    }
