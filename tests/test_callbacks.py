"""Dynamic-routing callbacks: scheduled closures in every env, route evaluation, recovery detection, bad schedules.

Training here only explores (``learning_starts`` beyond the run), so the tests are fast; where a test needs a policy
that routes well, the evaluation uses a scripted shortest-path policy, which makes recovery deterministic.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from campusnav_env import CampusNavEnv, RoadClosureError, generate_campus
from campusnav_env.callbacks import RoadClosureCallback, RouteEvaluationCallback
from campusnav_env.closures import ClosureEvent
from campusnav_env.features.view_build import ViewBuild
from campusnav_env.rendering.street_view import RenderSettings
from campusnav_env.route_evaluation import evaluate_routes
from sb3_dcqn import DCQN

WORLD = generate_campus(16, seed=1)


@pytest.fixture(scope="module")
def env_kwargs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    return dict(
        world=WORLD,
        goals="Dreese Lab",
        encoder="pixels",
        view_build=ViewBuild(
            render_settings=RenderSettings(width=64, height=48),
            cache_dir=tmp_path_factory.mktemp("cache"),
            progress=False,
        ),
        max_steps=30,
    )


def explorer(env: Any, tensorboard_log: Path | None = None) -> DCQN:
    """A DCQN that only explores during these short runs (no gradient steps: fast)."""
    return DCQN(
        "MultiInputPolicy",
        env,
        learning_starts=100_000,
        policy_kwargs=dict(net_arch=[16]),
        seed=0,
        tensorboard_log=None if tensorboard_log is None else str(tensorboard_log),
    )


def shortest_path_policy(env: CampusNavEnv, *, frozen: bool = False) -> Callable[..., tuple[np.ndarray, None]]:
    """A ``predict`` that reads the node off the views and moves one hop closer to the goal.

    ``frozen``: keep following the distances of the map as it is now (a policy that has not noticed closures).
    """
    goal = env.goal_nodes[0]
    frozen_hops, frozen_table = env.graph.state_hops_to(goal).copy(), env.graph.transition_table.copy()
    views = env._node_views

    def predict(
        observations: dict[str, np.ndarray], state: Any = None, episode_start: Any = None, deterministic: bool = True
    ) -> tuple[np.ndarray, None]:
        hops = frozen_hops if frozen else env.graph.state_hops_to(goal)
        table = frozen_table if frozen else env.graph.transition_table
        nodes = [int(np.flatnonzero((views == v).all(axis=1))[0]) for v in observations["views"]]
        states = np.array(nodes) * 4 + np.argmax(observations["heading"], axis=1)
        targets = table[states]
        score = np.where(targets >= 0, hops[np.maximum(targets, 0)], np.iinfo(np.int64).max)
        score = np.where(score < 0, np.iinfo(np.int64).max, score)
        return score.argmin(axis=1), None

    return predict


def scalars(log_dir: Path) -> dict[str, list[tuple[int, float]]]:
    (run,) = [p for p in log_dir.iterdir() if p.is_dir()]
    events = EventAccumulator(str(run))
    events.Reload()
    return {tag: [(e.step, e.value) for e in events.Scalars(tag)] for tag in events.Tags()["scalars"]}


def test_scheduled_events_fire_when_due_in_every_env_and_the_eval_env(env_kwargs, tmp_path: Path) -> None:
    env = make_vec_env(CampusNavEnv, n_envs=2, env_kwargs=env_kwargs)
    goal = env.get_attr("goal_nodes")[0][0]
    road = next(r for r in WORLD.roads if goal not in r and min(WORLD.degrees[list(r)]) > 2)
    evaluation = RouteEvaluationCallback(CampusNavEnv(**env_kwargs), eval_freq=10_000)
    schedule = [
        ClosureEvent(at=4, close=[road]),
        ClosureEvent(at=8, reopen="all"),
        ClosureEvent(at=300, unit="step", close_random=2, seed=1),
    ]
    callback = RoadClosureCallback(schedule, evaluation=evaluation)
    explorer(env, tmp_path).learn(600, callback=callback)

    first, second, third = callback.records
    assert first.closed == (road,) and first.episode >= 4 and first.step < second.step
    assert second.reopened == (road,) and second.episode >= 8
    assert len(third.closed) == 2 and third.step in (300, 301)  # two envs step together: counted in pairs
    assert all(r.refused == () for r in callback.records)
    # Training envs, the evaluation env and the callback's mirror agree
    closed = set(third.closed)
    assert [set(c) for c in env.get_attr("closed_roads")] == [closed, closed]
    assert set(evaluation.eval_env.closed_roads) == closed == set(callback.graph.closed_roads)
    # Each change was evaluated right away: the evaluation made at the closure opens its window
    opening = [evaluation.evaluations[record.evaluation_index] for record in callback.records]
    assert [e.step for e in opening] == [record.step for record in callback.records]
    logged = scalars(tmp_path)
    assert [value for _, value in logged["closure/events"]] == [1.0, 2.0, 3.0]
    assert [value for _, value in logged["closure/closed_roads"]] == [1.0, 0.0, 2.0]
    assert {"eval/success_rate", "eval/spl", "eval/coverage", "eval/mean_steps", "eval/optimality_gap"} <= set(logged)


def test_closures_reach_subprocess_envs(env_kwargs) -> None:
    env = make_vec_env(CampusNavEnv, n_envs=2, env_kwargs=env_kwargs, vec_env_cls=SubprocVecEnv)
    try:
        with pytest.raises(ValueError, match=r"SubprocVecEnv .* pass eval_env"):
            explorer(env).learn(10, callback=RouteEvaluationCallback())
        callback = RoadClosureCallback([ClosureEvent(at=50, unit="step", close_random=2, seed=0)])
        explorer(env).learn(100, callback=callback)
        (record,) = callback.records
        assert len(record.closed) == 2
        assert [set(c) for c in env.get_attr("closed_roads")] == [set(record.closed)] * 2
    finally:
        env.close()


def test_bad_schedules_fail_before_training(env_kwargs) -> None:
    env = DummyVecEnv([lambda: CampusNavEnv(**env_kwargs)])
    goal = env.get_attr("goal_nodes")[0][0]
    model = explorer(env)
    with pytest.raises(KeyError, match=r"episode 3: close 0-15: no road between nodes 0 and 15"):
        model.learn(100, callback=RoadClosureCallback([ClosureEvent(at=3, close=[(0, 15)])]))
    cut_off = [r for r in WORLD.roads if goal in r]
    with pytest.raises(RoadClosureError, match=rf"would cut protected node {goal}"):
        model.learn(100, callback=RoadClosureCallback([ClosureEvent(at=3, close=cut_off)]))
    assert model.num_timesteps == 0  # nothing ran
    assert env.get_attr("closed_roads") == [frozenset()]  # and nothing was closed
    with pytest.raises(FileNotFoundError, match=r"nowhere\.yml"):
        RoadClosureCallback("nowhere.yml")


def test_a_route_closure_without_route_evaluation_is_refused_and_reported(env_kwargs) -> None:
    env = DummyVecEnv([lambda: CampusNavEnv(**env_kwargs)])
    callback = RoadClosureCallback([ClosureEvent(at=1, close_on_route="busiest")])
    explorer(env).learn(200, callback=callback)
    (record,) = callback.records
    assert record.closed == () and "needs a RouteEvaluationCallback" in record.refused[0][1]
    with pytest.raises(ValueError, match="recoveries need a RouteEvaluationCallback"):
        _ = callback.recoveries


def test_recovery_is_detected_and_a_policy_that_never_adapts_is_reported(env_kwargs) -> None:
    env = DummyVecEnv([lambda: CampusNavEnv(**env_kwargs)])
    nav = env.envs[0].unwrapped
    model = explorer(env)
    evaluation = RouteEvaluationCallback(eval_freq=100_000, unit="episode")  # the training env itself
    schedule = [ClosureEvent(at=2, close_on_route="busiest"), ClosureEvent(at=12, close_on_route="busiest")]
    callback = RoadClosureCallback(schedule, evaluation=evaluation, recovery_eval_freq=3)

    # First a policy that adapts at once: recovered right after the closure (0 episodes)
    model.predict = shortest_path_policy(nav)
    model.learn(100, callback=callback)
    first = callback.recoveries[0]
    assert first.closure.routes_affected > 0 and first.recovered and first.episodes == 0

    # Then one stuck on the old routes: the next closure is never recovered from; dense evaluations kept running
    model.predict = shortest_path_policy(nav, frozen=True)
    model.learn(600, callback=callback, reset_num_timesteps=False)
    second = callback.recoveries[1]
    assert second.right_after.success_rate < 0.99 and not second.recovered and np.isinf(second.episodes)
    window = evaluation.evaluations[second.closure.evaluation_index :]
    assert len(window) >= 3 and all(b.episode - a.episode <= 4 for a, b in itertools.pairwise(window))


def test_stop_when_solved_ends_training_at_the_first_solved_evaluation(env_kwargs) -> None:
    env = DummyVecEnv([lambda: CampusNavEnv(**env_kwargs)])
    model = explorer(env)
    model.predict = shortest_path_policy(env.envs[0].unwrapped)
    evaluation = RouteEvaluationCallback(eval_freq=50, stop_when_solved=True, spl_threshold=0.98)
    model.learn(10_000, callback=evaluation)
    assert model.num_timesteps == 50 and evaluation.solved
    assert len(evaluation.evaluations) == 1 and evaluation.evaluations[0].report.success_rate == 1.0
    assert evaluation.evaluations[0].train_seconds > 0


def failing_at(env: CampusNavEnv, trap: int) -> Callable[..., tuple[np.ndarray, None]]:
    """The shortest-path ``predict``, except at node ``trap``: there it tries a move without a road, again and again."""
    route = shortest_path_policy(env)
    table = env.graph.transition_table
    views = env._node_views

    def predict(
        observations: dict[str, np.ndarray], state: Any = None, episode_start: Any = None, deterministic: bool = True
    ) -> tuple[np.ndarray, None]:
        nodes = np.array([int(np.flatnonzero((views == v).all(axis=1))[0]) for v in observations["views"]])
        states = nodes * 4 + np.argmax(observations["heading"], axis=1)
        stuck = np.argmax(table[states] < 0, axis=1)
        return np.where(nodes == trap, stuck, route(observations)[0]), None

    return predict


def test_a_sample_at_the_thresholds_counts_only_once_every_pair_confirms_it(env_kwargs, tmp_path: Path) -> None:
    env = DummyVecEnv([lambda: CampusNavEnv(**env_kwargs)])
    nav = env.envs[0].unwrapped
    # The first evaluation's sample (seed 7) and a node that none of its routes passes: the policy fails there alone
    drawn = evaluate_routes(nav, lambda obs: shortest_path_policy(nav)(obs)[0], sample=4, seed=7)
    passed = {node for route in drawn.routes for node in route.nodes}
    trap = next(n for n in range(WORLD.n_nodes) if n not in passed and WORLD.degrees[n] < 4)
    model = explorer(env, tmp_path)
    model.predict = failing_at(nav, trap)
    evaluation = RouteEvaluationCallback(eval_freq=50, stop_when_solved=True, sample=4, sample_seed=7)
    model.learn(100, callback=evaluation)

    # The sample looked solved; every pair did not: training went on, and what was recorded is every pair
    first = evaluation.evaluations[0]
    assert not first.report.is_sample and first.report.evaluated_pairs == drawn.total_pairs
    assert first.report.success_rate <= 1 - 4 / drawn.total_pairs  # the trap's four headings fail
    assert evaluation.refuted >= 1 and evaluation.confirmed == 0
    assert model.num_timesteps == 100 and not evaluation.solved
    # What train_until_solved reads: no recorded evaluation is at the thresholds
    assert not any(e.meets(evaluation.success_threshold, evaluation.spl_threshold) for e in evaluation.evaluations)
    assert all(route.nodes == (route.start,) for route in first.report.routes)  # nothing here needs the nodes
    logged = scalars(tmp_path)
    assert [v for _, v in logged["eval/sampled_pairs"]] == [4 * e.report.is_sample for e in evaluation.evaluations]


def test_a_sample_at_the_thresholds_that_every_pair_confirms_solves_the_map(env_kwargs) -> None:
    env = DummyVecEnv([lambda: CampusNavEnv(**env_kwargs)])
    model = explorer(env)
    model.predict = shortest_path_policy(env.envs[0].unwrapped)
    evaluation = RouteEvaluationCallback(eval_freq=50, stop_when_solved=True, spl_threshold=0.98, sample=4)
    model.learn(10_000, callback=evaluation)
    assert model.num_timesteps == 50 and evaluation.solved and evaluation.confirmed == 1
    (solved,) = evaluation.evaluations
    assert not solved.report.is_sample and solved.report.success_rate == 1.0
    assert solved.report.evaluated_pairs == solved.report.total_pairs == 4 * (WORLD.n_nodes - 1)


def test_each_sampled_evaluation_draws_its_own_pairs(env_kwargs, tmp_path: Path) -> None:
    env = DummyVecEnv([lambda: CampusNavEnv(**env_kwargs)])
    nav = env.envs[0].unwrapped
    model = explorer(env, tmp_path)
    model.predict = lambda observations, *_, **__: (np.full(len(observations["heading"]), 2), None)
    # Back and forth: never at the thresholds, so every evaluation stays a sample
    evaluation = RouteEvaluationCallback(eval_freq=50, sample=5, sample_seed=10, evaluate_at_end=False)
    model.learn(150, callback=evaluation)

    def drawn(seed: int) -> list[tuple[int, int]]:
        report = evaluate_routes(nav, lambda obs: model.predict(obs)[0], sample=5, seed=seed)
        return [(r.start, r.heading) for r in report.routes]

    evaluated = [[(r.start, r.heading) for r in e.report.routes] for e in evaluation.evaluations]
    assert evaluated == [drawn(10), drawn(11), drawn(12)] and evaluated[0] != evaluated[1]
    assert evaluation.confirmed == evaluation.refuted == 0
    assert [v for _, v in scalars(tmp_path)["eval/sampled_pairs"]] == [5.0, 5.0, 5.0]
    with pytest.raises(ValueError, match="sample must be at least 1 pair"):
        RouteEvaluationCallback(sample=0)


def test_sampled_evaluations_keep_the_nodes_a_closure_on_the_route_needs(env_kwargs) -> None:
    env = DummyVecEnv([lambda: CampusNavEnv(**env_kwargs)])
    model = explorer(env)
    model.predict = shortest_path_policy(env.envs[0].unwrapped)
    evaluation = RouteEvaluationCallback(eval_freq=100_000, sample=8)
    closures = RoadClosureCallback([ClosureEvent(at=1, close_on_route="busiest")], evaluation=evaluation)
    model.learn(100, callback=closures)
    (record,) = closures.records
    assert len(record.closed) == 1 and record.routes_affected > 0
    assert any(len(route.nodes) > 1 for route in evaluation.evaluations[0].report.routes)


def test_the_evaluated_policy_can_be_made_from_the_model_anew_at_each_evaluation(env_kwargs) -> None:
    env = DummyVecEnv([lambda: CampusNavEnv(**env_kwargs)])
    model = explorer(env)  # explores only: its own greedy policy does not route
    made: list[Any] = []

    def planner(trained: Any) -> Callable[[Any], np.ndarray]:
        made.append(trained)
        predict = shortest_path_policy(env.envs[0].unwrapped)
        return lambda observations: predict(observations)[0]

    evaluation = RouteEvaluationCallback(eval_freq=50, policy=planner, evaluate_at_end=False)
    model.learn(100, callback=evaluation)
    assert made == [model, model]  # one policy per evaluation, made from the model being trained
    assert [e.report.success_rate for e in evaluation.evaluations] == [1.0, 1.0]


def test_a_schedule_continues_over_several_learn_calls(env_kwargs) -> None:
    env = DummyVecEnv([lambda: CampusNavEnv(**env_kwargs)])
    road = next(r for r in WORLD.roads if min(WORLD.degrees[list(r)]) > 2)  # not a bridge
    callback = RoadClosureCallback([ClosureEvent(at=1, close=[road]), ClosureEvent(at=250, unit="step", reopen=[road])])
    model = explorer(env)
    model.learn(100, callback=callback)
    assert [r.closed for r in callback.records] == [(road,)]
    # The second call checks only what is still to come (the reopening), against the map as it is now
    model.learn(200, callback=callback, reset_num_timesteps=False)
    assert [r.reopened for r in callback.records] == [(), (road,)]
    assert callback.records[1].step == 250 and env.get_attr("closed_roads") == [frozenset()]


@pytest.fixture
def slow_evaluations(monkeypatch: pytest.MonkeyPatch) -> float:
    """Route evaluations that each sleep this long first: far slower than the training around them."""
    import campusnav_env.callbacks as callbacks

    evaluate_routes, pause = callbacks.evaluate_routes, 0.3

    def slow_evaluation(*args: Any, **kwargs: Any) -> Any:
        time.sleep(pause)
        return evaluate_routes(*args, **kwargs)

    monkeypatch.setattr(callbacks, "evaluate_routes", slow_evaluation)
    return pause


def test_training_seconds_never_count_the_evaluations_own_time(env_kwargs, slow_evaluations: float) -> None:
    env = DummyVecEnv([lambda: CampusNavEnv(**env_kwargs)])
    model = explorer(env)
    model.predict = shortest_path_policy(env.envs[0].unwrapped)
    evaluation = RouteEvaluationCallback(eval_freq=20)
    schedule = [ClosureEvent(at=40, unit="step", close_on_route="busiest")]
    closures = RoadClosureCallback(schedule, evaluation=evaluation, recovery_eval_freq=1)
    started = time.perf_counter()
    model.learn(100, callback=closures)
    wall = time.perf_counter() - started
    seconds = [e.train_seconds for e in evaluation.evaluations]
    assert len(seconds) >= 6 and seconds == sorted(seconds) and seconds[0] >= 0
    # Every evaluation slept; none of it is training time
    assert seconds[-1] <= wall - slow_evaluations * len(seconds) + 0.05
    recovery = closures.recoveries[0]
    assert recovery.recovered and recovery.seconds >= 0


def test_a_closure_between_learn_calls_never_makes_training_time_run_backwards(
    env_kwargs, slow_evaluations: float
) -> None:
    env = DummyVecEnv([lambda: CampusNavEnv(**env_kwargs)])
    model = explorer(env)
    model.predict = shortest_path_policy(env.envs[0].unwrapped)
    evaluation = RouteEvaluationCallback(eval_freq=1_000)
    closures = RoadClosureCallback([], evaluation=evaluation, recovery_eval_freq=1)
    model.learn(50, callback=closures)
    # As sb3_dcqn.campusnav.experiments does: the closure (and its evaluation) between two learn calls
    closures.apply(ClosureEvent(at=model.num_timesteps, unit="step", close_on_route="busiest"))
    model.learn(50, callback=closures, reset_num_timesteps=False)
    seconds = [e.train_seconds for e in evaluation.evaluations]
    assert seconds == sorted(seconds) and min(seconds) >= 0
    recovery = closures.recoveries[0]
    assert recovery.recovered and 0 <= recovery.seconds < slow_evaluations


@pytest.mark.parametrize(
    ("route_memory", "wears"),
    [(True, True), ({}, True), ({"explore": False}, True), (False, False), (None, False)],
    ids=["true", "the layer's defaults {}", "a setting", "false", "DCQN itself"],
)
def test_the_critics_alone_are_evaluated_for_every_model_that_wears_the_memory(
    env_kwargs, route_memory: Any, wears: bool
) -> None:
    # Whether a model wears the memory is its class's answer (wears_route_memory), never the truthiness of its
    # setting: route_memory={} (the memory's defaults) wears it, and its results rely on the critics' row
    from sb3_dcqn import RouteMemoryDCQN

    env = DummyVecEnv([lambda: CampusNavEnv(**env_kwargs)])
    kwargs = dict(learning_starts=100_000, policy_kwargs=dict(net_arch=[16]), seed=0)
    if route_memory is None:
        model = DCQN("MultiInputPolicy", env, **kwargs)
    else:
        model = RouteMemoryDCQN("MultiInputPolicy", env, route_memory=route_memory, **kwargs)
    assert getattr(model, "wears_route_memory", False) is wears
    evaluation = RouteEvaluationCallback(eval_freq=100_000, unit="episode")
    model.learn(20, callback=evaluation)
    assert evaluation.evaluations and all((e.critics is not None) is wears for e in evaluation.evaluations)
