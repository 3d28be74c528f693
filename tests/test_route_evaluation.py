"""Route evaluation: success, SPL, coverage and optimality gap of a policy from every start."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from campusnav_env import CampusNavEnv
from campusnav_env.features.view_build import ViewBuild
from campusnav_env.rendering.street_view import RenderSettings
from campusnav_env.route_evaluation import Route, RouteReport, evaluate_routes


@pytest.fixture(scope="module")
def env(shared_cache_dir: Path) -> CampusNavEnv:
    return CampusNavEnv(
        encoder="pixels",
        view_build=ViewBuild(
            render_settings=RenderSettings(width=64, height=48),
            cache_dir=shared_cache_dir,  # the session's (conftest.py): the campus's views are built once
            progress=False,
        ),
    )


def nodes_of(env: CampusNavEnv, observations: dict[str, np.ndarray]) -> np.ndarray:
    """The nodes that a batch of observations shows (read off the fixed views)."""
    return np.array([int(np.flatnonzero((env._node_views == views).all(axis=1))[0]) for views in observations["views"]])


def mixed(env: CampusNavEnv):
    """A deterministic policy whose routes end every way: back at nodes 0, 3, 6, ... (blocked at a dead end, a loop
    elsewhere), forward at nodes 2, 5, 8, ... and the shortest path elsewhere."""
    shortest = oracle(env)

    def act(observations: dict[str, np.ndarray]) -> np.ndarray:
        kind = nodes_of(env, observations) % 3
        return np.where(kind == 1, shortest(observations), np.array([2, 0, 0])[kind])

    return act


def pairs(report: RouteReport) -> list[tuple[str, int, int]]:
    return [(r.goal, r.start, r.heading) for r in report.routes]


def oracle(env: CampusNavEnv):
    """A policy that reads the node off the views and takes a shortest-path action."""

    def act(observations: dict[str, np.ndarray]) -> np.ndarray:
        actions = []
        goal = env.goal_nodes[0]
        distances = env.node_distances(goal)
        for views, heading in zip(observations["views"], observations["heading"], strict=True):
            node = int(np.flatnonzero((env._node_views == views).all(axis=1))[0])
            h = int(np.argmax(heading))
            for action in range(4):
                nxt = env.graph.transition_table[node * 4 + h, action]
                if nxt >= 0 and distances[nxt // 4] == distances[node] - 1:
                    actions.append(action)
                    break
        return np.array(actions)

    return act


def test_a_shortest_path_policy_scores_perfectly(env: CampusNavEnv) -> None:
    report = evaluate_routes(env, oracle(env))
    reachable = int((env.node_distances(env.goal_nodes[0]) > 0).sum())
    assert len(report.routes) == 4 * reachable  # every (node, heading) start
    assert report.success_rate == report.spl == report.coverage == 1.0
    assert report.optimality_gap == 0.0
    assert report.mean_steps == report.mean_shortest


class Remembering:
    """A model (SB3's ``predict``) that carries, per route, the state its last move led to, and counts the routes
    where that is not where the route now is (the evaluation mixed up the routes' states)."""

    def __init__(self, env: CampusNavEnv) -> None:
        self.env, self.act, self.mixed_up, self.starts = env, oracle(env), 0, []

    def predict(
        self,
        observations: dict[str, np.ndarray],
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
        nodes = nodes_of(self.env, observations)
        states = nodes * 4 + np.argmax(observations["heading"], axis=1)
        self.starts.append(np.asarray(episode_start).copy())
        if state is not None:
            self.mixed_up += int((state[0] != states)[~episode_start].sum())
        actions = self.act(observations)
        return actions, self.carried(states, actions)

    def carried(self, states: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, ...]:
        """The state carried to the next step: one row per route, the state each route's move leads to."""
        return (self.env.graph.move(states, actions)[0],)


def test_a_model_is_asked_with_episode_starts_and_its_state_kept_per_route(env: CampusNavEnv) -> None:
    model = Remembering(env)
    report = evaluate_routes(env, model, chunk_size=64)  # routes end at every length: rows drop at every step
    assert report.success_rate == report.spl == 1.0 and model.mixed_up == 0
    firsts = [starts for starts in model.starts if starts.all()]
    assert len(firsts) == -(-len(report.routes) // 64)  # each batch's first step, and only that one, starts episodes
    assert not any(starts.any() for starts in model.starts if not starts.all())


def test_a_model_state_without_a_row_per_route_is_named(env: CampusNavEnv) -> None:
    class Pooled(Remembering):
        def carried(self, states: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, ...]:
            return (np.zeros(3),)  # one state for all routes

    with pytest.raises(ValueError, match="one row per route along its first axis"):
        evaluate_routes(env, Pooled(env), chunk_size=8)


def test_a_policy_that_only_collides_fails_everywhere_quickly(env: CampusNavEnv) -> None:
    def turn_into_walls(observations: dict[str, np.ndarray]) -> np.ndarray:
        return np.full(len(observations["heading"]), 2)  # back: blocked at dead ends, loops elsewhere

    report = evaluate_routes(env, turn_into_walls, max_steps=50)
    assert report.success_rate < 0.2
    assert all(r.steps == 50 for r in report.routes if not r.success)


def test_spl_and_coverage_follow_their_definitions() -> None:
    routes = [
        Route("g", start=1, heading=0, success=True, steps=4, shortest=2, nodes=(1, 2, 3)),
        Route("g", start=1, heading=1, success=False, steps=10, shortest=2, nodes=(1,)),
        Route("g", start=2, heading=0, success=True, steps=3, shortest=3, nodes=(2, 3)),
    ]
    report = RouteReport(routes)
    assert report.spl == pytest.approx((0.5 + 0 + 1.0) / 3)
    assert report.success_rate == pytest.approx(2 / 3)
    assert report.coverage == pytest.approx(0.5)  # start 1 fails from one heading
    assert report.optimality_gap == pytest.approx(1.0)
    assert report.for_goal("g").routes == routes and report.for_goal("other").routes == []


def test_closures_change_the_shortest_paths_it_scores_against(env: CampusNavEnv) -> None:
    goal = env.goal_nodes[0]
    road = next(r for r in env.graph.map.roads if goal in r)
    before = evaluate_routes(env, oracle(env)).mean_shortest
    try:
        env.close_road(*road)
    except Exception:
        pytest.skip("that road is a bridge")
    try:
        after = evaluate_routes(env, oracle(env))
        assert after.success_rate == 1.0 and after.mean_shortest > before
    finally:
        env.reopen_road(*road)


def test_given_starts_are_routed_once_each_with_the_full_evaluation_scores(env: CampusNavEnv) -> None:
    full = {(r.start, r.heading): r for r in evaluate_routes(env, oracle(env)).routes}
    starts = np.array([5, 5, 40, 77])  # repeats allowed: test episodes may draw a start twice
    report = evaluate_routes(env, oracle(env), starts=starts)
    assert len(report.routes) == 4
    for state, route in zip(starts, report.routes, strict=True):
        assert (route.start, route.heading) == (env.graph.map.state_nodes[state], env.graph.map.state_headings[state])
        assert route.steps == full[(route.start, route.heading)].steps


def test_without_loop_stops_a_looping_policy_runs_to_the_step_limit(env: CampusNavEnv) -> None:
    def back_and_forth(observations: dict[str, np.ndarray]) -> np.ndarray:
        return np.full(len(observations["heading"]), 2)

    starts = np.flatnonzero(env.graph.transition_table[:, 2] >= 0)[:5]  # back leads somewhere: a two-state loop
    stopped = evaluate_routes(env, back_and_forth, starts=starts, max_steps=30)
    running = evaluate_routes(env, back_and_forth, starts=starts, max_steps=30, stop_loops=False)
    failed = [(a, b) for a, b in zip(stopped.routes, running.routes, strict=True) if not a.success]
    assert failed
    for a, b in failed:
        assert a.steps == b.steps == 30 and not b.success
        assert len(b.nodes) == 31 > len(a.nodes)  # it really drove back and forth until the limit


def test_a_start_that_cannot_reach_the_goal_is_refused(env: CampusNavEnv) -> None:
    goal_state = int(env.graph.map.state_of[env.goal_nodes[0]].max())
    with pytest.raises(ValueError, match="cannot reach goal"):
        evaluate_routes(env, oracle(env), starts=[goal_state])


def test_batches_of_starts_give_the_routes_of_one_batch(env: CampusNavEnv) -> None:
    one_batch = evaluate_routes(env, mixed(env), max_steps=40, chunk_size=None)
    assert {r.ended for r in one_batch.routes} == {"goal", "blocked", "loop"}  # every way a route stops is batched
    for chunk_size in (7, 64):
        assert evaluate_routes(env, mixed(env), max_steps=40, chunk_size=chunk_size).routes == one_batch.routes
    running = evaluate_routes(env, mixed(env), max_steps=40, stop_loops=False)
    assert evaluate_routes(env, mixed(env), max_steps=40, stop_loops=False, chunk_size=7).routes == running.routes
    with pytest.raises(ValueError, match="chunk_size must be at least 1"):
        evaluate_routes(env, mixed(env), chunk_size=0)


def test_a_route_ends_blocked_where_its_move_fails_and_in_a_loop_where_it_returns(env: CampusNavEnv) -> None:
    observed = []

    def back(observations: dict[str, np.ndarray]) -> np.ndarray:
        observed.append(len(observations["heading"]))
        return np.full(len(observations["heading"]), 2)

    table, state_of = env.graph.transition_table, env.graph.map.state_of
    goal = env.goal_nodes[0]
    routes = evaluate_routes(env, back, max_steps=30).routes
    # Each stops at the move that repeats a state: one observation where that is the first move, two for a loop
    assert sum(observed) == sum(1 + (r.ended == "loop") for r in routes)
    for route in routes:
        behind = table[state_of[route.start, route.heading], 2]
        if behind < 0:  # no road behind: the first move fails, and the state it stays in is one it has seen
            assert (route.ended, route.nodes, route.steps) == ("blocked", (route.start,), 30)
        elif behind // 4 == goal:
            assert (route.ended, route.nodes, route.steps) == ("goal", (route.start, goal), 1)
        else:  # there and back: the state it left is the first one it sees again
            assert route.ended == "loop" and route.nodes == (route.start, behind // 4, route.start)
            assert not route.success and route.steps == 30


def test_routes_without_their_nodes_keep_every_score(env: CampusNavEnv) -> None:
    full = evaluate_routes(env, mixed(env), max_steps=40)
    lean = evaluate_routes(env, mixed(env), max_steps=40, keep_nodes=False, chunk_size=50)
    assert lean.routes == [dataclasses.replace(r, nodes=(r.start,)) for r in full.routes]
    assert lean.summary() == full.summary()


def test_a_sample_draws_distinct_pairs_again_for_the_same_seed(env: CampusNavEnv) -> None:
    every = evaluate_routes(env, mixed(env), max_steps=40)
    by_pair = {(r.goal, r.start, r.heading): r for r in every.routes}
    sample = evaluate_routes(env, mixed(env), max_steps=40, sample=25, seed=3)
    assert len(set(pairs(sample))) == sample.evaluated_pairs == 25 and sample.total_pairs == len(every.routes)
    assert sample.is_sample and not every.is_sample
    assert sample.routes == [by_pair[pair] for pair in pairs(sample)]  # each route as in the full evaluation
    assert pairs(evaluate_routes(env, mixed(env), max_steps=40, sample=25, seed=3)) == pairs(sample)
    assert pairs(evaluate_routes(env, mixed(env), max_steps=40, sample=25, seed=4)) != pairs(sample)
    with pytest.raises(ValueError, match="sample must be at least 1"):
        evaluate_routes(env, mixed(env), sample=0)


def test_a_goal_draws_the_same_sample_whichever_goals_come_with_it(env: CampusNavEnv) -> None:
    def forward(observations: dict[str, np.ndarray]) -> np.ndarray:
        return np.zeros(len(observations["heading"]), dtype=np.int64)

    two_goals = CampusNavEnv(encoder="pixels", goals=["Dreese Lab", "Library"], view_build=env.view_build)
    library = evaluate_routes(two_goals, forward, goals=["Library"], max_steps=3, sample=10, seed=0)
    both = evaluate_routes(two_goals, forward, max_steps=3, sample=10, seed=0)
    assert pairs(both.for_goal("Library")) == pairs(library)
    assert both.evaluated_pairs == 20 and both.total_pairs == 2 * library.total_pairs
    assert both.by_goal()["Library"].total_pairs == library.total_pairs == 4 * (env.graph.map.n_nodes - 1)


def test_a_sample_of_at_least_every_pair_is_every_pair_and_estimates_nothing(env: CampusNavEnv) -> None:
    every = evaluate_routes(env, mixed(env), max_steps=40)
    whole = evaluate_routes(env, mixed(env), max_steps=40, sample=len(every.routes), seed=0)
    assert whole.routes == every.routes and not whole.is_sample
    assert whole.success_interval() == (every.success_rate, every.success_rate) == every.success_interval(0.5)
    assert 0 < every.success_rate < 1


def test_the_success_interval_is_wilsons_score_interval() -> None:
    def report(successes: int, n: int, population: int | None) -> RouteReport:
        routes = [Route("g", i, 0, i < successes, steps=5, shortest=5, nodes=(i,)) for i in range(n)]
        return RouteReport(routes, None if population is None else {"g": population})

    # 8 of 10, z = 1.959964: (p + z^2/2n -+ z sqrt(p(1 - p)/n + z^2/4n^2)) / (1 + z^2/n) with p = 0.8, n = 10
    low, high = report(8, 10, 1_000).success_interval(0.95)
    assert (low, high) == (pytest.approx(0.490162, abs=1e-6), pytest.approx(0.943318, abs=1e-6))
    # All 10 of 10: from n / (n + z^2) up to exactly 1; none: from exactly 0
    assert report(10, 10, 1_000).success_interval() == (pytest.approx(10 / (10 + 1.959964**2), abs=1e-6), 1.0)
    assert report(0, 10, 1_000).success_interval()[0] == 0.0
    # A wider confidence, a wider interval; every pair (no population): no estimate
    assert report(8, 10, 1_000).success_interval(0.99)[0] < low
    assert report(8, 10, None).success_interval() == (0.8, 0.8) == report(8, 10, 10).success_interval()
    with pytest.raises(ValueError, match="confidence must lie in"):
        report(8, 10, 1_000).success_interval(1.0)
