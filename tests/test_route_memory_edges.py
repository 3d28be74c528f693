"""The memory's moves: outcomes observed and inferred, closures with an age, aliasing (EdgeStore's public API)."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from sb3_dcqn.route_memory.edges import MAX_BACKOFF, EdgeStore, Outcome

BACK = 2  # two-way roads: right after a move, action 2 leads back
# A move from state s in slot k arrives facing away from the road: arrival frame = k here, so "back" (frame + 2) is
# the slot that leads back, as in CampusNav


def two_way(retry_after: int = 10) -> EdgeStore:
    edges = EdgeStore(4, reverse_action=BACK, retry_after=retry_after)
    edges.ensure(4)
    return edges


def test_a_drive_is_observed_and_its_way_back_inferred_not_tried() -> None:
    edges = two_way()
    edges.record(0, 1, following=1, arrival=1, dead=False)  # east from 0 to 1, facing east on arrival
    assert edges.outcome[0, 1] == Outcome.DRIVEN and edges.target[0, 1] == 1
    back = edges.back_slot(0, 1)
    assert back == 3 and edges.outcome[1, 3] == Outcome.INFERRED and edges.target[1, 3] == 0  # west leads back
    assert edges.arrival[1, 3] == 3 and edges.n_tried() == 1  # arriving back at 0 it would face west
    assert edges.moves(np.array([1]))[0, 3] and edges.untried(np.array([1]))[0].tolist() == [True, True, True, False]


def test_a_bump_on_a_driven_road_closes_both_ends_until_the_far_end_is_driven_again() -> None:
    edges = two_way()
    edges.record(0, 1, following=1, arrival=1, dead=False)
    edges.record(1, 3, following=0, arrival=3, dead=False)  # the way back, driven: observed now
    edges.record(0, 1, following=0, arrival=1, dead=False)  # a bump: the road is closed
    assert edges.outcome[0, 1] == Outcome.BLOCKED and edges.target[0, 1] == 1  # where it led is kept
    assert edges.outcome[1, 3] == Outcome.INFERRED_BLOCKED  # closures close both ways
    assert not edges.moves(np.array([0, 1])).any()
    edges.record(1, 3, following=0, arrival=3, dead=False)  # driven again from the far end: open
    assert edges.outcome[1, 3] == Outcome.DRIVEN and edges.outcome[0, 1] == Outcome.BLOCKED  # observed: kept


def test_on_a_one_way_road_an_observation_outranks_every_inference() -> None:
    edges = two_way()
    edges.record(0, 1, following=1, arrival=1, dead=False)  # one way: 0 -> 1
    edges.record(1, 3, following=1, arrival=3, dead=False)  # the inferred way back bumps
    assert edges.outcome[1, 3] == Outcome.BLOCKED
    assert edges.outcome[0, 1] == Outcome.DRIVEN  # the open road forward is not closed by a wrong inference
    edges.record(0, 1, following=1, arrival=1, dead=False)  # forward again
    assert edges.outcome[1, 3] == Outcome.BLOCKED  # the observed bump is not revived by the inference


def test_a_closed_slot_may_be_retried_after_retry_after_transitions_doubling_with_each_bump() -> None:
    edges = two_way(retry_after=10)
    edges.record(0, 0, following=0, arrival=0, dead=False)  # bumped: no road north (yet)
    assert not edges.retry_due(np.array([0]))[0, 0]
    edges.clock += 9
    assert not edges.retry_due(np.array([0]))[0, 0]
    edges.clock += 1
    assert edges.retry_due(np.array([0]))[0, 0]
    edges.record(0, 0, following=0, arrival=0, dead=False)  # still closed: wait twice as long
    edges.clock += 19
    assert not edges.retry_due(np.array([0]))[0, 0]
    edges.clock += 1
    assert edges.retry_due(np.array([0]))[0, 0]
    assert not edges.retry_due(np.array([0]))[0, 1]  # an untried slot is no closed one
    for _ in range(40):
        edges.record(0, 0, following=0, arrival=0, dead=False)
    edges.clock += 10 * 2**MAX_BACKOFF
    assert edges.retry_due(np.array([0]))[0, 0]  # the wait stops doubling: retried one day


def test_routes_go_through_a_closed_road_only_with_retry_and_once_its_retry_is_due() -> None:
    edges = two_way(retry_after=10)
    edges.record(0, 1, following=1, arrival=1, dead=False)
    edges.record(0, 1, following=0, arrival=1, dead=False)
    assert not edges.moves(np.array([0]), retry=True)[0, 1]
    edges.clock += 10
    assert edges.moves(np.array([0]), retry=True)[0, 1] and not edges.moves(np.array([0]))[0, 1]
    edges.record(0, 0, following=0, arrival=0, dead=False)  # a slot that never led anywhere
    edges.clock += 100
    assert not edges.moves(np.array([0]), retry=True)[0, 0]  # no known road to route along


def test_a_slot_that_leads_to_two_places_twice_each_marks_its_state_aliased() -> None:
    edges = EdgeStore(2)
    edges.ensure(4)
    edges.record(0, 0, following=1, arrival=-1, dead=False)
    edges.record(0, 0, following=2, arrival=-1, dead=False)  # once elsewhere: a glitch, the latest wins
    assert edges.aliased == set() and edges.target[0, 0] == 2
    edges.record(0, 0, following=1, arrival=-1, dead=False)
    assert edges.aliased == set()
    edges.record(0, 0, following=2, arrival=-1, dead=False)  # twice each: two places, one picture
    assert edges.aliased == {0} and not edges.moves(np.array([0])).any()


def test_a_slot_that_leads_to_two_states_of_one_look_is_no_alias() -> None:
    edges = EdgeStore(2)
    edges.ensure(4)
    twins = lambda first, second: {first, second} == {1, 2}  # noqa: E731  (states 1 and 2: one place remembered twice)
    for following in (1, 2, 1, 2, 1):
        edges.record(0, 0, following=following, arrival=-1, dead=False, alike=twins)
    assert edges.aliased == set() and edges.target[0, 0] == 1 and edges.moves(np.array([0]))[0, 0]
    for following in (3, 3):  # another look: an alias
        edges.record(0, 0, following=following, arrival=-1, dead=False, alike=twins)
    assert edges.aliased == {0}


def test_two_states_that_another_move_also_leads_to_are_one_place_remembered_twice_not_an_alias() -> None:
    edges = EdgeStore(2)
    edges.ensure(6)
    for following in (1, 2, 1, 2):  # from state 3: states 1 and 2 by turns (a place whose pictures vary a lot)
        edges.record(3, 0, following=following, arrival=-1, dead=False)
    assert edges.aliased == {3}  # alone, two places that state 3 pictures alike
    for following in (2, 1):  # state 4's move led to both too: one place, two states
        edges.record(4, 1, following=following, arrival=-1, dead=False)
    assert edges.aliased == set() and edges.moves(np.array([3]))[0, 0]  # state 3 routes again
    for following in (1, 2, 1, 2):
        edges.record(0, 0, following=following, arrival=-1, dead=False)
    assert edges.aliased == set() and edges.target[0, 0] == 2 and edges.moves(np.array([0]))[0, 0]


def test_two_states_shown_to_be_one_place_are_handed_over_and_merge_into_one() -> None:
    edges = EdgeStore(4)
    edges.ensure(6)
    for following in (1, 2, 1, 2):
        edges.record(3, 0, following=following, arrival=0, dead=False)
    for following in (2, 1):
        edges.record(4, 1, following=following, arrival=0, dead=False)
    assert edges.twins == {(1, 2)}  # for the caller to merge
    edges.record(1, 0, following=5, arrival=0, dead=False)  # state 1 drove slot 0, state 2 slots 0 (later) and 3
    edges.record(2, 3, following=0, arrival=0, dead=False)
    edges.record(2, 0, following=0, arrival=0, dead=False)
    edges.merge(1, 2)
    assert edges.target[1, 3] == 0 and edges.outcome[1, 3] == Outcome.DRIVEN  # state 2's move, state 1 had none
    assert edges.target[1, 0] == 0  # both tried slot 0: the later try stands
    assert not edges.moves(np.array([2])).any() and not edges.untried(np.array([2])).any()  # 2 keeps nothing
    assert (edges.target[:6] != 2).all() and edges.target[3, 0] == 1 and edges.target[4, 1] == 1
    assert edges.twins == set() and edges.aliased == set()


def test_an_aliased_state_split_in_two_keeps_one_end_of_its_slot_and_its_sibling_the_other() -> None:
    edges = two_way()
    edges.ensure(6)
    edges.record(3, 0, following=0, arrival=0, dead=False)  # north from 3 to "0": which of the two, nobody knows
    for _ in range(2):  # east from "0" leads to 1 and to 2 by turns, twice each: two places remembered as one
        edges.record(0, 1, following=1, arrival=1, dead=False)
        edges.record(0, 0, following=4, arrival=0, dead=False)
        edges.record(0, 1, following=2, arrival=1, dead=False)
    assert edges.aliased == {0} and edges.alias_of(0, lambda a, b: False) == (1, 1, 2)  # the first seen first on a tie
    assert (0, 1, 2) in edges.disputed  # for the caller, who knows the pictures
    edges.split(0, slot=1, sibling=5, moved=2)
    assert edges.aliased == set() and edges.alias_of(0, lambda a, b: False) is None
    assert edges.outcome[0, 1] == Outcome.DRIVEN and edges.target[0, 1] == 1
    assert edges.outcome[5, 1] == Outcome.DRIVEN and edges.target[5, 1] == 2
    assert edges.target[1, 3] == 0 and edges.target[2, 3] == 5  # each way back leads to its own place
    assert edges.outcome[0, 0] == Outcome.DRIVEN and edges.target[0, 0] == 4  # the state keeps its other moves
    assert (edges.outcome[5, [0, 2, 3]] == Outcome.UNTRIED).all()  # the sibling's are to be explored
    # Moves into the state from elsewhere (3's drive, 4's inferred way back) may have ended at either: explored again
    assert (
        edges.outcome[3, 0] == edges.outcome[4, 2] == Outcome.UNTRIED and edges.target[3, 0] == edges.target[4, 2] == -1
    )
    assert edges.moves(np.array([0, 5]))[:, 1].all()


def test_dead_ends_and_moves_outside_the_memory_are_kept_apart_from_moves() -> None:
    edges = EdgeStore(2)
    edges.ensure(2)
    edges.record(0, 0, following=1, arrival=-1, dead=True)
    edges.record(0, 1, following=-1, arrival=-1, dead=False)
    assert edges.outcome[0].tolist() == [Outcome.DEAD_END, Outcome.OUTSIDE]
    assert not edges.moves(np.array([0])).any() and edges.n_tried() == 2
    edges.record(0, 1, following=-1, arrival=-1, dead=False)
    assert edges.outcome[0, 1] == Outcome.OUTSIDE and edges.clock == 3


def test_pose_states_forget_every_move_into_a_state_a_bump_lost() -> None:
    edges = EdgeStore(4, forget_moves_into_on_bump=True)
    edges.ensure(4)
    for state in (0, 1, 2):
        edges.record(state, 0, following=3, arrival=-1, dead=False)  # three headings of one road into pose 3
    edges.record(0, 0, following=0, arrival=-1, dead=False)  # closed now
    assert edges.outcome[:3, 0].tolist() == [Outcome.BLOCKED, Outcome.UNTRIED, Outcome.UNTRIED]
    assert edges.forgotten == 2
    plain = EdgeStore(4)
    plain.ensure(4)
    for state in (0, 1, 2):
        plain.record(state, 0, following=3, arrival=-1, dead=False)
    plain.record(0, 0, following=0, arrival=-1, dead=False)
    assert plain.outcome[1:3, 0].tolist() == [Outcome.DRIVEN, Outcome.DRIVEN]


def test_versions_count_changes_and_lost_moves() -> None:
    edges = two_way()
    edges.record(0, 1, following=1, arrival=1, dead=False)
    version = edges.version
    edges.record(0, 1, following=1, arrival=1, dead=False)  # the same outcome again: no change
    assert edges.version == version and edges.lost_move_version == 0
    edges.record(0, 1, following=0, arrival=1, dead=False)
    assert edges.version > version and edges.lost_move_version == edges.version


def test_the_store_grows_and_pickles_its_used_rows() -> None:
    edges = EdgeStore(2)
    edges.ensure(5000)
    edges.record(4999, 1, following=0, arrival=-1, dead=False)
    copy = pickle.loads(pickle.dumps(edges))
    assert copy.n_rows == 5000 and copy.target[4999, 1] == 0 and len(copy.outcome) >= 5000
    assert copy.nbytes() == edges.nbytes() == 5000 * 2 * 16


def test_bad_settings_are_named() -> None:
    with pytest.raises(ValueError, match="retry_after"):
        EdgeStore(4, retry_after=0)


@pytest.mark.parametrize("count_outcomes", [False, True])
def test_a_reloaded_store_settles_its_disputes_as_the_store_that_saved_it_did(count_outcomes: bool) -> None:
    # A small world whose moves lead to their ends but from two states that picture two places each, and to a random
    # end now and then (disputes, aliases and twins; counted, moves that turn out to be chance), with merges, splits
    # and a forgetting among them: at every step the store and its copy loaded from a pickle of the step before (which
    # reads its disputes anew) decide the same aliases and twins
    rng = np.random.default_rng(0)
    edges = EdgeStore(4, reverse_action=BACK, retry_after=10, count_outcomes=count_outcomes)
    edges.ensure(16)
    sibling, aliased_ever = 10, False
    ends = rng.integers(0, 10, (10, 4))
    other_ends = rng.integers(0, 10, (10, 4))  # states 0 and 1 picture two places each
    for step in range(900):
        state, slot = (int(value) for value in rng.integers(0, (10, 4)))
        following = int((other_ends if state < 2 and step % 2 else ends)[state, slot])
        if rng.random() < 0.05:  # a glitch of recognition
            following = int(rng.integers(0, 10))
        keep, drop = sorted(rng.choice(10, 2, replace=False).tolist())
        copy = pickle.loads(pickle.dumps(edges))
        for store in (edges, copy):
            store.record(state, slot, following=following, arrival=slot, dead=False)
            if step % 150 == 149:
                store.merge(keep, drop)
            alias = store.alias_of(min(store.aliased), lambda first, second: False) if store.aliased else None
            if step % 40 == 39 and alias is not None and sibling < 16:
                store.split(min(store.aliased), alias[0], sibling, alias[2])
            if step == 300:
                store.forget_disputes()
        sibling += step % 40 == 39 and alias is not None
        assert (edges.aliased, edges.twins) == (copy.aliased, copy.twins), step
        aliased_ever |= bool(edges.aliased)
    assert edges.twins and aliased_ever  # the world exercised both
