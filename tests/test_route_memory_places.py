"""The recogniser: which place a picture shows, calibrated on the agent's own pictures; known, new or unsure."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from sb3_dcqn.route_memory.places import Answer, PlaceRecogniser, linked_groups, widest_gap

VIEWS, WIDTH = 4, 16  # four views of 16 features each
SPREAD = 3.0  # features of a place: N(0, SPREAD): two places are about SPREAD * sqrt(2 * WIDTH) = 17 apart per view
NOISE = 0.05  # per feature on each visit: about 0.3 per view


def world(n_places: int, seed: int = 0) -> np.ndarray:
    """The true pictures of ``n_places`` places, ``(n, VIEWS * WIDTH)``."""
    return np.random.default_rng(seed).normal(0.0, SPREAD, (n_places, VIEWS * WIDTH)).astype(np.float32)


def visits(places: np.ndarray, order: np.ndarray, seed: int, noise: float = NOISE) -> np.ndarray:
    """A picture of each place in ``order``, with fresh noise."""
    rng = np.random.default_rng(seed)
    return (places[order] + rng.normal(0.0, noise, (len(order), places.shape[1]))).astype(np.float32)


def calibrated(places: np.ndarray, seed: int = 1, repeats: int = 3, noise: float = NOISE) -> PlaceRecogniser:
    """A recogniser shown ``repeats`` noisy visits of every place (the window holds them all), states added."""
    recogniser = PlaceRecogniser(places.shape[1], VIEWS, window=4 * repeats * len(places), min_calibration=16)
    order = np.tile(np.arange(len(places)), repeats)
    pictures = visits(places, order, seed, noise)
    recogniser.show(pictures)
    recogniser.calibrate()
    recogniser.recognise(pictures, add=True)
    return recogniser


def test_before_its_first_calibration_every_picture_is_unsure_and_after_it_exact_repeats_are_found() -> None:
    recogniser = PlaceRecogniser(VIEWS * WIDTH, VIEWS, window=256, min_calibration=16)
    places = world(3)
    states, answers = recogniser.recognise(places, add=True)
    assert (states == -1).all() and (answers == Answer.UNSURE).all() and recogniser.n_states == 0  # no guess
    calibrated_one = calibrated(world(40))
    pictures = visits(world(40), np.arange(40), seed=11)
    states, answers = calibrated_one.recognise(pictures, add=True)
    again, answers_again = calibrated_one.recognise(pictures[::-1])
    np.testing.assert_array_equal(again, states[::-1])
    assert (answers_again == Answer.KNOWN).all()


def test_bit_identity_alone_makes_every_other_picture_a_new_state() -> None:
    recogniser = PlaceRecogniser(8, 1, similar=False)
    rows = np.arange(16, dtype=np.uint8).reshape(2, 8)
    assert recogniser.recognise(rows, add=True)[0].tolist() == [0, 1]
    nudged = rows.copy()
    nudged[0, 0] += 1
    states, answers = recogniser.recognise(nudged, add=True)
    assert states.tolist() == [2, 1] and answers.tolist() == [Answer.NEW, Answer.KNOWN]


def test_thresholds_fall_between_repeat_visits_and_other_places() -> None:
    places = world(40)
    recogniser = calibrated(places)
    per_view_noise = NOISE * np.sqrt(WIDTH)
    assert recogniser.separable
    assert per_view_noise < recogniser.known < recogniser.new < 5.0  # places are about 17 apart per view
    assert recogniser.genuine < recogniser.known and recogniser.new < recogniser.impostor


def test_a_noisy_revisit_is_its_place_and_an_unseen_place_is_new() -> None:
    places = world(41)
    recogniser = calibrated(places[:40])
    revisit = visits(places, np.arange(40), seed=7)
    states, answers = recogniser.recognise(revisit)
    assert states.tolist() == list(range(40)) and (answers == Answer.KNOWN).all()
    states, answers = recogniser.recognise(visits(places, np.array([40]), seed=7), add=True)
    assert answers.tolist() == [Answer.NEW] and states.tolist() == [40]


def mixture(recogniser: PlaceRecogniser, places: np.ndarray, a: int, b: int, distance: float) -> np.ndarray:
    """A picture on the line from place ``a`` to place ``b``, at ``distance`` from ``a``'s prototype."""
    span = recogniser.distances(places[b])[a]
    weight = distance / span
    return ((1 - weight) * places[a] + weight * places[b])[None].astype(np.float32)


def test_a_picture_between_the_thresholds_is_unsure() -> None:
    places = world(40)
    recogniser = calibrated(places)
    between = mixture(recogniser, places, 0, 1, np.sqrt(recogniser.known * recogniser.new))
    states, answers = recogniser.recognise(between, add=True)
    assert answers.tolist() == [Answer.UNSURE] and states.tolist() == [-1] and recogniser.n_states == 40
    far = mixture(recogniser, places, 0, 1, 1.5 * recogniser.new)  # farther than "new" from both: a new place
    assert recogniser.recognise(far)[1].tolist() == [Answer.NEW]


def test_one_view_that_differs_wholly_leaves_a_place_the_place_and_two_shared_views_never_merge_two() -> None:
    places = world(40)
    recogniser = calibrated(places)
    barrier = places[3].copy()
    barrier[:WIDTH] = np.random.default_rng(5).normal(0.0, SPREAD, WIDTH)  # the north view: a construction barrier
    assert recogniser.recognise(barrier[None])[0].tolist() == [3]
    twin = places[3].copy()
    twin[: 2 * WIDTH] = places[4][: 2 * WIDTH]  # shares two of its four views with place 4, two with place 3
    states, answers = recogniser.recognise(twin[None], add=True)
    assert answers[0] != Answer.KNOWN and states[0] not in (3, 4)


def test_the_expected_place_settles_what_the_picture_leaves_unsure_and_a_wrong_one_is_not_taken() -> None:
    places = world(40)
    recogniser = calibrated(places)
    between = mixture(recogniser, places, 0, 1, np.sqrt(recogniser.known * recogniser.new))
    assert recogniser.recognise(between, add=True)[1].tolist() == [Answer.UNSURE]  # too far to remember as place 0
    assert recogniser.recognise(between, add=True, expected=np.array([1]))[1].tolist() == [Answer.UNSURE]
    assert recogniser.recognise(between, add=True, expected=np.array([0]))[0].tolist() == [0]  # the graph's prior
    # A clear picture of place 5 is place 5 whatever the caller expected
    assert recogniser.recognise(visits(places, np.array([5]), seed=3), expected=np.array([9]))[0].tolist() == [5]


def shifted(recogniser: PlaceRecogniser, place: np.ndarray, share_of_new: float, seed: int = 8) -> np.ndarray:
    """``place`` moved by ``share_of_new`` times the "new" threshold in every view (one random direction each)."""
    direction = np.random.default_rng(seed).normal(0.0, 1.0, (VIEWS, WIDTH))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    return (place + share_of_new * recogniser.new * direction.reshape(-1)).astype(np.float32)


def test_the_expected_place_settles_a_tie_and_a_place_clearly_nearer_wins_over_it() -> None:
    places = world(40)
    recogniser = calibrated(places)
    neighbour = shifted(recogniser, places[5], 1.05)  # a new place just far enough from place 5
    assert recogniser.recognise(neighbour[None], add=True)[1].tolist() == [Answer.NEW]
    between = (places[5] + neighbour)[None] / 2  # as near to place 5 as to its neighbour
    assert recogniser.recognise(between)[1].tolist() == [Answer.UNSURE]  # the views alone cannot tell
    assert recogniser.recognise(between, expected=np.array([5]))[0].tolist() == [5]  # the graph's prior can
    other_visit = between + np.float32(1e-3)  # (a picture once recognised is its answer's at once: another one)
    assert recogniser.recognise(other_visit, expected=np.array([40]))[0].tolist() == [40]
    nearer = (0.1 * places[5] + 0.9 * neighbour)[None]  # clearly the neighbour's, whatever the graph expected
    assert recogniser.recognise(nearer, expected=np.array([5]))[0].tolist() == [40]
    # Nearer the neighbour by the ratio, though not within "known" of it: not place 5 either (unsure, remembering)
    leaning = (0.4 * places[5] + 0.6 * neighbour)[None]
    to_five, to_neighbour = recogniser.distances(leaning[0])[[5, 40]]
    assert recogniser.known < to_neighbour <= 0.8 * to_five < to_five < recogniser.new
    assert recogniser.recognise(leaning, add=True, expected=np.array([5]))[0].tolist() == [-1]


def test_a_picture_clearly_nearest_one_place_is_known_though_another_lies_within_new() -> None:
    places = world(40)
    recogniser = calibrated(places)
    neighbour = shifted(recogniser, places[5], 1.05)
    recogniser.recognise(neighbour[None], add=True)
    near_five = (0.85 * places[5] + 0.15 * neighbour)[None]  # within "known" of place 5, within "new" of place 40
    first, second = np.sort(recogniser.distances(near_five[0]))[:2]
    assert first <= recogniser.known and second < recogniser.new and first <= 0.8 * second  # Lowe's ratio
    states, answers = recogniser.recognise(near_five, add=True)  # remembered as place 5, not unsure
    assert states.tolist() == [5] and answers.tolist() == [Answer.KNOWN]


def test_a_known_place_that_the_screen_misses_is_never_a_new_place() -> None:
    places = world(200)
    recogniser = calibrated(places)  # 200 states: a search screens them by sketch, 32 compared view by view

    def behind_a_barrier(place: int) -> np.ndarray:
        picture = visits(places, np.array([place]), seed=4)
        picture[0, :WIDTH] = 50.0 * np.random.default_rng(place).normal(0.0, SPREAD, WIDTH)  # the sketch is this view's
        return picture

    # (the test's own construction: a place whose picture the screen's 32 candidates leave out)
    place = next(place for place in range(200) if place not in recogniser._candidates(behind_a_barrier(place))[0])
    answers = recogniser.recognise(behind_a_barrier(place), add=True)[1]
    assert answers.tolist() != [Answer.NEW] and recogniser.n_states == 200


def test_a_picture_a_little_beyond_new_of_the_expected_place_is_unsure_and_a_far_one_is_new() -> None:
    places = world(40)
    recogniser = calibrated(places)
    odd = shifted(recogniser, places[5], 1.1)[None]  # an odd picture of place 5, or a place next to it
    assert recogniser.recognise(odd)[1].tolist() == [Answer.NEW]  # nothing expected: a new place
    states, answers = recogniser.recognise(odd, add=True, expected=np.array([5]))  # the graph expects place 5
    assert answers.tolist() == [Answer.UNSURE] and states.tolist() == [-1] and recogniser.n_states == 40
    far = shifted(recogniser, places[5], 2.0)[None]  # where place 5's road now leads elsewhere (a one-way road)
    assert recogniser.recognise(far, expected=np.array([5]))[1].tolist() == [Answer.NEW]


def test_a_picture_with_two_odd_views_is_never_a_new_place_and_is_the_expected_place_where_those_agree() -> None:
    places = world(40)
    recogniser = calibrated(places)
    cars = places[3].copy()  # cars before two of its cameras: those views a little beyond "new" of the place's
    cars[: 2 * WIDTH] = shifted(recogniser, places[3], 1.1)[: 2 * WIDTH]
    assert np.sort(recogniser.distances(cars))[0] >= recogniser.new  # as far as a new place by three views
    states, answers = recogniser.recognise(cars[None], add=True)
    assert answers.tolist() == [Answer.UNSURE] and states.tolist() == [-1] and recogniser.n_states == 40
    # A query takes the one place it matches but for two views (nothing is remembered: a wrong answer costs a step);
    # where the graph expects place 3, the two views that agree with it settle it, and not where it expects place 4
    assert recogniser.recognise(cars[None] + np.float32(1e-3))[0].tolist() == [3]
    other = cars[None] + np.float32(2e-3)
    assert recogniser.recognise(other, add=True, expected=np.array([4]))[1].tolist() == [Answer.UNSURE]
    assert recogniser.recognise(cars[None], add=True, expected=np.array([3]))[0].tolist() == [3]


def test_a_query_takes_the_clearly_nearest_place_short_of_new_that_remembering_would_leave_unsure() -> None:
    places = world(40)
    recogniser = calibrated(places)
    between = mixture(recogniser, places, 0, 1, np.sqrt(recogniser.known * recogniser.new))  # in place 0's band
    states, answers = recogniser.recognise(between)
    assert states.tolist() == [0] and answers.tolist() == [Answer.KNOWN]
    # The very picture the query answered (a rollout's step asks, then remembers it): the query's answer is not taken
    assert recogniser.recognise(between, add=True)[1].tolist() == [Answer.UNSURE] and recogniser.n_states == 40
    assert recogniser.recognise(between)[0].tolist() == [0]  # asked again, the query's own answer


def test_a_query_is_answered_anew_once_a_place_was_added() -> None:
    places = world(40)
    recogniser = calibrated(places)
    neighbour = shifted(recogniser, places[5], 1.05)  # a place not remembered yet, just beyond "new" of place 5
    picture = (0.1 * places[5] + 0.9 * neighbour)[None]
    assert recogniser.recognise(picture)[0].tolist() == [5]  # the clearly nearest place short of "new", for now
    assert recogniser.recognise(neighbour[None], add=True)[0].tolist() == [40]
    assert recogniser.recognise(picture)[0].tolist() == [40]


def test_a_picture_as_near_to_two_places_as_their_repeat_visits_is_unsure() -> None:
    # Visits vary almost as much as places differ (noise 1.0: repeat visits about 6 apart, places 17): a picture
    # halfway between two places is within "known" of both, and picks neither
    places = world(40)
    recogniser = calibrated(places, noise=1.0)
    direction = np.random.default_rng(8).normal(0.0, 1.0, (VIEWS, WIDTH))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    shift = (1.05 * recogniser.new * direction).reshape(-1).astype(np.float32)
    assert recogniser.recognise((places[5] + shift)[None], add=True)[1] == Answer.NEW
    between = (places[5] + shift / 2)[None]
    assert (np.sort(recogniser.distances(between[0]))[:2] <= recogniser.known).all()
    assert recogniser.recognise(between)[1].tolist() == [Answer.UNSURE]


def test_two_states_of_one_place_look_alike_and_two_places_do_not() -> None:
    places = world(40)
    recogniser = calibrated(places)
    twin = recogniser.recognise(visits(places, np.array([7]), seed=9, noise=3.0), add=True)  # far off: a second state
    assert twin[1].tolist() == [Answer.NEW]
    assert recogniser.alike(7, int(twin[0][0])) is False  # as far as "new": the recogniser tells them apart
    recogniser.new = 1e9  # thresholds that can tell nothing apart
    assert recogniser.alike(7, int(twin[0][0])) and recogniser.alike(3, 4)
    assert not PlaceRecogniser(8, 1, similar=False).alike(0, 1)


def test_pictures_that_do_not_separate_places_say_so() -> None:
    recogniser = PlaceRecogniser(VIEWS * WIDTH, VIEWS, window=64, min_calibration=16)
    recogniser.show(np.random.default_rng(0).normal(0.0, 1.0, (64, VIEWS * WIDTH)))  # no place ever seen twice
    assert recogniser.calibrated and not recogniser.separable and recogniser.window_full
    _, answers = recogniser.recognise(np.zeros((1, VIEWS * WIDTH)), add=True)
    assert answers.tolist() == [Answer.UNSURE] and recogniser.n_states == 0


def test_a_prototype_averages_the_noise_of_the_visits() -> None:
    places = world(40)
    recogniser = calibrated(places, repeats=8)
    errors = [np.linalg.norm(recogniser.prototype(s) - places[s]) for s in range(40)]
    one_visit = NOISE * np.sqrt(VIEWS * WIDTH)
    assert np.median(errors) < 0.6 * one_visit


def test_thresholds_follow_a_world_whose_pictures_drift() -> None:
    places = world(32)
    recogniser = PlaceRecogniser(VIEWS * WIDTH, VIEWS, window=128, min_calibration=16)
    recogniser.show(visits(places, np.tile(np.arange(32), 4), seed=0, noise=0.01))
    quiet = recogniser.known
    recogniser.show(visits(places, np.tile(np.arange(32), 8), seed=1, noise=0.2))  # two windows of new pictures
    assert recogniser.calibrations >= 2 and recogniser.known > 5 * quiet


def separated(places: np.ndarray, noise: float) -> PlaceRecogniser:
    """A recogniser of a 128-picture window shown four visits of each place (they separate), states added."""
    recogniser = PlaceRecogniser(VIEWS * WIDTH, VIEWS, window=128, min_calibration=16)
    first = visits(places, np.tile(np.arange(len(places)), 4), seed=3, noise=noise)
    recogniser.show(first)
    recogniser.recognise(first, add=True)
    return recogniser


def test_a_window_of_a_few_places_does_not_shrink_repeat_visits_into_other_places() -> None:
    # After the places separated, a window of two places pictured at two noise levels has its widest gap inside the
    # repeat visits (0.006 -> 0.8): the split stays above the repeat visits seen before, so visits stay known
    places = world(32)
    recogniser = separated(places, noise=0.2)
    before, calibrations = recogniser.known, recogniser.calibrations
    order = np.tile([0, 1], 64)
    still, moving = visits(places, order[:64], seed=4, noise=0.001), visits(places, order[64:], seed=5, noise=0.2)
    recogniser.show(np.concatenate([still, moving]))
    assert recogniser.calibrations > calibrations and recogniser.known > 0.5 * before
    states, answers = recogniser.recognise(visits(places, np.arange(32), seed=6, noise=0.2))
    assert (answers == Answer.KNOWN).all() and states.tolist() == list(range(32))


def test_a_window_with_odd_pictures_far_from_everything_does_not_raise_repeat_visits_past_other_places() -> None:
    # After the places separated, a window whose pictures are a quarter odd (a dark hour: ten times as far from
    # everything as places from each other) has its widest gap inside the other places: the split stays below the
    # other places seen before, so two places never become one
    places = world(32)
    recogniser = separated(places, noise=1.0)
    impostor, calibrations = recogniser.impostor, recogniser.calibrations
    odd = 10.0 * world(32, seed=9)
    recogniser.show(np.concatenate([visits(places, np.tile(np.arange(32), 3), seed=4, noise=1.0), odd]))
    recogniser.calibrate()  # on a window of those pictures alone
    assert recogniser.calibrations > calibrations and recogniser.new < impostor
    answers = recogniser.recognise(visits(world(40), np.arange(32, 40), seed=6, noise=1.0))[1]
    assert (answers == Answer.NEW).all()  # places not yet seen are new, not known as some other place


def test_look_alike_places_are_new_places_not_unsure_at_every_visit() -> None:
    # Six places nearly repeat six others (about 3 apart per view, where repeat visits are 0.3 and two places 17): "new"
    # is judged against each picture's nearest other place, so the look-alikes become places of their own
    places = world(30)
    twins = places[:6] + np.random.default_rng(9).normal(0.0, 0.8, places[:6].shape).astype(np.float32)
    recogniser = calibrated(np.concatenate([places, twins]))
    assert recogniser.n_states == 36
    states, answers = recogniser.recognise(visits(np.concatenate([places, twins]), np.arange(36), seed=12))
    assert (answers == Answer.KNOWN).all() and len(set(states.tolist())) == 36


def test_a_place_whose_pictures_drift_visit_by_visit_stays_one_place() -> None:
    # Every place is pictured at 8 hours in turn, each hour's light 1.5 per view further along a direction of its own:
    # two visits of a place lie 1.5 to 10.5 apart, two places about 17. The widest gap falls inside the visits (4.5 ->
    # 6: three hours apart and four); a place's visits four or more hours apart are then its own far visits, linked to
    # it through the hours between, not its nearest other place: "new" is judged against the other places, and no
    # hour's pictures become new places
    places = world(30)
    rng = np.random.default_rng(1)
    drift = rng.normal(0.0, 1.0, places.shape).reshape(30, VIEWS, WIDTH)
    drift = (drift / np.linalg.norm(drift, axis=2, keepdims=True)).reshape(places.shape)
    hours = np.arange(8)
    pictures = places[None] + 1.5 * hours[:, None, None] * drift[None] + rng.normal(0.0, 0.02, (8, *places.shape))
    pictures = pictures.reshape(-1, VIEWS * WIDTH).astype(np.float32)  # hour by hour, every place each hour
    recogniser = PlaceRecogniser(VIEWS * WIDTH, VIEWS, window=256, min_calibration=16)
    recogniser.show(pictures)
    recogniser.calibrate()
    states, answers = recogniser.recognise(pictures, add=True)
    assert recogniser.n_states == 30 and (answers != Answer.UNSURE).all()
    assert all(len(set(states[place::30].tolist())) == 1 for place in range(30))  # each place one state, its own


def test_linked_groups_are_the_connected_components() -> None:
    linked = np.zeros((7, 7), dtype=bool)
    for first, second in [(0, 3), (3, 5), (5, 6), (1, 4)]:  # a chain 0-3-5-6, a pair 1-4, 2 alone
        linked[first, second] = linked[second, first] = True
    assert linked_groups(linked).tolist() == [0, 1, 2, 0, 1, 0, 0]
    path = np.eye(300, k=1, dtype=bool) | np.eye(300, k=-1, dtype=bool)  # one chain, 300 long
    assert set(linked_groups(path).tolist()) == {0}
    assert linked_groups(np.zeros((0, 0), dtype=bool)).size == 0


def test_a_world_of_a_few_renders_per_view_calibrates_on_the_renders_differences() -> None:
    # Each view of a place is one of 3 renders, drawn per visit: revisits early on share most views bit for bit, which
    # must not read as "repeats are exact" (every other render of a place would then be a new place)
    places, renders = world(24), 3
    rng = np.random.default_rng(5)
    offsets = rng.normal(0.0, 2.0, (len(places), renders, VIEWS, WIDTH)).astype(np.float32)  # ~8 per view apart
    order = np.concatenate([np.repeat(np.arange(4), 6), np.tile(np.arange(len(places)), 6)])
    drawn = rng.integers(renders, size=(len(order), VIEWS))
    pictures = places[order].reshape(len(order), VIEWS, WIDTH) + offsets[order[:, None], drawn, np.arange(VIEWS)]
    recogniser = PlaceRecogniser(VIEWS * WIDTH, VIEWS, window=256, min_calibration=8)
    states = np.full(len(order), -1)
    for index, row in enumerate(pictures.reshape(len(order), -1)):  # as the memory feeds it: shown, then recognised
        recogniser.show(row[None])
        states[index] = recogniser.recognise(row[None], add=True)[0][0]
    assert recogniser.separable and recogniser.known > 1.0  # the renders' spread, not float error
    known = states >= 0
    merged = [state for state in set(states[known].tolist()) if len(set(order[states == state].tolist())) > 1]
    assert not merged and abs(recogniser.n_states - len(places)) <= 2 and known[-len(places) :].mean() >= 0.75


def test_a_window_that_does_not_separate_keeps_the_thresholds_the_pictures_showed_before() -> None:
    places = world(32)
    recogniser = PlaceRecogniser(VIEWS * WIDTH, VIEWS, window=64, min_calibration=16)
    recogniser.show(visits(places, np.tile(np.arange(32), 2), seed=0))
    known, new = recogniser.known, recogniser.new
    assert recogniser.separable
    look_alikes = np.random.default_rng(3).normal(0.0, 1.0, (64, VIEWS * WIDTH))  # no place twice, none apart
    recogniser.show(look_alikes)
    assert recogniser.calibrations >= 3 and recogniser.separable and (recogniser.known, recogniser.new) == (known, new)


def test_no_state_past_max_states_and_the_memory_pickles() -> None:
    places = world(40)
    recogniser = PlaceRecogniser(VIEWS * WIDTH, VIEWS, max_states=39, window=512, min_calibration=16)
    recogniser.show(visits(places, np.tile(np.arange(40), 3), seed=1))
    states, answers = recogniser.recognise(places, add=True)
    assert recogniser.n_states == 39 and states[-1] == -1 and answers[-1] == Answer.NEW
    copy = pickle.loads(pickle.dumps(recogniser))
    picture = visits(places, np.arange(39), seed=9)
    np.testing.assert_array_equal(copy.recognise(picture)[0], recogniser.recognise(picture)[0])
    assert copy.nbytes() == recogniser.nbytes() > 39 * VIEWS * WIDTH * 4


def test_the_split_is_the_widest_gap_with_enough_values_on_either_side() -> None:
    values = np.log(np.sort(np.array([0.1, 0.2, 0.15, 0.12, 5.0, 6.0, 5.5, 7.0, 40.0])))
    assert widest_gap(values, min_group=2) == 4  # 0.2 -> 5.0, not 7 -> 40 (one value alone above it)
    assert widest_gap(values, min_group=1) == 4
    assert widest_gap(values[:3], min_group=2) is None
    assert widest_gap(values, min_group=1, above=np.log(5.2)) == 8  # 7 -> 40: the first split above 5.2
    assert widest_gap(values, min_group=1, above=np.log(5.2), below=np.log(6.5)) == 7  # 6 -> 7: within (5.2, 6.5]


def test_two_places_merged_are_one_recognised_by_either_picture_and_the_merged_one_never_answered() -> None:
    places = world(40)
    recogniser = calibrated(places)
    odd = visits(places, np.array([7]), seed=9, noise=3.0)  # place 7 pictured another way (a lorry before it)
    twin = int(recogniser.recognise(odd, add=True)[0][0])
    assert twin == 40 and recogniser.live_states().size == 41  # a second state: the place split in two
    seen = visits(places, np.array([7]), seed=10)
    recogniser.recognise(seen, add=True)  # a picture remembered by its digest
    recogniser.merge(7, twin)
    assert not recogniser.live(twin) and recogniser.live(7) and recogniser.live_states().size == 40
    assert recogniser.members(7).tolist() == [7, 40] and recogniser.alike(7, twin)
    for seed in range(5):  # fresh pictures of either kind: place 7, never the merged twin
        plain = visits(places, np.array([7]), seed=20 + seed)
        other_way = odd + np.random.default_rng(seed).normal(0.0, NOISE, odd.shape).astype(np.float32)
        for picture in (plain, other_way):
            states, answers = recogniser.recognise(picture, add=True)
            assert states.tolist() == [7] and answers.tolist() == [Answer.KNOWN]
    assert recogniser.recognise(odd)[0].tolist() == [7] and recogniser.recognise(seen)[0].tolist() == [7]
    assert recogniser.recognise(visits(world(41), np.array([40]), seed=6), add=True)[1].tolist() == [Answer.NEW]
    copy = pickle.loads(pickle.dumps(recogniser))
    assert copy.recognise(odd)[0].tolist() == [7] and copy.live_states().size == 41  # saved, merged; and the new one


def test_look_alike_places_split_by_the_graph_are_told_apart_by_the_view_they_differ_in() -> None:
    places = world(40)
    recogniser = calibrated(places[:39])
    look_alike = places[0].copy()  # place 0 but for its last view
    look_alike.reshape(VIEWS, WIDTH)[3] = places[39].reshape(VIEWS, WIDTH)[3]
    both = np.stack([places[0], look_alike])
    first_look = visits(both, np.array([1]), seed=3)
    assert recogniser.recognise(first_look, add=True)[0].tolist() == [0]  # three views of four alike: one place
    for seed in range(2):  # the graph's evidence: pictures of each side (where a road from the state led)
        recogniser.witness(0, "north to A", visits(both, np.array([0]), seed=10 + seed)[0])
        recogniser.witness(0, "north to B", visits(both, np.array([1]), seed=20 + seed)[0])
    sibling = recogniser.split(0, "north to A", "north to B")
    assert sibling == 39 and recogniser.siblings(0) == {39} and recogniser.siblings(39) == {0}
    for seed in range(5):  # fresh pictures, remembered or asked, with or without the prior: each side its own
        for side, state in ((0, 0), (1, 39)):
            picture = visits(both, np.array([side]), seed=30 + seed)
            assert recogniser.recognise(picture)[0].tolist() == [state]
            assert recogniser.recognise(picture, add=True, expected=np.array([0]))[0].tolist() == [state]
    assert recogniser.recognise(first_look)[0].tolist() == [39]  # the state's exact pictures were forgotten
    assert pickle.loads(pickle.dumps(recogniser)).recognise(first_look)[0].tolist() == [39]


def test_a_state_whose_sides_picture_one_place_is_not_split() -> None:
    places = world(40)
    recogniser = calibrated(places)
    for seed in range(2):
        recogniser.witness(5, "east to A", visits(places, np.array([5]), seed=10 + seed)[0])
        recogniser.witness(5, "east to B", visits(places, np.array([5]), seed=20 + seed)[0])
    assert recogniser.split(5, "east to A", "east to B") == -1 and recogniser.n_states == 40  # nothing tells them apart
    assert recogniser.split(6, "east to A", "east to B") == -1  # nothing witnessed


def test_bad_pictures_are_named() -> None:
    with pytest.raises(ValueError, match="does not split into 3 equal views"):
        PlaceRecogniser(64, 3)
    with pytest.raises(ValueError, match=r"pictures must be \(batch, 64\)"):
        PlaceRecogniser(64, 4).recognise(np.zeros((2, 63)))
    with pytest.raises(ValueError, match="window"):
        PlaceRecogniser(64, 4, window=8, min_calibration=16)
