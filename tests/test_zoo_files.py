"""The zoo's hyperparameter files: one entry reading (``sb3_dcqn.zoo_entry``) for ``dcqn-campusnav`` and ``dcqn-zoo``.

An entry reads as rl_zoo3 2.9 reads it (``ExperimentManager.read_hyperparameters`` and ``_preprocess_hyperparams``,
the oracle here): ``lin_`` schedules, evaluated strings, callbacks, ``-params`` overrides and the ``default`` entry;
with rl_zoo3 installed through its own public functions, without it through ours, and both agree with the zoo's
``ExperimentManager``. The zoo's env-building keys (``normalize``, ``frame_stack``, wrappers, ``monitor_kwargs``) are
checked and kept as written, for the zoo to apply. The checks raise an error carrying the file, the entry, the key and
the value of a bad setting before anything is built.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest
import yaml
from stable_baselines3 import HerReplayBuffer
from stable_baselines3.common.utils import FloatSchedule

from sb3_dcqn import DCQN
from sb3_dcqn.replay import (
    DCQNDictReplayBuffer,
    LeanDictReplayBuffer,
    LeanRevisionHerReplayBuffer,
    RevisionDictReplayBuffer,
)
from sb3_dcqn.route_memory import algorithm_name, with_route_memory
from sb3_dcqn.zoo_entry import (
    ZOO_ENV_KEYS,
    EntryError,
    ZooEntry,
    check_params,
    load_zoo_entry,
    read_entry,
    read_params,
)
from sb3_dcqn.zoo_files import default_hyperparams_path

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


@contextlib.contextmanager
def without_rl_zoo3(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """rl_zoo3 cannot be imported inside the block, as where the zoo extra is not installed."""
    with monkeypatch.context() as hidden:
        hidden.setitem(sys.modules, "rl_zoo3", None)
        yield


def entry_of(**settings: Any) -> ZooEntry:
    """An entry of ``conf.yml`` for CartPole-v1 with these settings (and a small ``n_timesteps``)."""
    return read_entry({"n_timesteps": 10, **settings}, Path("conf.yml"), "CartPole-v1")


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
@pytest.mark.parametrize("zoo_installed", [True, False], ids=["with rl_zoo3", "without rl_zoo3"])
def test_an_entry_with_a_lin_schedule_reads_as_rl_zoo3_reads_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, zoo_installed: bool
) -> None:
    conf = tmp_path / "conf.yml"
    conf.write_text(EVERY_KEY)
    manager, algorithm_kwargs, env_wrapper, callbacks = as_rl_zoo3_reads(conf, "CartPole-v1", tmp_path / "logs")
    with contextlib.nullcontext() if zoo_installed else without_rl_zoo3(monkeypatch):
        entry = load_zoo_entry(conf, "CartPole-v1")
    schedule = entry.hyperparams["learning_rate"]
    assert type(schedule).__module__.startswith("rl_zoo3") is zoo_installed  # the zoo's own schedule, or ours

    assert_same_algorithm_kwargs(entry.hyperparams, algorithm_kwargs)
    assert entry.hyperparams["learning_rate"](0.5) == pytest.approx(5e-4)  # from 1e-3 at the start to 0 at the end
    assert (entry.n_timesteps, entry.n_envs) == (manager.n_timesteps, manager.n_envs) == (2000, 2)
    assert entry.env_kwargs == manager.env_kwargs == {"sutton_barto_reward": True}
    built = entry.make_callbacks()
    assert [type(c) for c in built] == [type(c) for c in callbacks] and built[0].max_episodes == callbacks[
        0
    ].max_episodes
    # The zoo's env-building keys: checked, kept as written for the zoo's own code (dcqn-campusnav refuses them)
    written = yaml.safe_load(EVERY_KEY)["CartPole-v1"]
    assert entry.zoo_settings == {key: written[key] for key in ZOO_ENV_KEYS if key in written}
    assert set(entry.zoo_settings) == {"normalize", "frame_stack", "env_wrapper", "monitor_kwargs"}
    assert manager.frame_stack == 2 and env_wrapper is not None


def test_params_overrides_replace_the_entrys_settings_before_they_are_read(tmp_path: Path) -> None:
    conf = tmp_path / "conf.yml"
    conf.write_text(EVERY_KEY)
    overrides = {"learning_rate": "lin_5e-4", "batch_size": 16, "env_kwargs": {}}  # -params as the zoo evaluates them
    entry = load_zoo_entry(conf, "CartPole-v1", overrides)
    _, algorithm_kwargs, _, _ = as_rl_zoo3_reads(conf, "CartPole-v1", tmp_path / "logs", overrides)
    assert_same_algorithm_kwargs(entry.hyperparams, algorithm_kwargs)
    assert entry.hyperparams["batch_size"] == 16 and entry.env_kwargs == {}
    assert entry.params == ("learning_rate", "batch_size", "env_kwargs")
    # A bad override is named as the override it is, not as the file's
    with pytest.raises(EntryError, match=r"^-params learning_rate: expected a linear schedule") as raised:
        load_zoo_entry(conf, "CartPole-v1", {"learning_rate": "lin_fast"})
    assert raised.value.from_params and (raised.value.file, raised.value.entry) == (conf, "CartPole-v1")


@pytest.mark.parametrize("zoo_installed", [True, False], ids=["with rl_zoo3", "without rl_zoo3"])
def test_params_read_the_same_with_and_without_rl_zoo3(monkeypatch: pytest.MonkeyPatch, zoo_installed: bool) -> None:
    # -params' one reading (Python as the zoo reads it, else YAML) needs no rl_zoo3: dcqn-campusnav reads them alike
    items = ["learning_rate:lin_1e-3", "train_freq:[2, step]", "policy_kwargs:dict(net_arch=[8])", "gamma:0.9"]
    with contextlib.nullcontext() if zoo_installed else without_rl_zoo3(monkeypatch):
        params = read_params(items)
        entry = entry_of(policy="MlpPolicy", **params)
    assert params == {
        "learning_rate": "lin_1e-3",
        "train_freq": [2, "step"],
        "policy_kwargs": {"net_arch": [8]},
        "gamma": 0.9,
    }
    assert entry.hyperparams["learning_rate"](0.5) == pytest.approx(5e-4) and entry.hyperparams["train_freq"] == (
        2,
        "step",
    )


def test_an_env_without_its_own_entry_reads_the_default_entry_as_the_zoo_does(tmp_path: Path) -> None:
    conf = tmp_path / "conf.yml"
    conf.write_text("default:\n  n_timesteps: 100\n  policy: MlpPolicy\n  learning_rate: 0.002\n")
    entry = load_zoo_entry(conf, "Acrobot-v1")
    _, algorithm_kwargs, _, _ = as_rl_zoo3_reads(conf, "Acrobot-v1", tmp_path / "logs")
    assert_same_algorithm_kwargs(entry.hyperparams, algorithm_kwargs)
    assert entry.hyperparams["learning_rate"] == 0.002  # a number stays a number: SB3 makes it a constant schedule
    assert entry.name == "default" and entry.source == f"{conf}: entry 'default'"
    with pytest.raises(EntryError, match=r"conf.yml: no entry for 'Acrobot-v1' \(entries: \['default'\]\)"):
        load_zoo_entry(conf, "Acrobot-v1", fallbacks=())


def test_a_lin_schedule_passes_the_checks_and_reaches_dcqns_optimizer(tmp_path: Path) -> None:
    conf = tmp_path / "conf.yml"
    conf.write_text("CartPole-v1:\n  n_timesteps: 100\n  policy: MlpPolicy\n  learning_rate: lin_0.001\n")
    entry = load_zoo_entry(conf, "CartPole-v1")
    model = entry.make_model(gym.make("CartPole-v1"))
    assert isinstance(model, DCQN) and entry.algorithm_class() is DCQN
    assert model.lr_schedule(1.0) == pytest.approx(1e-3) and model.lr_schedule(0.25) == pytest.approx(2.5e-4)


@pytest.mark.parametrize(
    ("schedule", "message"),
    [
        ("lin_abc", r"expected a linear schedule lin_<initial value> \(e.g. lin_0.001\), got 'lin_abc'"),
        ("lin_inf", r"expected a linear schedule lin_<initial value> \(e.g. lin_0.001\), got 'lin_inf'"),
        ("lin_-1e-3", r"expected a linear schedule lin_<initial value> \(e.g. lin_0.001\), got 'lin_-1e-3'"),
        ("1e-3", r"expected a positive number or a schedule .*\(YAML reads 1e-3 as a string: write 0.001 or !!float"),
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
    with pytest.raises(EntryError, match=rf"conf.yml: entry 'CartPole-v1': learning_rate: {message}") as raised:
        load_zoo_entry(conf, "CartPole-v1")
    assert (raised.value.key, raised.value.value) == ("learning_rate", schedule)


def in_entry(line: str) -> str:
    """A file whose CartPole-v1 entry has ``n_timesteps`` and this line."""
    return f"CartPole-v1:\n  n_timesteps: 100\n  {line}\n"


@pytest.mark.parametrize(
    ("text", "key", "message"),
    [
        (in_entry("normalize: 3"), "normalize", r"entry 'CartPole-v1': normalize: expected true, false or a mapping"),
        (in_entry("frame_stack: two"), "frame_stack", r"entry 'CartPole-v1': frame_stack: expected a positive integer"),
        (in_entry("frame_stack: 0"), "frame_stack", r"entry 'CartPole-v1': frame_stack: expected a positive integer"),
        (in_entry("env_wrapper: gym.NoSuchWrapper"), "env_wrapper", r".*: 'gym.NoSuchWrapper' cannot be imported"),
        (in_entry("monitor_kwargs: '[1, 2]'"), "monitor_kwargs", r".*: expected a mapping, got \[1, 2\]"),
        (in_entry("policy: my_package.NoPolicy"), "policy", r".*: 'my_package.NoPolicy' cannot be imported"),
        (in_entry("n_envs: 1.5"), "n_envs", r"entry 'CartPole-v1': n_envs: expected a positive integer, got 1.5"),
        (in_entry("env_kwargs: [1]"), "env_kwargs", r"entry 'CartPole-v1': env_kwargs: expected a mapping, got \[1\]"),
        ("CartPole-v1:\n  policy: [MlpPolicy\n", None, r"not valid YAML \(line 3, column 1: "),
        ("- CartPole-v1\n", None, r"not a zoo-format hyperparameter file"),
        ("CartPole-v1: 3\n", None, r"entry 'CartPole-v1': not a mapping of hyperparameters"),
        ("CartPole-v1:\n  policy: MlpPolicy\n", None, r"entry 'CartPole-v1': no 'n_timesteps'"),
    ],
)
def test_a_bad_file_entry_or_zoo_setting_is_named(tmp_path: Path, text: str, key: str | None, message: str) -> None:
    conf = tmp_path / "conf.yml"
    conf.write_text(text)
    with pytest.raises(EntryError, match=rf"^{conf}: {message}") as raised:
        load_zoo_entry(conf, "CartPole-v1")
    assert (raised.value.file, raised.value.key, raised.value.from_params) == (conf, key, False)
    with pytest.raises(EntryError, match=r"^hyperparameter file not found: .*nope\.yml$"):
        load_zoo_entry(tmp_path / "nope.yml", "CartPole-v1")


def test_an_entry_without_the_zoos_env_keys_says_so() -> None:
    assert load_zoo_entry(default_hyperparams_path(), "CartPole-v1").zoo_settings == {}


# ------------------------------------------------------------------------------------------------ the shipped entries
@pytest.mark.parametrize("env_id", ["CampusNavCity-v0", "CampusNavCity10k-v0"])
def test_the_shipped_city_entries_pass_the_checks_and_bring_their_curriculum(env_id: str) -> None:
    entry = load_zoo_entry(default_hyperparams_path(), env_id)
    assert entry.hyperparams["replay_buffer_class"] is LeanDictReplayBuffer and entry.hyperparams["n_steps"] > 1
    assert entry.hyperparams["route_memory"] == {"explore": "first"}
    assert [type(c).__name__ for c in entry.make_callbacks()] == ["StartCurriculumCallback"]


def test_the_shipped_goal_entry_reads_as_sb3s_her_buffer_and_passes_the_checks() -> None:
    entry = load_zoo_entry(default_hyperparams_path(), GOAL_ENV)
    assert entry.hyperparams["replay_buffer_class"] is HerReplayBuffer
    assert entry.hyperparams["replay_buffer_kwargs"] == {"n_sampled_goal": 4, "goal_selection_strategy": "future"}
    # DCQN's HER buffer's own arguments are accepted for HerReplayBuffer (DCQN serves it with that buffer)
    extra = {**entry.hyperparams["replay_buffer_kwargs"], "terminal_relabels": False, "relabel_tries": 2}
    assert check_params({"replay_buffer_class": HerReplayBuffer, "replay_buffer_kwargs": extra})["replay_buffer_kwargs"]


# ------------------------------------------------------------------------------------------------ the route memory
def test_whether_a_model_wears_the_memory_is_decided_once_by_the_layer() -> None:
    multi = load_zoo_entry(default_hyperparams_path(), "CampusNavMulti-v0")
    single = load_zoo_entry(default_hyperparams_path(), "CampusNav-v0")
    # An entry that names the memory gets DCQN wearing it (off where it says False); one that does not, DCQN itself
    assert multi.algorithm_class() is with_route_memory(DCQN) and single.algorithm_class() is DCQN
    # The model answers whether the memory is on (wears_route_memory), by the layer's reading of the setting: {} (the
    # memory's defaults) is on, as True is; never the setting's truthiness
    for setting, wears in [(True, True), ({}, True), ({"explore": False}, True), (False, False)]:
        model = entry_of(policy="MlpPolicy", route_memory=setting).make_model("CartPole-v1")
        assert model.wears_route_memory is wears and (model.memory is not None) is wears, setting
        assert algorithm_name(model) == ("DCQN + memory" if wears else "DCQN")
    with pytest.raises(EntryError, match=r"route_memory: expected true, false or a mapping of the memory's settings"):
        entry_of(route_memory="yes")
    # The layer's own check, at reading: a misspelt setting is named with the file and the entry, before any model
    with pytest.raises(
        EntryError, match=r"^conf.yml: entry 'CartPole-v1': route_memory: unknown settings \['max_state'\]"
    ):
        entry_of(route_memory={"max_state": 3})


# ------------------------------------------------------------------------------------------------ the checks
def test_bad_replay_buffer_settings_are_named(tmp_path: Path) -> None:
    her = {"policy": "MultiInputPolicy", "replay_buffer_class": "HerReplayBuffer"}
    misspelt = {**her, "replay_buffer_kwargs": {"n_sampled_goals": 4}}
    with pytest.raises(
        EntryError, match=r"entry 'CartPole-v1': replay_buffer_kwargs: unknown key 'n_sampled_goals' .*'n_sampled_goal'"
    ):
        entry_of(**misspelt)
    with pytest.raises(EntryError, match="replay_buffer_class: 'HerReplayBuffer' is not a replay buffer class"):
        check_params({**her, "replay_buffer_class": "'HerReplayBuffer'"})  # a string, not the class
    # The keys are those of the buffer named: DCQN's own buffer does no relabelling
    own = {**her, "replay_buffer_class": "DCQNDictReplayBuffer", "replay_buffer_kwargs": {"n_sampled_goal": 4}}
    with pytest.raises(EntryError, match="replay_buffer_kwargs: unknown key 'n_sampled_goal' of DCQNDictReplayBuffer"):
        entry_of(**own)
    assert DCQNDictReplayBuffer.__name__ in own["replay_buffer_class"]
    # Variants that do not combine are named, both of them, with the entry
    with pytest.raises(EntryError, match=r"replay_buffer_class: n-step returns \(nstep\) does not combine with exp"):
        entry_of(replay_buffer_class=RevisionDictReplayBuffer.__name__, n_steps=3)
    # Every combination's class is a name a YAML entry may give
    conf = tmp_path / "conf.yml"
    conf.write_text(f"{GOAL_ENV}:\n  n_timesteps: 10\n  replay_buffer_class: LeanRevisionHerReplayBuffer\n")
    assert load_zoo_entry(conf, GOAL_ENV).hyperparams["replay_buffer_class"] is LeanRevisionHerReplayBuffer
    conf.write_text(f"{GOAL_ENV}:\n  n_timesteps: 10\n  replay_buffer_class: HerReplayBufer\n")
    with pytest.raises(EntryError, match=r"replay_buffer_class: cannot evaluate 'HerReplayBufer' .*NameError"):
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
        EntryError, match=r"conf.yml: entry 'CampusNav-v0': callback: 'campusnav_env.callbacks.NoSuchCallback'"
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
    conf.write_text("CartPole-v1:\n  n_timesteps: abc\n")
    with pytest.raises(
        EntryError, match=r"conf.yml: entry 'CartPole-v1': n_timesteps: expected a whole number, got 'abc'"
    ):
        load_zoo_entry(conf, "CartPole-v1")
    conf.write_text("CartPole-v1:\n  n_timesteps: 3e4\n")  # YAML 1.1: a string
    with pytest.raises(EntryError, match=r"YAML reads 3e4 as a string: write 30000 or !!float 3e4"):
        load_zoo_entry(conf, "CartPole-v1")
    # n_timesteps of 0 reads (a command line may give the steps), and is refused where it is the budget
    zero = entry_of(n_timesteps=0)
    assert zero.budget(500) == 500
    with pytest.raises(EntryError, match=r"^conf.yml: entry 'CartPole-v1': n_timesteps: expected a positive integer"):
        zero.budget()


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"learning_rat": 0.001}, r"learning_rat: unknown DCQN hyperparameter \(did you mean 'learning_rate'\?\)"),
        ({"policy": "MlpPolicyy"}, r"policy: unknown policy 'MlpPolicyy' \(policies: MlpPolicy, CnnPolicy"),
        ({"policy_kwargs": "dict(net_arc=[8])"}, r"policy_kwargs: unknown key 'net_arc' of DCQNPolicy .*'net_arch'"),
        ({"policy_kwargs": "[8]"}, r"policy_kwargs: expected a mapping, got \[8\]"),
        ({"train_freq": [4, "episodes"]}, r"train_freq: unknown unit 'episodes' .*did you mean 'episode'\?"),
        ({"gradient_steps": -2}, r"gradient_steps: expected a positive integer, or -1 \(as many as env steps\)"),
        ({"seed": 1.5}, r"seed: expected an integer or null, got 1.5"),
        ({"max_grad_norm": 0}, r"max_grad_norm: expected a positive number, got 0"),
        ({"optimize_memory_usage": "no"}, r"optimize_memory_usage: expected true or false, got 'no' \(write false"),
    ],
)
def test_a_bad_algorithm_setting_carries_the_file_entry_key_and_value(settings: dict[str, Any], message: str) -> None:
    settings = {"policy": "MlpPolicy", **settings}
    with pytest.raises(EntryError, match=rf"^conf.yml: entry 'CartPole-v1': {message}") as raised:
        entry_of(**settings)
    key = message.split(":")[0]
    assert (raised.value.file, raised.value.entry, raised.value.key) == (Path("conf.yml"), "CartPole-v1", key)
    evaluated = {"policy_kwargs": eval(str(settings.get("policy_kwargs")), {"dict": dict})}  # the zoo's Python string
    assert raised.value.value == evaluated.get(key, settings[key])
    # The same settings given alone (-params for a loaded model) are named as -params
    with pytest.raises(EntryError, match=rf"^-params {message}"):
        check_params(settings)
