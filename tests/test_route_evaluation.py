"""Route evaluation: success, SPL, coverage and optimality gap of a policy from every start."""

from __future__ import annotations

from pathlib import Path

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
