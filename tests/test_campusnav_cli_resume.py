"""The flags an SB3 / RL Zoo user expects of ``dcqn-campusnav``, spelt as the RL Zoo spells them.

``train -i MODEL`` (``--trained-agent``) goes on training a saved run with its levers, callbacks, replay buffer and
the roads closed when it was saved (in force, not closed again), in a folder of its own; ``--save-freq N`` writes
checkpoints that ``-i`` goes on from; ``-params key:value`` overrides the entry's hyperparameters, checked as the
YAML's keys are; ``--device`` picks torch's device; ``--version`` says the package's version. A replay buffer file is
as large as what the buffer stores, and loads back whole with SB3's ``load_replay_buffer``. The built-in campus with
the cheap ``pixels`` encoder on 64 x 48 views and a few hundred steps.
"""

from __future__ import annotations

import json
from importlib.metadata import version
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_runs_support import FAST, ROAD, TINY_CONF, cli
from stable_baselines3.common.callbacks import BaseCallback

from sb3_dcqn import DCQN
from sb3_dcqn.campusnav import experiments
from sb3_dcqn.campusnav.cli import main

# The session's feature cache: the views are rendered and encoded once, not once per test or module (conftest.py)
pytestmark = pytest.mark.usefixtures("shared_feature_cache")


def fails(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """Run the command line, expect exit status 2 and one line on stderr; return it."""
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "Traceback" not in error, error
    return error


class _Spy:
    """Wraps ``train_with_closures``: records the callbacks and the closure plan of each run."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.calls: list[dict[str, Any]] = []
        self._original = experiments.train_with_closures
        monkeypatch.setattr(experiments, "train_with_closures", self)

    def __call__(self, model: Any, plan: Any, *, callbacks: list[BaseCallback], **kwargs: Any) -> Any:
        self.calls.append({"callbacks": list(callbacks), "plan": plan, **kwargs})
        return self._original(model, plan, callbacks=callbacks, **kwargs)


# ------------------------------------------------------------------------------------------------ train -i
def test_train_i_goes_on_with_the_saved_levers_callbacks_closures_and_buffer_in_a_folder_of_its_own(
    tmp_path: Path, conf: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "runs" / "fixed"
    cli(
        "train", *FAST, "--conf", str(conf), "--levers", "boost", "--close", *map(str, ROAD), "--close-at", "100",
        *("--timesteps", "200", "--eval-freq", "100", "--keep-training", "--out", str(out)),
    )  # fmt: skip
    model = out / "dcqn_campusnav.zip"
    first = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    capsys.readouterr()

    spy = _Spy(monkeypatch)
    summary = cli("train", "-i", str(model), *FAST[-1:], "--timesteps", "100", "--eval-freq", "50", "--keep-training")
    resumed = tmp_path / "runs" / "fixed_2"  # the model's folder holds results: the next numbered one
    error = capsys.readouterr().err
    assert f"writing to {resumed}" in error and "closed again: 14-15" in error
    assert "replay buffer: " in error and "(200 transitions)" in error
    assert summary["num_timesteps"] == 300 and summary["resumed_from"] == str(model)
    assert summary["closures"] == [] and summary["levers"] == ["boost"]  # the saved closure is not closed again
    (call,) = spy.calls
    assert call["plan"].empty and call["budget"] == 100
    assert sorted(type(c).__name__ for c in call["callbacks"]) == ["AdaptationBoost", "StartCurriculumCallback"]
    saved = json.loads((resumed / "dcqn_campusnav.env.json").read_text())
    assert saved["closed_roads_at_save"] == [list(ROAD)] and saved["num_timesteps"] == 300
    assert DCQN.load(resumed / "dcqn_campusnav.zip").num_timesteps == 300
    # The resumed buffer holds the saved transitions and the new ones
    again = DCQN.load(resumed / "dcqn_campusnav.zip")
    again.load_replay_buffer(resumed / "dcqn_campusnav_replay_buffer.pkl")
    assert again.replay_buffer is not None and again.replay_buffer.size() == 300
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == first  # the first run kept whole
    # Going on from the resumed run: the next number, runs/fixed_3
    third = cli("train", "-i", str(resumed / "dcqn_campusnav.zip"), *FAST[-1:], "-n", "20", "--eval-freq", "20")
    assert third["files"]["model"] == str(tmp_path / "runs" / "fixed_3" / "dcqn_campusnav.zip")


def test_save_freq_writes_checkpoints_that_train_i_goes_on_from(tmp_path: Path, conf: Path) -> None:
    out = tmp_path / "run"
    cli(
        "train", *FAST, "--conf", str(conf), "--save-freq", "100", "--timesteps", "300", "--eval-freq", "300",
        *("--keep-training", "--out", str(out)),
    )  # fmt: skip
    checkpoints = out / "checkpoints"
    names = sorted(p.name for p in checkpoints.glob("*.zip"))
    assert names == [f"dcqn_campusnav_{n}_steps.zip" for n in (100, 200, 300)]
    middle = checkpoints / "dcqn_campusnav_200_steps.zip"
    assert json.loads(middle.with_suffix(".env.json").read_text())["num_timesteps"] == 200
    assert (checkpoints / "dcqn_campusnav_200_steps_replay_buffer.pkl").is_file()
    summary = cli("train", "-i", str(middle), *FAST[-1:], "-n", "48", "--eval-freq", "48", "--keep-training")
    assert summary["num_timesteps"] == 248 and summary["files"]["model"] == str(
        tmp_path / "run_2" / "dcqn_campusnav.zip"
    )


# ------------------------------------------------------------------------------------------------ -params, --device
def test_params_override_the_entry_and_device_picks_torchs_device(tmp_path: Path, conf: Path) -> None:
    out = tmp_path / "run"
    cli(
        "train", *FAST, "--conf", str(conf), "--timesteps", "100", "--eval-freq", "100", "--device", "cpu",
        *("-params", "learning_rate:0.005", "batch_size:16", "train_freq:[2, step]", "--out", str(out)),
    )  # fmt: skip
    model = DCQN.load(out / "dcqn_campusnav.zip")
    assert model.learning_rate == pytest.approx(0.005) and model.batch_size == 16
    assert model.train_freq.frequency == 2 and model.device.type == "cpu"
    # A loaded model goes on with -params that do not change what it was built with
    summary = cli(
        "train", "-i", str(out / "dcqn_campusnav.zip"), *FAST[-1:], "--timesteps", "50", "-params", "gamma:0.9"
    )
    assert DCQN.load(summary["files"]["model"]).gamma == pytest.approx(0.9)


def test_params_read_schedules_as_the_zoo_reads_them(tmp_path: Path, conf: Path) -> None:
    out = tmp_path / "run"
    cli("train", *FAST, "--conf", str(conf), "--timesteps", "100", "--eval-freq", "100",
        *("-params", "learning_rate:lin_0.004", "--out", str(out)))  # fmt: skip
    model = DCQN.load(out / "dcqn_campusnav.zip")
    assert model.lr_schedule(1.0) == pytest.approx(0.004) and model.lr_schedule(0.25) == pytest.approx(0.001)


@pytest.mark.parametrize(
    ("params", "message"),
    [
        (["learnig_rate:0.1"], "-params learnig_rate: unknown DCQN hyperparameter (did you mean 'learning_rate'?)"),
        (["batch_size:-3"], "-params batch_size: expected a positive integer, got -3"),
        (["gamma:1.5"], "-params gamma: expected a number in [0, 1], got 1.5"),
        (["n_timesteps:0"], "-params n_timesteps: expected a positive integer, got 0"),
        (["learning_rate"], "-params learning_rate: expected key:value"),
        (["learning_rate:lin_x"], "-params learning_rate: expected a linear schedule lin_<initial value>"),
        (["normalize:true"], "-params normalize: not applied by dcqn-campusnav (VecNormalize: "),
    ],
)
def test_bad_params_are_one_line_naming_the_key(
    tmp_path: Path, conf: Path, params: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    error = fails(["train", *FAST, "--conf", str(conf), "--out", str(out), "-params", *params], capsys)
    assert message in error
    assert not out.exists()


def test_a_bad_device_and_params_a_loaded_model_was_built_with_are_refused(
    tmp_path: Path, conf: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    error = fails(["train", *FAST, "--conf", str(conf), "--device", "cuad", "--out", str(tmp_path / "out")], capsys)
    assert "--device: unknown device 'cuad'" in error and "did you mean 'cuda'?" in error
    out = tmp_path / "run"
    cli("train", *FAST, "--conf", str(conf), "--timesteps", "100", "--eval-freq", "100", "--out", str(out))
    capsys.readouterr()
    error = fails(["train", "-i", str(out / "dcqn_campusnav.zip"), "-params", "buffer_size:10"], capsys)
    assert "-params buffer_size: set when a model is built" in error
    assert not (tmp_path / "run_2").exists()


@pytest.mark.parametrize("flag", [["--open-map"], ["--replay-buffer", "buffer.pkl"]])
def test_flags_of_a_saved_run_need_i(flag: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    error = fails(["train", *FAST, *flag, "--out", str(tmp_path / "out")], capsys)
    assert f"{flag[0]}: only with -i MODEL" in error and not (tmp_path / "out").exists()


def test_version_says_the_packages_version(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out == f"dcqn-campusnav {version('sb3-dcqn')}\n"


# ------------------------------------------------------------------------------------------------ replay buffer file
def test_a_replay_buffer_file_is_as_large_as_what_it_stores_and_loads_back_whole(tmp_path: Path) -> None:
    # The shipped CampusNav-v0 entry's buffer (50,000 transitions, 64-dimensional views) after 1,500 steps: 207 MB
    # as SB3 saves it
    conf = tmp_path / "shipped.yml"
    conf.write_text(
        TINY_CONF.replace("view_dim: 16", "view_dim: 64").replace("buffer_size: 2000", "buffer_size: 50000")
    )
    out = tmp_path / "run"
    cli("train", *FAST, "--conf", str(conf), "--timesteps", "1500", "--eval-freq", "1500", "--out", str(out))
    buffer_file = out / "dcqn_campusnav_replay_buffer.pkl"
    assert buffer_file.stat().st_size <= 2_000_000
    model = DCQN.load(out / "dcqn_campusnav.zip")
    model.load_replay_buffer(buffer_file)  # SB3's own loader
    buffer = model.replay_buffer
    assert buffer is not None and buffer.buffer_size == 50_000 and buffer.pos == 1500 and not buffer.full
    assert buffer.observations["views"].shape == (50_000, 1, 4 * 64)
    # The slots not yet stored are as SB3 made them: zeros
    assert not np.any(buffer.observations["views"][1500:]) and not np.any(buffer.actions[1500:])
    assert np.any(buffer.observations["views"][:1500])
