"""The route memory in a stochastic world: a (state, move) that leads to several states by chance is a model to plan
on (outcome counts, value iteration), not two look-alike places; a closure in a deterministic world stays a closure.

World: Gymnasium's FrozenLake 8x8, slippery (each move goes the intended way or either side, a third each) and not.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from sb3_dcqn.route_memory import RouteMemory
from sb3_dcqn.route_memory.edges import STOCHASTIC_CHANGES, EdgeStore, Outcome
from sb3_dcqn.route_memory.explorer import UntriedExplorer
from sb3_dcqn.route_memory.layer import RouteMemoryDQN
from sb3_dcqn.route_memory.planner import PLAN_DISCOUNT

EPISODES = 300


def slippery() -> gym.Env:
    return gym.make("FrozenLake-v1", is_slippery=True, map_name="8x8")


def optimal_actions(env: gym.Env, discount: float = PLAN_DISCOUNT) -> np.ndarray:
    """The optimal policy of FrozenLake's own model (value iteration at the planner's discount)."""
    table = env.unwrapped.P  # state -> action -> [(probability, next state, reward, terminated)]
    values = np.zeros(len(table))

    def value(state: int, action: int) -> float:
        return sum(p * (r + (0.0 if end else discount * values[s])) for p, s, r, end in table[state][action])

    for _ in range(3_000):
        q = np.array([[value(state, action) for action in table[state]] for state in range(len(table))])
        values = q.max(axis=1)
    return q.argmax(axis=1)


def success_rate(act: Any, episodes: int = EPISODES) -> float:
    """The share of ``episodes`` (seeded starts) that reach the goal, acting by ``act(observation, first_step)``."""
    env, wins = slippery(), 0.0
    for episode in range(episodes):
        observation, _ = env.reset(seed=episode)
        done, first = False, True
        while not done:
            observation, reward, terminated, truncated, _ = env.step(int(act(observation, first)))
            wins, done, first = wins + reward, terminated or truncated, False
    return wins / episodes


def sampled_tries(env: gym.Env, tries: int, seed: int) -> tuple[np.ndarray, ...]:
    """``tries`` samples of every (state, action) of FrozenLake's own model, shuffled: what a long random walk sees."""
    rng = np.random.default_rng(seed)
    rows = []
    for state, moves in env.unwrapped.P.items():
        if env.unwrapped.desc.flatten()[state] in b"HG":
            continue  # an episode ends there
        for action, outcomes in moves.items():
            probabilities = np.array([p for p, *_ in outcomes])
            for pick in rng.choice(len(outcomes), size=tries, p=probabilities / probabilities.sum()):
                _, following, reward, end = outcomes[pick]
                rows.append((state, action, following, reward, end))
    columns = np.array(rows, dtype=np.float64)[rng.permutation(len(rows))].T
    return columns[0].astype(np.int64), columns[1].astype(np.int64), columns[2].astype(np.int64), columns[3], columns[4]


def remember(memory: RouteMemory, tries: tuple[np.ndarray, ...]) -> None:
    """Remember the tries in order; FrozenLake's success is its reward (1 at the goal, the only one)."""
    states, actions, following, rewards, ends = tries
    memory.add_batch(states, actions, following, rewards, ends.astype(bool), successes=rewards > 0)


def test_a_slippery_world_is_planned_on_outcome_counts_as_well_as_its_own_model_allows() -> None:
    env = slippery()
    memory = RouteMemory.for_env(env, success_reward=0.0)  # FrozenLake says nothing of success: its reward does
    remember(memory, sampled_tries(env, tries=200, seed=0))
    statistics = memory.statistics()
    assert memory.aliased == set() and statistics["stochastic_moves"] > 100  # chance, not two places in one picture
    assert memory.speaks and statistics["prediction_accuracy"] > 0.9  # its predictions are the ends it has seen
    planned = np.array([memory.route_actions(np.array([state]))[0] for state in range(64)])
    optimal = optimal_actions(env)
    best = success_rate(lambda observation, _: optimal[observation])
    assert success_rate(lambda observation, _: planned[observation]) >= best - 0.03, best


def test_a_model_wearing_the_memory_evaluates_a_slippery_world_by_its_plan() -> None:
    env = slippery()
    model = RouteMemoryDQN("MlpPolicy", env, route_memory={"success_reward": 0.0}, seed=0)
    remember(model.memory, sampled_tries(env, tries=200, seed=1))
    planned = np.array([model.memory.route_actions(np.array([state]))[0] for state in range(64)])
    state: Any = None

    def act(observation: int, first: bool) -> int:
        nonlocal state
        action, state = model.predict(observation, state=state, episode_start=np.array([first]), deterministic=True)
        return int(action)

    # A slip into the wall leaves the agent where it was: chance, not a closed road the guard must ban
    assert success_rate(act) >= success_rate(lambda observation, _: planned[observation]) - 0.05


def test_a_closure_in_a_deterministic_world_is_a_closure_not_chance() -> None:
    edges = EdgeStore(4, count_outcomes=True)
    edges.ensure(3)
    for _ in range(5):
        edges.record(0, 1, following=1, arrival=-1, dead=False)
    for _ in range(5):  # closed: the agent stays
        edges.record(0, 1, following=0, arrival=-1, dead=False)
    assert edges.outcome[0, 1] == Outcome.BLOCKED and not edges.stochastic[0, 1] and edges.n_stochastic == 0
    edges.record(0, 1, following=1, arrival=-1, dead=False)  # reopened: two changes
    assert edges.outcome[0, 1] == Outcome.DRIVEN and not edges.stochastic[0, 1]
    for following in [0, 1, 0][:STOCHASTIC_CHANGES]:  # and by turns again: the world's chance
        edges.record(0, 1, following=following, arrival=-1, dead=False)
    assert edges.stochastic[0, 1] and edges.outcome[0, 1] == Outcome.DRIVEN and edges.target[0, 1] == 1


def test_revision_keeps_every_outcome_of_a_stochastic_move_in_the_replay_buffer() -> None:
    model = RouteMemoryDQN("MlpPolicy", slippery(), route_memory={"success_reward": 0.0}, learning_starts=5_000, seed=0)
    model.learn(3_000)  # the warm-up only: no gradient step, the buffer as the rollouts filled it
    buffer, size = model.replay_buffer, model.replay_buffer.size()
    observations = buffer.observations[:size].reshape(-1).astype(np.int64)  # FrozenLake's cell, as SB3 stores it
    ends = buffer.next_observations[:size].reshape(-1).astype(np.int64)
    moves = observations * 4 + buffer.actions[:size].reshape(-1).astype(np.int64)
    outcomes = {int(move): set(ends[moves == move].tolist()) for move in np.unique(moves)}
    memory = model.memory
    stochastic = [move for move in outcomes if memory.edges.stochastic[memory.state_of(np.array(move // 4)), move % 4]]
    assert len(stochastic) > 50
    # A new end of a stochastic move contradicts none stored: every end it had is still in the buffer
    assert np.mean([len(outcomes[move]) >= 2 for move in stochastic]) > 0.9


def test_a_move_tried_a_few_times_in_a_slippery_world_is_planned_on_what_it_did() -> None:
    env = slippery()
    memory = RouteMemory.for_env(env, success_reward=0.0)
    remember(memory, sampled_tries(env, tries=3, seed=2))
    values = memory.planner.values_to(memory.goal_states(np.array(0)))
    tried = np.isfinite(values)
    assert tried.sum() > 100 and (values[tried] >= 0).all() and (values[tried] <= 1.0).all()  # chances, discounted


def few_tries_of_one_move(env: gym.Env, state: int, action: int, tries: int) -> tuple[np.ndarray, ...]:
    """Every move of FrozenLake tried 200 times, but ``(state, action)`` only its first ``tries`` times."""
    states, actions, *rest = sampled_tries(env, tries=200, seed=3)
    kept = ((states != state) | (actions != action)).nonzero()[0]
    kept = np.sort(np.concatenate([kept, ((states == state) & (actions == action)).nonzero()[0][:tries]]))
    return tuple(column[kept] for column in (states, actions, *rest))


def test_a_move_tried_too_few_times_to_plan_on_is_sought_as_an_untried_one() -> None:
    env = slippery()
    memory = RouteMemory.for_env(env, success_reward=0.0)
    remember(memory, few_tries_of_one_move(env, state=1, action=2, tries=3))
    here = memory.state_of(np.array(1))
    assert memory.edges.is_undersampled(here, 2) and memory.edges.undersampled().sum() == 1
    # Three tries of a three-way slip are a guess: the explorer goes back to it before the goal's never-tried moves,
    # which no episode outlives
    assert memory.path_to_untried(here) == [2]
    assert UntriedExplorer(memory).actions_at(np.array([here]), np.array([1]))[0] == 2


def test_a_move_tried_once_in_a_deterministic_world_is_known() -> None:
    env = gym.make("FrozenLake-v1", is_slippery=False, map_name="8x8")
    memory = RouteMemory.for_env(env, success_reward=0.0)
    remember(memory, few_tries_of_one_move(env, state=1, action=2, tries=1))
    assert memory.edges.n_stochastic == 0 and not memory.edges.undersampled().any()
    assert memory.path_to_untried(memory.state_of(np.array(1))) != [2]
