"""RL Zoo integration: `dcqn-zoo` trains and optimises DCQN from a zoo-format YAML file and runs the zoo's commands.

One tiny CartPole run (``dcqn-zoo train``) and one tiny CampusNav run (``dcqn-zoo`` without the command word, cheap
``pixels`` views) are trained once for the module; ``enjoy``, ``record_video`` and ``plot_train`` use them. A third run
trains the goal-conditioned ``CampusNavGoal-v0`` from the shipped entry as it is (``-n`` short, ``--env-kwargs`` with
the ``pixels`` encoder in place of the entry's ``env_kwargs``): the zoo evaluates ``replay_buffer_class:
HerReplayBuffer`` and the ``replay_buffer_kwargs`` string itself and builds DCQN with the env, which DCQN's HER buffer
needs (:mod:`sb3_dcqn.zoo_entry`, tested in ``test_zoo_files.py``, reads the same classes for ``dcqn-campusnav``).
Before the zoo's own ``train`` runs, untouched, ``dcqn-zoo`` reads and checks the entry through that schema.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import re
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml
from stable_baselines3.common.utils import FloatSchedule

pytest.importorskip("rl_zoo3")

from campusnav_env.features.view_build import ViewBuild
from campusnav_env.goal_env import CampusNavGoalEnv
from sb3_dcqn import DCQN
from sb3_dcqn.replay import DCQNHerReplayBuffer
from sb3_dcqn.zoo import COMMANDS, main, register_dcqn
from sb3_dcqn.zoo_files import default_hyperparams_path

TINY = {
    "CartPole-v1": {
        "n_timesteps": 400,
        "policy": "MlpPolicy",
        "learning_starts": 100,
        "buffer_size": 1000,
        "batch_size": 16,
        "train_freq": 4,
        "target_update_interval": 50,
        "policy_kwargs": "dict(net_arch=[16])",
    }
}


# CampusNav with cheap views (pixels encoder) and short episodes; trained without the command word
TINY_CAMPUSNAV = {
    "CampusNav-v0": {
        "n_timesteps": 150,
        "policy": "MultiInputPolicy",
        "env_kwargs": {"encoder": "pixels", "view_build": {"progress": False}, "view_dim": 16, "max_steps": 30},
        "learning_starts": 100,
        "buffer_size": 1000,
        "batch_size": 16,
        "train_freq": 4,
        "target_update_interval": 50,
        "policy_kwargs": "dict(features_extractor_class=EmbeddingFusionExtractor, features_extractor_kwargs="
        "dict(embed_dim=16, features_dim=16), share_features_extractor=True, net_arch=[16], heading_key='heading')",
    }
}
# CampusNavGoal-v0 from the shipped entry: its env_kwargs (view_dim 64) with the cheap encoder, no progress bar
GOAL_ENV = "CampusNavGoal-v0"
GOAL_PIXELS = ["--env-kwargs", "encoder:'pixels'", "view_dim:64", "view_build:{'progress':False}"]
PLOTS_INSTALLED = all(importlib.util.find_spec(name) is not None for name in ("seaborn", "scipy"))


def run_zoo(args: list[str], cwd: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    code = "import sys; from sb3_dcqn.campusnav.zoo import main; main(sys.argv[1:])"  # the dcqn-zoo script
    return subprocess.run(
        [sys.executable, "-c", code, *args],
        cwd=cwd,
        env={**os.environ, **(env or {})},
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )


# Every run's views in the session's feature cache (conftest.py): the campus's views are built once for the module's
# runs (CampusNav-v0 and CampusNavGoal-v0 with pixels share them) and for the other modules'
pytestmark = pytest.mark.usefixtures("shared_feature_cache")


def module_env(root: Path) -> dict[str, str]:
    # Module fixtures run before the autouse function fixtures of conftest: keep SB3's logger in the module's folder;
    # the headless Agg backend for the plot commands
    return {"SB3_LOGDIR": str(root / "sb3-logs"), "MPLBACKEND": "Agg"}


@pytest.fixture(scope="module")
def cartpole_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder whose ``logs/`` holds one tiny DCQN run on CartPole-v1 trained by ``dcqn-zoo train``."""
    root = tmp_path_factory.mktemp("zoo-cartpole")
    (root / "tiny.yml").write_text(yaml.safe_dump(TINY))
    args = ["train", "--algo", "dcqn", "--env", "CartPole-v1", "-conf", "tiny.yml", "-f", "logs", "--eval-freq", "-1"]
    result = run_zoo([*args, "--seed", "0"], root, module_env(root))
    assert result.returncode == 0, result.stderr[-3000:]
    return root


@pytest.fixture(scope="module")
def campusnav_run(tmp_path_factory: pytest.TempPathFactory, shared_feature_cache: Path) -> Path:
    """A folder whose ``logs/`` holds one tiny DCQN run on CampusNav-v0 trained by ``dcqn-zoo`` (no command word)."""
    root = tmp_path_factory.mktemp("zoo-campusnav")
    (root / "tiny.yml").write_text(yaml.safe_dump(TINY_CAMPUSNAV))
    args = ["--algo", "dcqn", "--env", "CampusNav-v0", "-conf", "tiny.yml", "-f", "logs", "--eval-freq", "-1"]
    result = run_zoo([*args, "--seed", "0"], root, module_env(root))
    assert result.returncode == 0, result.stderr[-3000:]
    return root


# ------------------------------------------------------------------------------------------ the shipped CampusNav entry
# As a user runs it: the shipped dcqn.yml, no --env-kwargs (so the entry's own env_kwargs, view_dim 64, make the env;
# any --env-kwargs would replace them) and evaluation on. Few steps, two evaluation episodes.
SHIPPED_EVAL = ["-n", "300", "--eval-freq", "100", "--eval-episodes", "2", "--seed", "0"]


@pytest.fixture(scope="module")
def shipped_campusnav_run(tmp_path_factory: pytest.TempPathFactory, shared_feature_cache: Path) -> tuple[Path, str]:
    """A folder whose ``logs/`` holds a short run of the shipped CampusNav-v0 entry with evaluation; its stdout (its
    EfficientNet views encoded once into the session's feature cache, which the sweep below reads)."""
    root = tmp_path_factory.mktemp("zoo-shipped")
    args = ["train", "--algo", "dcqn", "--env", "CampusNav-v0", "-f", "logs", *SHIPPED_EVAL, "--verbose", "2"]
    result = run_zoo(args, root, module_env(root))
    assert result.returncode == 0, result.stderr[-3000:]
    return root, result.stdout


def test_the_shipped_campusnav_entry_is_evaluated_with_its_own_env_kwargs(
    shipped_campusnav_run: tuple[Path, str],
) -> None:
    root, stdout = shipped_campusnav_run
    assert "eval_env_kwargs={'view_dim': 64}" in stdout  # the entry's, not given on the command line
    evaluations = np.load(root / "logs" / "dcqn" / "CampusNav-v0_1" / "evaluations.npz")
    assert evaluations["timesteps"].tolist() == [100, 200, 300]
    assert evaluations["results"].shape == (3, 2) and np.isfinite(evaluations["results"]).all()
    model = DCQN.load(root / "logs" / "dcqn" / "CampusNav-v0_1" / "CampusNav-v0.zip")
    assert model.observation_space["views"].shape == (4 * 64,)  # four views of view_dim 64


@pytest.mark.skipif(not PLOTS_INSTALLED, reason="the zoo's plots need seaborn and scipy")
def test_all_plots_tabulates_the_evaluations_of_the_shipped_campusnav_run(
    shipped_campusnav_run: tuple[Path, str],
) -> None:
    root, _ = shipped_campusnav_run
    args = ["all_plots", "-a", "dcqn", "-e", "CampusNav-v0", "-f", "logs", "-o", "results", "--no-display"]
    result = run_zoo(args, root, module_env(root))
    assert result.returncode == 0, result.stderr[-3000:]
    assert "|CampusNav-v0|" in result.stdout and (root / "results.pkl").is_file()


def test_a_sweep_of_the_shipped_campusnav_entry_completes_its_trials(tmp_path: Path) -> None:
    storage = tmp_path / "study.log"
    args = ["--algo", "dcqn", "--env", "CampusNav-v0", "-f", "logs", "-optimize", "--storage", str(storage)]
    args += ["--study-name", "shipped", "--n-trials", "2", "--n-jobs", "1", "--sampler", "random", "--pruner", "none"]
    args += ["-n", "300", "--n-evaluations", "1", "--eval-episodes", "2", "--seed", "0"]
    result = run_zoo(args, tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    study = optuna.load_study(study_name="shipped", storage=JournalStorage(JournalFileBackend(str(storage))))
    assert [t.state for t in study.trials] == [optuna.trial.TrialState.COMPLETE] * 2, result.stdout[-3000:]
    # A trial's value is its mean evaluation reward: 200 steps at most, none below -0.01, +1 at the goal
    assert all(-2.0 - 1e-6 <= t.value <= 1.0 for t in study.trials), [t.value for t in study.trials]


def test_campusnav_ids_train_with_one_torch_thread_unless_told_otherwise(
    shipped_campusnav_run: tuple[Path, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from rl_zoo3 import train as zoo_train

    from sb3_dcqn.campusnav.zoo import main as dcqn_zoo

    _, stdout = shipped_campusnav_run
    assert "Setting torch.num_threads to 1" in stdout  # the zoo's own message (--verbose 2): the default arrived
    given: list[list[str]] = []
    monkeypatch.setattr(zoo_train, "train", lambda: given.append(sys.argv[1:]))

    zoo_parser = argparse.ArgumentParser()  # the zoo's train reads --num-threads so (prefixes too; the last wins)
    zoo_parser.add_argument("--num-threads", type=int, default=-1)

    def threads(*args: str) -> int:
        dcqn_zoo(["train", "--algo", "dcqn", *args])
        return zoo_parser.parse_known_args(given.pop())[0].num_threads

    for env_id in ("CampusNav-v0", "CampusNavCity-v0", "campusnav_env:CampusNavGoal-v0"):
        assert threads("--env", env_id) == 1, env_id
    assert threads("--env=CampusNavMulti-v0") == 1
    # The user's own choice is kept, in each of argparse's spellings
    assert threads("--env", "CampusNav-v0", "--num-threads", "4") == 4
    assert threads("--env", "CampusNav-v0", "--num-threads=4") == 4
    assert threads("--env", "CampusNav-v0", "--num-t", "4") == 4
    # Other envs keep torch's default (-1)
    assert threads("--env", "CartPole-v1") == -1
    assert threads() == -1  # the zoo's default env, CartPole-v1


def test_register_adds_dcqn_to_the_zoo_tables() -> None:
    from rl_zoo3 import exp_manager
    from rl_zoo3.hyperparams_opt import HYPERPARAMS_CONVERTER, HYPERPARAMS_SAMPLER
    from rl_zoo3.utils import ALGOS

    register_dcqn()
    assert ALGOS["dcqn"] is DCQN
    assert "dcqn" in HYPERPARAMS_SAMPLER and "dcqn" in HYPERPARAMS_CONVERTER
    assert exp_manager.ALGOS["dcqn"] is DCQN
    assert "EmbeddingFusionExtractor" in vars(exp_manager)


def test_shipped_hyperparams_cover_the_classic_control_envs_and_campusnav() -> None:
    table = yaml.safe_load(default_hyperparams_path().read_text())
    for env_id in ("CartPole-v1", "Acrobot-v1", "LunarLander-v3", "MountainCar-v0", "CampusNav-v0"):
        assert "n_timesteps" in table[env_id], env_id
    assert Path("hyperparams/dcqn.yml").resolve() == default_hyperparams_path().resolve()


def test_dcqn_zoo_trains_and_saves_a_model(cartpole_run: Path, campusnav_run: Path) -> None:
    model_path = cartpole_run / "logs" / "dcqn" / "CartPole-v1_1" / "CartPole-v1.zip"
    assert model_path.is_file()
    assert DCQN.load(model_path).policy.n_critics == 2
    # Without the command word (backwards compatible): train
    assert (campusnav_run / "logs" / "dcqn" / "CampusNav-v0_1" / "CampusNav-v0.zip").is_file()


def test_dcqn_zoo_optimize_writes_the_study_to_a_journal_file(tmp_path: Path) -> None:
    conf = tmp_path / "tiny.yml"
    conf.write_text(yaml.safe_dump(TINY))
    storage = tmp_path / "study.log"
    args = ["--algo", "dcqn", "--env", "CartPole-v1", "-conf", str(conf), "--log-folder", "logs"]
    args += ["-optimize", "--storage", str(storage), "--study-name", "dcqn-test", "--n-trials", "2", "--n-jobs", "1"]
    args += ["-n", "300", "--sampler", "random", "--pruner", "none", "--n-evaluations", "1", "--eval-episodes", "2"]
    result = run_zoo(args, tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    study = optuna.load_study(study_name="dcqn-test", storage=JournalStorage(JournalFileBackend(str(storage))))
    finished = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    assert len(finished) == 2
    assert "Writing report to" in result.stdout


def test_enjoy_runs_the_trained_dcqn_agent(cartpole_run: Path) -> None:
    args = ["enjoy", "--algo", "dcqn", "--env", "CartPole-v1", "-f", "logs", "-n", "200", "--no-render"]
    result = run_zoo(args, cartpole_run, module_env(cartpole_run))
    assert result.returncode == 0, result.stderr[-3000:]
    assert "Loading logs/dcqn/CartPole-v1_1/CartPole-v1.zip" in result.stdout
    assert "Episode Reward:" in result.stdout and "Mean reward:" in result.stdout


@pytest.mark.skipif(importlib.util.find_spec("pygame") is None, reason="CartPole renders with pygame")
def test_record_video_writes_a_video_of_cartpole(cartpole_run: Path, tmp_path: Path) -> None:
    args = ["record_video", "--algo", "dcqn", "--env", "CartPole-v1", "-f", "logs", "-n", "20"]
    result = run_zoo([*args, "-o", str(tmp_path / "videos")], cartpole_run, module_env(cartpole_run))
    assert result.returncode == 0, result.stderr[-3000:]
    videos = list((tmp_path / "videos").glob("final-model-dcqn-CartPole-v1-*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 0


def test_campusnav_agent_plays_and_is_recorded_with_its_saved_env_kwargs(campusnav_run: Path, tmp_path: Path) -> None:
    env = module_env(campusnav_run)
    args = ["enjoy", "--algo", "dcqn", "--env", "CampusNav-v0", "-f", "logs", "-n", "30", "--no-render"]
    result = run_zoo([*args, "--verbose", "2"], campusnav_run, env)
    assert result.returncode == 0, result.stderr[-3000:]
    # The model loads (view_dim 16) and an episode ends within 30 steps (max_steps 30): the config's env_kwargs
    assert "Episode Reward:" in result.stdout
    assert "Setting torch.num_threads to 1" in result.stdout  # one thread by default for the CampusNav ids
    # record_video: the env is made with the saved env_kwargs (view_dim 16), else the model's spaces would not match
    args = ["record_video", "--algo", "dcqn", "--env", "CampusNav-v0", "-f", "logs", "-n", "10"]
    result = run_zoo([*args, "-o", str(tmp_path / "videos")], campusnav_run, env)
    assert result.returncode == 0, result.stderr[-3000:]
    videos = list((tmp_path / "videos").glob("final-model-dcqn-CampusNav-v0-*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 0


@pytest.mark.skipif(not PLOTS_INSTALLED, reason="the zoo's plots need seaborn and scipy")
def test_plot_train_saves_the_training_curve(cartpole_run: Path, tmp_path: Path) -> None:
    figure = tmp_path / "curve.png"
    args = ["plot_train", "-a", "dcqn", "-e", "CartPole-v1", "-f", "logs", "-w", "5", "-o", str(figure)]
    result = run_zoo(args, cartpole_run, module_env(cartpole_run))
    assert result.returncode == 0, result.stderr[-3000:]
    assert figure.read_bytes().startswith(b"\x89PNG")
    assert "No data available" not in result.stdout


@pytest.mark.skipif(PLOTS_INSTALLED, reason="seaborn and scipy are installed")
def test_plot_commands_name_the_missing_plot_packages(cartpole_run: Path, tmp_path: Path) -> None:
    args = ["plot_train", "-a", "dcqn", "-e", "CartPole-v1", "-f", "logs", "-o", str(tmp_path / "curve.png")]
    result = run_zoo(args, cartpole_run, module_env(cartpole_run))
    assert result.returncode == 1
    assert "pip install seaborn scipy" in result.stderr


def test_unknown_command_exits_with_code_2_and_lists_the_commands(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["enjoi", "--algo", "dcqn"])
    assert exit_info.value.code == 2
    error = capsys.readouterr().err
    assert "unknown command 'enjoi'" in error
    assert all(command in error for command in ("train", "enjoy", "record_video", "plot_train", "all_plots"))


def test_help_lists_the_commands_and_the_train_options(capsys: pytest.CaptureFixture[str]) -> None:
    argv = list(sys.argv)
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0
    assert sys.argv == argv
    out = capsys.readouterr().out
    assert all(command in out for command in COMMANDS)
    assert "usage: dcqn-zoo [-h]" in out and "--algo" in out and "dcqn" in out  # the zoo's train help
    with pytest.raises(SystemExit) as exit_info:
        main([])
    assert exit_info.value.code == 2


# ------------------------------------------------------------------------------------------------ goal env (HER)
@pytest.fixture(scope="module")
def goal_run(tmp_path_factory: pytest.TempPathFactory, shared_feature_cache: Path) -> Path:
    """A folder whose ``logs/`` holds a DCQN run on CampusNavGoal-v0 from the shipped entry, 1500 steps."""
    root = tmp_path_factory.mktemp("zoo-goal")
    args = ["--algo", "dcqn", "--env", GOAL_ENV, "-conf", str(default_hyperparams_path()), "-n", "1500"]
    args += ["-f", "logs", "--eval-freq", "-1", "--seed", "0", "--num-threads", "1", *GOAL_PIXELS]
    result = run_zoo(args, root, module_env(root))
    assert result.returncode == 0, result.stderr[-3000:]
    return root


def test_dcqn_zoo_trains_the_goal_env_from_the_shipped_entry_with_hindsight_relabelling(
    goal_run: Path, shared_feature_cache: Path
) -> None:
    run = goal_run / "logs" / "dcqn" / f"{GOAL_ENV}_1"
    config = dict(yaml.load((run / GOAL_ENV / "config.yml").read_text(), Loader=yaml.UnsafeLoader))
    assert config["replay_buffer_class"] == "HerReplayBuffer" and config["env_kwargs"]["encoder"] == "pixels"
    env_kwargs = config["env_kwargs"]
    run_cache = ViewBuild.of(env_kwargs["view_build"], cache_dir=shared_feature_cache)  # the session's feature cache
    env = CampusNavGoalEnv(**{**env_kwargs, "view_build": run_cache})
    model = DCQN.load(run / f"{GOAL_ENV}.zip", env=env)  # SB3's HER buffer is built with the env
    assert isinstance(model.replay_buffer, DCQNHerReplayBuffer) and model.replay_buffer.n_sampled_goal == 4
    assert model.num_timesteps == 1500 and model._n_updates > 0


def test_enjoy_plays_the_goal_env_agent(goal_run: Path) -> None:
    args = ["enjoy", "--algo", "dcqn", "--env", GOAL_ENV, "-f", "logs", "-n", "20", "--no-render"]
    result = run_zoo(args, goal_run, module_env(goal_run))
    assert result.returncode == 0, result.stderr[-3000:]
    assert f"Loading logs/dcqn/{GOAL_ENV}_1/{GOAL_ENV}.zip" in result.stdout


def test_enjoy_loads_a_model_that_wears_the_memory_as_the_class_that_wears_it(
    goal_run: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The shipped goal entry asks for the route memory: DCQN.load would drop it and play the critics alone
    from rl_zoo3 import enjoy
    from rl_zoo3.utils import ALGOS

    from sb3_dcqn.route_memory import with_route_memory

    loaded: list[type] = []
    monkeypatch.setattr(enjoy, "enjoy", lambda: loaded.append(ALGOS["dcqn"]))
    main(["enjoy", "--algo", "dcqn", "--env", GOAL_ENV, "-f", str(goal_run / "logs"), "-n", "20", "--no-render"])
    assert loaded == [with_route_memory(DCQN)]


# ------------------------------------------------------------------------------------------------ bad input
# Bad input is one line on stderr, exit 2, before any folder exists; a failed run leaves no empty folders
FAILING_CALLBACK = """
from stable_baselines3.common.callbacks import BaseCallback


class FailAt(BaseCallback):
    def __init__(self, step: int) -> None:
        super().__init__()
        self.step = step

    def _on_step(self) -> bool:
        if self.num_timesteps >= self.step:
            raise RuntimeError("the callback failed")
        return True
"""


def write_tiny(path: Path, **changes: object) -> Path:
    path.write_text(yaml.safe_dump({"CartPole-v1": {**TINY["CartPole-v1"], **changes}}))
    return path


def zoo_train(conf: Path, logs: Path, *more: str) -> None:
    args = ["--algo", "dcqn", "--env", "CartPole-v1", "-conf", str(conf), "-f", str(logs), "--eval-freq", "-1"]
    main(["train", *args, *more])


def one_error_line(capsys: pytest.CaptureFixture[str]) -> str:
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "Traceback" not in error, error
    return error.strip()


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"learning_rat": 0.001}, r"learning_rat: unknown DCQN hyperparameter \(did you mean 'learning_rate'\?\)"),
        ({"batch_size": "64"}, r"batch_size: expected a positive integer, got '64'"),
        ({"learning_rate": "lin_1e-3x"}, r"learning_rate: expected a linear schedule lin_<initial value>"),
        ({"train_freq": [4, "episodes"]}, r"train_freq: unknown unit 'episodes' .*did you mean 'episode'"),
        ({"policy_kwargs": "dict(net_arch=[16]"}, r"policy_kwargs: cannot evaluate 'dict\(net_arch=\[16\]'"),
        ({"policy_kwargs": "dict(net_arch='abc')"}, r"TypeError: "),  # found by the model's constructor
    ],
)
def test_a_bad_entry_is_one_line_naming_the_file_the_entry_and_the_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], changes: dict, message: str
) -> None:
    conf = write_tiny(tmp_path / "tiny.yml", **changes)
    with pytest.raises(SystemExit) as exit_info:
        zoo_train(conf, tmp_path / "logs")
    assert exit_info.value.code == 2
    assert re.match(
        rf"dcqn-zoo train: error: {re.escape(str(conf))}: entry 'CartPole-v1': {message}", one_error_line(capsys)
    )
    assert not (tmp_path / "logs").exists()  # the constructor's failure too: its run folder is removed


def test_malformed_yaml_a_missing_entry_and_an_unknown_env_are_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    conf = tmp_path / "bad.yml"
    conf.write_text("CartPole-v1:\n  n_timesteps: 200\n  policy: [MlpPolicy\n")
    for env_id, conf_text, message in [
        ("CartPole-v1", conf.read_text(), rf"{re.escape(str(conf))}: not valid YAML \(line 4, column 1: "),
        ("Acrobot-v1", "CartPole-v1:\n  n_timesteps: 200\n", rf"{re.escape(str(conf))}: no entry for 'Acrobot-v1'"),
        ("CartPol-v1", "CartPole-v1:\n  n_timesteps: 200\n", r"ValueError: CartPol-v1 not found .*CartPole-v1"),
    ]:
        conf.write_text(conf_text)
        with pytest.raises(SystemExit) as exit_info:
            main(["train", "--algo", "dcqn", "--env", env_id, "-conf", str(conf), "-f", str(tmp_path / "logs")])
        assert exit_info.value.code == 2
        assert re.match(rf"dcqn-zoo train: error: {message}", one_error_line(capsys)), env_id
    assert not (tmp_path / "logs").exists()


def test_a_bad_params_override_is_one_line_naming_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    conf, logs = write_tiny(tmp_path / "tiny.yml"), tmp_path / "logs"
    for params, message in [
        (["batch_siz:32"], r": error: -params batch_siz: unknown DCQN hyperparameter \(did you mean 'batch_size'"),
        (["learning_rate:'lin_x'"], r": error: -params learning_rate: expected a linear schedule lin_"),
        (["learning_rate:1/0"], r": error: -params learning_rate: cannot evaluate '1/0' \(ZeroDivisionError: "),
        (["learning_rate"], r": error: -params learning_rate: expected key:value"),
    ]:
        with pytest.raises(SystemExit) as exit_info:
            zoo_train(conf, logs, "-params", *params)
        assert exit_info.value.code == 2
        assert re.search(message, one_error_line(capsys)), params
    assert not logs.exists()


def test_the_zoo_trains_with_its_own_experiment_manager_and_the_entrys_eval_env_kwargs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from rl_zoo3 import train as train_module
    from rl_zoo3.exp_manager import ExperimentManager

    methods = dict(vars(ExperimentManager))
    ran: list[tuple[bool, list[str]]] = []
    monkeypatch.setattr(train_module, "train", lambda: ran.append((dict(vars(ExperimentManager)) == methods, sys.argv)))
    conf = write_tiny(tmp_path / "tiny.yml", env_kwargs={"sutton_barto_reward": True})
    zoo_train(conf, tmp_path / "logs")
    ((untouched, argv),) = ran
    assert untouched  # no method of the zoo's replaced: dcqn-zoo checked the entry before the zoo ran
    # The evaluation envs get the entry's env_kwargs (the zoo gives them only --env-kwargs), as the zoo reads them
    assert argv[-2:] == ["--eval-env-kwargs", "sutton_barto_reward:True"]
    zoo_train(conf, tmp_path / "logs", "--env-kwargs", "sutton_barto_reward:False")  # given: the zoo's own rule
    assert "--eval-env-kwargs" not in ran[-1][1]


def test_dcqn_zoo_reports_a_bad_entry_in_one_line_as_a_command(tmp_path: Path) -> None:
    write_tiny(tmp_path / "tiny.yml", learning_rat=0.001)
    result = run_zoo(["train", "--algo", "dcqn", "--env", "CartPole-v1", "-conf", "tiny.yml"], tmp_path)
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert "tiny.yml: entry 'CartPole-v1': learning_rat: unknown DCQN hyperparameter" in result.stderr
    assert not (tmp_path / "logs").exists()


@pytest.mark.parametrize(
    "command",
    [
        ["train", "-n", "-5"],
        ["train", "--n-timesteps=0"],
        ["train", "--n-ti", "-1"],
        ["train", "-n-5"],
        ["train", "-n", "abc"],
        ["enjoy", "-n", "0"],
    ],
)
def test_a_budget_that_is_not_a_positive_number_of_steps_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: list[str]
) -> None:
    # The zoo reads -n <= 0 as "not given" and would train the entry's n_timesteps
    conf = write_tiny(tmp_path / "tiny.yml")
    with pytest.raises(SystemExit) as exit_info:
        main([*command, "--algo", "dcqn", "--env", "CartPole-v1", "-conf", str(conf), "-f", str(tmp_path / "logs")])
    assert exit_info.value.code == 2
    assert "-n/--n-timesteps: expected a positive number of steps, got " in one_error_line(capsys)
    assert not (tmp_path / "logs").exists()


def without_the_zoo(args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    code = "import sys; sys.modules['rl_zoo3'] = None; from sb3_dcqn.campusnav.zoo import main; main(sys.argv[1:])"
    return subprocess.run(
        [sys.executable, "-c", code, *args], cwd=cwd, capture_output=True, text=True, timeout=300, check=False
    )


def test_without_the_zoo_extra_a_dcqn_zoo_command_says_in_one_line_how_to_install_it(tmp_path: Path) -> None:
    result = without_the_zoo(["train", "--algo", "dcqn", "--env", "CartPole-v1"], tmp_path)
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.count("\n") == 1 and 'pip install "sb3-dcqn[zoo]"' in result.stderr, result.stderr


def test_without_the_zoo_extra_dcqn_zoo_help_shows_the_commands_and_how_to_install_it(tmp_path: Path) -> None:
    result = without_the_zoo(["--help"], tmp_path)
    assert result.returncode == 0 and result.stderr == "", result.stderr
    assert result.stdout.startswith("usage: dcqn-zoo") and "record_video" in result.stdout
    assert result.stdout.rstrip().endswith('pip install "sb3-dcqn[zoo]"')


def test_without_the_zoo_extra_main_reads_the_arguments_it_is_given(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # sb3_dcqn.zoo.main(argv) called from Python: its own argv decides help (exit 0) or not, never sys.argv's
    monkeypatch.setitem(sys.modules, "rl_zoo3", None)
    monkeypatch.setattr(sys, "argv", ["python", "train", "--algo", "dcqn"])
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0 and capsys.readouterr().out.startswith("usage: dcqn-zoo")
    monkeypatch.setattr(sys, "argv", ["python", "--help"])
    with pytest.raises(SystemExit) as exit_info:
        main(["train", "--algo", "dcqn"])
    assert exit_info.value.code == 2 and 'pip install "sb3-dcqn[zoo]"' in capsys.readouterr().err


def test_the_zoo_extra_declares_what_the_zoos_enjoy_imports_undeclared() -> None:
    # rl_zoo3 2.9's enjoy imports its Hub download, which imports requests (not among rl_zoo3's requirements): the
    # zoo extra declares it, so that enjoy imports as it is (no stand-in module)
    import importlib.metadata

    zoo_requires = importlib.metadata.requires("rl_zoo3") or []
    assert not any(re.match(r"requests\b", requirement) for requirement in zoo_requires)
    extra = re.search(r"^zoo = \[(.*)\]$", Path("pyproject.toml").read_text(), re.MULTILINE)  # tomllib: 3.11+
    assert extra is not None and re.search(r'"requests\b', extra.group(1)), extra
    import rl_zoo3.enjoy
    import rl_zoo3.load_from_hub

    assert rl_zoo3.load_from_hub.__file__ is not None and callable(rl_zoo3.enjoy.enjoy)


def test_a_failed_run_leaves_no_folder_unless_it_wrote_results(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "failing_callback.py").write_text(FAILING_CALLBACK)
    monkeypatch.syspath_prepend(str(tmp_path))
    logs, conf = tmp_path / "logs", tmp_path / "tiny.yml"

    def train_failing_at(step: int) -> None:
        write_tiny(conf, callback=[{"failing_callback.FailAt": {"step": step}}])
        with pytest.raises(RuntimeError, match="the callback failed"):  # a failure while training is not bad input
            zoo_train(conf, logs)

    train_failing_at(1)  # before any episode ended: nothing worth keeping, nor the log folders made for it
    assert not logs.exists()
    train_failing_at(300)  # after some episodes: their monitor log is kept
    assert sorted(p.name for p in (logs / "dcqn").iterdir()) == ["CartPole-v1_1"]
    train_failing_at(1)  # the second run's folder goes, the first run's and the log folders stay
    assert sorted(p.name for p in (logs / "dcqn").iterdir()) == ["CartPole-v1_1"]


def test_a_lin_schedule_trains_under_dcqn_zoo(tmp_path: Path) -> None:
    conf = write_tiny(tmp_path / "tiny.yml", learning_rate="lin_1e-3")
    zoo_train(conf, tmp_path / "logs", "-n", "200", "--seed", "0")
    model = DCQN.load(tmp_path / "logs" / "dcqn" / "CartPole-v1_1" / "CartPole-v1.zip")
    assert model.num_timesteps == 200 and model.lr_schedule(0.5) == pytest.approx(5e-4)


def test_ctrl_c_before_the_zoo_catches_it_exits_with_130_and_one_line(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from rl_zoo3 import train as zoo_train

    def interrupted() -> None:  # e.g. while CampusNav encodes its views, before training starts
        raise KeyboardInterrupt

    monkeypatch.setattr(zoo_train, "train", interrupted)
    with pytest.raises(SystemExit) as exit_info:
        main(["train", "--algo", "dcqn", "--env", "CartPole-v1"])
    assert exit_info.value.code == 130
    assert capsys.readouterr().err.strip() == "dcqn-zoo train: interrupted"


@pytest.mark.parametrize(
    ("command", "folder", "message"),
    [
        (["enjoy", "--no-render"], "nowhere", "The nowhere/dcqn folder was not found"),
        (
            ["enjoy", "--no-render"],
            None,
            "The rl-trained-agents/dcqn folder was not found",
        ),  # the zoo's default: no download
        (
            ["record_video"],
            "logs",
            "No model found for dcqn on CartPole-v1, path: logs/dcqn/CartPole-v1_1/CartPole-v1.zip",
        ),
    ],
)
def test_a_log_folder_without_the_agent_is_one_line(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    command: list[str],
    folder: str | None,
    message: str,
) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "logs" / "dcqn" / "CartPole-v1_1").mkdir(parents=True)  # a run folder without its model
    args = [*command, "--algo", "dcqn", "--env", "CartPole-v1", "-n", "10", *(["-f", folder] if folder else [])]
    with pytest.raises(SystemExit) as exit_info:
        main(args)
    assert exit_info.value.code == 2
    assert (
        one_error_line(capsys)
        == f"dcqn-zoo {command[0]}: error: {message} (-f names the log folder of the trained agents)"
    )


# ------------------------------------------------------------------------------------------------ -params
# The same -params items, and what both command lines make of each: a value as the zoo reads it (Python), and one that
# Python cannot read (a bare word) as YAML reads it
PARAMS = [
    ("learning_rate:lin_1e-3", "learning_rate", (1e-3, 5e-4)),  # a bare word: the zoo's schedule string, via YAML
    ("learning_rate:'lin_1e-3'", "learning_rate", (1e-3, 5e-4)),
    ("learning_rate:1e-3", "learning_rate", (1e-3, 1e-3)),  # Python's float (YAML 1.1 would read a string)
    ("batch_size:32", "batch_size", (32, 32)),
    ("train_freq:[2, step]", "train_freq", (2, "step")),
    ("train_freq:(2, 'episode')", "train_freq", (2, "episode")),
    ("optimize_memory_usage:false", "optimize_memory_usage", False),
    ("optimize_memory_usage:False", "optimize_memory_usage", False),
    ("policy:MlpPolicy", "policy", "MlpPolicy"),
    (
        "policy_kwargs:dict(net_arch=[8], activation_fn=nn.Tanh)",
        "policy_kwargs",
        {"net_arch": [8], "activation_fn": "Tanh"},
    ),
    ("policy_kwargs:{net_arch: [8]}", "policy_kwargs", {"net_arch": [8]}),
]


def as_built(value: object) -> object:
    """A value as the tests compare it: a learning rate by its values at the start and half way (SB3 makes a number
    the constant schedule the zoo makes), a class by its name."""
    if isinstance(value, float | int | Callable) and not isinstance(value, type | bool):
        schedule = FloatSchedule(value)
        return (round(schedule(1.0), 12), round(schedule(0.5), 12))
    if isinstance(value, dict):
        return {key: as_built(item) for key, item in value.items()}
    return value.__name__ if isinstance(value, type) else value


@pytest.mark.parametrize(("item", "key", "expected"), PARAMS, ids=[item for item, _, _ in PARAMS])
def test_params_mean_the_same_in_dcqn_campusnav_and_dcqn_zoo(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, item: str, key: str, expected: object
) -> None:
    from rl_zoo3 import train as train_module
    from rl_zoo3.exp_manager import ExperimentManager
    from rl_zoo3.utils import StoreDict

    from sb3_dcqn.campusnav.cli import build_parser
    from sb3_dcqn.campusnav.entries import conf_entry
    from sb3_dcqn.campusnav.requests import Request

    conf = write_tiny(tmp_path / "tiny.yml")
    # dcqn-campusnav: its parser and the entry its subcommands train with
    request = Request.from_args(build_parser().parse_args(["train", "--conf", str(conf), "-params", item]))
    campusnav = conf_entry(request.conf, "CartPole-v1", request.params).hyperparams[key]
    # dcqn-zoo: the command line the zoo's train is given, read by the zoo's own StoreDict and experiment manager
    given: list[list[str]] = []
    monkeypatch.setattr(train_module, "train", lambda: given.append(list(sys.argv)))
    zoo_train(conf, tmp_path / "logs", "-params", item)
    parser = argparse.ArgumentParser()
    parser.add_argument("-params", "--hyperparams", nargs="+", action=StoreDict)
    overrides = parser.parse_known_args(given[0][1:])[0].hyperparams
    manager = ExperimentManager(argparse.Namespace(), "dcqn", "CartPole-v1", str(tmp_path / "logs"), config=str(conf))
    manager.custom_hyperparams = overrides
    zoo = manager._preprocess_hyperparams(manager.read_hyperparameters()[0])[0][key]
    if key == "train_freq":
        zoo = tuple(zoo)
    assert as_built(campusnav) == as_built(zoo) == expected
