"""RL Zoo integration: `dcqn-zoo` trains and optimises DCQN from a zoo-format YAML file."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

pytest.importorskip("rl_zoo3")

from sb3_dcqn import DCQN
from sb3_dcqn.zoo import default_hyperparams_path, register_dcqn

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


def run_zoo(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    code = "import sys; from sb3_dcqn.zoo import main; main(sys.argv[1:])"
    return subprocess.run(
        [sys.executable, "-c", code, *args], cwd=cwd, capture_output=True, text=True, timeout=600, check=False
    )


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


def test_dcqn_zoo_trains_and_saves_a_model(tmp_path: Path) -> None:
    conf = tmp_path / "tiny.yml"
    conf.write_text(yaml.safe_dump(TINY))
    result = run_zoo(
        ["--algo", "dcqn", "--env", "CartPole-v1", "-conf", str(conf), "--log-folder", "logs", "--eval-freq", "-1"],
        tmp_path,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    model_path = tmp_path / "logs" / "dcqn" / "CartPole-v1_1" / "CartPole-v1.zip"
    assert model_path.is_file()
    assert DCQN.load(model_path).policy.n_critics == 2


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
