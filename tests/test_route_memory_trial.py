"""The memory's routes on trial against the critics': who drives, judged by the episodes each drove."""

from __future__ import annotations

import pickle
from collections import deque

import gymnasium as gym
import numpy as np
import pytest

from sb3_dcqn import RouteMemoryDQN
from sb3_dcqn.route_memory.evidence import (
    MIN_PREDICTIONS,
    TRIAL_BELOW,
    TRIAL_MIN_EPISODES,
    TRIAL_SHARE,
    EpisodeTrial,
    PredictionRecord,
)

NET = {"policy_kwargs": {"net_arch": [32]}}


def drive(trial: EpisodeTrial, lengths: dict[bool, int], episodes: int, seed: int = 0) -> None:
    """``episodes`` episodes of one env on trial, each as long as ``lengths`` says for the side that drives it."""
    rng = np.random.default_rng(seed)
    for _ in range(episodes):
        length = lengths[bool(trial.critics_drive()[0])]
        for step in range(length):
            trial.step(np.array([step == length - 1]), True, rng.random(1))


def test_the_side_whose_episodes_are_shorter_leads_and_the_other_still_drives_its_share() -> None:
    trial = EpisodeTrial(n_envs=1)
    drive(trial, {False: 12, True: 9}, episodes=TRIAL_MIN_EPISODES)  # too few of the critics' episodes yet
    assert not trial.critics_lead
    drive(trial, {False: 12, True: 9}, episodes=200)
    assert trial.critics_lead and trial.changes == 1
    assert trial.mean_steps(True) == 9 and trial.mean_steps(False) == 12
    share = trial.episodes(False) / (trial.episodes(False) + trial.episodes(True))
    assert 0.5 * TRIAL_SHARE < share < 2 * TRIAL_SHARE  # the memory drives its share: its case can still be made
    drive(trial, {False: 6, True: 9}, episodes=400, seed=1)  # the memory's routes got better (its window refills)
    assert not trial.critics_lead and trial.changes == 2


def test_both_sides_are_judged_on_the_latest_episodes_not_on_critics_long_gone() -> None:
    trial = EpisodeTrial(n_envs=1)
    drive(trial, {False: 40, True: 60}, episodes=400)  # early training: the memory's routes arrive sooner
    assert not trial.critics_lead
    # The critics learn: now their episodes are shorter. The quarter they drive is judged among the latest episodes,
    # not on a window of their own reaching back four times as far, to their long early ones
    drive(trial, {False: 10, True: 8}, episodes=250)
    assert trial.critics_lead and trial.mean_steps(True) == 8 and trial.mean_steps(False) == 10


def test_a_gap_within_the_noise_changes_no_lead() -> None:
    trial = EpisodeTrial(n_envs=1)
    rng = np.random.default_rng(0)
    for _ in range(600):  # both sides' episodes from the same spread: 5 to 25 steps
        length = int(rng.integers(5, 26))
        for step in range(length):
            trial.step(np.array([step == length - 1]), True, rng.random(1))
    assert trial.episodes(True) >= TRIAL_MIN_EPISODES and trial.changes <= 1


def test_off_trial_nothing_is_judged_and_the_memory_leads() -> None:
    trial = EpisodeTrial(n_envs=2)
    for step in range(2_000):
        trial.step(np.array([step % 5 == 4, step % 7 == 6]), False, None)  # off trial: no draws are taken
    assert not trial.critics_lead and trial.episodes(False) == trial.episodes(True) == 0
    assert not trial.critics_drive().any()


def test_the_routes_are_on_trial_below_the_bar_and_not_where_the_memory_stands_aside() -> None:
    record = PredictionRecord()
    record.score(np.ones(MIN_PREDICTIONS, dtype=bool))
    assert not record.on_trial  # every prediction came true
    record.score(np.arange(200) % 10 != 0)  # 0.9 of them: routes arrive, not always as planned
    assert record.accuracy < TRIAL_BELOW and record.on_trial and not record.standing_aside
    record.score(np.arange(256) % 2 == 0)  # 0.5: it stands aside, there is nothing to try
    assert record.standing_aside and not record.on_trial


@pytest.fixture
def model_on_trial() -> RouteMemoryDQN:
    """A memory-wearing DQN on deterministic FrozenLake that knows the way to the goal (the reward above 0), whose
    predictions came true 0.9 of the time."""
    env = gym.make("FrozenLake-v1", is_slippery=False)
    settings = {"route_memory": {"success_reward": 0.0}, "exploration_fraction": 1.0}
    model = RouteMemoryDQN("MlpPolicy", env, learning_starts=10, seed=0, **settings, **NET)
    model.learn(600)
    model.memory.predictions.score(np.arange(256) % 10 != 0)
    assert model.memory.predictions.on_trial
    return model


def test_where_the_critics_lead_the_model_acts_as_its_critics_and_says_so_once(
    model_on_trial: RouteMemoryDQN, capsys: pytest.CaptureFixture[str]
) -> None:
    model, batch = model_on_trial, np.arange(16)
    routes = model.predict(batch, deterministic=True)[0]
    critics = model.policy.predict(batch, deterministic=True)[0]
    assert not np.array_equal(routes, critics)  # the memory's routes are not the critics' greedy actions here
    revised = model._place_keys(np.array([0]), np.array([1]), np.array([4])).moves
    model._trial.critics_lead = True
    np.testing.assert_array_equal(model.predict(batch, deterministic=True)[0], critics)
    # Nor does it revise the critics' data while they lead (the memory did, while it led)
    assert revised.tolist() == [1] and model._place_keys(
        np.array([0]), np.array([1]), np.array([4])
    ).moves.tolist() == [-1]
    model.verbose = 1
    model._trial.critics_lead = False
    drive(model._trial, {False: 20, True: 6}, episodes=200)  # the trial's own evidence turns the lead
    model.memory.notices.append(model._trial_notice())
    model.memory.notices.append(model._trial_notice())
    model._say(model.memory.notices)
    said = [line for line in capsys.readouterr().out.splitlines() if line.startswith("route memory:")]
    assert len(said) == 1 and "the critics drive" in said[0] and "6.0 against 20.0 steps" in said[0]


def test_a_trial_the_critics_lead_goes_on_where_the_memorys_predictions_come_true_again(
    model_on_trial: RouteMemoryDQN,
) -> None:
    model, batch = model_on_trial, np.arange(16)
    critics = model.policy.predict(batch, deterministic=True)[0]
    drive(model._trial, {False: 20, True: 6}, episodes=200)  # the critics' episodes are shorter: they lead
    model.memory.predictions.score(np.ones(256, dtype=bool))  # every prediction comes true again
    assert not model.memory.predictions.on_trial and model._trial.critics_lead
    # Predictions that come true do not make routes short: the critics drive until the memory's episodes win
    np.testing.assert_array_equal(model.predict(batch, deterministic=True)[0], critics)
    drive(model._trial, {False: 4, True: 6}, episodes=400, seed=1)
    assert not model._trial.critics_lead
    assert not np.array_equal(model.predict(batch, deterministic=True)[0], critics)


def test_training_episodes_are_driven_by_the_trials_draw(model_on_trial: RouteMemoryDQN) -> None:
    model = model_on_trial
    model._trial._critics_drive[:] = True  # this env's episode is the critics'
    observation = np.array([0])
    for _ in range(20):  # the critics' epsilon-greedy action, never the memory's route
        model.exploration_rate = 0.0
        assert (
            model.predict(observation)[0].tolist() == model.policy.predict(observation, deterministic=True)[0].tolist()
        )
    model.learn(300, reset_num_timesteps=False)
    assert model._trial.episodes(True) + model._trial.episodes(False) > 0  # on trial, the episodes were counted
    assert model.logger.name_to_value["memory/routes_on_trial"] in (0.0, 1.0)


def test_a_trial_saved_with_a_window_per_side_loads_with_its_episodes() -> None:
    trial = EpisodeTrial(n_envs=1)
    state = {**trial.__dict__, "_lengths": {False: deque([12] * 30), True: deque([9] * 25)}}
    del state["_episodes"]  # the state of a model saved before the window was shared
    loaded = pickle.loads(pickle.dumps(trial))
    loaded.__setstate__(state)
    assert (loaded.episodes(False), loaded.episodes(True)) == (30, 25)
    assert (loaded.mean_steps(False), loaded.mean_steps(True)) == (12, 9)
