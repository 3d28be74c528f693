"""Closure schedules: the event forms, YAML, and the checks made before training."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from campusnav_env import NavigationGraph, RoadClosureError, default_campus, road_key
from campusnav_env.closures import (
    ClosureEvent,
    ClosureSchedule,
    apply_fixed_event,
    busiest_road,
    first_road_on_route,
    road_usage,
)


@pytest.fixture()
def campus() -> NavigationGraph:
    return NavigationGraph(default_campus())


def goal_roads(graph: NavigationGraph, goal: int) -> list[tuple[int, int]]:
    return [road for road in graph.map.roads if goal in road]


def test_each_event_does_exactly_one_thing() -> None:
    assert ClosureEvent(at=5, close=[(82, 81)]).close == ((81, 82),)  # canonical roads
    assert ClosureEvent(at=5, reopen="all").reopen == "all"
    with pytest.raises(ValueError, match="exactly one of close, close_random, close_on_route, reopen"):
        ClosureEvent(at=5)
    with pytest.raises(ValueError, match="exactly one"):
        ClosureEvent(at=5, close=[(1, 2)], close_random=3)
    with pytest.raises(ValueError, match="'at' must be a non-negative int"):
        ClosureEvent(at=-1, reopen="all")
    with pytest.raises(ValueError, match="unit must be 'episode' or 'step'"):
        ClosureEvent(at=1, unit="minute", reopen="all")
    with pytest.raises(ValueError, match="a road is a pair of node ids"):
        ClosureEvent(at=1, close=[(1, 2, 3)])
    with pytest.raises(ValueError, match="close_on_route must be 'busiest' or a start node"):
        ClosureEvent(at=1, close_on_route="quietest")
    assert ClosureEvent(at=3, unit="step", close=[(1, 2)]).describe() == "step 3: close 1-2"


def test_a_yaml_schedule_reads_every_form(tmp_path: Path) -> None:
    path = tmp_path / "schedule.yml"
    path.write_text(
        "closures:\n"
        "  - {at: 20, close: [[81, 82]]}\n"
        "  - {at: 10, close_on_route: busiest}\n"
        "  - {at: 40, close_random: 11, seed: 3}\n"
        "  - {at: 30, reopen: all}\n"
        "  - {at: 50, close_on_route: 17}\n"
    )
    schedule = ClosureSchedule.from_yaml(path)
    assert [e.at for e in schedule.ordered()] == [10, 20, 30, 40, 50]
    assert schedule.events[2] == ClosureEvent(at=40, close_random=11, seed=3)
    assert schedule.events[4].close_on_route == 17


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("closures: 3\n", r"expected a list under the key 'closures'"),
        ("closures:\n  - {close: [[1, 2]]}\n", r"closures\[0\] needs the key 'at'"),
        ("closures:\n  - {at: 1, shut: [[1, 2]]}\n", r"closures\[0\] has unknown key\(s\) \['shut'\]"),
        ("closures:\n  - {at: 1, reopen: all}\n  - {at: 2}\n", r"closures\[1\]: .*exactly one"),
        ("closures: [\n", r"not valid YAML"),
    ],
)
def test_a_bad_yaml_schedule_names_the_file_and_the_entry(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.yml"
    path.write_text(text)
    with pytest.raises(ValueError, match=rf"bad\.yml.*{message}"):
        ClosureSchedule.from_yaml(path)
    with pytest.raises(FileNotFoundError, match=r"missing\.yml"):
        ClosureSchedule.from_yaml(tmp_path / "missing.yml")


def test_validation_catches_unknown_roads_and_closures_that_cut_a_goal_off(campus: NavigationGraph) -> None:
    goal = campus.landmarks["Dreese Lab"]
    with pytest.raises(KeyError, match=r"episode 5: close 0-100: no road between nodes 0 and 100"):
        ClosureSchedule([ClosureEvent(at=5, close=[(0, 100)])]).validate(campus, [goal])
    roads = goal_roads(campus, goal)
    cut_off = ClosureSchedule([ClosureEvent(at=1, close=roads)])
    with pytest.raises(RoadClosureError, match=rf"episode 1: close .*would cut protected node {goal}"):
        cut_off.validate(campus, [goal])
    # One at a time, in order: the last of the goal's roads is the one refused
    one_by_one = ClosureSchedule([ClosureEvent(at=i, close=[road]) for i, road in enumerate(roads)])
    with pytest.raises(RoadClosureError, match=rf"episode {len(roads) - 1}: close"):
        one_by_one.validate(campus, [goal])
    with pytest.raises(ValueError, match="is not closed"):
        ClosureSchedule([ClosureEvent(at=1, reopen=[roads[0]])]).validate(campus, [goal])
    with pytest.raises(ValueError, match="cannot close 500 roads"):
        ClosureSchedule([ClosureEvent(at=1, close_random=500)]).validate(campus, [goal])
    with pytest.raises(ValueError, match="close_on_route start 999 out of range"):
        ClosureSchedule([ClosureEvent(at=1, close_on_route=999)]).validate(campus, [goal])
    assert campus.closed_roads == frozenset()  # validation works on a copy


def test_a_valid_schedule_passes_and_reopening_makes_room_for_later_closures(campus: NavigationGraph) -> None:
    goal = campus.landmarks["Dreese Lab"]
    roads = goal_roads(campus, goal)
    schedule = ClosureSchedule(
        [
            ClosureEvent(at=1, close=roads[:-1]),
            ClosureEvent(at=2, reopen="all"),
            ClosureEvent(at=3, close=roads[-1:]),
            ClosureEvent(at=4, close_random=11, seed=0),
            ClosureEvent(at=5, close_on_route="busiest"),
        ]
    )
    schedule.validate(campus, [goal])  # passes: no error
    assert campus.closed_roads == frozenset()
    # Without the reopening, episode 3's closure would close the goal's last road: refused
    without_reopening = ClosureSchedule([event for event in schedule.events if event.reopen != "all"])
    with pytest.raises(RoadClosureError, match=rf"episode 3: close .*would cut protected node {goal}"):
        without_reopening.validate(campus, [goal])
    # Applied in order, the fixed events leave the goal reachable from every node after each one
    reach = campus.hops_to(goal) >= 0
    for event, closed_after in zip(schedule.ordered()[:4], [roads[:-1], [], roads[-1:], None], strict=True):
        closed, _ = apply_fixed_event(campus, event, [goal])
        if closed_after is not None:
            assert campus.closed_roads == {road_key(*road) for road in closed_after}, event.describe()
        else:
            assert len(closed) == 11 and set(closed) <= campus.closed_roads
        np.testing.assert_array_equal(campus.hops_to(goal) >= 0, reach, err_msg=event.describe())


def test_fixed_events_apply_closures_and_reopenings(campus: NavigationGraph) -> None:
    protect = [campus.landmarks["Dreese Lab"]]
    closed, reopened = apply_fixed_event(campus, ClosureEvent(at=0, close_random=11, seed=7), protect)
    assert len(closed) == 11 and reopened == [] and campus.closed_roads == set(closed)
    again = NavigationGraph(default_campus())
    assert apply_fixed_event(again, ClosureEvent(at=0, close_random=11, seed=7), protect)[0] == closed  # seeded
    closed, reopened = apply_fixed_event(campus, ClosureEvent(at=0, reopen="all"), protect)
    assert closed == [] and sorted(reopened) == sorted(again.closed_roads) and campus.closed_roads == frozenset()


def test_roads_on_routes_are_chosen_by_use_and_closability(campus: NavigationGraph) -> None:
    goal = campus.landmarks["Dreese Lab"]
    routes = [campus.shortest_path(start, goal) for start in range(campus.n_nodes) if start != goal]
    usage = road_usage(routes)
    assert sum(usage.values()) == sum(len(r) - 1 for r in routes)
    road = busiest_road(campus, routes, [goal])
    assert usage[road] == max(n for r, n in usage.items() if _closable(campus, r, goal))
    assert campus.closed_roads == frozenset()  # choosing does not close
    # The first road of a route out of a dead end is its only road: not closable, so a later one is chosen
    dead_end = int(np.flatnonzero(campus.map.degrees == 1)[0])
    route = campus.shortest_path(dead_end, goal)
    chosen = first_road_on_route(campus, route, [goal])
    on_route = [road_key(u, v) for u, v in itertools.pairwise(route)]
    first_closable = next(road for road in on_route if _closable(campus, road, goal))
    assert chosen == first_closable != road_key(*route[:2])
    assert first_road_on_route(campus, route[:2], [goal]) is None


def _closable(graph: NavigationGraph, road: tuple[int, int], goal: int) -> bool:
    trial = graph.copy()
    try:
        trial.close_road(*road, protect=[goal])
    except RoadClosureError:
        return False
    return True
