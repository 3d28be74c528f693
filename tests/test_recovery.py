"""Recovery after a closure: episodes, steps and seconds until the routes are back at the thresholds."""

from __future__ import annotations

import math

import pytest

from campusnav_env.recovery import (
    ClosureRecord,
    RouteEvaluation,
    measure_recoveries,
    median_recovery,
    recovery_table,
)
from campusnav_env.route_evaluation import Route, RouteReport


def report(success: float, spl: float | None = None, n: int = 100) -> RouteReport:
    """A report with ``success * n`` successful routes whose SPL averages ``spl``."""
    spl = success if spl is None else spl
    n_ok = round(success * n)
    # Successful routes of shortest 10 taking p steps: SPL per route 10/p; choose p to hit the mean SPL
    steps = 10 / (spl * n / n_ok) if n_ok else 10
    ok = [Route("g", i, 0, True, steps=steps, shortest=10, nodes=(i,)) for i in range(n_ok)]
    failed = [Route("g", i, 1, False, steps=200, shortest=10, nodes=(i,)) for i in range(n - n_ok)]
    return RouteReport(ok + failed)


def evaluation(step: int, episode: int, seconds: float, success: float, spl: float | None = None) -> RouteEvaluation:
    return RouteEvaluation(step=step, episode=episode, train_seconds=seconds, report=report(success, spl))


def closure(step: int, episode: int, seconds: float, index: int, roads=((1, 2),)) -> ClosureRecord:
    return ClosureRecord(
        description=f"episode {episode}: close",
        step=step,
        episode=episode,
        train_seconds=seconds,
        closed=tuple(roads),
        reopened=(),
        refused=(),
        evaluation_index=index,
    )


def test_recovery_is_measured_to_the_first_evaluation_at_both_thresholds() -> None:
    evaluations = [
        evaluation(900, 90, 9.0, 1.0),  # before the closure
        evaluation(1000, 100, 10.0, 0.6),  # right after it
        evaluation(1100, 105, 11.0, 0.995, spl=0.9),  # success back, SPL not yet
        evaluation(1250, 110, 12.5, 1.0, spl=0.97),  # recovered
        evaluation(1300, 115, 13.0, 1.0),
    ]
    (recovery,) = measure_recoveries([closure(1000, 100, 10.0, index=1)], evaluations)
    assert recovery.recovered and recovery.right_after is evaluations[1]
    assert recovery.recovered_at is evaluations[3]
    assert (recovery.episodes, recovery.steps, recovery.seconds) == (10, 250, pytest.approx(2.5))
    assert recovery.last is evaluations[4]


def test_thresholds_are_settable() -> None:
    evaluations = [evaluation(1000, 100, 10.0, 0.6), evaluation(1100, 105, 11.0, 0.9, spl=0.85)]
    (strict,) = measure_recoveries([closure(1000, 100, 10.0, 0)], evaluations)
    (lenient,) = measure_recoveries([closure(1000, 100, 10.0, 0)], evaluations, 0.9, 0.8)
    assert not strict.recovered and lenient.episodes == 5


def test_a_closure_never_recovered_from_is_reported_as_such_and_slows_the_median() -> None:
    evaluations = [
        evaluation(1000, 100, 10.0, 0.6),
        evaluation(1100, 110, 11.0, 1.0),  # first closure recovered after 10 episodes
        evaluation(2000, 200, 20.0, 0.5),  # second closure: never good again before the third
        evaluation(2100, 210, 21.0, 0.9),
        evaluation(3000, 300, 30.0, 0.7),  # third closure
        evaluation(3100, 330, 31.0, 1.0),  # recovered after 30 episodes
    ]
    closures = [closure(1000, 100, 10.0, 0), closure(2000, 200, 20.0, 2), closure(3000, 300, 30.0, 4)]
    first, second, third = measure_recoveries(closures, evaluations)
    assert first.episodes == 10 and third.episodes == 30
    assert not second.recovered and second.recovered_at is None
    assert math.isinf(second.episodes) and math.isinf(second.steps) and math.isinf(second.seconds)
    assert second.last is evaluations[3]  # its window ends where the next closure starts
    # Median of 10, 30 and "never": 30, not the 20 one would get by dropping the failure
    assert median_recovery([first, second, third]) == 30
    assert math.isinf(median_recovery([first, second]))
    assert math.isnan(median_recovery([]))
    table = recovery_table([first, second, third])
    assert "not recovered" in table and "| **median** | | | | 30 |" in table
    with pytest.raises(ValueError, match="measure"):
        median_recovery([first], "minutes")


def test_a_closure_without_evaluations_after_it_is_not_recovered() -> None:
    (recovery,) = measure_recoveries([closure(5000, 500, 50.0, 1)], [evaluation(4000, 400, 40.0, 1.0)])
    assert not recovery.recovered and recovery.right_after is None and recovery.last is None


def test_events_that_changed_nothing_have_no_recovery() -> None:
    refused = ClosureRecord(
        "episode 1: close", 10, 1, 0.1, closed=(), reopened=(), refused=(("x", "why"),), evaluation_index=0
    )
    assert measure_recoveries([refused], [evaluation(10, 1, 0.1, 1.0)]) == []


def test_every_goal_asks_each_goal_to_meet_the_thresholds_on_its_own() -> None:
    # Goal a: perfect (9 routes); goal b: one detour (SPL 0.5): over all 10 routes SPL is 0.95, b alone 0.5
    routes = [Route("a", i, 0, True, steps=10, shortest=10, nodes=(i,)) for i in range(9)]
    routes.append(Route("b", 0, 0, True, steps=20, shortest=10, nodes=(0,)))
    evaluation = RouteEvaluation(step=0, episode=0, train_seconds=0.0, report=RouteReport(routes))
    assert evaluation.meets(0.99, 0.95)
    assert not evaluation.meets(0.99, 0.95, every_goal=True)
    assert evaluation.meets(0.99, 0.5, every_goal=True)
