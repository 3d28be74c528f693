"""Figures of the dynamic-routing experiments: route panels per closure and training curves."""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
import pytest

from campusnav_env import generate_campus
from campusnav_env.figures import (
    CURRICULUM_NOTE,
    closure_panels,
    closure_route_panels,
    panel_title,
    pick_route,
    route_steps,
    route_text,
    tile_panels,
    training_curves,
    write_figure,
)
from campusnav_env.maps.compass import ACTION_NAMES
from campusnav_env.maps.navigation import NavigationGraph
from campusnav_env.maps.road_graph import RoadGraph
from campusnav_env.recovery import ClosureRecord, Recovery, RouteEvaluation, measure_recoveries
from campusnav_env.rendering.map_view import CLOSED_RGB
from campusnav_env.rendering.palette import LEARNED_ROUTE_RGB, REROUTED_RGB
from campusnav_env.route_evaluation import Route, RouteReport

GOAL = "Dreese Lab"
Road = tuple[int, int]


@pytest.fixture(scope="module")
def campus() -> RoadGraph:
    # 16 intersections: from node 0 the shortest way to Dreese Lab (13) runs 0-3-4-5-9-8-13; closing 5-9 sends it
    # round the one loop of the map, 5-6-7-10-9
    return generate_campus(16, seed=1)


def _share(image: np.ndarray, rgb: tuple[int, int, int], tol: int = 6) -> float:
    return float(np.mean(np.abs(image.astype(int) - np.asarray(rgb)).max(axis=-1) <= tol))


def _evaluation(graph: RoadGraph, closed: Sequence[Road], episode: int, failing: Sequence[int] = ()) -> RouteEvaluation:
    """Routes along the shortest paths over open roads from every node (heading 0); ``failing`` starts loop."""
    navigation = NavigationGraph(graph, closed)
    goal = graph.landmarks[GOAL]
    routes = []
    for start in range(graph.n_nodes):
        path = navigation.shortest_path(start, goal)
        if start == goal or not path:
            continue
        shortest = len(path) - 1
        if start in failing:  # out and back again: a loop, stopped as failed
            routes.append(Route(GOAL, start, 0, False, 200, shortest, (*path[:3], *path[1:2])))
        else:
            routes.append(Route(GOAL, start, 0, True, shortest, shortest, tuple(path)))
    return RouteEvaluation(step=10 * episode, episode=episode, train_seconds=episode / 10, report=RouteReport(routes))


def _closure(episode: int, index: int, closed: Sequence[Road] = (), reopened: Sequence[Road] = ()) -> ClosureRecord:
    return ClosureRecord(
        description=f"episode {episode}: change",
        step=10 * episode,
        episode=episode,
        train_seconds=episode / 10,
        closed=tuple(closed),
        reopened=tuple(reopened),
        refused=(),
        evaluation_index=index,
    )


def _timeline(graph: RoadGraph, recover_second: bool = True) -> tuple[list[RouteEvaluation], list[ClosureRecord]]:
    """Close 5-9 (recovered), reopen it (recovered unless told), close 9-10 (recovered)."""
    evaluations = [_evaluation(graph, [], 100)]
    closures = [_closure(100, 1, closed=[(5, 9)])]
    evaluations += [_evaluation(graph, [(5, 9)], 100, failing=[0]), _evaluation(graph, [(5, 9)], 135)]
    closures.append(_closure(200, 3, reopened=[(5, 9)]))
    evaluations.append(_evaluation(graph, [], 200, failing=[0]))
    evaluations.append(_evaluation(graph, [], 230, failing=[] if recover_second else [0]))
    closures.append(_closure(300, 5, closed=[(9, 10)]))
    evaluations += [_evaluation(graph, [(9, 10)], 300), _evaluation(graph, [(9, 10)], 320)]
    return evaluations, closures


def test_one_panel_per_closure_with_both_routes_closures_start_and_goal(campus: RoadGraph) -> None:
    evaluations, closures = _timeline(campus)
    recoveries = measure_recoveries(closures, evaluations)
    assert len(recoveries) == 3 and all(r.recovered for r in recoveries)
    one = closure_route_panels(campus, evaluations, recoveries[:1], size=300)
    two = closure_route_panels(campus, evaluations, recoveries[:2], size=300)
    three = closure_route_panels(campus, evaluations, recoveries, size=300, columns=2)
    for image in (one, two, three):
        assert image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3
    # Side by side up to `columns` panels, then a new row
    assert two.shape[0] == one.shape[0] and two.shape[1] > 1.8 * one.shape[1]
    assert three.shape[1] == two.shape[1] and three.shape[0] > 1.8 * one.shape[0]
    # The learned route in orange and the re-routed one in purple, the closed road in red
    for colour in (LEARNED_ROUTE_RGB, REROUTED_RGB, CLOSED_RGB):
        assert _share(one, colour) > 0.001
    # The start is the one whose learned route used the closed road (the longest such: node 0), heading 0
    explicit = closure_route_panels(campus, evaluations, recoveries[:1], start=0, heading=0, size=300)
    np.testing.assert_array_equal(one, explicit)
    other = closure_route_panels(campus, evaluations, recoveries[:1], start=12, size=300)
    assert not np.array_equal(one, other)


def test_closed_roads_accumulate_and_reopened_ones_are_no_longer_red(campus: RoadGraph) -> None:
    evaluations, closures = _timeline(campus)
    close, reopen, _ = measure_recoveries(closures, evaluations)
    image = closure_route_panels(campus, evaluations, [close, reopen], size=300, columns=1)
    middle = image.shape[0] // 2  # two panels stacked
    assert _share(image[:middle], CLOSED_RGB) > 0.001
    assert _share(image[middle:], CLOSED_RGB) == 0.0  # 5-9 reopened: no road closed in the second panel


def test_a_closure_never_recovered_from_says_so(campus: RoadGraph) -> None:
    evaluations, closures = _timeline(campus, recover_second=False)
    first, second, _ = measure_recoveries(closures, evaluations)
    assert not second.recovered
    assert panel_title(1, first) == "closure 1: road 5-9 closed; recovered after 35 episodes / 3.5 s"
    assert panel_title(2, second) == "closure 2: road 5-9 reopened; not recovered"
    # The panel shows the route at the end of the window (a failed one) and says so in red
    recovered = closure_route_panels(campus, *_recovered_timeline(campus), size=300)
    stuck = closure_route_panels(campus, evaluations, [first, second], size=300)
    assert recovered.shape == stuck.shape and not np.array_equal(recovered, stuck)
    header = stuck[: stuck.shape[0] // 8, stuck.shape[1] // 2 :]  # the second panel's title
    assert _share(header, CLOSED_RGB, tol=40) > 0.0005


def test_each_panel_is_titled_with_start_goal_closed_roads_and_score(campus: RoadGraph) -> None:
    evaluations, closures = _timeline(campus)
    recoveries = measure_recoveries(closures, evaluations)
    panels = closure_panels(campus, evaluations, recoveries)
    assert [p.number for p in panels] == [1, 2, 3] and {(p.start, p.heading, p.goal_node) for p in panels} == {
        (0, 0, 13)
    }
    assert [p.closed for p in panels] == [((5, 9),), (), ((9, 10),)]
    assert [p.title for p in panels] == [
        (
            "closure 1: road 5-9 closed; recovered after 35 episodes / 3.5 s",
            "start 0 facing N -> Dreese Lab (13) | closed: 5-9",
            "learned 6 steps | re-routed 9 steps | shortest 9 | success 1.00, SPL 1.00",
        ),
        (
            "closure 2: road 5-9 reopened; recovered after 30 episodes / 3.0 s",
            "start 0 facing N -> Dreese Lab (13) | closed: none",
            "learned 9 steps | re-routed 6 steps | shortest 6 | success 1.00, SPL 1.00",
        ),
        (
            "closure 3: road 9-10 closed; recovered after 0 episodes / 0.0 s",
            "start 0 facing N -> Dreese Lab (13) | closed: 9-10",
            "learned 6 steps | re-routed 6 steps | shortest 6 | success 1.00, SPL 1.00",
        ),
    ]
    # The score is that of the evaluation the second route comes from: there one start of fifteen (0) loops
    evaluations, closures = _timeline(campus, recover_second=False)
    stuck = closure_panels(campus, evaluations, measure_recoveries(closures, evaluations))[1]
    assert stuck.after_evaluation is stuck.recovery.last and stuck.after is not None and not stuck.after.success
    assert stuck.title[2] == "learned 9 steps | at end of window fails | shortest 6 | success 0.93, SPL 0.93"


def test_a_figure_title_goes_above_the_panels(campus: RoadGraph) -> None:
    evaluations, recoveries = _recovered_timeline(campus)
    plain = closure_route_panels(campus, evaluations, recoveries, size=300)
    titled = closure_route_panels(campus, evaluations, recoveries, size=300, title="DCQN, seed 0")
    band = titled.shape[0] - plain.shape[0]
    assert band > 10 and titled.shape[1] == plain.shape[1]
    np.testing.assert_array_equal(titled[band:], plain)
    assert _share(titled[:band], (30, 30, 34), tol=60) > 0.005  # the title text


def _recovered_timeline(campus: RoadGraph) -> tuple[list[RouteEvaluation], list[Recovery]]:
    evaluations, closures = _timeline(campus)
    return evaluations, measure_recoveries(closures, evaluations)[:2]


def test_without_evaluations_before_the_closure_the_farthest_start_is_taken(campus: RoadGraph) -> None:
    closure = _closure(0, 0, closed=[(5, 9)])
    evaluations = [_evaluation(campus, [(5, 9)], 20)]
    recoveries = measure_recoveries([closure], evaluations)
    image = closure_route_panels(campus, evaluations, recoveries, size=300)
    farthest = int(np.argmax(NavigationGraph(campus).hops_to(campus.landmarks[GOAL])))
    np.testing.assert_array_equal(
        image, closure_route_panels(campus, evaluations, recoveries, start=farthest, heading=0, size=300)
    )
    assert _share(image, REROUTED_RGB) > 0.001  # only the route after the closure exists


def test_route_panels_reject_bad_input(campus: RoadGraph) -> None:
    evaluations, recoveries = _recovered_timeline(campus)
    with pytest.raises(ValueError, match=r"start 99 out of range \[0, 16\)"):
        closure_route_panels(campus, evaluations, recoveries, start=99)
    with pytest.raises(ValueError, match="is the goal"):
        closure_route_panels(campus, evaluations, recoveries, start=campus.landmarks[GOAL])
    with pytest.raises(ValueError, match="heading"):
        closure_route_panels(campus, evaluations, recoveries, heading=4)
    with pytest.raises(ValueError, match="at least one recovery"):
        closure_route_panels(campus, evaluations, [])
    with pytest.raises(ValueError, match="not a landmark"):
        closure_route_panels(campus, evaluations, recoveries, goal="Moon base")
    with pytest.raises(ValueError, match="columns"):
        closure_route_panels(campus, evaluations, recoveries, columns=0)
    with pytest.raises(TypeError, match="RoadGraph"):
        closure_route_panels("map", evaluations, recoveries)  # type: ignore[arg-type]


def test_pick_route_prefers_a_road_about_to_close_then_a_failure_then_the_farthest_start() -> None:
    far = Route(GOAL, 1, 0, True, 9, 9, (1, 2, 3))
    failed_near = Route(GOAL, 2, 1, False, 200, 3, (2, 3))
    failed_far = Route(GOAL, 3, 2, False, 200, 5, (3, 4))
    over_road = Route(GOAL, 4, 3, True, 4, 4, (4, 5, 6, 7))
    other_goal = Route("Cinema", 5, 0, False, 200, 12, (5, 6))
    routes = [far, failed_near, failed_far, over_road, other_goal]
    assert pick_route(routes, goal=GOAL, roads=[(6, 5)]) == over_road  # either order of the road's ends
    assert pick_route(routes, goal=GOAL) == failed_far
    assert pick_route([far, over_road], goal=GOAL) == far
    assert pick_route(routes, goal=GOAL, start=2) == failed_near and pick_route(routes, start=5) == other_goal
    assert pick_route(routes, goal=GOAL, heading=3) == over_road
    assert pick_route(routes, goal="Library") is None and pick_route([]) is None


def test_a_route_reads_as_its_nodes_and_the_turn_at_each(campus: RoadGraph) -> None:
    navigation = NavigationGraph(campus)
    nodes = navigation.shortest_path(0, campus.landmarks[GOAL])
    route = Route(GOAL, 0, 0, True, len(nodes) - 1, len(nodes) - 1, tuple(nodes))
    steps = route_steps(campus, route)
    assert [(s.node, s.to) for s in steps] == list(itertools.pairwise(nodes))
    # Each turn, taken by the env's move rule from where the last one left the agent, gives the next node
    state = campus.state_index(0, 0)
    for step in steps:
        assert (campus.state_nodes[state], campus.state_headings[state]) == (step.node, step.heading)
        state = int(navigation.move(state, ACTION_NAMES.index(step.action))[0])
        assert (campus.state_nodes[state], campus.state_headings[state]) == (step.to, step.to_heading)
    text = route_text(navigation, route)
    lines = text.splitlines()
    assert lines[0] == f"route from node 0 (Chapel) facing N to {GOAL}: reached in 6 steps (shortest 6)"
    assert lines[1] == "nodes: " + " ".join(map(str, nodes))
    assert lines[-1].endswith(f"-> 13 ({GOAL}) facing {'NESW'[steps[-1].to_heading]}")  # names where it has one
    assert [line.split(": ")[1].split(" -> ")[0] for line in lines[2:]] == [s.action for s in steps]

    # A move that stayed put (a closed road) is a blocked step; a failed route says so
    stuck = Route(GOAL, 0, 0, False, 200, len(nodes) - 1, (0, 0, nodes[1]))
    assert route_steps(campus, stuck)[0].action == "blocked"
    assert "fails after 1 move (a loop, blocked or the step limit; scored as 200 steps)" in route_text(campus, stuck)
    with pytest.raises(ValueError, match="no action leads from node 0 facing N to node 13"):
        route_steps(campus, Route(GOAL, 0, 0, False, 1, 6, (0, 13)))
    with pytest.raises(ValueError, match="its nodes must start there"):
        route_steps(campus, Route(GOAL, 0, 0, False, 1, 6, (3, 4)))


def test_tiles_are_as_close_to_square_as_the_pictures_allow() -> None:
    panel = np.zeros((562, 630, 3), dtype=np.uint8)
    grid = tile_panels([panel] * 4, gap=10)
    assert grid.shape == (2 * 562 + 3 * 10, 2 * 630 + 3 * 10, 3)  # 2 x 2, not a 4-high column
    row = np.zeros((562, 3 * 630, 3), dtype=np.uint8)
    assert tile_panels([row] * 4, gap=10).shape[:2] == (4 * 562 + 5 * 10, 3 * 630 + 2 * 10)  # wide rows: a column
    assert tile_panels([panel] * 3, columns=3, gap=0).shape[:2] == (562, 3 * 630)
    with pytest.raises(ValueError, match="at least one picture"):
        tile_panels([])
    with pytest.raises(ValueError, match="columns"):
        tile_panels([panel], columns=0)


def _episodes(n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    lengths = np.round(8 + 60 * np.exp(-np.arange(n) / 80) + rng.gamma(2.0, 4.0, n))
    return 1.0 - 0.01 * lengths, lengths


def test_training_curves_mark_the_closures(campus: RoadGraph) -> None:
    rewards, lengths = _episodes()
    evaluations, closures = _timeline(campus)
    plain = training_curves(rewards, lengths, size=(600, 400))
    assert plain.dtype == np.uint8 and plain.shape == (400, 600, 3)
    marked = training_curves(rewards, lengths, closures, size=(600, 400))
    assert marked.shape == plain.shape and not np.array_equal(plain, marked)
    tab_red = (214, 39, 40)  # the closure lines and their numbers
    assert _share(marked, tab_red, tol=30) > _share(plain, tab_red, tol=30) + 0.001
    with_evaluations = training_curves(rewards, lengths, measure_recoveries(closures, evaluations), evaluations)
    assert with_evaluations.shape == (780, 1100, 3)  # the default size with an evaluation panel


def test_training_curves_can_say_why_episode_reward_runs_ahead_of_route_success() -> None:
    rewards, lengths = _episodes()
    plain = training_curves(rewards, lengths, size=(900, 500))
    noted = training_curves(rewards, lengths, size=(900, 500), note=CURRICULUM_NOTE)
    assert noted.shape == plain.shape
    dark = [(image[-40:] < 128).any(axis=-1).mean() for image in (plain, noted)]  # the note goes under the panels
    assert dark[1] > dark[0] + 0.005
    assert "curriculum" in CURRICULUM_NOTE and "every start" in CURRICULUM_NOTE


def test_training_curves_reject_bad_input() -> None:
    rewards, lengths = _episodes(50)
    with pytest.raises(ValueError, match="one value per episode each, got 50 rewards and 49 lengths"):
        training_curves(rewards, lengths[:-1])
    with pytest.raises(ValueError, match="finite"):
        training_curves(np.r_[rewards[:-1], np.nan], lengths)
    with pytest.raises(ValueError, match="window"):
        training_curves(rewards, lengths, window=0)
    with pytest.raises(ValueError, match="size"):
        training_curves(rewards, lengths, size=(50, 50))
    with pytest.raises(TypeError, match="ClosureRecord or Recovery"):
        training_curves(rewards, lengths, closures=["episode 10: close 1-2"])  # type: ignore[list-item]


def test_write_figure_writes_a_png_atomically(tmp_path: Path) -> None:
    image = np.zeros((20, 30, 3), dtype=np.uint8)
    image[:, :10] = (255, 0, 0)
    path = write_figure(tmp_path / "figures" / "panels.png", image)
    assert path == tmp_path / "figures" / "panels.png"
    np.testing.assert_array_equal(cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB), image)
    assert [p.name for p in path.parent.iterdir()] == ["panels.png"]  # no temporary file left
    with pytest.raises(ValueError, match="uint8 RGB"):
        write_figure(tmp_path / "bad.png", image.astype(np.float32))


def test_result_files_get_the_permissions_of_a_plain_open(tmp_path: Path) -> None:
    import campusnav_env.atomic_files as atomic_files

    written = atomic_files.write_text_atomic(tmp_path / "summary.md", "x")
    plain = tmp_path / "plain.md"
    plain.write_text("x")
    # Not mkstemp's private 0600: what open() gives under this process's umask
    assert written.stat().st_mode & 0o777 == plain.stat().st_mode & 0o777 == 0o666 & ~atomic_files._UMASK
