"""Place recognition: goal photos matched to remembered places, also when pictured in a condition never seen.

Synthetic places (no CNN): random unit vectors in ``D`` dimensions. A condition (time of day, passing cars) is a fixed
random linear distortion of a place vector inside a shared ``R``-dimensional subspace (a random ``R x R`` map of the
place's part there, plus a random offset there), scaled by ``strength``, plus Gaussian noise: every condition is of
the same family, each one its own draw.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import pytest
import torch as th
from gymnasium import spaces

from sb3_dcqn.place_frame import PlaceFrame
from sb3_dcqn.place_recognition import (
    NOT_IN_MEMORY,
    AlignedNearestPlace,
    NearestPlace,
    PlaceEmbedding,
    fit_place_matcher,
)
from sb3_dcqn.route_memory import RouteMemory

D, N_PLACES, R = 64, 60, 8
NOISE = 0.02


@pytest.fixture(autouse=True)
def one_thread():
    """Training is deterministic for a seed on one thread (and the machine is shared)."""
    threads = th.get_num_threads()
    th.set_num_threads(1)
    yield
    th.set_num_threads(threads)


class Campus:
    """Synthetic places and the conditions they can be pictured in."""

    def __init__(self, seed: int = 0, n_places: int = N_PLACES) -> None:
        rng = np.random.default_rng(seed)
        places = rng.normal(size=(n_places, D))
        self.places = places / np.linalg.norm(places, axis=1, keepdims=True)
        self.subspace = np.linalg.qr(rng.normal(size=(D, R)))[0]  # where the conditions act

    def condition(self, seed: int, strength: float) -> Callable[[np.ndarray], np.ndarray]:
        """The photos of places ``nodes`` in condition ``seed`` (a fixed distortion, fresh noise each call)."""
        rng = np.random.default_rng(1_000 + seed)
        mixing, offset = rng.normal(size=(R, R)), rng.normal(size=R)

        def photos(nodes: np.ndarray) -> np.ndarray:
            own = self.places[nodes]
            inside = (own @ self.subspace @ mixing.T + offset) @ self.subspace.T
            return (own + strength * inside + NOISE * rng.normal(size=own.shape)).astype(np.float32)

        return photos


def references_of(campus: Campus, nodes: np.ndarray, conditions: list[int], strength: float):
    """The memory's side: every node of ``nodes`` pictured in each condition, labelled by its node."""
    rows = np.concatenate([campus.condition(seed, strength)(nodes) for seed in conditions])
    return rows, np.tile(nodes, len(conditions)).astype(np.int64)


def accuracy(rows: np.ndarray, labels: np.ndarray, truth: np.ndarray) -> float:
    """Share of queries whose matched row is of their own place (a -1 counts as a miss)."""
    return float(np.mean((rows >= 0) & (labels[np.maximum(rows, 0)] == truth)))


@pytest.mark.parametrize("learned", [False, True])
def test_a_route_memory_finds_a_goal_photo_in_a_new_condition_through_its_matcher(learned: bool):
    campus = Campus()
    space = spaces.Dict({"place": spaces.Box(-9, 9, (D,)), "goal": spaces.Box(-9, 9, (D,))})
    frame = PlaceFrame.from_declaration(
        {"place_keys": ["place"], "goal_pictures": {"goal": "place"}}, space, spaces.Discrete(2)
    )
    photos = campus.condition(1, strength=0.5)
    goal = campus.condition(7, strength=0.5)(np.array([3]))[0]  # place 3, pictured in a condition never seen
    bare = RouteMemory(2, space, place_frame=frame, place_matcher=None)
    default = RouteMemory(2, space, place_frame=frame)  # its own matcher: the goal photo aligned with its views
    references, labels = references_of(campus, np.arange(N_PLACES), [1, 2], strength=0.5)
    matcher = fit_place_matcher(references, labels, learned=learned, seed=0)
    matched = RouteMemory(2, space, place_frame=frame, place_matcher=matcher)
    for _ in range(3):  # a line of places 0 - 1 - 2 - 3 - 4, driven forward (action 0), fresh photos each time
        places = [{"place": picture, "goal": goal} for picture in photos(np.arange(5))]
        for memory in (bare, default, matched):
            for node in range(4):
                memory.add(places[node], 0, places[node + 1], 0.0, False)
    assert bare.n_states == default.n_states == matched.n_states == 5  # the five places, on the memory's own pictures
    assert bare.route_from(places[0]) == []  # the recogniser does not know the goal photo: no route
    assert matched.route_from(places[0]) == default.route_from(places[0]) == [0, 0, 0]  # a matcher does
    seen = {**places[0], "goal": photos(np.array([3]))[0]}  # place 3 pictured as the agent saw it: no matcher needed
    assert bare.route_from(seen) == [0, 0, 0]


def test_a_slightly_distorted_photo_matches_its_place():
    campus = Campus()
    nodes = np.arange(N_PLACES)
    references, labels = references_of(campus, nodes, [1], strength=0.1)
    queries = campus.condition(7, strength=0.1)(nodes)  # a condition the references lack, mild
    matcher = NearestPlace().calibrate(references, labels)
    assert accuracy(matcher.match(queries, references, labels), labels, nodes) == 1.0


def test_an_absent_place_is_not_in_memory_after_calibration():
    campus = Campus()
    remembered, absent = np.arange(40), np.arange(40, N_PLACES)
    references, labels = references_of(campus, remembered, [1, 2], strength=0.1)
    for learned in (False, True):
        matcher = fit_place_matcher(references, labels, learned=learned, seed=0)
        assert matcher.threshold is not None
        unseen = campus.condition(3, strength=0.1)
        assert np.all(matcher.match(unseen(absent), references, labels) == NOT_IN_MEMORY), learned
        # ... while the remembered places, in that condition, are still found
        assert accuracy(matcher.match(unseen(remembered), references, labels), labels, remembered) >= 0.95, learned


def test_without_a_threshold_an_absent_place_is_answered_with_a_wrong_one_and_calibration_refuses_it():
    campus = Campus()
    references, labels = references_of(campus, np.arange(40), [1], strength=0.1)
    queries = campus.condition(3, strength=0.1)(np.arange(40, N_PLACES))  # places the memory never saw
    assert np.all(NearestPlace().match(queries, references, labels) >= 0)  # each gets some remembered place
    calibrated = NearestPlace().calibrate(references, labels)
    assert np.mean(calibrated.match(queries, references, labels) == NOT_IN_MEMORY) >= 0.95


def test_calibration_splits_impostors_from_genuine_rows():
    campus = Campus()
    references, labels = references_of(campus, np.arange(N_PLACES), [1, 2], strength=0.1)
    matcher = NearestPlace().calibrate(references, labels)
    impostor, genuine = matcher.impostor_similarities, matcher.genuine_similarities
    assert impostor.shape == genuine.shape == (len(references),)
    # Separated here, so the threshold is the midpoint between the highest impostor and the lowest genuine row
    assert impostor.max() < genuine.min()
    assert matcher.threshold == pytest.approx((impostor.max() + genuine.min()) / 2, abs=1e-6)


def test_calibration_with_one_row_per_place_rejects_above_every_impostor():
    campus = Campus()
    nodes = np.arange(N_PLACES)
    references = campus.condition(1, strength=0.1)(nodes)
    matcher = NearestPlace().calibrate(references, nodes)
    assert matcher.genuine_similarities.size == 0
    assert matcher.threshold == pytest.approx(float(matcher.impostor_similarities.max()), abs=1e-6)


@pytest.mark.parametrize("world_seed", [0, 1, 2])
def test_the_learned_embedding_finds_places_in_a_condition_raw_cosine_fails_on(world_seed: int):
    campus = Campus(world_seed)
    nodes = np.arange(N_PLACES)
    references, labels = references_of(campus, nodes, [1, 2], strength=1.0)  # conditions A and B
    queries = campus.condition(3, strength=1.0)(nodes)  # C: of the same family, never trained on
    raw = accuracy(NearestPlace().match(queries, references, labels), labels, nodes)
    embedding = PlaceEmbedding().fit(references, labels, seed=0)
    learned = accuracy(NearestPlace(embedding=embedding).match(queries, references, labels), labels, nodes)
    assert raw < 0.5
    assert learned >= 0.9
    assert embedding.losses[-1] < embedding.losses[0]


def test_fitting_is_deterministic_for_a_seed_and_fast():
    campus = Campus()
    references, labels = references_of(campus, np.arange(N_PLACES), [1, 2], strength=1.0)
    queries = campus.condition(3, strength=1.0)(np.arange(N_PLACES))
    start = time.perf_counter()
    first = PlaceEmbedding().fit(references, labels, seed=3).transform(queries)
    seconds = time.perf_counter() - start
    again = PlaceEmbedding().fit(references, labels, seed=3).transform(queries)
    other = PlaceEmbedding().fit(references, labels, seed=4).transform(queries)
    np.testing.assert_allclose(first, again, atol=1e-5)
    assert np.abs(first - other).max() > 1e-2  # the seed does set the weights
    np.testing.assert_allclose(np.linalg.norm(first, axis=1), 1.0, atol=1e-5)
    assert seconds < 10.0


@pytest.mark.parametrize(
    "settings", [dict(dim=32, hidden=128, learning_rate=1e-2), dict(batch_size=64)], ids=["hidden", "batches"]
)
def test_a_hidden_layer_or_small_batches_learn_too(settings: dict):
    campus = Campus()
    nodes = np.arange(N_PLACES)
    references, labels = references_of(campus, nodes, [1, 2, 4], strength=1.0)
    queries = campus.condition(3, strength=1.0)(nodes)
    embedding = PlaceEmbedding(**settings).fit(references, labels, seed=0)
    assert embedding.transform(references).shape == (len(references), settings.get("dim", 64))
    raw = accuracy(NearestPlace().match(queries, references, labels), labels, nodes)
    learned = accuracy(NearestPlace(embedding=embedding).match(queries, references, labels), labels, nodes)
    # The linear family of distortions suits the linear map best: the ReLU layer gains less (0.38 against 0.13)
    assert learned >= raw + 0.2


def test_no_references_means_nothing_is_in_memory():
    rows = NearestPlace(threshold=0.5).match(np.ones((3, D), np.float32), np.zeros((0, D), np.float32), np.zeros(0))
    np.testing.assert_array_equal(rows, [-1, -1, -1])


def test_bad_shapes_name_the_argument():
    references = np.ones((6, D), np.float32)
    labels = np.arange(6)
    matcher = NearestPlace()
    with pytest.raises(ValueError, match=r"queries has 5 columns \(shape \(2, 5\)\), expected d = 64"):
        matcher.match(np.ones((2, 5), np.float32), references, labels)
    with pytest.raises(ValueError, match=r"queries must be a 2-D array \(rows, d\), got shape \(64,\)"):
        matcher.match(np.ones(D, np.float32), references, labels)
    with pytest.raises(ValueError, match=r"references must be a 2-D array"):
        matcher.match(np.ones((2, D), np.float32), np.ones((6, D, 1)), labels)
    with pytest.raises(ValueError, match=r"labels must have shape \(n,\).*labels \(5,\), references \(6, 64\)"):
        matcher.match(np.ones((2, D), np.float32), references, np.arange(5))
    with pytest.raises(ValueError, match=r"labels must be integers"):
        matcher.calibrate(references, labels.astype(np.float32))
    with pytest.raises(ValueError, match=r"references holds NaN"):
        matcher.calibrate(np.full((6, D), np.nan, np.float32), labels)
    with pytest.raises(ValueError, match=r"at least two places"):
        matcher.calibrate(references, np.zeros(6, np.int64))
    with pytest.raises(ValueError, match=r"threshold is a cosine similarity in \[-1, 1\], got 1.5"):
        NearestPlace(threshold=1.5)


def test_bad_training_data_names_the_problem():
    campus = Campus()
    nodes = np.arange(10)
    references = campus.condition(1, strength=0.1)(nodes)
    with pytest.raises(ValueError, match=r"every one of the 10 labels has one row"):
        PlaceEmbedding().fit(references, nodes)
    with pytest.raises(ValueError, match=r"labels must have shape \(n,\)"):
        PlaceEmbedding().fit(references, nodes[:, None])
    embedding = PlaceEmbedding().fit(np.concatenate([references, references]), np.tile(nodes, 2), steps=5)
    with pytest.raises(ValueError, match=r"vectors has 32 columns \(shape \(3, 32\)\), expected d = 64"):
        embedding.transform(np.ones((3, 32), np.float32))
    with pytest.raises(RuntimeError, match=r"call fit"):
        PlaceEmbedding().transform(references)


def night_of(places: np.ndarray, views: int, seed: int = 0) -> np.ndarray:
    """Photos of ``places`` in another light: every feature of every view rescaled and shifted alike (a darker,
    otherwise coloured camera), plus noise."""
    rng = np.random.default_rng(100 + seed)
    width = places.shape[1] // views
    scale, shift = rng.uniform(0.3, 3.0, size=width), rng.normal(scale=10.0, size=width)
    blocks = places.reshape(len(places), views, width) * scale + shift
    return (blocks.reshape(len(places), -1) + 0.05 * rng.normal(size=places.shape)).astype(np.float32)


def test_aligned_matching_finds_a_goal_photo_in_other_light_from_the_photo_alone():
    rng = np.random.default_rng(0)
    places = rng.normal(size=(N_PLACES, D))
    night = night_of(places, views=4)
    references, labels = places[10:].astype(np.float32), np.arange(10, N_PLACES)  # places 0-9 never visited
    matcher = AlignedNearestPlace(views=4)
    visited = np.arange(10, 30)
    one_by_one = np.array([matcher.match(night[[place]], references, labels)[0] for place in visited])
    np.testing.assert_array_equal(labels[one_by_one], visited)  # every one, from its own four views
    raw = NearestPlace().match(night[visited], references, labels)
    assert np.mean(labels[raw] == visited) <= 0.5  # without the alignment most are other places
    assert matcher.other_condition(night, references).all()
    assert matcher.other_condition(places[:10].astype(np.float32), references).sum() <= 1
    # A place never visited, pictured as the agent pictures: the recogniser called it new, and no near tie is an answer
    np.testing.assert_array_equal(matcher.match(places[:10].astype(np.float32), references, labels), -1)


def test_a_photo_of_one_view_in_other_light_is_placed_once_other_photos_of_that_light_were_shown():
    rng = np.random.default_rng(1)
    places = rng.normal(size=(N_PLACES, 16))
    night = night_of(places, views=1)
    references, labels = places.astype(np.float32), np.arange(N_PLACES)
    matcher = AlignedNearestPlace(views=1)
    asked = np.arange(20)
    alone = matcher.match(night[asked], references, labels)  # one view's features cannot say their light's moments
    assert np.mean(alone == asked) <= 0.3
    shown = np.concatenate([places[20:].astype(np.float32), night[20:]])  # goal photos asked before, in both lights
    found = matcher.match(night[asked], references, labels, shown)  # the other light's photos estimate it
    assert np.mean(found == asked) >= 0.9 and np.all((found == asked) | (found == -1))


def test_a_photo_within_the_references_light_overall_is_still_placed_in_the_asked_photos_light():
    # One place glares at noon (every feature of its views far off): the references' light reaches so far that some
    # night photos lie within it overall. Compared as they are, they match no place clearly; moved with the moments
    # of the other night photos asked, they are found as those are
    rng = np.random.default_rng(2)
    places = rng.normal(size=(N_PLACES, D))
    night = night_of(places, views=4)
    references, labels = places.astype(np.float32), np.arange(N_PLACES)
    references[0] += 10.0  # the glaring place
    matcher = AlignedNearestPlace(views=4)
    asked = np.arange(1, 21)
    within = ~matcher.other_condition(night[asked], references)
    assert 5 <= within.sum() <= 15  # some night photos within the references' light overall, some not
    found = matcher.match(night[asked], references, labels, night[asked])
    np.testing.assert_array_equal(found, asked)


def test_a_near_tie_or_a_single_place_is_no_answer():
    references = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], dtype=np.float32)
    matcher = AlignedNearestPlace()
    between = np.array([[1.0, 0.9, 0.0]], dtype=np.float32)
    assert matcher.match(between, references, np.arange(3))[0] == -1
    assert matcher.match(np.array([[1.0, 0.1, 0.0]], dtype=np.float32), references, np.arange(3))[0] == 0
    # Two rows of one place are no rival of each other; one place alone has no margin to judge
    assert matcher.match(np.array([[1.0, 0.1, 0.0]], dtype=np.float32), references, np.array([0, 0, 1]))[0] == 0
    assert matcher.match(between, references[:1], np.arange(1))[0] == -1


def test_a_photo_in_other_light_between_two_places_names_both_as_candidates_and_a_clear_one_names_one():
    blocks = np.random.default_rng(0).normal(size=(N_PLACES, 4, D // 4))
    places = (blocks / np.linalg.norm(blocks, axis=2, keepdims=True)).reshape(N_PLACES, D).astype(np.float32)
    labels = np.arange(N_PLACES)
    shown = places + 10.0  # every place pictured in another light: the goal photos asked about
    between = 0.5 * (places[[0, 2]] + places[[1, 3]]) + 10.0  # in that light, halfway between two places
    matcher = AlignedNearestPlace(views=4)
    np.testing.assert_array_equal(matcher.match(between, places, labels, shown), -1)  # no place clearly the nearest
    candidates = matcher.candidates(between, places, labels, shown)
    assert candidates.shape == (2, 4) and [set(row[row >= 0]) for row in candidates] == [{0, 1}, {2, 3}]
    np.testing.assert_array_equal(matcher.candidates(shown[[7]], places, labels, shown), [[7, -1, -1, -1]])
    # In the references' own light a near tie is a place not visited: no candidates
    np.testing.assert_array_equal(matcher.candidates(between - 10.0, places, labels, shown), -1)
    one = AlignedNearestPlace(views=4, max_candidates=1).candidates(between, places, labels, shown)
    np.testing.assert_array_equal(one, [[-1], [-1]])


@pytest.mark.parametrize(
    "settings, message",
    [
        ({"views": 0}, "views"),
        ({"own_ratio": 1.5}, "own_ratio"),
        ({"other_ratio": 0.0}, "other_ratio"),
        ({"candidate_ratio": 0.99}, "candidate_ratio"),
        ({"max_candidates": 0}, "max_candidates"),
    ],
)
def test_aligned_matching_names_a_bad_setting(settings: dict, message: str):
    with pytest.raises(ValueError, match=message):
        AlignedNearestPlace(**settings)


def test_aligned_matching_names_a_picture_that_does_not_split_into_its_views():
    with pytest.raises(ValueError, match="do not split into 3 views"):
        AlignedNearestPlace(views=3).match(np.zeros((1, 8)), np.ones((2, 8)), np.arange(2))
