"""Where each goal is among the memory's states (GoalIndex's public API)."""

from __future__ import annotations

import numpy as np

from sb3_dcqn.route_memory import goals as goals_module
from sb3_dcqn.route_memory.goals import MAX_GOALS_ASKED, GoalIndex
from sb3_dcqn.route_memory.places import PlaceRecogniser
from sb3_dcqn.route_memory.planner import BoundedCache

VIEWS, WIDTH = 4, 8


def places(n: int) -> np.ndarray:
    return np.random.default_rng(0).normal(0.0, 3.0, (n, VIEWS * WIDTH)).astype(np.float32)


def calibrated_recogniser(pictures: np.ndarray) -> PlaceRecogniser:
    recogniser = PlaceRecogniser(VIEWS * WIDTH, VIEWS, window=256, min_calibration=16)
    rng = np.random.default_rng(1)
    visits = np.concatenate([pictures + rng.normal(0, 0.05, pictures.shape) for _ in range(3)]).astype(np.float32)
    recogniser.show(visits)
    recogniser.recognise(pictures, add=True)
    return recogniser


class CountingMatcher:
    """A place matcher that answers one row and counts the questions."""

    def __init__(self, answer: int) -> None:
        self.answer, self.asked = answer, 0

    def match(self, queries, references, labels, goal_pictures=None) -> np.ndarray:
        self.asked += 1
        assert references.shape == (len(labels), VIEWS * WIDTH) and goal_pictures is not None
        return np.full(len(queries), self.answer, dtype=np.int64)


def index(recogniser: PlaceRecogniser, matcher=None, achieved: str | None = None) -> GoalIndex:
    return GoalIndex(
        asked_keys=["goal"], picture_key="goal" if achieved is None else None, recogniser=recogniser,
        cache=BoundedCache(1 << 20), achieved_key=achieved, place_matcher=matcher,
    )  # fmt: skip


def test_a_goal_picture_is_at_the_place_the_recogniser_knows_and_nowhere_for_a_new_place() -> None:
    pictures = places(30)
    goals = index(calibrated_recogniser(pictures[:20]))
    asked = {"goal": pictures[[4, 25]]}
    keys = goals.digests(asked, 2)
    assert goals.states(keys[0], asked, 0, 2).tolist() == [4]
    assert goals.states(keys[1], asked, 1, 2).tolist() == []  # a place never seen: no state, the critics act


def test_a_goal_whose_place_is_seen_later_is_found_then() -> None:
    pictures = places(30)
    recogniser = calibrated_recogniser(pictures[:20])
    goals = index(recogniser)
    asked = {"goal": pictures[[25]]}
    key = goals.digests(asked, 1)[0]
    assert goals.states(key, asked, 0, 1).size == 0
    recogniser.recognise(pictures[25:26], add=True)  # the place is driven through: a new state
    assert goals.states(key, asked, 0, 1).tolist() == [20]  # the cached "nowhere" is not reused


def test_the_matcher_is_asked_only_for_pictures_the_recogniser_does_not_know() -> None:
    pictures = places(30)
    matcher = CountingMatcher(answer=7)
    goals = index(calibrated_recogniser(pictures[:20]), matcher)
    known = {"goal": pictures[[3]]}
    assert goals.states(goals.digests(known, 1)[0], known, 0, 1).tolist() == [3] and matcher.asked == 0
    night = {"goal": -pictures[[3]]}  # another light altogether
    assert goals.states(goals.digests(night, 1)[0], night, 0, 1).tolist() == [7] and matcher.asked == 1


def test_a_success_attaches_its_goal_and_vectors_within_the_tolerance_are_that_goal() -> None:
    goals = index(PlaceRecogniser(4, 1, similar=False))
    goals.picture_key = None  # goals by successes only
    reached = {"goal": np.array([[1.0, 2.0]])}
    goals.add_reached(reached, np.array([5]))
    nudged = {"goal": np.array([[1.0 + 5e-5, 2.0]])}
    far = {"goal": np.array([[1.001, 2.0]])}
    assert goals.states(goals.digests(nudged, 1)[0], nudged, 0, 1).tolist() == [5]
    assert goals.states(goals.digests(far, 1)[0], far, 0, 1).tolist() == []


def test_pose_states_of_a_goal_env_attach_goals_by_the_achieved_goal() -> None:
    goals = index(PlaceRecogniser(4, 1, similar=False), achieved="achieved_goal")
    seen = {"achieved_goal": np.array([[0.0, 1.0], [1.0, 1.0]]), "goal": np.zeros((2, 2))}
    goals.add_achieved(seen, np.array([3, 4]))
    asked = {"goal": np.array([[1.0, 1.0]])}
    assert goals.states(goals.digests(asked, 1)[0], asked, 0, 1).tolist() == [4]
    assert goals.conditioned


class SampleMatcher:
    """A place matcher that answers row 7 once it has been shown ``needed`` goal pictures, and keeps what it saw."""

    def __init__(self, needed: int) -> None:
        self.needed, self.seen = needed, np.zeros((0, VIEWS * WIDTH))

    def match(self, queries, references, labels, goal_pictures=None) -> np.ndarray:
        self.seen = goal_pictures
        return np.full(len(queries), 7 if len(goal_pictures) >= self.needed else -1, dtype=np.int64)


def test_a_goal_is_looked_up_again_once_more_pictures_of_unknown_goals_were_asked() -> None:
    pictures = places(30)
    matcher = SampleMatcher(needed=2)
    goals = index(calibrated_recogniser(pictures[:20]), matcher)
    first, second = {"goal": -pictures[[3]]}, {"goal": -pictures[[5]]}
    key = goals.digests(first, 1)[0]
    assert goals.states(key, first, 0, 1).size == 0  # one picture of that light: the matcher cannot place it yet
    goals.states(goals.digests(second, 1)[0], second, 0, 1)
    assert goals.states(key, first, 0, 1).tolist() == [7]  # the cached "nowhere" is not reused


def test_the_matcher_is_shown_the_most_recent_goal_pictures_oldest_first() -> None:
    pictures = places(20)
    matcher = SampleMatcher(needed=1)
    goals = index(calibrated_recogniser(pictures), matcher)
    unknown = np.random.default_rng(2).normal(0.0, 30.0, (MAX_GOALS_ASKED + 5, VIEWS * WIDTH)).astype(np.float32)
    for picture in [*unknown, unknown[-3]]:  # the last one asked before: it stays where it was
        asked = {"goal": picture[None]}
        goals.states(goals.digests(asked, 1)[0], asked, 0, 1)
    np.testing.assert_array_equal(matcher.seen, unknown[-MAX_GOALS_ASKED:])


class FirstRowMatcher:
    """A place matcher that places every picture at its first reference (the lowest state not ruled out)."""

    def match(self, queries, references, labels, goal_pictures=None) -> np.ndarray:
        return np.zeros(len(queries), dtype=np.int64)


def test_a_matched_place_where_the_goals_episode_went_on_is_ruled_out_and_the_matcher_asked_again() -> None:
    pictures = places(30)
    recogniser = calibrated_recogniser(pictures[:20])
    goals = index(recogniser, FirstRowMatcher())
    night = {"goal": -pictures[[3]]}
    key = goals.digests(night, 1)[0]
    assert goals.states(key, night, 0, 1).tolist() == [0] and goals.matched == {key: (0,)}
    goals.rule_out([key, b"another goal"], np.array([5, 0]))  # its episode went on elsewhere; another goal's here
    assert goals.states(key, night, 0, 1).tolist() == [0]
    goals.rule_out([key], np.array([0]))  # it went on where the matcher placed the goal: the goal is not there
    assert goals.states(key, night, 0, 1).tolist() == [1]
    recogniser.merge(2, 1)  # the place it was matched to and another are one place...
    goals.merge(2, 1)
    goals.rule_out([key], np.array([2]))  # ...ruled out there: at neither
    assert goals.states(key, night, 0, 1).tolist() == [3]


class TwoCandidatesMatcher:
    """A candidate matcher that names the two lowest states not ruled out (its one answer: none)."""

    def match(self, queries, references, labels, goal_pictures=None) -> np.ndarray:
        return np.full(len(queries), -1, dtype=np.int64)

    def candidates(self, queries, references, labels, goal_pictures=None) -> np.ndarray:
        return np.tile(np.array([1, 0]), (len(queries), 1))


def test_a_goal_a_matcher_names_candidates_for_is_at_each_until_its_episode_goes_on_there() -> None:
    pictures = places(30)
    goals = index(calibrated_recogniser(pictures[:20]), TwoCandidatesMatcher())
    night = {"goal": -pictures[[3]]}
    key = goals.digests(night, 1)[0]
    assert goals.states(key, night, 0, 1).tolist() == [0, 1] and goals.matched == {key: (1, 0)}  # likeliest first
    goals.rule_out([key], np.array([1]))  # its episode went on at one of them: asked again without it
    assert goals.states(key, night, 0, 1).tolist() == [0, 2]
    goals.rule_out([key], np.array([2]))
    # Toured: as many places ruled out as the matcher names, its candidates are no answer (its one clear one would be)
    assert goals.states(key, night, 0, 1).tolist() == []


def test_a_memory_saved_when_the_matcher_named_one_place_per_goal_loads_its_answers_as_places() -> None:
    pictures = places(30)
    goals = index(calibrated_recogniser(pictures[:20]), FirstRowMatcher())
    night = {"goal": -pictures[[3]]}
    key = goals.digests(night, 1)[0]
    goals.states(key, night, 0, 1)
    state = goals.__dict__.copy()
    state["_matched"] = {key: 0}  # as saved then: one place, -1 where the matcher named none
    state["_matcher_answers"] = {key: (*state["_matcher_answers"][key][:3], 0), b"nowhere": (20, 1, 0, -1)}
    loaded = GoalIndex.__new__(GoalIndex)
    loaded.__setstate__(state)
    assert loaded.matched == {key: (0,)} and loaded._matcher_answers[b"nowhere"][3] == ()
    loaded.rule_out([key], np.array([0]))
    assert loaded.states(key, night, 0, 1).tolist() == [1]


def test_the_matcher_is_asked_again_once_the_places_grew_by_a_share_not_at_every_new_place() -> None:
    pictures = places(110)
    recogniser = calibrated_recogniser(pictures[:100])
    matcher = CountingMatcher(answer=-1)
    goals = index(recogniser, matcher)
    night = {"goal": -pictures[[3]]}
    key = goals.digests(night, 1)[0]
    goals.states(key, night, 0, 1)
    recogniser.recognise(pictures[100:101], add=True)  # one place more of a hundred: the answer stands
    goals.states(key, night, 0, 1)
    assert matcher.asked == 1
    recogniser.recognise(pictures[101:103], add=True)  # 3% more: the goal's place may be among them
    goals.states(key, night, 0, 1)
    assert matcher.asked == 2


def test_the_places_ruled_out_are_kept_for_a_bounded_number_of_goals(monkeypatch) -> None:
    monkeypatch.setattr(goals_module, "MAX_GOALS_PLACED", 2)
    pictures = places(30)
    goals = index(calibrated_recogniser(pictures[:20]), FirstRowMatcher())
    asked = [{"goal": -pictures[[n]]} for n in range(3)]
    keys = [goals.digests(goal, 1)[0] for goal in asked]
    for key, goal in zip(keys, asked, strict=True):
        assert goals.states(key, goal, 0, 1).tolist() == [0]
        goals.rule_out([key], np.array([0]))
    # The oldest goal's fact is forgotten (one more trip there at worst); the two newest are kept
    assert [goals.states(key, goal, 0, 1).tolist() for key, goal in zip(keys, asked, strict=True)] == [[0], [1], [1]]
