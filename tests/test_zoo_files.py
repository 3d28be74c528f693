"""The zoo's hyperparameter files: one reader (``sb3_dcqn.zoo_files``) for ``dcqn-campusnav`` and ``dcqn-zoo``.

An entry reads as rl_zoo3 2.9 reads it (``ExperimentManager.read_hyperparameters`` and ``_preprocess_hyperparams``):
``lin_`` schedules, evaluated strings, ``normalize``, ``frame_stack``, wrappers, callbacks, ``-params`` overrides and
the ``default`` entry. The checks name the file, the entry and the key of a bad setting before anything is built.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest
from stable_baselines3 import HerReplayBuffer
from stable_baselines3.common.utils import FloatSchedule

from sb3_dcqn import DCQN
from sb3_dcqn.replay import (
    DCQNDictReplayBuffer,
    LeanDictReplayBuffer,
    LeanRevisionHerReplayBuffer,
    RevisionDictReplayBuffer,
)
from sb3_dcqn.zoo_files import ZooEntry, check_hyperparams, default_hyperparams_path, load_zoo_entry

GOAL_ENV = "CampusNavGoal-v0"
# One entry with every key the zoo preprocesses, a lin_ learning rate first of all
EVERY_KEY = """\
CartPole-v1:
  n_timesteps: !!float 2e3
  n_envs: 2
  policy: MlpPolicy
  learning_rate: lin_1e-3
  gamma: 0.98
  train_freq: [4, step]
  policy_kwargs: "dict(net_arch=[32, 32], activation_fn=nn.ReLU)"
  replay_buffer_kwargs: "dict(handle_timeout_termination=False)"
  normalize: "dict(norm_obs=True, norm_reward=False)"
  frame_stack: 2
  env_kwargs: {sutton_barto_reward: true}
  monitor_kwargs: "dict(info_keywords=())"
  env_wrapper:
    - gymnasium.wrappers.TimeLimit: {max_episode_steps: 100}
  callback:
    - stable_baselines3.common.callbacks.StopTrainingOnMaxEpisodes: {max_episodes: 5}
"""
PROGRESS = (1.0, 0.75, 0.5, 0.0)


def as_rl_zoo3_reads(conf: Path, env_id: str, log_folder: Path, overrides: dict[str, Any] | None = None) -> tuple:
    """The zoo's own reading of an entry: its experiment manager, what it keeps, and the constructor's arguments."""
    pytest.importorskip("rl_zoo3")
    from rl_zoo3.exp_manager import ExperimentManager

    from sb3_dcqn.zoo import register_dcqn

    register_dcqn()
    manager = ExperimentManager(argparse.Namespace(), "dcqn", env_id, str(log_folder), config=str(conf))
    manager.custom_hyperparams = overrides
    hyperparams, _ = manager.read_hyperparameters()
    algorithm_kwargs, env_wrapper, callbacks, _ = manager._preprocess_hyperparams(hyperparams)
    return manager, algorithm_kwargs, env_wrapper, callbacks


def assert_same_algorithm_kwargs(ours: dict[str, Any], zoo: dict[str, Any]) -> None:
    """The same keys and values; schedules (the zoo makes constants schedules too) compared where they are evaluated."""
    assert set(ours) == set(zoo)
    for key, value in ours.items():
        if key == "learning_rate":
            for progress in PROGRESS:
                assert FloatSchedule(value)(progress) == pytest.approx(zoo[key](progress), rel=1e-9), progress
        else:
            assert value == zoo[key], key


# ------------------------------------------------------------------------------------------------ as rl_zoo3 reads it
def test_an_entry_with_a_lin_schedule_reads_as_rl_zoo3_reads_it(tmp_path: Path) -> None:
    conf = tmp_path / "conf.yml"
    conf.write_text(EVERY_KEY)
    entry = load_zoo_entry(conf, "CartPole-v1")
    manager, algorithm_kwargs, env_wrapper, callbacks = as_rl_zoo3_reads(conf, "CartPole-v1", tmp_path / "logs")

    assert_same_algorithm_kwargs(entry.hyperparams, algorithm_kwargs)
    assert entry.hyperparams["learning_rate"](0.5) == pytest.approx(5e-4)  # from 1e-3 at the start to 0 at the end
    assert (entry.n_timesteps, entry.n_envs) == (manager.n_timesteps, manager.n_envs) == (2000, 2)
    assert entry.env_kwargs == manager.env_kwargs == {"sutton_barto_reward": True}
    assert manager.normalize and entry.normalize == manager.normalize_kwargs  # gamma 0.98 added, as the zoo does
    assert entry.normalize == {"norm_obs": True, "norm_reward": False, "gamma": 0.98}
    assert entry.frame_stack == manager.frame_stack == 2
    assert entry.monitor_kwargs == manager.monitor_kwargs == {"info_keywords": ()}
    ours, zoo = entry.wrap_env(gym.make("CartPole-v1")), env_wrapper(gym.make("CartPole-v1"))
    assert (
        type(ours) is type(zoo) is gym.wrappers.TimeLimit and ours._max_episode_steps == zoo._max_episode_steps == 100
    )
    built = entry.make_callbacks()
    assert [type(c) for c in built] == [type(c) for c in callbacks] and built[0].max_episodes == callbacks[
        0
    ].max_episodes
    assert entry.zoo_only_settings == ("normalize", "frame_stack", "env_wrapper", "monitor_kwargs")


def test_params_overrides_replace_the_entrys_settings_before_they_are_read(tmp_path: Path) -> None:
    conf = tmp_path / "conf.yml"
    conf.write_text(EVERY_KEY)
    overrides = {"learning_rate": "lin_5e-4", "batch_size": 16, "env_kwargs": {}}  # -params as the zoo evaluates them
    entry = load_zoo_entry(conf, "CartPole-v1", overrides)
    _, algorithm_kwargs, _, _ = as_rl_zoo3_reads(conf, "CartPole-v1", tmp_path / "logs", overrides)
    assert_same_algorithm_kwargs(entry.hyperparams, algorithm_kwargs)
    assert entry.hyperparams["batch_size"] == 16 and entry.env_kwargs == {}
    with pytest.raises(ValueError, match=r"conf.yml: entry 'CartPole-v1' with -params learning_rate: learning_rate: "):
        load_zoo_entry(conf, "CartPole-v1", {"learning_rate": "lin_fast"})


def test_an_env_without_its_own_entry_reads_the_default_entry_as_the_zoo_does(tmp_path: Path) -> None:
    conf = tmp_path / "conf.yml"
    conf.write_text("default:\n  n_timesteps: 100\n  policy: MlpPolicy\n  learning_rate: 0.002\n")
    entry = load_zoo_entry(conf, "Acrobot-v1")
    _, algorithm_kwargs, _, _ = as_rl_zoo3_reads(conf, "Acrobot-v1", tmp_path / "logs")
    assert_same_algorithm_kwargs(entry.hyperparams, algorithm_kwargs)
    assert entry.hyperparams["learning_rate"] == 0.002  # a number stays a number: SB3 makes it a constant schedule
    with pytest.raises(KeyError, match="no entry for 'Acrobot-v1'"):
        load_zoo_entry(conf, "Acrobot-v1", fallbacks=())


def test_a_lin_schedule_passes_the_checks_and_reaches_dcqns_optimizer(tmp_path: Path) -> None:
    conf = tmp_path / "conf.yml"
    conf.write_text("CartPole-v1:\n  n_timesteps: 100\n  policy: MlpPolicy\n  learning_rate: lin_0.001\n")
    entry = load_zoo_entry(conf, "CartPole-v1")
    check_hyperparams(entry.hyperparams, DCQN, "here")  # what dcqn-campusnav refused before
    model = DCQN(env=gym.make("CartPole-v1"), **entry.hyperparams)
    assert model.lr_schedule(1.0) == pytest.approx(1e-3) and model.lr_schedule(0.25) == pytest.approx(2.5e-4)


@pytest.mark.parametrize(
    ("schedule", "message"),
    [
        ("lin_abc", r"expected a linear schedule lin_<initial value> \(e.g. lin_0.001\), got 'lin_abc'"),
        ("lin_inf", r"expected a linear schedule lin_<initial value> \(e.g. lin_0.001\), got 'lin_inf'"),
        (
            "exp_0.001",
            r"expected a positive number or a schedule .*got 'exp_0.001' \(a linear schedule is written lin_",
        ),
        ("lin0.001", r"expected a positive number or a schedule .*got 'lin0.001' \(a linear schedule is written lin_"),
    ],
)
def test_a_schedule_string_other_than_lin_and_a_number_is_named(tmp_path: Path, schedule: str, message: str) -> None:
    # The zoo reads any word_<number> as linear and fails on the rest with a traceback
    conf = tmp_path / "conf.yml"
    conf.write_text(f"CartPole-v1:\n  n_timesteps: 100\n  learning_rate: {schedule}\n")
    with pytest.raises(ValueError, match=rf"conf.yml: entry 'CartPole-v1': learning_rate: {message}"):
        entry = load_zoo_entry(conf, "CartPole-v1")
        check_hyperparams(entry.hyperparams, DCQN, f"{conf}: entry 'CartPole-v1'")


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("normalize: 3", r"normalize: expected true, false or a mapping"),
        ("frame_stack: two", r"frame_stack: expected a whole number, got 'two'"),
        ("env_wrapper: gymnasium.wrappers.NoSuchWrapper", r"env_wrapper: 'gymnasium.wrappers.NoSuchWrapper' cannot be"),
        ("monitor_kwargs: '[1, 2]'", r"monitor_kwargs must be a mapping, got \[1, 2\]"),
        ("policy: my_package.NoPolicy", r"policy: 'my_package.NoPolicy' cannot be imported"),
        ("n_envs: 1.5", r"n_envs: expected a whole number, got 1.5"),
    ],
)
def test_bad_zoo_settings_are_named_with_the_file_and_the_entry(tmp_path: Path, line: str, message: str) -> None:
    conf = tmp_path / "conf.yml"
    conf.write_text(f"CartPole-v1:\n  n_timesteps: 100\n  {line}\n")
    with pytest.raises(ValueError, match=rf"conf.yml: entry 'CartPole-v1': {message}"):
        load_zoo_entry(conf, "CartPole-v1")


def test_an_entry_without_zoo_only_settings_says_so() -> None:
    entry = load_zoo_entry(default_hyperparams_path(), "CartPole-v1")
    assert entry.zoo_only_settings == () and entry.normalize is None and entry.frame_stack is None
    assert entry.wrap_env(env := gym.make("CartPole-v1")) is env


# ------------------------------------------------------------------------------------------------ the shipped entries
@pytest.mark.parametrize("env_id", ["CampusNavCity-v0", "CampusNavCity10k-v0"])
def test_the_shipped_city_entries_pass_the_checks_and_bring_their_curriculum(env_id: str) -> None:
    entry = load_zoo_entry(default_hyperparams_path(), env_id)
    check_hyperparams(entry.hyperparams, DCQN, f"dcqn.yml: entry {env_id!r}")
    assert entry.hyperparams["replay_buffer_class"] is LeanDictReplayBuffer and entry.hyperparams["n_steps"] > 1
    assert [type(c).__name__ for c in entry.make_callbacks()] == ["StartCurriculumCallback"]


def test_the_shipped_goal_entry_reads_as_sb3s_her_buffer_and_passes_the_checks() -> None:
    entry = load_zoo_entry(default_hyperparams_path(), GOAL_ENV)
    assert entry.hyperparams["replay_buffer_class"] is HerReplayBuffer
    assert entry.hyperparams["replay_buffer_kwargs"] == {"n_sampled_goal": 4, "goal_selection_strategy": "future"}
    check_hyperparams(entry.hyperparams, DCQN, "dcqn.yml: entry 'CampusNavGoal-v0'")
    # DCQN's HER buffer's own arguments are accepted for HerReplayBuffer (DCQN serves it with that buffer)
    extra = {**entry.hyperparams["replay_buffer_kwargs"], "terminal_relabels": False, "relabel_tries": 2}
    check_hyperparams({**entry.hyperparams, "replay_buffer_kwargs": extra}, DCQN, "here")


# ------------------------------------------------------------------------------------------------ the checks
def test_bad_replay_buffer_settings_are_named(tmp_path: Path) -> None:
    her = {"policy": "MultiInputPolicy", "replay_buffer_class": HerReplayBuffer}
    misspelt = {**her, "replay_buffer_kwargs": {"n_sampled_goals": 4}}
    with pytest.raises(
        ValueError, match=r"here: unknown replay_buffer_kwargs key 'n_sampled_goals' .*'n_sampled_goal'"
    ):
        check_hyperparams(misspelt, DCQN, "here")
    with pytest.raises(ValueError, match="here: replay_buffer_class 'HerReplayBuffer' is not a replay buffer class"):
        check_hyperparams({**her, "replay_buffer_class": "HerReplayBuffer"}, DCQN, "here")  # not evaluated
    # The keys are those of the buffer named: DCQN's own buffer does no relabelling
    own = {**her, "replay_buffer_class": DCQNDictReplayBuffer, "replay_buffer_kwargs": {"n_sampled_goal": 4}}
    with pytest.raises(ValueError, match="unknown replay_buffer_kwargs key 'n_sampled_goal'"):
        check_hyperparams(own, DCQN, "here")
    # Variants that do not combine are named, both of them, with the entry
    with pytest.raises(ValueError, match=r"here: n-step returns \(nstep\) does not combine with experience revision"):
        check_hyperparams({"replay_buffer_class": RevisionDictReplayBuffer, "n_steps": 3}, DCQN, "here")
    # Every combination's class is a name a YAML entry may give
    conf = tmp_path / "conf.yml"
    conf.write_text(f"{GOAL_ENV}:\n  n_timesteps: 10\n  replay_buffer_class: LeanRevisionHerReplayBuffer\n")
    assert load_zoo_entry(conf, GOAL_ENV).hyperparams["replay_buffer_class"] is LeanRevisionHerReplayBuffer
    conf.write_text(f"{GOAL_ENV}:\n  n_timesteps: 10\n  replay_buffer_class: HerReplayBufer\n")
    with pytest.raises(ValueError, match="replay_buffer_class: cannot evaluate 'HerReplayBufer'"):
        load_zoo_entry(conf, GOAL_ENV)


def test_an_entrys_callbacks_are_read_as_the_zoo_reads_them_and_built_anew_for_each_model(tmp_path: Path) -> None:
    conf = tmp_path / "conf.yml"
    conf.write_text(
        "CampusNav-v0:\n  n_timesteps: 10\n  callback:\n"
        "    - campusnav_env.callbacks.StartCurriculumCallback:\n        initial: 3\n        window: 7\n"
        "    - stable_baselines3.common.callbacks.StopTrainingOnMaxEpisodes:\n        max_episodes: 5\n"
    )
    entry = load_zoo_entry(conf, "CampusNav-v0")
    assert "callback" not in entry.hyperparams  # not a DCQN argument
    first, second = entry.make_callbacks(), entry.make_callbacks()
    assert [type(c).__name__ for c in first] == ["StartCurriculumCallback", "StopTrainingOnMaxEpisodes"]
    assert first[0].window == 7 and first[1].max_episodes == 5
    assert first[0] is not second[0]
    # One class path alone, as the zoo also takes it
    conf.write_text("CampusNav-v0:\n  n_timesteps: 10\n  callback: campusnav_env.callbacks.StartCurriculumCallback\n")
    assert [type(c).__name__ for c in load_zoo_entry(conf, "CampusNav-v0").make_callbacks()] == [
        "StartCurriculumCallback"
    ]
    conf.write_text("CampusNav-v0:\n  n_timesteps: 10\n  callback: campusnav_env.callbacks.NoSuchCallback\n")
    with pytest.raises(
        ValueError, match=r"conf.yml: entry 'CampusNav-v0': callback: 'campusnav_env.callbacks.NoSuchCallback'"
    ):
        load_zoo_entry(conf, "CampusNav-v0")
    # Made by hand (a model saved with its entry's callbacks), an entry builds them the same way
    assert [type(c).__name__ for c in ZooEntry(0, {}, callbacks=entry.callbacks).make_callbacks()] == [
        "StartCurriculumCallback",
        "StopTrainingOnMaxEpisodes",
    ]


def test_counts_and_train_freq_are_read_as_the_zoo_reads_them(tmp_path: Path) -> None:
    conf = tmp_path / "conf.yml"
    conf.write_text("CartPole-v1:\n  n_timesteps: !!float 2e3\n  policy: MlpPolicy\n  train_freq: [2, episode]\n")
    entry = load_zoo_entry(conf, "CartPole-v1")
    assert entry.n_timesteps == 2000 and entry.hyperparams["train_freq"] == (2, "episode")  # a tuple, as the zoo's
    check_hyperparams(entry.hyperparams, DCQN, "here")
    conf.write_text("CartPole-v1:\n  n_timesteps: abc\n")
    with pytest.raises(
        ValueError, match=r"conf.yml: entry 'CartPole-v1': n_timesteps: expected a whole number, got 'abc'"
    ):
        load_zoo_entry(conf, "CartPole-v1")
    conf.write_text("CartPole-v1:\n  n_timesteps: 3e4\n")  # YAML 1.1: a string
    with pytest.raises(ValueError, match=r"YAML reads 3e4 as a string"):
        load_zoo_entry(conf, "CartPole-v1")
    conf.write_text("CartPole-v1:\n  policy: MlpPolicy\n")
    with pytest.raises(KeyError, match=r"conf.yml: entry 'CartPole-v1': no 'n_timesteps'"):
        load_zoo_entry(conf, "CartPole-v1")
